//! Bingham's model of an MR damper (Stanway et al. 1987): a dashpot and a
//! yield (Coulomb) force, its sign made smooth,
//!
//! F = c0 ẋ + fc tanh(ẋ / v0),
//!
//! v0 the velocity over which the yield force turns (a sign function
//! would make the likelihood jump). The accumulator's spring and a force
//! offset are the model terms. No state: the force at each sample follows
//! from its velocity.

use super::ode::{tanh, Jacobian, State, StateLaw, MAX_STATES};
use super::{bouc_wen, LawKind, LawParameter, LawValues, LANES, MAX_LAW_PARAMETERS};
use crate::data::RunData;
use crate::model::simd::F64xN;

const FC: LawParameter =
    LawParameter { name: "fc", unit: "N", range: (1e-3, 1e6), plausible: (30.0, 3000.0) };
const V0: LawParameter =
    LawParameter { name: "v0", unit: "m/s", range: (1e-6, 10.0), plausible: (1e-3, 3e-2) };

const PARAMETERS: &[LawParameter] = &[bouc_wen::C0, FC, V0];

#[derive(Clone, Copy, Debug, Default)]
pub struct Bingham;

#[derive(Clone, Copy)]
pub struct Lanes<S> {
    c0: S,
    fc: S,
    inv_v0: S,
}

/// A parameter set in the order of the law's parameters.
pub fn values(c0: f64, fc: f64, v0: f64) -> LawValues {
    let mut v = [0.0; MAX_LAW_PARAMETERS];
    v[..3].copy_from_slice(&[c0, fc, v0]);
    v
}

impl StateLaw for Bingham {
    const KIND: LawKind = LawKind::Bingham;
    const PARAMETERS: &'static [LawParameter] = PARAMETERS;
    type Lanes<S: F64xN> = Lanes<S>;

    #[inline(always)]
    fn lanes<S: F64xN>(p: &[LawValues; LANES], _run: &RunData) -> Lanes<S> {
        Lanes {
            c0: S::from_array(p.each_ref().map(|v| v[0])),
            fc: S::from_array(p.each_ref().map(|v| v[1])),
            inv_v0: S::from_array(p.each_ref().map(|v| 1.0 / v[2])),
        }
    }

    #[inline(always)]
    fn rate<S: F64xN>(_c: &Lanes<S>, _x: S, _v: S, _state: State<S>) -> State<S> {
        [S::splat(0.0); MAX_STATES]
    }

    #[inline(always)]
    fn jacobian<S: F64xN>(_c: &Lanes<S>, _x: S, _v: S, _state: State<S>) -> Jacobian<S> {
        [[S::splat(0.0); MAX_STATES]; MAX_STATES]
    }

    #[inline(always)]
    fn force<S: F64xN>(c: &Lanes<S>, _x: S, v: S, _state: State<S>) -> S {
        c.c0 * v + c.fc * tanh(v * c.inv_v0)
    }

    fn force_stiffness_bound(_p: &LawValues, _run: &RunData) -> f64 {
        0.0
    }

    fn starts(force: f64, velocity: f64, _stroke: f64) -> Vec<LawValues> {
        vec![
            values(0.3 * force / velocity, 0.7 * force, 0.05 * velocity),
            values(0.1 * force / velocity, 0.9 * force, 0.01 * velocity),
            values(0.6 * force / velocity, 0.4 * force, 0.2 * velocity),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::ode::Ode;
    use crate::laws::testing;

    /// The force by hand at every sample: c0 v + fc tanh(v/v0), v the
    /// central difference of the displacement.
    #[test]
    fn the_force_is_the_formula() {
        let p = values(800.0, 500.0, 0.01);
        let run = testing::crank_run(1000.0, 1.0);
        let reference = testing::reference_path(&run, |_x, v, _s| {
            ([0.0; 1], 800.0 * v + 500.0 * (v / 0.01).tanh())
        });
        testing::close_to(&Ode::<Bingham>::new(), &p, &run, &reference, 1e-12);
    }

    #[test]
    fn conformance() {
        testing::conformance(&Ode::<Bingham>::new(), &values(800.0, 500.0, 0.01));
    }
}
