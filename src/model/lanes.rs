//! The law of [`super::law`] for [`LANES`] parameter sets at once, one per
//! SIMD lane (`wide::f64x4`), for the integrator's hot loop.

use wide::{f64x4, CmpGt};

use super::params::{Params, D0};

/// Parameter sets integrated together.
pub const LANES: usize = 4;

const INV_SQRT_3: f64 = 0.577_350_269_189_625_8;

/// Largest exponent kept in q = (z/(√3|τ|))^(2n): e^700 is finite, and
/// exp(−½ q (n+1)/n) underflows to exactly 0 long before.
const MAX_LOG_Q: f64 = 700.0;

/// Per-lane parameters with the constants of eq. 3 precomputed.
pub struct LaneLaw {
    pub g: f64x4,
    r0: f64x4,
    r1: f64x4,
    d1: f64x4,
    m1: f64x4,
    m2: f64x4,
    /// ½ (n+1)/n
    half_n1_over_n: f64x4,
    two_n: f64x4,
    n_plus_1: f64x4,
}

impl LaneLaw {
    pub fn new(p: &[Params; LANES]) -> Self {
        let lanes = |f: fn(&Params) -> f64| f64x4::from(p.each_ref().map(f));
        LaneLaw {
            g: lanes(|p| p.g),
            r0: lanes(|p| p.r0),
            r1: lanes(|p| p.r1),
            d1: lanes(|p| p.d1),
            m1: lanes(|p| p.m1),
            m2: lanes(|p| p.m2),
            half_n1_over_n: lanes(|p| 0.5 * (p.n + 1.0) / p.n),
            two_n: lanes(|p| 2.0 * p.n),
            n_plus_1: lanes(|p| p.n + 1.0),
        }
    }

    /// R + D after inelastic work `w` (eq. 4).
    #[inline(always)]
    pub fn hardening_sum(&self, w: f64x4) -> f64x4 {
        let e1 = (-self.m1 * w).exp();
        let e2 = (-self.m2 * w).exp();
        self.r1 + (self.r0 - self.r1) * e1 + self.d1 * (f64x4::ONE - e2)
    }

    /// γ̇ᴵ (with the sign of τ) and ∂γ̇ᴵ/∂τ at stress `tau` under hardening
    /// `z` (eq. 3); both 0 at τ = 0 and far below yield.
    #[inline(always)]
    pub fn flow(&self, tau: f64x4, z: f64x4) -> (f64x4, f64x4) {
        let abs_tau = tau.abs();
        // at τ = 0 the logarithm is +∞ and the cap makes q finite and huge
        let log_q = (self.two_n * (z * f64x4::splat(INV_SQRT_3) / abs_tau).ln()).min(f64x4::splat(MAX_LOG_Q));
        let q = log_q.exp();
        let magnitude = f64x4::splat(2.0 * D0) * (-self.half_n1_over_n * q).exp();
        let flowing = magnitude.cmp_gt(f64x4::ZERO);
        let slope = flowing.blend(magnitude * self.n_plus_1 * q / abs_tau, f64x4::ZERO);
        (magnitude.copysign(tau), slope)
    }
}
