//! Euler integration of the B-P law along a prescribed strain history.
//!
//! The state (τ, Wᴵ) evolves by τ̇ = G (γ̇ − γ̇ᴵ), Ẇᴵ = τ γ̇ᴵ, with γ(t) given at
//! the sample times of a record and linear in between. The law is stiff after
//! yield, with local stiffness λ = G ∂γ̇ᴵ/∂τ: an explicit step with λh > 2
//! oscillates and then explodes. Two schemes cope with that:
//!
//! * [`Scheme::Explicit`], the paper's method, takes sub-steps short enough
//!   that λh stays below [`Integrator::stability`] (1 by default: the stress
//!   then relaxes without overshoot);
//! * [`Scheme::LinearlyImplicit`] treats the flow term implicitly to first
//!   order, τ ← τ + hG(γ̇ − γ̇ᴵ)/(1 + hλ), stable for any h at the price of one
//!   division.
//!
//! Both are first order; [`Integrator::extrapolate`] combines two Euler
//! solutions into a second-order one. The integrator never returns a
//! silently wrong curve: non-finite values or a step count past
//! [`Integrator::max_substeps`] are an [`IntegrationError`], which a
//! posterior turns into log-density −∞.
//!
//! The loop runs [`LANES`] parameter sets at once, one per SIMD lane
//! ([`super::lanes`]): a likelihood integrates several walkers together,
//! and a single integration uses one lane. Lanes never interact, so a
//! parameter set gives the same bits whichever lane it runs in and whatever
//! runs beside it. The loop is compiled for any CPU and, where the CPU has
//! it, for AVX2, with identical results ([`super::simd`]).

use super::lanes::{LaneLaw, LANES};
use super::params::Params;
use super::simd::{F64xN, Portable};

/// Largest change of τ in one sub-step, as a share of (R + D)/√3.
const MAX_STRESS_STEP: f64 = 0.25;
const INV_SQRT_3: f64 = 0.577_350_269_189_625_8;

/// Time-stepping scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Scheme {
    /// Explicit Euler with stability-limited sub-steps.
    Explicit,
    /// Linearly implicit (Rosenbrock-Euler) step in τ.
    LinearlyImplicit,
}

/// The integrator's settings. `Default` gives explicit Euler with at least
/// one step per sample interval.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Integrator {
    pub scheme: Scheme,
    /// Minimum number of equal sub-steps per sample interval (the knob that
    /// halves the step in a convergence study).
    pub substeps: u32,
    /// Largest λh an explicit step may take (stability needs < 2).
    pub stability: f64,
    /// Most sub-steps allowed in one sample interval before giving up.
    pub max_substeps: u32,
    /// Richardson extrapolation: run Euler twice, with `substeps` and with
    /// twice as many, and report 2 x_{h/2} − x_h at every sample. Both runs
    /// are plain Euler with every control above; their combination cancels
    /// the O(h) error term, so the result is second order at three Euler
    /// steps per `substeps`.
    pub extrapolate: bool,
}

impl Default for Integrator {
    fn default() -> Self {
        Integrator {
            scheme: Scheme::Explicit,
            substeps: 1,
            stability: 1.0,
            max_substeps: 1000,
            extrapolate: false,
        }
    }
}

/// The integrated state: shear stress τ (Pa) and inelastic work Wᴵ (Pa).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct State {
    pub tau: f64,
    pub w: f64,
}

/// Why an integration failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum IntegrationError {
    #[error("invalid parameters: {0}")]
    InvalidParams(String),
    #[error("invalid strain history: {0}")]
    InvalidHistory(String),
    #[error("too stiff: more than {substeps} sub-steps needed in one sample interval at t = {time} s")]
    TooStiff { time: f64, substeps: u32 },
    #[error("non-finite stress or work at t = {time} s")]
    NonFinite { time: f64 },
}

/// τ(t) and Wᴵ(t) at the sample times.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    pub tau: Vec<f64>,
    pub w: Vec<f64>,
}

/// The states of all lanes at one sample time.
#[derive(Clone, Copy, Debug)]
pub struct LaneStates {
    pub tau: [f64; LANES],
    pub w: [f64; LANES],
}

/// One Euler track of every lane: the state with the flow rule and
/// hardening at it, carried from step to step so that each accepted
/// sub-step evaluates the law once.
#[derive(Clone, Copy)]
struct Track<S> {
    tau: S,
    w: S,
    /// γ̇ᴵ and ∂γ̇ᴵ/∂τ at (τ, Wᴵ)
    rate: S,
    slope: S,
    /// R + D at Wᴵ
    z: S,
}

impl<S: F64xN> Track<S> {
    #[inline(always)]
    fn new(law: &LaneLaw<S>, tau: S, w: S) -> Self {
        let z = law.hardening_sum(w);
        let (rate, slope) = law.flow(tau, z);
        Track { tau, w, rate, slope, z }
    }
}

/// Whether this CPU runs the AVX2 build of the loop (checked once).
pub fn uses_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static DETECTED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| std::env::var_os("MRBP_NO_AVX2").is_none() && is_x86_feature_detected!("avx2"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

impl Integrator {
    /// Integrates every lane's parameter set from stress `initial_tau` (and
    /// Wᴵ = 0) at `t[0]`, calling `visit(k, states)` at every sample time
    /// `t[k]`. Allocates nothing; the visitor decides what to keep (a
    /// likelihood keeps only sums of residuals). Returns each lane's outcome;
    /// the states a failed lane reports after its failure mean nothing.
    pub fn run_lanes(
        &self,
        params: &[Params; LANES],
        t: &[f64],
        gamma: &[f64],
        initial_tau: f64,
        mut visit: impl FnMut(usize, &LaneStates),
    ) -> [Result<(), IntegrationError>; LANES] {
        let mut outcome: [Result<(), IntegrationError>; LANES] = std::array::from_fn(|_| Ok(()));
        if t.len() != gamma.len() {
            let e = IntegrationError::InvalidHistory(format!("{} times but {} strains", t.len(), gamma.len()));
            return std::array::from_fn(|_| Err(e.clone()));
        }
        // a lane with invalid parameters runs a valid set and is reported failed
        let mut usable = *params;
        for (lane, p) in params.iter().enumerate() {
            if let Err(e) = p.validate() {
                outcome[lane] = Err(IntegrationError::InvalidParams(e));
                usable[lane] = Params::reference_1a();
            }
        }
        if t.is_empty() {
            return outcome;
        }
        #[cfg(target_arch = "x86_64")]
        if uses_avx2() {
            // SAFETY: the CPU has AVX2 (checked just above)
            unsafe { self.integrate_avx2(&usable, t, gamma, initial_tau, &mut outcome, &mut visit) };
            return outcome;
        }
        self.integrate::<Portable>(&usable, t, gamma, initial_tau, &mut outcome, &mut visit);
        outcome
    }

    /// [`Integrator::integrate`] compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn integrate_avx2(
        &self,
        params: &[Params; LANES],
        t: &[f64],
        gamma: &[f64],
        initial_tau: f64,
        outcome: &mut [Result<(), IntegrationError>; LANES],
        visit: &mut impl FnMut(usize, &LaneStates),
    ) {
        self.integrate::<super::simd::avx2::Avx2>(params, t, gamma, initial_tau, outcome, visit);
    }

    /// The Euler steps one integration of `p` along the history takes (both
    /// tracks of an extrapolated one, rejected steps included): the work a
    /// log-density costs, which stiff records raise for the explicit scheme.
    pub fn euler_steps(&self, p: &Params, t: &[f64], gamma: &[f64], initial_tau: f64) -> u64 {
        let mut outcome = std::array::from_fn(|_| Ok(()));
        self.integrate::<Portable>(&[*p; LANES], t, gamma, initial_tau, &mut outcome, &mut |_, _| {})
    }

    /// The loop over the samples of a record, in the lanes of `S`; returns
    /// the Euler steps it took.
    #[inline(always)]
    fn integrate<S: F64xN>(
        &self,
        params: &[Params; LANES],
        t: &[f64],
        gamma: &[f64],
        initial_tau: f64,
        outcome: &mut [Result<(), IntegrationError>; LANES],
        visit: &mut impl FnMut(usize, &LaneStates),
    ) -> u64 {
        let mut steps = 0u64;
        let law = LaneLaw::<S>::new(params);
        let tau0 = S::splat(initial_tau);
        let mut coarse = Track::new(&law, tau0, S::splat(0.0));
        let mut finer = coarse;
        let fine = Integrator { substeps: 2 * self.substeps, ..*self };
        let mut states = LaneStates { tau: [initial_tau; LANES], w: [0.0; LANES] };
        visit(0, &states);
        for k in 0..t.len() - 1 {
            let dt = t[k + 1] - t[k];
            if !(dt > 0.0) {
                let e = IntegrationError::InvalidHistory(format!("time does not increase at sample {}", k + 1));
                *outcome = std::array::from_fn(|_| Err(e.clone()));
                return steps;
            }
            let strain_rate = (gamma[k + 1] - gamma[k]) / dt;
            steps += self.advance(&law, &mut coarse, strain_rate, dt, t[k], outcome) as u64;
            let (tau, w) = if self.extrapolate {
                // independent of the coarse track: the CPU overlaps the two
                steps += fine.advance(&law, &mut finer, strain_rate, dt, t[k], outcome) as u64;
                let two = S::splat(2.0);
                (two * finer.tau - coarse.tau, two * finer.w - coarse.w)
            } else {
                (coarse.tau, coarse.w)
            };
            states.tau = tau.to_array();
            states.w = w.to_array();
            visit(k + 1, &states);
        }
        steps
    }

    /// Integrates one parameter set from `initial` at `t[0]` and calls
    /// `visit(k, state)` at every sample time `t[k]` (lane 0 of
    /// [`Integrator::run_lanes`]).
    pub fn run_with(
        &self,
        p: &Params,
        t: &[f64],
        gamma: &[f64],
        initial: State,
        mut visit: impl FnMut(usize, State),
    ) -> Result<State, IntegrationError> {
        if initial.w != 0.0 {
            return Err(IntegrationError::InvalidHistory("a run starts with Wᴵ = 0".into()));
        }
        let mut last = initial;
        let [first, ..] = self.run_lanes(&[*p; LANES], t, gamma, initial.tau, |k, s| {
            last = State { tau: s.tau[0], w: s.w[0] };
            visit(k, last);
        });
        first.map(|_| last)
    }

    /// τ and Wᴵ at every sample time, from the virgin state τ = 0, Wᴵ = 0.
    pub fn run(&self, p: &Params, t: &[f64], gamma: &[f64]) -> Result<Trajectory, IntegrationError> {
        let mut out = Trajectory {
            tau: vec![0.0; t.len()],
            w: vec![0.0; t.len()],
        };
        self.run_with(p, t, gamma, State::default(), |k, s| {
            out.tau[k] = s.tau;
            out.w[k] = s.w;
        })?;
        Ok(out)
    }

    /// Advances every lane over one sample interval of length `dt` at
    /// constant total strain rate `strain_rate`. This is the hot loop of
    /// every likelihood evaluation.
    ///
    /// Step control, lane by lane: a sub-step is at most `dt / substeps` and
    /// moves τ by at most a quarter of (R + D)/√3 (beyond that the flow rate
    /// saturates at 2D₀ and λ no longer measures how fast the state can
    /// change); both limits change continuously with the state. An explicit
    /// step also keeps λh ≤ `stability` with λ at its start (as long a step
    /// as that allows, the last one what is left, so that the state at the
    /// sample time changes continuously with the parameters), and is
    /// rejected and halved when it ends where the stiffness says it was too
    /// long (λh > 2 at its end): this catches the elastic predictor that
    /// jumps far past yield in one step, which the stiffness at the start
    /// cannot see. The linearly implicit step is stable at any length and
    /// needs neither: its result is a continuous function of the parameters,
    /// which keeps the likelihood smooth where the explicit scheme's
    /// rejections make it rugged (stiff records with large residuals). A lane
    /// that has reached the sample time waits for the others.
    ///
    /// One function on purpose: step control, the rejection test and the
    /// update share the lane masks and the track's registers, and this loop
    /// is where a likelihood spends its time.
    #[inline(always)]
    fn advance<S: F64xN>(
        &self,
        law: &LaneLaw<S>,
        tr: &mut Track<S>,
        strain_rate: f64,
        dt: f64,
        t0: f64,
        outcome: &mut [Result<(), IntegrationError>; LANES],
    ) -> u32 {
        let explicit = self.scheme == Scheme::Explicit;
        let zero = S::splat(0.0);
        let one = S::splat(1.0);
        let g = law.g;
        let gd = S::splat(strain_rate);
        let h_max = S::splat(dt / self.substeps as f64);
        let stability = S::splat(self.stability);
        let done_below = S::splat(1e-12 * dt);
        let shortest = S::splat(1e-9 * dt);
        // lanes that already failed do not step
        let failed = S::from_array(outcome.each_ref().map(|o| if o.is_err() { 1.0 } else { 0.0 })).gt(zero);
        let mut left = S::select(failed, zero, S::splat(dt));
        let mut h_cap = h_max;
        let mut attempts = 0u32;
        loop {
            let running = left.gt(done_below);
            if !running.any() {
                break;
            }
            attempts += 1;
            if attempts > self.max_substeps {
                for (lane, r) in running.mask_to_bools().into_iter().enumerate() {
                    if r && outcome[lane].is_ok() {
                        outcome[lane] = Err(IntegrationError::TooStiff { time: t0, substeps: self.max_substeps });
                    }
                }
                break;
            }
            let lambda = g * tr.slope;
            let stress_rate = g * (gd - tr.rate);
            let mut h = left.min(h_cap);
            if explicit {
                // as long a step as stability allows, the last one what is
                // left: the state at the sample time then changes
                // continuously with the parameters (equal sub-steps would
                // jump where their count changes, and make the likelihood
                // rugged on stiff records)
                let unstable = (lambda * h).gt(stability);
                h = S::select(unstable, stability / lambda, h);
            }
            let max_dtau = S::splat(MAX_STRESS_STEP * INV_SQRT_3) * tr.z;
            let big = (stress_rate.abs() * h).gt(max_dtau);
            h = S::select(big, max_dtau / stress_rate.abs(), h);
            let dtau = stress_rate * h;
            let dtau = if explicit { dtau } else { dtau / (one + h * lambda) };
            let tau = tr.tau + dtau;
            // τ γ̇ᴵ ≥ 0 because γ̇ᴵ has the sign of τ: Wᴵ never decreases
            let w = tr.w + h * tr.tau * tr.rate;
            let z = law.hardening_sum(w);
            let (rate, slope) = law.flow(tau, z);
            // an explicit step is too long where the stiffness at its end says
            // so (λh > 2); the linearly implicit one is stable for any step and
            // is never rejected, so its result changes continuously with the
            // parameters
            let too_long = (g * slope * h).gt(S::splat(2.0));
            let reject = if explicit { running.and(too_long).and(h.gt(shortest)) } else { zero };
            let accept = reject.and_not(running);
            h_cap = S::select(reject, h * S::splat(0.5), S::select(accept, (h + h).min(h_max), h_cap));
            tr.tau = S::select(accept, tau, tr.tau);
            tr.w = S::select(accept, w, tr.w);
            tr.rate = S::select(accept, rate, tr.rate);
            tr.slope = S::select(accept, slope, tr.slope);
            tr.z = S::select(accept, z, tr.z);
            left = S::select(accept, left - h, left);
        }
        let finite = tr.tau.finite().and(tr.w.finite());
        if !finite.all() {
            for (lane, ok) in finite.mask_to_bools().into_iter().enumerate() {
                if !ok && outcome[lane].is_ok() {
                    outcome[lane] = Err(IntegrationError::NonFinite { time: t0 + dt });
                }
            }
            // keep the failed lanes finite so they cannot disturb the loop
            *tr = Track::new(law, S::select(finite, tr.tau, zero), S::select(finite, tr.w, zero));
        }
        attempts
    }
}

/// τ and Wᴵ with the default integrator (explicit Euler, stable sub-steps).
pub fn integrate(p: &Params, t: &[f64], gamma: &[f64]) -> Result<Trajectory, IntegrationError> {
    Integrator::default().run(p, t, gamma)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::lanes::LaneLaw;
    use crate::model::law::{flow_stress, hardening};

    fn ramp(rate: f64, duration: f64, n: usize) -> (Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..=n).map(|k| duration * k as f64 / n as f64).collect();
        let g = t.iter().map(|t| rate * t).collect();
        (t, g)
    }

    /// Half a crank cycle and back: a smooth history with yield, hardening
    /// and a reversal.
    fn crank(n: usize) -> (Vec<f64>, Vec<f64>) {
        let period = 0.6;
        let t: Vec<f64> = (0..=n).map(|k| 0.9 * period * k as f64 / n as f64).collect();
        let g = t
            .iter()
            .map(|t| 6.75 * (1.0 - (2.0 * std::f64::consts::PI * t / period).cos()))
            .collect();
        (t, g)
    }

    #[test]
    fn elastic_limit_gives_hookes_law() {
        // R0 so large that no flow happens: τ = G γ exactly (the strain is linear)
        let mut p = Params::reference_1a();
        p.r0 = 5.0e6;
        p.r1 = 5.0e6;
        let (t, g) = ramp(10.0, 0.01, 100);
        let tr = integrate(&p, &t, &g).unwrap();
        for (tau, gamma) in tr.tau.iter().zip(&g) {
            assert!((tau - p.g * gamma).abs() <= 1e-9 * p.g * gamma.max(1e-12), "{tau} vs {}", p.g * gamma);
        }
        assert!(tr.w.iter().all(|&w| w < 1e-6));
    }

    #[test]
    fn steady_flow_reaches_the_stress_of_eq3_with_saturated_hardening() {
        // constant total rate for long enough that R → R1, D → D1 and γ̇ᴵ → γ̇
        let p = Params::reference_1a();
        let rate = 100.0;
        let (t, g) = ramp(rate, 3.0, 30_000);
        let tr = Integrator {
            substeps: 4,
            ..Integrator::default()
        }
        .run(&p, &t, &g)
        .unwrap();
        let (r, d) = hardening(&p, *tr.w.last().unwrap());
        assert!((r + d - (p.r1 + p.d1)).abs() < 1e-6 * (p.r1 + p.d1));
        let expected = flow_stress(&p, rate, p.r1 + p.d1);
        let got = *tr.tau.last().unwrap();
        assert!((got - expected).abs() < 1e-4 * expected, "{got} vs {expected}");
    }

    #[test]
    fn inelastic_work_never_decreases() {
        let p = Params::reference_1a();
        let (t, g) = crank(2000);
        for scheme in [Scheme::Explicit, Scheme::LinearlyImplicit] {
            let tr = Integrator {
                scheme,
                ..Integrator::default()
            }
            .run(&p, &t, &g)
            .unwrap();
            assert!(tr.w.windows(2).all(|w| w[1] >= w[0]), "{scheme:?}");
            assert!(*tr.w.last().unwrap() > 0.0);
        }
    }

    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    /// Maximum |τ − τ_ref| over the record, with the reference on a grid 64
    /// times finer than the coarsest tested.
    fn errors(scheme: Scheme, p: &Params) -> Vec<f64> {
        let (t, g) = crank(1000);
        let run = |substeps| {
            Integrator {
                scheme,
                substeps,
                ..Integrator::default()
            }
            .run(p, &t, &g)
            .unwrap()
            .tau
        };
        let reference = run(512);
        [1, 2, 4, 8]
            .iter()
            .map(|&m| max_diff(&run(m), &reference))
            .collect()
    }

    #[test]
    fn first_order_convergence_against_fine_step_reference() {
        // soft parameters so the stability limit never shortens the step and the
        // ratio measures the method alone; 1000 intervals over 0.54 s
        let mut p = Params::reference_1a();
        p.g = 5.0e4;
        p.n = 0.8;
        for scheme in [Scheme::Explicit, Scheme::LinearlyImplicit] {
            let e = errors(scheme, &p);
            for w in e.windows(2) {
                let ratio = w[0] / w[1];
                // first order: halving the step halves the error; the reference
                // itself carries 1/64 of the coarsest error, which pulls the last
                // ratio a few percent above 2
                assert!((1.8..2.3).contains(&ratio), "{scheme:?}: errors {e:?}");
            }
        }
    }

    #[test]
    fn richardson_extrapolation_is_second_order() {
        let mut p = Params::reference_1a();
        p.g = 5.0e4;
        p.n = 0.8;
        let (t, g) = crank(1000);
        let run = |substeps, extrapolate| {
            Integrator { substeps, extrapolate, max_substeps: 100_000, ..Integrator::default() }.run(&p, &t, &g).unwrap().tau
        };
        // reference: extrapolated with 256 sub-steps, itself second order
        let reference = run(256, true);
        let err = |m| max_diff(&run(m, true), &reference);
        let (e1, e2, e4) = (err(1), err(2), err(4));
        // second order: halving the step divides the error by about 4; and
        // far below plain Euler at the same step
        assert!(e1 / e2 > 3.0 && e2 / e4 > 3.0, "{e1} {e2} {e4}");
        let plain = max_diff(&run(1, false), &reference);
        assert!(e1 < 0.1 * plain, "{e1} vs {plain}");
    }

    #[test]
    fn explicit_stays_stable_where_plain_euler_would_explode() {
        // stiff corner of the parameter space: λΔt ≫ 2 at the record's step
        let mut p = Params::reference_1a();
        p.g = 5.0e7;
        p.n = 3.0;
        let (t, g) = crank(500);
        // λΔt is about 3000 here: explicit needs that many sub-steps per interval
        let patient = Integrator {
            max_substeps: 100_000,
            ..Integrator::default()
        };
        let tr = patient.run(&p, &t, &g).unwrap();
        let bound = 2.0 * flow_stress(&p, 1e-3, p.r1 + p.d1);
        assert!(tr.tau.iter().all(|x| x.abs() < bound));
        let li = Integrator {
            scheme: Scheme::LinearlyImplicit,
            ..Integrator::default()
        }
        .run(&p, &t, &g)
        .unwrap();
        assert!(li.tau.iter().all(|x| x.abs() < bound));
    }

    #[test]
    fn lanes_are_independent_of_their_neighbours() {
        // the same parameter set gives the same bits in any lane, beside any
        // other sets, failing ones included
        let p = Params::reference_1a();
        let mut stiff = p;
        stiff.g = 5.0e7;
        stiff.n = 3.0;
        let mut bad = p;
        bad.n = -1.0;
        let (t, g) = crank(300);
        let integ = Integrator { max_substeps: 50, ..Integrator::default() };
        let alone = integ.run(&p, &t, &g).unwrap().tau;
        let mut mixed = vec![[0.0; LANES]; t.len()];
        let outcome = integ.run_lanes(&[stiff, bad, p, p, stiff, p, bad, p], &t, &g, 0.0, |k, s| mixed[k] = s.tau);
        assert!(matches!(outcome[0], Err(IntegrationError::TooStiff { .. })));
        assert!(matches!(outcome[1], Err(IntegrationError::InvalidParams(_))));
        for lane in [2, 3, 5, 7] {
            assert!(outcome[lane].is_ok());
            for (k, a) in alone.iter().enumerate() {
                assert_eq!(a.to_bits(), mixed[k][lane].to_bits());
            }
        }
    }

    /// The AVX2 build of the loop gives the portable build's bits along a
    /// crank record, Richardson extrapolation and a stiff lane included.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_loop_equals_portable_loop() {
        if !is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        let (t, g) = crank(3000);
        let mut stiff = Params::reference_1a();
        stiff.g = 2.0e6;
        stiff.n = 3.0;
        let p = Params::reference_1a();
        let params = [p, stiff, Params { n: 0.6, ..p }, Params { m2: 1e-3, ..p }, Params { g: 5e4, ..p }, Params { r0: 3e4, ..p }, Params { d1: 1e5, ..p }, Params { m1: 1e-5, ..p }];
        for integ in [Integrator { extrapolate: true, substeps: 2, ..Integrator::default() }, Integrator { scheme: Scheme::LinearlyImplicit, ..Integrator::default() }] {
            let run = |avx: bool| {
                let mut out = Vec::new();
                let mut outcome = std::array::from_fn(|_| Ok(()));
                let mut visit = |_: usize, s: &LaneStates| out.extend(s.tau.iter().chain(&s.w).map(|v| v.to_bits()));
                if avx {
                    // SAFETY: AVX2 detected above
                    unsafe { integ.integrate_avx2(&params, &t, &g, 0.0, &mut outcome, &mut visit) };
                } else {
                    integ.integrate::<Portable>(&params, &t, &g, 0.0, &mut outcome, &mut visit);
                }
                (out, outcome)
            };
            let (a, oa) = run(true);
            let (p, op) = run(false);
            assert_eq!(oa, op);
            assert!(a == p, "{integ:?}: the builds differ");
        }
    }

    #[test]
    fn lanes_follow_the_scalar_law() {
        // one explicit step from rest, by hand with the scalar law: the
        // elastic predictor τ = G γ̇ h, Wᴵ = 0
        let p = Params::reference_1a();
        let t = [0.0, 1e-4];
        let g = [0.0, 1e-3];
        let tr = integrate(&p, &t, &g).unwrap();
        assert!((tr.tau[1] - p.g * 1e-3).abs() < 1e-9 * p.g * 1e-3);
        // the lane flow rule agrees with the scalar one of law.rs
        let law = LaneLaw::<Portable>::new(&[p; LANES]);
        let z = crate::model::law::Law::new(&p).hardening_sum(1.0e4);
        let (rate, slope) = law.flow(Portable::from_array([3.0e4, -3.2e4, 0.0, 2.0e3, 3.0e4, -3.2e4, 0.0, 2.0e3]), Portable::splat(z));
        let scalar = crate::model::law::Law::new(&p);
        for (i, tau) in [3.0e4, -3.2e4, 0.0, 2.0e3].iter().enumerate() {
            let f = scalar.flow(*tau, z);
            assert!((rate.to_array()[i] - f.rate).abs() <= 1e-11 * f.rate.abs() + 1e-300, "{tau}");
            assert!((slope.to_array()[i] - f.slope).abs() <= 1e-11 * f.slope.abs() + 1e-300, "{tau}");
        }
        assert!((law.hardening_sum(Portable::splat(1.0e4)).to_array()[0] - z).abs() < 1e-9 * z);
    }

    #[test]
    fn failures_are_errors_not_panics() {
        let mut p = Params::reference_1a();
        p.g = 5.0e7;
        p.n = 3.0;
        let (t, g) = crank(100);
        let tight = Integrator {
            max_substeps: 2,
            ..Integrator::default()
        };
        let r = tight.run(&p, &t, &g);
        assert!(matches!(r, Err(IntegrationError::TooStiff { .. })), "{r:?}");
        let mut bad = Params::reference_1a();
        bad.n = f64::NAN;
        assert!(matches!(integrate(&bad, &t, &g), Err(IntegrationError::InvalidParams(_))));
        let mut g2 = g.clone();
        g2[50] = f64::NAN;
        assert!(matches!(integrate(&Params::reference_1a(), &t, &g2), Err(IntegrationError::NonFinite { .. })));
        let mut t2 = t.clone();
        t2[10] = t2[9];
        assert!(matches!(integrate(&Params::reference_1a(), &t2, &g), Err(IntegrationError::InvalidHistory(_))));
    }
}
