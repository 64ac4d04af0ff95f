//! The integrator of the laws with an internal state driven by the
//! displacement and its velocity (the Bouc-Wen family): written once, in
//! the lanes of [`crate::model::simd`], for every [`StateLaw`].
//!
//! The excitation is the run's strain as the B-P integrator takes it:
//! linear between samples, so over each sample interval the displacement
//! x = h γ moves at the interval's constant velocity v. The state (at most
//! two variables) takes [`Integrator::substeps`] equal sub-steps of ROS2
//! within the interval, the two-stage Rosenbrock method of Verwer et al.
//! (1999): second order, L-stable, and second order with any matrix in
//! place of the Jacobian (a W-method; here the law's own ∂rate/∂state,
//! x taken as one more state moving at v). The hysteresis of a real damper
//! turns over microns at its reversals, far less than the displacement
//! between samples: an explicit method would need hundreds of sub-steps
//! there, an L-stable one lands on the branch it turns to. With
//! [`Integrator::extrapolate`] a second track takes twice the sub-steps and
//! the stress reported is (4 τ_{h/2} − τ_h)/3 (Richardson for a
//! second-order method). The scheme choice is the B-P law's: these states
//! are integrated by ROS2 whatever it says. The work counted is three
//! evaluations a sub-step (two rates and the Jacobian), what the step rule
//! compares as "Euler steps".
//!
//! The force at a sample uses the state there and the velocity of a smooth
//! path through the samples (central differences), and is reported as
//! stress, F/A, with the run's area.

use super::{DamperLaw, LawKind, LawParameter, LawValues, LANES};
use crate::data::RunData;
use crate::model::simd::{F64xN, Portable};
use crate::model::{uses_avx2, IntegrationError, Integrator, Params};

/// The most variables a law's state has.
pub const MAX_STATES: usize = 3;

/// A law's state (unused places stay 0).
pub type State<S> = [S; MAX_STATES];

/// ∂rate/∂state: `j[r][s]` = ∂(rate r)/∂(state s), 0 for an unused state.
pub type Jacobian<S> = [[S; MAX_STATES]; MAX_STATES];

/// A law whose force follows from a state of up to [`MAX_STATES`]
/// variables, driven by the displacement x (m) and its velocity v (m/s). Every method is
/// evaluated in lanes, for [`Portable`] and for AVX2 alike: write them with
/// the [`F64xN`] operations only, and `#[inline(always)]`.
pub trait StateLaw: Send + Sync + std::fmt::Debug + Default + 'static {
    const KIND: LawKind;
    const PARAMETERS: &'static [LawParameter];

    /// How many variables its state has (the first of [`State`]); up to
    /// two use a 2 × 2 solve, three the 3 × 3.
    const STATES: usize = 2;

    /// Parameters walked as ln(θ + c) instead of ln(θ − floor): (index, c);
    /// see [`super::DamperLaw::shifted`].
    const SHIFTED: &'static [(usize, f64)] = &[];

    /// The lanes' constants, read off their parameter sets and the run's
    /// geometry (a law written in stress, as the B-P element, needs it).
    type Lanes<S: F64xN>: Copy;

    fn lanes<S: F64xN>(params: &[LawValues; LANES], run: &RunData) -> Self::Lanes<S>;

    /// d(state)/dt at displacement `x`, velocity `v` and `state`.
    fn rate<S: F64xN>(c: &Self::Lanes<S>, x: S, v: S, state: State<S>) -> State<S>;

    /// ∂rate/∂state at displacement `x`, velocity `v` and `state`.
    fn jacobian<S: F64xN>(c: &Self::Lanes<S>, x: S, v: S, state: State<S>) -> Jacobian<S>;

    /// The force (N) at displacement `x`, velocity `v` and `state`.
    fn force<S: F64xN>(c: &Self::Lanes<S>, x: S, v: S, state: State<S>) -> S;

    /// The largest quasi-static stiffness dF/dx (N/m) of one parameter set
    /// on `run`'s geometry.
    fn force_stiffness_bound(p: &LawValues, run: &RunData) -> f64;

    /// Parameter sets a MAP search may start from, given the records' peak
    /// force (N), velocity (m/s) and stroke (m).
    fn starts(force: f64, velocity: f64, stroke: f64) -> Vec<LawValues>;

    /// Whether the law is built on the B-P element, so that the paper's
    /// identification gives it a start ([`Self::around`]).
    fn builds_on_bodner_partom() -> bool {
        false
    }

    /// Starts around the B-P parameters `bp` of an identification, given
    /// the records' scales as [`Self::starts`] takes them.
    fn around(_bp: &Params, _force: f64, _velocity: f64, _stroke: f64) -> Vec<LawValues> {
        Vec::new()
    }
}

/// A [`StateLaw`] as a [`DamperLaw`]: the registry's entry of such a law.
#[derive(Clone, Copy, Debug, Default)]
pub struct Ode<L>(std::marker::PhantomData<L>);

impl<L: StateLaw> Ode<L> {
    pub const fn new() -> Self {
        Ode(std::marker::PhantomData)
    }
}

impl<L: StateLaw> DamperLaw for Ode<L> {
    fn kind(&self) -> LawKind {
        L::KIND
    }

    fn parameters(&self) -> &'static [LawParameter] {
        L::PARAMETERS
    }

    fn order(&self) -> u32 {
        2
    }

    fn follows_scheme(&self) -> bool {
        false
    }

    fn run_lanes(
        &self,
        integrator: &Integrator,
        params: &[LawValues; LANES],
        run: &RunData,
        visit: &mut dyn FnMut(usize, &[f64; LANES]),
    ) -> [Result<(), IntegrationError>; LANES] {
        let mut outcome: [Result<(), IntegrationError>; LANES] = std::array::from_fn(|_| Ok(()));
        // a lane with invalid parameters runs a valid set and is reported failed
        let mut usable = *params;
        let fallback = L::starts(1.0, 1.0, 1.0)[0];
        for (lane, p) in params.iter().enumerate() {
            if let Err(e) = self.validate(p) {
                outcome[lane] = Err(IntegrationError::InvalidParams(e));
                usable[lane] = fallback;
            }
        }
        if run.time.is_empty() {
            return outcome;
        }
        #[cfg(target_arch = "x86_64")]
        if uses_avx2() {
            // SAFETY: the CPU has AVX2 (checked just above)
            unsafe { integrate_avx2::<L>(integrator, &usable, run, &mut outcome, visit) };
            return outcome;
        }
        integrate::<L, Portable>(integrator, &usable, run, &mut outcome, visit);
        outcome
    }

    fn euler_steps(&self, integrator: &Integrator, params: &LawValues, run: &RunData) -> u64 {
        let mut outcome = std::array::from_fn(|_| Ok(()));
        integrate::<L, Portable>(integrator, &[*params; LANES], run, &mut outcome, &mut |_, _| {})
    }

    fn stiffness_bound(&self, params: &LawValues, run: &RunData) -> f64 {
        L::force_stiffness_bound(params, run) * run.gap_m / run.area_m2
    }

    fn starts_at(&self, force: f64, velocity: f64, stroke: f64) -> Vec<LawValues> {
        L::starts(force, velocity, stroke).into_iter().map(|v| super::clamped(self, v)).collect()
    }

    fn builds_on_bodner_partom(&self) -> bool {
        L::builds_on_bodner_partom()
    }

    fn shifted(&self) -> &'static [(usize, f64)] {
        L::SHIFTED
    }

    fn starts_around(&self, bp: &Params, runs: &[RunData]) -> Vec<LawValues> {
        let (force, velocity, stroke) = super::scales(runs);
        L::around(bp, force.max(1e-3), velocity.max(1e-6), stroke.max(1e-6))
            .into_iter()
            .map(|v| super::clamped(self, v))
            .collect()
    }
}

/// [`integrate`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn integrate_avx2<L: StateLaw>(
    integrator: &Integrator,
    params: &[LawValues; LANES],
    run: &RunData,
    outcome: &mut [Result<(), IntegrationError>; LANES],
    visit: &mut dyn FnMut(usize, &[f64; LANES]),
) -> u64 {
    integrate::<L, crate::model::simd::avx2::Avx2>(integrator, params, run, outcome, visit)
}

/// One Euler track of every lane: its state.
#[derive(Clone, Copy)]
struct Track<S> {
    state: State<S>,
}

/// The loop over the samples of `run` in the lanes of `S`; returns lane
/// 0's sub-steps (both tracks where extrapolating).
#[inline(always)]
fn integrate<L: StateLaw, S: F64xN>(
    integrator: &Integrator,
    params: &[LawValues; LANES],
    run: &RunData,
    outcome: &mut [Result<(), IntegrationError>; LANES],
    visit: &mut dyn FnMut(usize, &[f64; LANES]),
) -> u64 {
    let (t, gamma) = (&run.time, &run.gamma);
    let c = L::lanes::<S>(params, run);
    let (h_gap, inv_area) = (run.gap_m, 1.0 / run.area_m2);
    let zero = S::splat(0.0);
    let mut coarse = Track { state: [zero; MAX_STATES] };
    let mut finer = coarse;
    let fine = Integrator { substeps: 2 * integrator.substeps, ..*integrator };
    let rates = super::strain_rates(run);
    let mut steps = 0u64;
    let mut failed = [false; LANES];
    // no closures over lanes here: a closure would not inherit the AVX2
    // target feature of the function this loop is compiled into
    let (x, v) = (S::splat(h_gap * gamma[0]), S::splat(h_gap * rates[0]));
    visit(0, &(L::force(&c, x, v, coarse.state) * S::splat(inv_area)).to_array());
    for k in 0..t.len() - 1 {
        let dt = t[k + 1] - t[k];
        if !(dt > 0.0) {
            let e = IntegrationError::InvalidHistory(format!(
                "time does not increase at sample {}",
                k + 1
            ));
            *outcome = std::array::from_fn(|_| Err(e.clone()));
            return steps;
        }
        let x0 = h_gap * gamma[k];
        let v = h_gap * (gamma[k + 1] - gamma[k]) / dt;
        steps += interval::<L, S>(integrator, &c, &mut coarse, x0, v, dt);
        if integrator.extrapolate {
            steps += interval::<L, S>(&fine, &c, &mut finer, x0, v, dt);
        }
        let (x, v) = (S::splat(h_gap * gamma[k + 1]), S::splat(h_gap * rates[k + 1]));
        let force = if integrator.extrapolate {
            (S::splat(4.0) * L::force(&c, x, v, finer.state) - L::force(&c, x, v, coarse.state))
                / S::splat(3.0)
        } else {
            L::force(&c, x, v, coarse.state)
        };
        let stress = force * S::splat(inv_area);
        let finite = stress.finite().mask_to_bools();
        for lane in 0..LANES {
            if !finite[lane] && !failed[lane] {
                failed[lane] = true;
                outcome[lane] = Err(IntegrationError::NonFinite { time: t[k + 1] });
            }
        }
        visit(k + 1, &stress.to_array());
    }
    steps
}

/// The 1 + 1/√2 of ROS2.
const GAMMA: f64 = 1.707_106_781_186_547_5;

/// One sample interval of length `dt` from displacement `x0` at velocity
/// `v` for every lane of `track`: the integrator's sub-steps of ROS2, the
/// state at the interval's end; returns the work (three evaluations a
/// sub-step).
#[inline(always)]
fn interval<L: StateLaw, S: F64xN>(
    integrator: &Integrator,
    c: &L::Lanes<S>,
    track: &mut Track<S>,
    x0: f64,
    v: f64,
    dt: f64,
) -> u64 {
    let m = integrator.substeps.max(1);
    let h = dt / m as f64;
    let (vs, hs) = (S::splat(v), S::splat(h));
    let (gh, two, one) = (S::splat(GAMMA * h), S::splat(2.0), S::splat(1.0));
    let (three_half, half) = (S::splat(1.5 * h), S::splat(0.5 * h));
    let mut s = track.state;
    if L::STATES > 2 {
        for i in 0..m {
            let x = S::splat(x0 + v * h * i as f64);
            s = rosenbrock_3::<L, S>(c, x, vs, [hs, gh, three_half, half], s);
        }
        track.state = s;
        return 3 * m as u64;
    }
    for i in 0..m {
        let x = S::splat(x0 + v * h * i as f64);
        // W = I − γ h J and its inverse (2 × 2), written out (no closures:
        // see `integrate`)
        let j = L::jacobian(c, x, vs, s);
        let (a, b) = (one - gh * j[0][0], S::splat(0.0) - gh * j[0][1]);
        let (cc, d) = (S::splat(0.0) - gh * j[1][0], one - gh * j[1][1]);
        let inv_det = one / (a * d - b * cc);
        let f1 = L::rate(c, x, vs, s);
        let k1 = [(d * f1[0] - b * f1[1]) * inv_det, (a * f1[1] - cc * f1[0]) * inv_det];
        let f2 = L::rate(c, x + vs * hs, vs, [s[0] + hs * k1[0], s[1] + hs * k1[1], s[2]]);
        let g = [f2[0] - two * k1[0], f2[1] - two * k1[1]];
        let k2 = [(d * g[0] - b * g[1]) * inv_det, (a * g[1] - cc * g[0]) * inv_det];
        s = [
            s[0] + three_half * k1[0] + half * k2[0],
            s[1] + three_half * k1[1] + half * k2[1],
            s[2],
        ];
    }
    track.state = s;
    3 * m as u64
}

/// One ROS2 sub-step of a three-variable state, with `steps` = [h, γ h,
/// 1.5 h, 0.5 h] as [`interval`] computes them: W = I − γ h J inverted by
/// its adjugate, once for both stages.
#[inline(always)]
fn rosenbrock_3<L: StateLaw, S: F64xN>(
    c: &L::Lanes<S>,
    x: S,
    v: S,
    steps: [S; 4],
    s: State<S>,
) -> State<S> {
    let [h, gh, three_half, half] = steps;
    let (zero, one, two) = (S::splat(0.0), S::splat(1.0), S::splat(2.0));
    // W = I − γ h J and its adjugate, written out (no closures: see
    // `integrate`)
    let j = L::jacobian(c, x, v, s);
    let (a, b, cc) = (one - gh * j[0][0], zero - gh * j[0][1], zero - gh * j[0][2]);
    let (d, e, f) = (zero - gh * j[1][0], one - gh * j[1][1], zero - gh * j[1][2]);
    let (g, hh, k) = (zero - gh * j[2][0], zero - gh * j[2][1], one - gh * j[2][2]);
    let adj = [
        [e * k - f * hh, cc * hh - b * k, b * f - cc * e],
        [f * g - d * k, a * k - cc * g, cc * d - a * f],
        [d * hh - e * g, b * g - a * hh, a * e - b * d],
    ];
    let inv_det = one / (a * adj[0][0] + b * adj[1][0] + cc * adj[2][0]);
    let k1 = solve_3(&adj, inv_det, L::rate(c, x, v, s));
    let f2 = L::rate(c, x + v * h, v, [s[0] + h * k1[0], s[1] + h * k1[1], s[2] + h * k1[2]]);
    let k2 =
        solve_3(&adj, inv_det, [f2[0] - two * k1[0], f2[1] - two * k1[1], f2[2] - two * k1[2]]);
    [
        s[0] + three_half * k1[0] + half * k2[0],
        s[1] + three_half * k1[1] + half * k2[1],
        s[2] + three_half * k1[2] + half * k2[2],
    ]
}

/// W⁻¹ r from W's adjugate and the inverse of its determinant.
#[inline(always)]
fn solve_3<S: F64xN>(adj: &Jacobian<S>, inv_det: S, r: State<S>) -> State<S> {
    [
        (adj[0][0] * r[0] + adj[0][1] * r[1] + adj[0][2] * r[2]) * inv_det,
        (adj[1][0] * r[0] + adj[1][1] * r[1] + adj[1][2] * r[2]) * inv_det,
        (adj[2][0] * r[0] + adj[2][1] * r[1] + adj[2][2] * r[2]) * inv_det,
    ]
}

/// |w|ⁿ for n ≥ 1 (0 at w = 0), in lanes.
#[inline(always)]
pub fn abs_pow<S: F64xN>(w: S, n: S) -> S {
    crate::model::simd::exp(n * crate::model::simd::ln(w.abs()))
}

/// tanh a, in lanes (±1 beyond where eᵃ overflows).
#[inline(always)]
pub fn tanh<S: F64xN>(a: S) -> S {
    let one = S::splat(1.0);
    let e = crate::model::simd::exp(S::splat(2.0) * a.abs());
    (one - S::splat(2.0) / (e + one)).copysign(a)
}

/// The normalised Bouc-Wen element's rate (Ikhouane & Rodellar's form):
/// ẇ = ρ [u − σ |u| |w|ⁿ sgn w + (σ − 1) u |w|ⁿ] for the element's
/// velocity `u`; |w| ≤ 1 for σ ≥ 0.
#[inline(always)]
pub fn bouc_wen_rate<S: F64xN>(rho: S, sigma: S, n: S, u: S, w: S) -> S {
    let wn = abs_pow(w, n);
    let signed = S::select(w.lt(S::splat(0.0)), -wn, wn);
    rho * (u - sigma * u.abs() * signed + (sigma - S::splat(1.0)) * u * wn)
}

/// ∂ẇ/∂u and ∂ẇ/∂w of [`bouc_wen_rate`] at element velocity `u` and `w`:
/// ρ [1 − σ sgn(u) sgn(w) |w|ⁿ + (σ − 1) |w|ⁿ] and
/// ρ n |w|ⁿ⁻¹ [(σ − 1) u sgn w − σ |u|].
#[inline(always)]
pub fn bouc_wen_derivatives<S: F64xN>(rho: S, sigma: S, n: S, u: S, w: S) -> (S, S) {
    let zero = S::splat(0.0);
    let one = S::splat(1.0);
    let wn = abs_pow(w, n);
    let wn1 = abs_pow(w, n - one);
    let sign_w = S::select(w.lt(zero), -one, one);
    let sign_u = S::select(u.lt(zero), -one, one);
    let du = rho * (one - sigma * sign_u * sign_w * wn + (sigma - one) * wn);
    let dw = rho * n * wn1 * ((sigma - one) * u * sign_w - sigma * u.abs());
    (du, dw)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::{bingham, bouc_wen, bp_spencer, spencer, testing};

    /// The AVX2 build gives the portable build's bits, for every state law
    /// (where the CPU has AVX2), with and without extrapolation.
    #[test]
    fn avx2_and_portable_builds_agree_bit_for_bit() {
        fn both<L: StateLaw>(p: &LawValues) {
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let run = testing::crank_run(1000.0, 1.0);
                let sets: [LawValues; LANES] = std::array::from_fn(|lane| {
                    let mut q = *p;
                    q[lane % L::PARAMETERS.len()] *= 1.0 + 0.03 * lane as f64;
                    q
                });
                for extrapolate in [false, true] {
                    let i = Integrator { extrapolate, ..Integrator::default() };
                    let mut a = Vec::new();
                    let mut b = Vec::new();
                    let mut oa = std::array::from_fn(|_| Ok(()));
                    let mut ob = std::array::from_fn(|_| Ok(()));
                    let sa = integrate::<L, Portable>(&i, &sets, &run, &mut oa, &mut |_, s| {
                        a.push(s.map(f64::to_bits))
                    });
                    // SAFETY: the CPU has AVX2 (checked above)
                    let sb = unsafe {
                        integrate_avx2::<L>(&i, &sets, &run, &mut ob, &mut |_, s| {
                            b.push(s.map(f64::to_bits))
                        })
                    };
                    assert_eq!((sa, a), (sb, b), "{:?}", L::KIND);
                }
            }
        }
        both::<bouc_wen::BoucWen>(&bouc_wen::values(1500.0, 600.0, 4000.0, 0.6, 2.3));
        both::<spencer::Spencer>(&spencer::values(3000.0, 4.0e4, 3000.0, 600.0, 1.0e4, 0.5, 2.0));
        both::<bingham::Bingham>(&bingham::values(800.0, 500.0, 0.01));
        both::<bp_spencer::BpSpencer>(&bp_spencer::values(
            &crate::model::Params::reference_1a(),
            2000.0,
            3.0e4,
            5.0e3,
        ));
    }
}
