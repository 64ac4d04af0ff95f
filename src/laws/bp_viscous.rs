//! The B-P law with a dashpot in parallel: the fluid's viscoplastic stress
//! (eqs. 3–4, [`super::bodner_partom`]) and a force linear in velocity,
//!
//! τ = τ_BP(γ history) + c0 h γ̇ / A,
//!
//! c0 in N s/m (the force c0 ẋ over the area; ẋ = h γ̇ by central
//! differences, as the Bouc-Wen family's dashpots). On the measured damper
//! a force linear in velocity explains much of what the B-P law leaves on
//! its slow strokes (docs/real-data.md).

use super::bodner_partom::{params_of, BodnerPartom};
use super::{bouc_wen, DamperLaw, LawKind, LawParameter, LawValues, MAX_LAW_PARAMETERS};
use crate::data::RunData;
use crate::model::{IntegrationError, Integrator, Params, LANES};

const PARAMETERS: [LawParameter; 8] = {
    let bp = super::bodner_partom::PARAMETERS;
    [bp[0], bp[1], bp[2], bp[3], bp[4], bp[5], bp[6], bouc_wen::C0]
};

#[derive(Clone, Copy, Debug, Default)]
pub struct BpViscous;

impl BpViscous {
    pub const fn new() -> Self {
        BpViscous
    }
}

/// A parameter set: the B-P parameters and the dashpot (N s/m).
pub fn values(p: &Params, c0: f64) -> LawValues {
    let mut v = [0.0; MAX_LAW_PARAMETERS];
    v[..7].copy_from_slice(&p.to_array());
    v[7] = c0;
    v
}

impl DamperLaw for BpViscous {
    fn kind(&self) -> LawKind {
        LawKind::BpViscous
    }

    fn parameters(&self) -> &'static [LawParameter] {
        &PARAMETERS
    }

    fn run_lanes(
        &self,
        integrator: &Integrator,
        params: &[LawValues; LANES],
        run: &RunData,
        visit: &mut dyn FnMut(usize, &[f64; LANES]),
    ) -> [Result<(), IntegrationError>; LANES] {
        let p = params.each_ref().map(params_of);
        let eta: [f64; LANES] = params.map(|v| v[7] * run.gap_m / run.area_m2);
        let rates = super::strain_rates(run);
        let mut outcome =
            integrator.run_lanes(&p, &run.time, &run.gamma, run.initial_tau, |k, s| {
                let stress: [f64; LANES] = std::array::from_fn(|l| s.tau[l] + eta[l] * rates[k]);
                visit(k, &stress)
            });
        for (lane, v) in params.iter().enumerate() {
            let (lo, hi) = PARAMETERS[7].range;
            if outcome[lane].is_ok() && !(v[7] >= lo && v[7] <= hi) {
                outcome[lane] = Err(IntegrationError::InvalidParams(format!(
                    "parameter c0 = {:e} is outside its physical range [{lo:e}, {hi:e}]",
                    v[7]
                )));
            }
        }
        outcome
    }

    fn euler_steps(&self, integrator: &Integrator, params: &LawValues, run: &RunData) -> u64 {
        BodnerPartom.euler_steps(integrator, params, run)
    }

    fn stiffness_bound(&self, params: &LawValues, _run: &RunData) -> f64 {
        params[0]
    }

    fn starts_at(&self, force: f64, velocity: f64, stroke: f64) -> Vec<LawValues> {
        let bp = BodnerPartom.starts_at(force, velocity, stroke)[0];
        vec![values(&params_of(&bp), 0.1 * force / velocity)]
    }

    fn typical(&self) -> LawValues {
        values(&Params::reference_1a(), 0.1 * 2700.0 / 0.28)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::testing;

    /// The B-P stress plus the dashpot's, by hand.
    #[test]
    fn the_stress_is_the_laws_and_the_dashpots() {
        let run = testing::crank_run(1000.0, 1.0);
        let p = Params::reference_1a();
        let bp = Integrator::default().run(&p, &run.time, &run.gamma).unwrap().tau;
        let path = BpViscous.path(&Integrator::default(), &values(&p, 2000.0), &run).unwrap();
        let n = run.time.len();
        for k in 1..n - 1 {
            let v = (run.gamma[k + 1] - run.gamma[k - 1]) / (run.time[k + 1] - run.time[k - 1]);
            let expected = bp[k] + 2000.0 * run.gap_m * v / run.area_m2;
            assert!((path[k] - expected).abs() <= 1e-9 * expected.abs().max(1.0), "{k}");
        }
    }

    #[test]
    fn conformance() {
        testing::conformance(&BpViscous, &values(&Params::reference_1a(), 2000.0));
    }
}
