//! The law of [`super::law`] for [`LANES`] parameter sets at once, one per
//! SIMD lane, for the integrator's hot loop; generic over the build of the
//! lanes ([`super::simd`]).

use super::params::{Params, D0};
use super::simd::{exp_of_finite, ln_of_positive, F64xN};

pub use super::simd::LANES;

const INV_SQRT_3: f64 = 0.577_350_269_189_625_8;

/// Largest exponent kept in q = (z/(√3|τ|))^(2n): e^700 is finite, and
/// exp(−½ q (n+1)/n) underflows to exactly 0 long before.
const MAX_LOG_Q: f64 = 700.0;

/// Per-lane parameters with the constants of eq. 3 precomputed.
#[derive(Clone, Copy)]
pub struct LaneLaw<S> {
    pub g: S,
    r0: S,
    r1: S,
    d1: S,
    m1: S,
    m2: S,
    /// ½ (n+1)/n
    half_n1_over_n: S,
    two_n: S,
    n_plus_1: S,
}

impl<S: F64xN> LaneLaw<S> {
    #[inline(always)]
    pub fn new(p: &[Params; LANES]) -> Self {
        let lanes = |f: fn(&Params) -> f64| S::from_array(p.each_ref().map(f));
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

    /// The law the share `s` (per lane, 0 to 1) of the way from `self` to
    /// `to`, every field linear in between: the parameters within a sample
    /// interval over which they change.
    #[inline(always)]
    pub fn toward(&self, to: &Self, s: S) -> Self {
        // written out, not through a closure: a closure would not inherit
        // the AVX2 target feature of the loop it is called from
        LaneLaw {
            g: self.g + (to.g - self.g) * s,
            r0: self.r0 + (to.r0 - self.r0) * s,
            r1: self.r1 + (to.r1 - self.r1) * s,
            d1: self.d1 + (to.d1 - self.d1) * s,
            m1: self.m1 + (to.m1 - self.m1) * s,
            m2: self.m2 + (to.m2 - self.m2) * s,
            half_n1_over_n: self.half_n1_over_n + (to.half_n1_over_n - self.half_n1_over_n) * s,
            two_n: self.two_n + (to.two_n - self.two_n) * s,
            n_plus_1: self.n_plus_1 + (to.n_plus_1 - self.n_plus_1) * s,
        }
    }

    /// e^(−m1 W) and e^(−m2 W), the decays of eq. 4.
    #[inline(always)]
    fn decays(&self, w: S) -> (S, S) {
        // the state carries a NaN on by itself: the checked exp is not needed
        (exp_of_finite(-self.m1 * w), exp_of_finite(-self.m2 * w))
    }

    /// R + D from the decays `(e1, e2)` (eq. 4).
    #[inline(always)]
    fn sum_of(&self, (e1, e2): (S, S)) -> S {
        self.r1 + (self.r0 - self.r1) * e1 + self.d1 * (S::splat(1.0) - e2)
    }

    /// R + D after inelastic work `w` (eq. 4).
    #[inline(always)]
    pub fn hardening_sum(&self, w: S) -> S {
        self.sum_of(self.decays(w))
    }

    /// R + D after inelastic work `w` and its slope d(R + D)/dW =
    /// m1 (R1 − R0) e^(−m1 W) + m2 D1 e^(−m2 W), from one pair of decays.
    #[inline(always)]
    pub fn hardening_with_slope(&self, w: S) -> (S, S) {
        let (e1, e2) = self.decays(w);
        (self.sum_of((e1, e2)), self.m1 * (self.r1 - self.r0) * e1 + self.m2 * self.d1 * e2)
    }

    /// γ̇ᴵ (with the sign of τ) and ∂γ̇ᴵ/∂τ at stress `tau` under hardening
    /// `z` (eq. 3); both 0 at τ = 0 and far below yield.
    #[inline(always)]
    pub fn flow(&self, tau: S, z: S) -> (S, S) {
        // one division for both uses of 1/|τ|
        let inv_abs_tau = S::splat(1.0) / tau.abs();
        // at τ = 0 the ratio is +∞, the logarithm too, and the cap makes q
        // finite and huge; z > 0 (R0, R1 > 0) keeps the ratio positive
        let log_q = (self.two_n * ln_of_positive(z * S::splat(INV_SQRT_3) * inv_abs_tau))
            .min(S::splat(MAX_LOG_Q));
        let q = exp_of_finite(log_q);
        let magnitude = S::splat(2.0 * D0) * exp_of_finite(-self.half_n1_over_n * q);
        let flowing = magnitude.gt(S::splat(0.0));
        let slope = S::select(flowing, magnitude * self.n_plus_1 * q * inv_abs_tau, S::splat(0.0));
        (magnitude.copysign(tau), slope)
    }
}
