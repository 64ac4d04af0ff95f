//! Bouc-Wen: a dashpot in parallel with Wen's hysteretic element, in the
//! normalised form of Ikhouane & Rodellar (2007), whose parameters the
//! records can each fix:
//!
//! F = c0 ẋ + fz w,   ẇ = ρ [ẋ − σ |ẋ| |w|ⁿ sgn w + (σ − 1) ẋ |w|ⁿ],
//!
//! |w| ≤ 1 for σ ≥ 0, so fz is the hysteretic force's amplitude and 1/ρ the
//! displacement over which it builds up; σ (`shape` in outputs, beside the
//! noise's σ) sets how the loop turns at a reversal. The classical form (Spencer et
//! al.'s notation) F = c0 ẋ + α z, ż = −γ |ẋ| z |z|ⁿ⁻¹ − β ẋ |z|ⁿ + A ẋ is the
//! same model with z₀ = (A/(β + γ))^(1/n), w = z/z₀, fz = α z₀, ρ = A/z₀
//! and σ = γ/(β + γ); α and A alone are not identifiable (only α z₀ is).
//! The parallel spring k0 (x − x0) of some writings is the model terms'
//! gas spring and force offset.

use super::ode::{bouc_wen_derivatives, bouc_wen_rate, Jacobian, State, StateLaw, MAX_STATES};
use super::{LawKind, LawParameter, LawValues, LANES, MAX_LAW_PARAMETERS};
use crate::data::RunData;
use crate::model::simd::F64xN;

pub(super) const C0: LawParameter =
    LawParameter { name: "c0", unit: "N s/m", range: (1e-2, 1e7), plausible: (1e2, 1e4) };
pub(super) const FZ: LawParameter =
    LawParameter { name: "fz", unit: "N", range: (1e-3, 1e6), plausible: (30.0, 3000.0) };
pub(super) const RHO: LawParameter =
    LawParameter { name: "rho", unit: "1/m", range: (1.0, 1e8), plausible: (1e2, 1e5) };
/// σ, named `shape` in outputs (beside the noise's σ of each run).
pub(super) const SIGMA: LawParameter =
    LawParameter { name: "shape", unit: "-", range: (1e-3, 1e3), plausible: (0.2, 1.5) };
pub(super) const N: LawParameter =
    LawParameter { name: "n", unit: "-", range: (1.0, 20.0), plausible: (1.2, 3.5) };

const PARAMETERS: &[LawParameter] = &[C0, FZ, RHO, SIGMA, N];

#[derive(Clone, Copy, Debug, Default)]
pub struct BoucWen;

#[derive(Clone, Copy)]
pub struct Lanes<S> {
    c0: S,
    fz: S,
    rho: S,
    sigma: S,
    n: S,
}

/// A parameter set in the order of the law's parameters.
pub fn values(c0: f64, fz: f64, rho: f64, sigma: f64, n: f64) -> LawValues {
    let mut v = [0.0; MAX_LAW_PARAMETERS];
    v[..5].copy_from_slice(&[c0, fz, rho, sigma, n]);
    v
}

impl StateLaw for BoucWen {
    const KIND: LawKind = LawKind::BoucWen;
    const PARAMETERS: &'static [LawParameter] = PARAMETERS;
    type Lanes<S: F64xN> = Lanes<S>;

    #[inline(always)]
    fn lanes<S: F64xN>(p: &[LawValues; LANES], _run: &RunData) -> Lanes<S> {
        let at = |i: usize| S::from_array(p.each_ref().map(|v| v[i]));
        Lanes { c0: at(0), fz: at(1), rho: at(2), sigma: at(3), n: at(4) }
    }

    #[inline(always)]
    fn rate<S: F64xN>(c: &Lanes<S>, _x: S, v: S, state: State<S>) -> State<S> {
        [bouc_wen_rate(c.rho, c.sigma, c.n, v, state[0]), S::splat(0.0), S::splat(0.0)]
    }

    #[inline(always)]
    fn jacobian<S: F64xN>(c: &Lanes<S>, _x: S, v: S, state: State<S>) -> Jacobian<S> {
        let zero = S::splat(0.0);
        let (_, dw) = bouc_wen_derivatives(c.rho, c.sigma, c.n, v, state[0]);
        [[dw, zero, zero], [zero; MAX_STATES], [zero; MAX_STATES]]
    }

    #[inline(always)]
    fn force<S: F64xN>(c: &Lanes<S>, _x: S, v: S, state: State<S>) -> S {
        c.c0 * v + c.fz * state[0]
    }

    fn force_stiffness_bound(p: &LawValues, _run: &RunData) -> f64 {
        p[1] * p[2] * (2.0 * p[3]).max(1.0)
    }

    fn starts(force: f64, velocity: f64, stroke: f64) -> Vec<LawValues> {
        vec![
            values(0.3 * force / velocity, 0.7 * force, 20.0 / stroke, 0.5, 2.0),
            values(0.1 * force / velocity, 0.9 * force, 100.0 / stroke, 0.5, 1.5),
            values(0.6 * force / velocity, 0.4 * force, 5.0 / stroke, 1.0, 2.0),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::ode::Ode;
    use crate::laws::testing;

    /// Wen's classical equations, integrated independently (scalar RK4 on
    /// z in its own units, from α, β, γ, A): the law's path from the
    /// normalised parameters they map to.
    #[test]
    fn the_classical_form_is_the_same_model() {
        let (alpha, a, beta, gamma, n): (f64, f64, f64, f64, f64) =
            (4.0e4, 120.0, 2.0e6, 3.0e6, 2.0);
        let z0 = (a / (beta + gamma)).powf(1.0 / n);
        let c0 = 1500.0;
        let p = values(c0, alpha * z0, a / z0, gamma / (beta + gamma), n);
        let run = testing::crank_run(2000.0, 1.0);
        let reference = testing::reference_path(&run, |x, v, z: [f64; 2]| {
            let zdot = -gamma * v.abs() * z[0] * z[0].abs().powf(n - 1.0)
                - beta * v * z[0].abs().powf(n)
                + a * v;
            let _ = x;
            ([zdot, 0.0], c0 * v + alpha * z[0])
        });
        testing::close_to(&Ode::<BoucWen>::new(), &p, &run, &reference, 1e-3);
    }

    #[test]
    fn conformance() {
        testing::conformance(&Ode::<BoucWen>::new(), &values(1500.0, 600.0, 4000.0, 0.6, 2.0));
    }
}
