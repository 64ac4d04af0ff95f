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
//! Both are first order. The integrator never returns a silently wrong curve:
//! non-finite values or a step count past [`Integrator::max_substeps`] are an
//! [`IntegrationError`], which a posterior turns into log-density −∞.

use super::law::{Flow, Law};
use super::params::Params;

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
}

impl Default for Integrator {
    fn default() -> Self {
        Integrator {
            scheme: Scheme::Explicit,
            substeps: 1,
            stability: 1.0,
            max_substeps: 1000,
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

impl Integrator {
    /// Integrates from `initial` at `t[0]` and calls `visit(k, state)` at every
    /// sample time `t[k]`, `k = 0..t.len()`. Allocates nothing; the visitor
    /// decides what to keep (a likelihood keeps only a sum of squares).
    #[inline]
    pub fn run_with(
        &self,
        p: &Params,
        t: &[f64],
        gamma: &[f64],
        initial: State,
        mut visit: impl FnMut(usize, State),
    ) -> Result<State, IntegrationError> {
        p.validate().map_err(IntegrationError::InvalidParams)?;
        if t.len() != gamma.len() {
            return Err(IntegrationError::InvalidHistory(format!(
                "{} times but {} strains",
                t.len(),
                gamma.len()
            )));
        }
        if t.is_empty() {
            return Ok(initial);
        }
        let law = Law::new(p);
        let mut s = initial;
        let mut z = law.hardening_sum(s.w);
        let mut flow = law.flow(s.tau, z);
        visit(0, s);
        for k in 0..t.len() - 1 {
            let dt = t[k + 1] - t[k];
            if !(dt > 0.0) {
                return Err(IntegrationError::InvalidHistory(format!(
                    "time does not increase at sample {}",
                    k + 1
                )));
            }
            self.advance(&law, &mut s, &mut flow, &mut z, (gamma[k + 1] - gamma[k]) / dt, dt, t[k])?;
            visit(k + 1, s);
        }
        Ok(s)
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

    /// Advances the state over one sample interval of length `dt` at constant
    /// total strain rate `strain_rate`. This is the hot loop of every
    /// likelihood evaluation. `flow` and `z` = R + D belong to `s` and are
    /// carried from step to step, so each accepted sub-step evaluates the law
    /// once.
    ///
    /// Step control: a sub-step is at most `dt / substeps`, moves τ by at
    /// most a quarter of (R + D)/√3, and, if explicit, keeps λh ≤ `stability`
    /// with λ at its start. A sub-step is
    /// rejected and halved when it ends where the stiffness says it was too
    /// long: λh > 2 at its end (explicit), or λ grew by more than 1/h over it
    /// (linearly implicit, whose linearisation at the start then no longer
    /// holds). This catches the elastic predictor that jumps far past yield
    /// in one step, which the stiffness at the start cannot see.
    #[inline(always)]
    fn advance(
        &self,
        law: &Law,
        s: &mut State,
        flow: &mut Flow,
        z: &mut f64,
        strain_rate: f64,
        dt: f64,
        t0: f64,
    ) -> Result<(), IntegrationError> {
        let g = law.p.g;
        let h_max = dt / self.substeps as f64;
        let explicit = self.scheme == Scheme::Explicit;
        let mut left = dt;
        let mut attempts = 0u32;
        let mut h_cap = h_max;
        // the last sub-step ends exactly at the sample time, up to round-off
        while left > 1e-12 * dt {
            attempts += 1;
            if attempts > self.max_substeps {
                return Err(IntegrationError::TooStiff {
                    time: t0,
                    substeps: self.max_substeps,
                });
            }
            let lambda = g * flow.slope;
            let stress_rate = g * (strain_rate - flow.rate);
            let mut h = left.min(h_cap);
            if explicit && lambda * h > self.stability {
                // equal sub-steps over what is left, each within the stability limit
                h = left / (left * lambda / self.stability).ceil();
            }
            // no sub-step may move τ by more than a share of the stress scale
            // of eq. 3, (R + D)/√3: beyond it the flow rate saturates at 2D₀
            // and λ no longer measures how fast the state can change
            let max_dtau = MAX_STRESS_STEP * *z * INV_SQRT_3;
            if stress_rate.abs() * h > max_dtau {
                h = max_dtau / stress_rate.abs();
            }
            let dtau = stress_rate * h;
            let tau = s.tau
                + if explicit {
                    dtau
                } else {
                    dtau / (1.0 + h * lambda)
                };
            // τ γ̇ᴵ ≥ 0 because γ̇ᴵ has the sign of τ: Wᴵ never decreases
            let w = s.w + h * s.tau * flow.rate;
            let end_z = law.hardening_sum(w);
            let end = law.flow(tau, end_z);
            let end_lambda = g * end.slope;
            let too_long = if explicit {
                end_lambda * h > 2.0
            } else {
                (end_lambda - lambda) * h > 1.0
            };
            if too_long && h > 1e-9 * dt {
                h_cap = 0.5 * h;
                continue;
            }
            s.tau = tau;
            s.w = w;
            *flow = end;
            *z = end_z;
            left -= h;
            h_cap = (2.0 * h).min(h_max);
        }
        if !(s.tau.is_finite() && s.w.is_finite()) {
            return Err(IntegrationError::NonFinite { time: t0 + dt });
        }
        Ok(())
    }
}

/// τ and Wᴵ with the default integrator (explicit Euler, stable sub-steps).
pub fn integrate(p: &Params, t: &[f64], gamma: &[f64]) -> Result<Trajectory, IntegrationError> {
    Integrator::default().run(p, t, gamma)
}

#[cfg(test)]
mod tests {
    use super::*;
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
            .map(|&m| {
                run(m)
                    .iter()
                    .zip(&reference)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
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
