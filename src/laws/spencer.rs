//! Spencer, Dyke, Sain & Carlson's (1997) modified Bouc-Wen model of an MR
//! damper ("phenomenological model"): a Bouc-Wen element with a dashpot c0
//! and a spring k0 moves an internal displacement y, in series with a
//! dashpot c1 that carries the force,
//!
//! F = c1 ẏ,   ẏ = [fz w + c0 ẋ + k0 (x − y)] / (c0 + c1),
//! ẇ = ρ [u − σ |u| |w|ⁿ sgn w + (σ − 1) u |w|ⁿ],   u = ẋ − ẏ,
//!
//! the hysteretic element in the normalised form of [`super::bouc_wen`]
//! (fz = α z₀, ρ = A/z₀, σ = γ/(β + γ) of the paper's α, β, γ, A). The
//! accumulator's spring k1 (x − x0) is the model terms' gas spring and
//! force offset. The internal displacement starts at the record's first
//! displacement, the hysteresis at rest.

use super::ode::{bouc_wen_derivatives, bouc_wen_rate, Jacobian, State, StateLaw, MAX_STATES};
use super::{bouc_wen, LawKind, LawParameter, LawValues, LANES, MAX_LAW_PARAMETERS};
use crate::data::RunData;
use crate::model::simd::F64xN;

const C1: LawParameter =
    LawParameter { name: "c1", unit: "N s/m", range: (1.0, 1e8), plausible: (1e3, 1e6) };
const K0: LawParameter =
    LawParameter { name: "k0", unit: "N/m", range: (1e-2, 1e8), plausible: (1e2, 1e5) };

const PARAMETERS: &[LawParameter] =
    &[bouc_wen::C0, C1, K0, bouc_wen::FZ, bouc_wen::RHO, bouc_wen::SIGMA, bouc_wen::N];

#[derive(Clone, Copy, Debug, Default)]
pub struct Spencer;

#[derive(Clone, Copy)]
pub struct Lanes<S> {
    c0: S,
    c1: S,
    k0: S,
    fz: S,
    rho: S,
    sigma: S,
    n: S,
    /// 1 / (c0 + c1)
    inv_c: S,
}

/// A parameter set in the order of the law's parameters.
#[allow(clippy::too_many_arguments)]
pub fn values(c0: f64, c1: f64, k0: f64, fz: f64, rho: f64, sigma: f64, n: f64) -> LawValues {
    let mut v = [0.0; MAX_LAW_PARAMETERS];
    v[..7].copy_from_slice(&[c0, c1, k0, fz, rho, sigma, n]);
    v
}

/// ẏ at (x, v, state).
#[inline(always)]
fn y_rate<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> S {
    (c.fz * state[1] + c.c0 * v + c.k0 * (x - state[0])) * c.inv_c
}

impl StateLaw for Spencer {
    const KIND: LawKind = LawKind::Spencer;
    const PARAMETERS: &'static [LawParameter] = PARAMETERS;
    type Lanes<S: F64xN> = Lanes<S>;

    #[inline(always)]
    fn lanes<S: F64xN>(p: &[LawValues; LANES], _run: &RunData) -> Lanes<S> {
        let at = |i: usize| S::from_array(p.each_ref().map(|v| v[i]));
        Lanes {
            c0: at(0),
            c1: at(1),
            k0: at(2),
            fz: at(3),
            rho: at(4),
            sigma: at(5),
            n: at(6),
            inv_c: S::from_array(p.each_ref().map(|v| 1.0 / (v[0] + v[1]))),
        }
    }

    #[inline(always)]
    fn rate<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> State<S> {
        let y_dot = y_rate(c, x, v, state);
        [y_dot, bouc_wen_rate(c.rho, c.sigma, c.n, v - y_dot, state[1]), S::splat(0.0)]
    }

    /// ∂ẏ/∂y = −k0/(c0 + c1), ∂ẏ/∂w = fz/(c0 + c1); ẇ through u = ẋ − ẏ
    /// and directly.
    #[inline(always)]
    fn jacobian<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> Jacobian<S> {
        let (dy_dy, dy_dw) = (S::splat(0.0) - c.k0 * c.inv_c, c.fz * c.inv_c);
        let u = v - y_rate(c, x, v, state);
        let (dw_du, dw_dw) = bouc_wen_derivatives(c.rho, c.sigma, c.n, u, state[1]);
        let zero = S::splat(0.0);
        [
            [dy_dy, dy_dw, zero],
            [zero - dw_du * dy_dy, dw_dw - dw_du * dy_dw, zero],
            [zero; MAX_STATES],
        ]
    }

    #[inline(always)]
    fn force<S: F64xN>(c: &Lanes<S>, x: S, v: S, state: State<S>) -> S {
        c.c1 * y_rate(c, x, v, state)
    }

    fn force_stiffness_bound(p: &LawValues, _run: &RunData) -> f64 {
        p[2] + p[3] * p[4] * (2.0 * p[5]).max(1.0)
    }

    fn starts(force: f64, velocity: f64, stroke: f64) -> Vec<LawValues> {
        let c = force / velocity;
        vec![
            values(0.3 * c, 3.0 * c, 0.1 * force / stroke, 0.8 * force, 20.0 / stroke, 0.5, 2.0),
            values(0.1 * c, 10.0 * c, 0.3 * force / stroke, 0.9 * force, 100.0 / stroke, 0.5, 2.0),
            values(0.5 * c, 2.0 * c, 0.03 * force / stroke, 0.5 * force, 5.0 / stroke, 1.0, 1.5),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::ode::Ode;
    use crate::laws::testing;

    /// The paper's equations in its own parameters (α, β, γ, A, n = 2),
    /// integrated independently (scalar RK4): the law's path from the
    /// normalised parameters they map to. Values of the order of the
    /// paper's fit (its Table 1 at about 1 V, SI).
    #[test]
    fn the_papers_equations_are_the_same_model() {
        let (alpha, beta, gamma, a, n): (f64, f64, f64, f64, f64) =
            (6.0e4, 3.63e6, 3.63e6, 301.0, 2.0);
        let (c0, c1, k0) = (4.0e3, 5.0e4, 4.69e3);
        let z0 = (a / (beta + gamma)).powf(1.0 / n);
        let p = values(c0, c1, k0, alpha * z0, a / z0, gamma / (beta + gamma), n);
        let run = testing::crank_run(2000.0, 1.0);
        let reference = testing::reference_path(&run, |x, v, s: [f64; 2]| {
            let (y, z) = (s[0], s[1]);
            let y_dot = (alpha * z + c0 * v + k0 * (x - y)) / (c0 + c1);
            let u = v - y_dot;
            let z_dot =
                -gamma * u.abs() * z * z.abs().powf(n - 1.0) - beta * u * z.abs().powf(n) + a * u;
            ([y_dot, z_dot], c1 * y_dot)
        });
        testing::close_to(&Ode::<Spencer>::new(), &p, &run, &reference, 2e-3);
    }

    #[test]
    fn conformance() {
        testing::conformance(
            &Ode::<Spencer>::new(),
            &values(3000.0, 4.0e4, 3000.0, 600.0, 1.0e4, 0.5, 2.0),
        );
    }
}
