//! The B-P law in Spencer et al.'s (1997) frame: the fluid's viscoplastic
//! element (paper eqs. 3–4, [`super::bodner_partom`]) takes the place of
//! the Bouc-Wen element of [`super::spencer`], beside a dashpot c0 and a
//! spring k0 that move an internal displacement y, in series with a
//! dashpot c1 that carries the force,
//!
//! F = c1 ẏ,   ẏ = [A τ + c0 ẋ + k0 (x − y)] / (c0 + c1),
//! τ̇ = G [(ẋ − ẏ)/h − γ̇ᴵ(τ, R + D)],   Ẇ = τ γ̇ᴵ,
//!
//! with the run's area A and gap h, and R + D the hardening after the
//! inelastic work W (eq. 4). The dashpot c1 gives the force its roll-off
//! at small velocities, which the B-P law alone cannot show: on a
//! measured damper the B-P law misses most where the velocity reverses.
//! The state (y, τ, W) starts at rest; the accumulator's spring and the
//! force offset are the model terms', as for every law. Its start is the
//! paper's identification of the B-P element with the dashpots and the
//! spring read off the records' scales.

use super::ode::{Jacobian, State, StateLaw};
use super::{bodner_partom, bouc_wen, LawKind, LawParameter, LawValues, LANES, MAX_LAW_PARAMETERS};
use crate::data::RunData;
use crate::model::lanes::LaneLaw;
use crate::model::simd::F64xN;
use crate::model::Params;

const C1: LawParameter =
    LawParameter { name: "c1", unit: "N s/m", range: (1.0, 1e8), plausible: (1e3, 1e6) };
const K0: LawParameter =
    LawParameter { name: "k0", unit: "N/m", range: (1e-2, 1e8), plausible: (1e2, 1e5) };

const PARAMETERS: [LawParameter; 10] = {
    let bp = bodner_partom::PARAMETERS;
    [bp[0], bp[1], bp[2], bp[3], bp[4], bp[5], bp[6], bouc_wen::C0, C1, K0]
};

#[derive(Clone, Copy, Debug, Default)]
pub struct BpSpencer;

#[derive(Clone, Copy)]
pub struct Lanes<S> {
    law: LaneLaw<S>,
    c0: S,
    c1: S,
    k0: S,
    /// 1 / (c0 + c1)
    inv_c: S,
    /// the run's area A (m²) and 1/h (1/m)
    area: S,
    inv_gap: S,
}

/// A parameter set: the B-P parameters, the dashpots c0, c1 (N s/m) and
/// the spring k0 (N/m).
pub fn values(p: &Params, c0: f64, c1: f64, k0: f64) -> LawValues {
    let mut v = [0.0; MAX_LAW_PARAMETERS];
    v[..7].copy_from_slice(&p.to_array());
    v[7..10].copy_from_slice(&[c0, c1, k0]);
    v
}

/// ẏ at (x, v, state).
#[inline(always)]
fn y_rate<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> S {
    (c.area * state[1] + c.c0 * v + c.k0 * (x - state[0])) * c.inv_c
}

impl StateLaw for BpSpencer {
    const KIND: LawKind = LawKind::BpSpencer;
    const PARAMETERS: &'static [LawParameter] = &PARAMETERS;
    const STATES: usize = 3;
    /// c0 walked as ln(c0 + 1 kN s/m), 1 kN s/m the centre of its plausible
    /// values: the records fix the damping c0 and the element's rate
    /// exponent n give together, and below a few hundred N s/m cannot tell
    /// the dashpot from the element's rate dependence, so c0's lower tail
    /// is its prior's (docs/performance.md, "What holds `bp-spencer` at 1
    /// A"): walked in ln c0 it took past 1 500 steps to fill, in this
    /// coordinate about 150.
    const SHIFTED: &'static [(usize, f64)] = &[(7, 1.0e3)];
    type Lanes<S: F64xN> = Lanes<S>;

    #[inline(always)]
    fn lanes<S: F64xN>(p: &[LawValues; LANES], run: &RunData) -> Lanes<S> {
        let at = |i: usize| S::from_array(p.each_ref().map(|v| v[i]));
        Lanes {
            law: LaneLaw::new(&p.each_ref().map(bodner_partom::params_of)),
            c0: at(7),
            c1: at(8),
            k0: at(9),
            inv_c: S::from_array(p.each_ref().map(|v| 1.0 / (v[7] + v[8]))),
            area: S::splat(run.area_m2),
            inv_gap: S::splat(1.0 / run.gap_m),
        }
    }

    /// (ẏ, τ̇, Ẇ) of the module's equations.
    #[inline(always)]
    fn rate<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> State<S> {
        let y_dot = y_rate(c, x, v, state);
        let (flow, _) = c.law.flow(state[1], c.law.hardening_sum(state[2]));
        let tau_dot = c.law.g * ((v - y_dot) * c.inv_gap - flow);
        [y_dot, tau_dot, state[1] * flow]
    }

    /// With a = ∂ẏ/∂y = −k0/(c0 + c1) and b = ∂ẏ/∂τ = A/(c0 + c1), s =
    /// ∂γ̇ᴵ/∂τ and ∂γ̇ᴵ/∂z = −s τ/z (eq. 3), z' = d(R + D)/dW (eq. 4):
    /// τ̇ through ẏ and the flow, Ẇ = τ γ̇ᴵ through both of its factors.
    #[inline(always)]
    fn jacobian<S: F64xN>(c: &Lanes<S>, _x: S, _v: S, state: State<S>) -> Jacobian<S> {
        let zero = S::splat(0.0);
        let tau = state[1];
        let (a, b) = (zero - c.k0 * c.inv_c, c.area * c.inv_c);
        let (z, z_w) = c.law.hardening_with_slope(state[2]);
        let (flow, slope) = c.law.flow(tau, z);
        // ∂γ̇ᴵ/∂W = −s τ/z · z'
        let flow_w = zero - slope * tau / z * z_w;
        let g_h = c.law.g * c.inv_gap;
        [
            [a, b, zero],
            [zero - g_h * a, zero - g_h * b - c.law.g * slope, zero - c.law.g * flow_w],
            [zero, flow + tau * slope, tau * flow_w],
        ]
    }

    #[inline(always)]
    fn force<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> S {
        c.c1 * y_rate(c, x, v, state)
    }

    /// The spring k0 and the element's elastic stiffness G A/h side by
    /// side: no path through the frame is stiffer than both together.
    fn force_stiffness_bound(p: &LawValues, run: &RunData) -> f64 {
        p[9] + p[0] * run.area_m2 / run.gap_m
    }

    /// The B-P element at the plausible centre of its parameters, the
    /// dashpots and the spring as [`super::spencer`]'s starts take them.
    fn starts(force: f64, velocity: f64, stroke: f64) -> Vec<LawValues> {
        let bp = Params::from_array(std::array::from_fn(Params::plausible_centre));
        Self::around(&bp, force, velocity, stroke)
    }

    fn builds_on_bodner_partom() -> bool {
        true
    }

    fn around(bp: &Params, force: f64, velocity: f64, stroke: f64) -> Vec<LawValues> {
        let c = force / velocity;
        vec![
            values(bp, 0.3 * c, 3.0 * c, 0.1 * force / stroke),
            values(bp, 0.1 * c, 10.0 * c, 0.3 * force / stroke),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::ode::Ode;
    use crate::laws::testing;
    use crate::model::law::Law;

    /// The module's equations with the scalar law of `crate::model::law`
    /// (its flow rule and hardening, not the lanes'), integrated
    /// independently (scalar RK4): the law's path.
    #[test]
    fn the_equations_are_the_same_model() {
        let bp = Params::reference_1a();
        let (c0, c1, k0) = (2000.0, 3.0e4, 5.0e3);
        let p = values(&bp, c0, c1, k0);
        let run = testing::crank_run(2000.0, 1.0);
        let (area, gap) = (run.area_m2, run.gap_m);
        let law = Law::new(&bp);
        let reference = testing::reference_path(&run, |x, v, s: [f64; 3]| {
            let (y, tau, w) = (s[0], s[1], s[2]);
            let y_dot = (area * tau + c0 * v + k0 * (x - y)) / (c0 + c1);
            let flow = law.flow(tau, law.hardening_sum(w)).rate;
            let tau_dot = bp.g * ((v - y_dot) / gap - flow);
            ([y_dot, tau_dot, tau * flow], c1 * y_dot)
        });
        testing::close_to(&Ode::<BpSpencer>::new(), &p, &run, &reference, 2e-3);
    }

    /// The flow rule's knee at yield is stiff at the harness's usual
    /// ladder (16–64 sub-steps on its crank): measured, the error falls by
    /// 2.4, 2.9, 3.3, 3.6, 3.8× per doubling from 8 to 256 sub-steps
    /// (second order reached), extrapolated by 4.2, 5.2, 6.2, 6.9, 7.4×
    /// (third): the ladder starts at 64.
    #[test]
    fn conformance() {
        testing::conformance_from(
            &Ode::<BpSpencer>::new(),
            &values(&Params::reference_1a(), 2000.0, 3.0e4, 5.0e3),
            64,
        );
    }
}
