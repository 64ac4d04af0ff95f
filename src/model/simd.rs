//! [`LANES`] f64 lanes, written once for the integrator's hot loop and compiled
//! twice: for any x86-64 (or other) CPU ([`Portable`], plain arrays the
//! compiler vectorises as it can) and, chosen at run time where the CPU has
//! it, for AVX2 ([`avx2::Avx2`], 256-bit registers).
//!
//! Both builds compute the same IEEE operations in the same order — no
//! fused multiply-add, `exp` and `ln` from the same polynomials below — so
//! their results are identical bit for bit: chains do not depend on the
//! machine's instruction set.

// the polynomial coefficients keep the digits they were published with
#![allow(clippy::excessive_precision)]

use std::ops::{Add, Div, Mul, Neg, Sub};

#[cfg(target_arch = "x86_64")]
pub mod avx2;

/// Lanes of a value: two groups of four, so that the two halves' long
/// chains of dependent operations (exp, ln, the step control) overlap in
/// the CPU. One AVX2 register holds four.
pub const LANES: usize = 8;

/// [`LANES`] f64 lanes. A *mask* is a value whose lanes are all ones (true) or
/// all zeros (false) bit for bit, as the comparisons return.
pub trait F64xN:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    fn splat(v: f64) -> Self;
    fn from_array(a: [f64; LANES]) -> Self;
    fn to_array(self) -> [f64; LANES];
    fn abs(self) -> Self;
    /// `self` where `self < other`, else `other` (also when either is NaN).
    fn min(self, other: Self) -> Self;
    fn floor(self) -> Self;
    fn ceil(self) -> Self;
    /// Rounded to the nearest integer, ties to even.
    fn round(self) -> Self;
    fn gt(self, other: Self) -> Self;
    fn lt(self, other: Self) -> Self;
    /// Lanes that are neither infinite nor NaN.
    fn finite(self) -> Self;
    fn and(self, other: Self) -> Self;
    fn or(self, other: Self) -> Self;
    /// `!self & other`.
    fn and_not(self, other: Self) -> Self;
    /// `t` in the lanes where `mask` is set, `f` elsewhere.
    fn select(mask: Self, t: Self, f: Self) -> Self;
    fn any(self) -> bool;
    fn all(self) -> bool;
    /// The magnitude of `self` with the sign of `sign`.
    fn copysign(self, sign: Self) -> Self;
    /// 2ⁿ for integral `n` in [−1022, 1023].
    fn pow2(n: Self) -> Self;
    /// For finite positive normal `self`: (m, e) with self = m 2ᵉ, m ∈ [1, 2).
    fn split_exponent(self) -> (Self, Self);

    fn mask_to_bools(self) -> [bool; LANES] {
        self.to_array().map(|v| v.to_bits() != 0)
    }
}

/// The portable build: plain arrays, lane by lane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Portable(pub [f64; LANES]);

macro_rules! lanewise {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for Portable {
            type Output = Portable;
            #[inline(always)]
            fn $method(self, o: Portable) -> Portable {
                Portable(std::array::from_fn(|i| self.0[i] $op o.0[i]))
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);
lanewise!(Div, div, /);

impl Neg for Portable {
    type Output = Portable;
    #[inline(always)]
    fn neg(self) -> Portable {
        Portable(self.0.map(|v| -v))
    }
}

const ALL: u64 = u64::MAX;
const SIGN: u64 = 1 << 63;

#[inline(always)]
fn mask_of(b: bool) -> f64 {
    f64::from_bits(if b { ALL } else { 0 })
}

impl Portable {
    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Portable {
        Portable(self.0.map(f))
    }
    #[inline(always)]
    fn zip(self, o: Portable, f: impl Fn(f64, f64) -> f64) -> Portable {
        Portable(std::array::from_fn(|i| f(self.0[i], o.0[i])))
    }
    #[inline(always)]
    fn bits(self, o: Portable, f: impl Fn(u64, u64) -> u64) -> Portable {
        self.zip(o, |a, b| f64::from_bits(f(a.to_bits(), b.to_bits())))
    }
}

impl F64xN for Portable {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        Portable([v; LANES])
    }
    #[inline(always)]
    fn from_array(a: [f64; LANES]) -> Self {
        Portable(a)
    }
    #[inline(always)]
    fn to_array(self) -> [f64; LANES] {
        self.0
    }
    #[inline(always)]
    fn abs(self) -> Self {
        self.map(|v| f64::from_bits(v.to_bits() & !SIGN))
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.zip(o, |a, b| if a < b { a } else { b })
    }
    #[inline(always)]
    fn floor(self) -> Self {
        self.map(f64::floor)
    }
    #[inline(always)]
    fn ceil(self) -> Self {
        self.map(f64::ceil)
    }
    #[inline(always)]
    fn round(self) -> Self {
        self.map(f64::round_ties_even)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Self {
        self.zip(o, |a, b| mask_of(a > b))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> Self {
        self.zip(o, |a, b| mask_of(a < b))
    }
    #[inline(always)]
    fn finite(self) -> Self {
        self.map(|v| mask_of(v.is_finite()))
    }
    #[inline(always)]
    fn and(self, o: Self) -> Self {
        self.bits(o, |a, b| a & b)
    }
    #[inline(always)]
    fn or(self, o: Self) -> Self {
        self.bits(o, |a, b| a | b)
    }
    #[inline(always)]
    fn and_not(self, o: Self) -> Self {
        self.bits(o, |a, b| !a & b)
    }
    #[inline(always)]
    fn select(mask: Self, t: Self, f: Self) -> Self {
        Portable(std::array::from_fn(|i| if mask.0[i].to_bits() != 0 { t.0[i] } else { f.0[i] }))
    }
    #[inline(always)]
    fn any(self) -> bool {
        self.0.iter().any(|v| v.to_bits() != 0)
    }
    #[inline(always)]
    fn all(self) -> bool {
        self.0.iter().all(|v| v.to_bits() != 0)
    }
    #[inline(always)]
    fn copysign(self, sign: Self) -> Self {
        self.bits(sign, |a, s| (a & !SIGN) | (s & SIGN))
    }
    #[inline(always)]
    fn pow2(n: Self) -> Self {
        n.map(|v| f64::from_bits(((v as i64 + 1023) as u64) << 52))
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        let m = self.map(|v| f64::from_bits((v.to_bits() & !(0x7ff << 52)) | (1023 << 52)));
        let e = self.map(|v| ((v.to_bits() >> 52) & 0x7ff) as f64 - 1023.0);
        (m, e)
    }
}

const LN2_HI: f64 = 6.931_471_803_691_238_164_90e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_700_02e-10;
const LOG2_E: f64 = std::f64::consts::LOG2_E;
const SQRT_2: f64 = std::f64::consts::SQRT_2;
const TWO_54: f64 = 18_014_398_509_481_984.0;

/// 1/k! for k = 2..=13: with eʳ = 1 + r + Σ r^k/k!, the truncation error
/// for |r| ≤ ln2/2 is below 5e-18.
const EXP_TAYLOR: [f64; 12] = [
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5040.0,
    1.0 / 40320.0,
    1.0 / 362880.0,
    1.0 / 3628800.0,
    1.0 / 39916800.0,
    1.0 / 479001600.0,
    1.0 / 6227020800.0,
];

/// eˣ for x ≤ 709.7, within two units in the last place; 0 below −708.
/// A NaN comes out finite: for callers whose state carries a NaN on by
/// itself (the integrator's τ and Wᴵ do); [`exp`] keeps it.
#[inline(always)]
pub fn exp_of_finite<S: F64xN>(x: S) -> S {
    let lo = S::splat(-708.0);
    let below = x.lt(lo);
    let x = S::select(below, lo, x);
    // x = k ln2 + r, |r| ≤ ln2/2, with ln2 in two parts so r is exact
    let k = (x * S::splat(LOG2_E)).round();
    let r = (x - k * S::splat(LN2_HI)) - k * S::splat(LN2_LO);
    // eʳ − 1 − r by Estrin's scheme: independent products for the CPU to overlap
    let c = |i: usize| S::splat(EXP_TAYLOR[i]);
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let low = (c(0) + r * c(1)) + r2 * (c(2) + r * c(3));
    let mid = (c(4) + r * c(5)) + r2 * (c(6) + r * c(7));
    let high = (c(8) + r * c(9)) + r2 * (c(10) + r * c(11));
    let tail = r2 * (low + r4 * mid + r8 * high);
    let y = S::splat(1.0) + (r + tail);
    S::select(below, S::splat(0.0), y * S::pow2(k))
}

/// eˣ, within one unit in the last place; 0 below −708, +∞ above 709.7,
/// NaN at NaN.
#[inline(always)]
pub fn exp<S: F64xN>(x: S) -> S {
    let hi = S::splat(709.7);
    let above = x.gt(hi);
    let y = S::select(above, S::splat(f64::INFINITY), exp_of_finite(x.min(hi)));
    // a NaN is neither finite nor above: it stays NaN
    S::select(x.finite().or(above).or(x.lt(S::splat(0.0))), y, x)
}

/// The minimax coefficients of fdlibm's log for ln(1 + f) = f − f²/2 +
/// s (f²/2 + R(s²)), s = f/(2 + f).
const LN_LG: [f64; 7] = [
    6.666_666_666_666_735_130e-1, 3.999_999_999_940_941_908e-1, 2.857_142_874_366_239_149e-1,
    2.222_219_843_214_978_396e-1, 1.818_357_216_161_805_012e-1, 1.531_383_769_920_937_332e-1,
    1.479_819_860_511_658_591e-1,
];

/// ln x for positive normal x and +∞ (which gives +∞), within one unit in
/// the last place. Zero, negative, subnormal or NaN x give nonsense: for
/// callers that never pass them; [`ln`] takes every x.
#[inline(always)]
pub fn ln_of_positive<S: F64xN>(x: S) -> S {
    let (m, e) = x.split_exponent();
    // m in [√½, √2): the polynomial is accurate around 1
    let big = m.gt(S::splat(SQRT_2));
    let m = S::select(big, m * S::splat(0.5), m);
    let k = S::select(big, e + S::splat(1.0), e);
    let f = m - S::splat(1.0);
    let s = f / (S::splat(2.0) + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (S::splat(LN_LG[1]) + w * (S::splat(LN_LG[3]) + w * S::splat(LN_LG[5])));
    let t2 = z
        * (S::splat(LN_LG[0])
            + w * (S::splat(LN_LG[2]) + w * (S::splat(LN_LG[4]) + w * S::splat(LN_LG[6]))));
    let r = t2 + t1;
    let hfsq = S::splat(0.5) * f * f;
    let y = k * S::splat(LN2_HI) - ((hfsq - (s * (hfsq + r) + k * S::splat(LN2_LO))) - f);
    S::select(x.gt(S::splat(f64::MAX)), S::splat(f64::INFINITY), y)
}

/// ln x, within one unit in the last place: +∞ at +∞, −∞ at 0, NaN below 0
/// and at NaN.
#[inline(always)]
pub fn ln<S: F64xN>(x: S) -> S {
    let zero = S::splat(0.0);
    let (positive, negative) = (x.gt(zero), x.lt(zero));
    // subnormals: scaled into the normal range first
    let subnormal = x.lt(S::splat(f64::MIN_POSITIVE)).and(positive);
    let scaled = S::select(subnormal, x * S::splat(TWO_54), x);
    let y = ln_of_positive(scaled)
        - S::select(subnormal, S::splat(54.0 * std::f64::consts::LN_2), zero);
    let y = S::select(positive.or(negative).and_not(x.finite()), S::splat(f64::NEG_INFINITY), y);
    let y = S::select(negative, S::splat(f64::NAN), y);
    // a NaN is neither positive, nor negative, nor zero: it stays NaN
    S::select(positive.or(negative).or(x.finite()), y, x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// exp and ln against the C library's, over the ranges the law uses,
    /// within 2 units in the last place; and their special values.
    #[test]
    fn exp_and_ln_are_accurate() {
        let ulps = |a: f64, b: f64| (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs();
        let mut worst = (0, 0);
        for k in 0..200_000 {
            let x = -700.0 + 1400.0 * k as f64 / 200_000.0 + 1e-7 * (k % 7) as f64;
            let e = exp(Portable::splat(x)).0[0];
            worst.0 = worst.0.max(ulps(e, x.exp()));
            let y = (x / 10.0).exp() * (1.0 + 0.3 * ((k % 13) as f64));
            let l = ln(Portable::splat(y)).0[0];
            worst.1 = worst.1.max(ulps(l, y.ln()));
        }
        assert!(worst.0 <= 2 && worst.1 <= 2, "ulps: exp {}, ln {}", worst.0, worst.1);
        let e = exp(Portable::from_array([-800.0, 800.0, f64::NAN, 0.0, 1.0, -1.0, 2.0, 3.0])).0;
        assert!(e[0] == 0.0 && e[1] == f64::INFINITY && e[2].is_nan() && e[3] == 1.0);
        let l = ln(Portable::from_array([0.0, f64::INFINITY, -1.0, 1e-310, 1.0, 2.0, 3.0, 4.0])).0;
        assert!(l[0] == f64::NEG_INFINITY && l[1] == f64::INFINITY && l[2].is_nan());
        assert!((l[3] - 1e-310f64.ln()).abs() < 1e-12 * 713.0);
        assert!(ln(Portable::splat(f64::NAN)).0[0].is_nan());
    }
}
