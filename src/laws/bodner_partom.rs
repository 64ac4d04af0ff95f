//! The Bodner-Partom law for shear (paper eqs. 3–4) as a damper law: the
//! seven parameters of [`crate::model::Params`] and the integrators of
//! [`crate::model`], unchanged (the same bits as calling them directly).
//! Its start is the paper's identification (`crate::identify`), which the
//! calibration runs itself; [`DamperLaw::starts`] gives the plausible
//! centre for other callers.

use super::{DamperLaw, LawKind, LawParameter, LawValues, MAX_LAW_PARAMETERS};
use crate::data::RunData;
use crate::model::{
    IntegrationError, Integrator, Params, LANES, PARAM_NAMES, PARAM_UNITS, PHYSICAL_RANGE,
    PLAUSIBLE_RANGE,
};

pub(super) const PARAMETERS: [LawParameter; 7] = {
    let mut p = [LawParameter { name: "", unit: "", range: (0.0, 0.0), plausible: (0.0, 0.0) }; 7];
    let mut i = 0;
    while i < 7 {
        p[i] = LawParameter {
            name: PARAM_NAMES[i],
            unit: PARAM_UNITS[i],
            range: PHYSICAL_RANGE[i],
            plausible: PLAUSIBLE_RANGE[i],
        };
        i += 1;
    }
    p
};

/// The B-P parameters of a law's values.
pub fn params_of(v: &LawValues) -> Params {
    Params::from_array(std::array::from_fn(|i| v[i]))
}

/// A law's values of the B-P parameters.
pub fn values_of(p: &Params) -> LawValues {
    let mut v = [0.0; MAX_LAW_PARAMETERS];
    v[..7].copy_from_slice(&p.to_array());
    v
}

#[derive(Clone, Copy, Debug, Default)]
pub struct BodnerPartom;

impl BodnerPartom {
    pub const fn new() -> Self {
        BodnerPartom
    }
}

impl DamperLaw for BodnerPartom {
    fn kind(&self) -> LawKind {
        LawKind::BodnerPartom
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
        integrator.run_lanes(&p, &run.time, &run.gamma, run.initial_tau, |k, s| visit(k, &s.tau))
    }

    fn euler_steps(&self, integrator: &Integrator, params: &LawValues, run: &RunData) -> u64 {
        integrator.euler_steps(&params_of(params), &run.time, &run.gamma, run.initial_tau)
    }

    fn stiffness_bound(&self, params: &LawValues, _run: &RunData) -> f64 {
        params[0]
    }

    fn starts_at(&self, _force: f64, _velocity: f64, _stroke: f64) -> Vec<LawValues> {
        vec![values_of(&Params::from_array(std::array::from_fn(Params::plausible_centre)))]
    }

    fn typical(&self) -> LawValues {
        values_of(&Params::reference_1a())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::testing;

    /// The law through the seam gives the integrator's own bits.
    #[test]
    fn the_law_is_the_integrators() {
        let run = testing::crank_run(1000.0, 0.5);
        let p = Params::reference_1a();
        let direct = Integrator::default().run(&p, &run.time, &run.gamma).unwrap().tau;
        let through = BodnerPartom.path(&Integrator::default(), &values_of(&p), &run).unwrap();
        assert_eq!(direct, through);
    }

    #[test]
    fn conformance() {
        testing::conformance(&BodnerPartom, &values_of(&Params::reference_1a()));
    }
}
