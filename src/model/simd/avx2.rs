//! The AVX2 build of [`F64xN`]: two 256-bit registers per value.
//!
//! Every method is `#[inline(always)]` and uses AVX/AVX2 instructions, so
//! it may only run inside a function compiled with those target features
//! (see `Integrator::run_lanes`, which checks the CPU first). A value of
//! this type exists only there.

use std::arch::x86_64::*;
use std::ops::{Add, Div, Mul, Neg, Sub};

use super::{F64xN, LANES};

#[derive(Clone, Copy, Debug)]
pub struct Avx2(__m256d, __m256d);

/// `op` on both halves.
macro_rules! both {
    ($op:ident($($a:expr),*)) => {
        Avx2($op($($a.0),*), $op($($a.1),*))
    };
}

macro_rules! binary {
    ($trait:ident, $method:ident, $intrinsic:ident) => {
        impl $trait for Avx2 {
            type Output = Avx2;
            #[inline(always)]
            fn $method(self, o: Avx2) -> Avx2 {
                // SAFETY: only reached where the CPU has AVX2 (module doc)
                unsafe { both!($intrinsic(self, o)) }
            }
        }
    };
}
binary!(Add, add, _mm256_add_pd);
binary!(Sub, sub, _mm256_sub_pd);
binary!(Mul, mul, _mm256_mul_pd);
binary!(Div, div, _mm256_div_pd);

impl Neg for Avx2 {
    type Output = Avx2;
    #[inline(always)]
    fn neg(self) -> Avx2 {
        // SAFETY: as above
        unsafe {
            let s = _mm256_set1_pd(-0.0);
            Avx2(_mm256_xor_pd(self.0, s), _mm256_xor_pd(self.1, s))
        }
    }
}

/// One intrinsic of one argument and an immediate, on both halves.
macro_rules! both_imm {
    ($op:ident::<$imm:block>($a:expr)) => {
        Avx2($op::<$imm>($a.0), $op::<$imm>($a.1))
    };
    ($op:ident::<$imm:block>($a:expr, $b:expr)) => {
        Avx2($op::<$imm>($a.0, $b.0), $op::<$imm>($a.1, $b.1))
    };
}

// SAFETY (every method below): only reached where the CPU has AVX2.
impl F64xN for Avx2 {
    #[inline(always)]
    fn splat(v: f64) -> Self {
        unsafe { Avx2(_mm256_set1_pd(v), _mm256_set1_pd(v)) }
    }
    #[inline(always)]
    fn from_array(a: [f64; LANES]) -> Self {
        unsafe { Avx2(_mm256_loadu_pd(a.as_ptr()), _mm256_loadu_pd(a[4..].as_ptr())) }
    }
    #[inline(always)]
    fn to_array(self) -> [f64; LANES] {
        let mut a = [0.0; LANES];
        unsafe {
            _mm256_storeu_pd(a.as_mut_ptr(), self.0);
            _mm256_storeu_pd(a[4..].as_mut_ptr(), self.1);
        }
        a
    }
    #[inline(always)]
    fn abs(self) -> Self {
        let s = Self::splat(-0.0);
        unsafe { both!(_mm256_andnot_pd(s, self)) }
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        // minpd returns the second operand unless the first is smaller
        unsafe { both!(_mm256_min_pd(self, o)) }
    }
    #[inline(always)]
    fn floor(self) -> Self {
        unsafe { both_imm!(_mm256_round_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(self)) }
    }
    #[inline(always)]
    fn ceil(self) -> Self {
        unsafe { both_imm!(_mm256_round_pd::<{ _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC }>(self)) }
    }
    #[inline(always)]
    fn round(self) -> Self {
        unsafe {
            both_imm!(_mm256_round_pd::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(self))
        }
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Self {
        unsafe { both_imm!(_mm256_cmp_pd::<{ _CMP_GT_OQ }>(self, o)) }
    }
    #[inline(always)]
    fn lt(self, o: Self) -> Self {
        unsafe { both_imm!(_mm256_cmp_pd::<{ _CMP_LT_OQ }>(self, o)) }
    }
    #[inline(always)]
    fn finite(self) -> Self {
        // |x| < ∞ is false for ±∞ and for NaN
        self.abs().lt(Self::splat(f64::INFINITY))
    }
    #[inline(always)]
    fn and(self, o: Self) -> Self {
        unsafe { both!(_mm256_and_pd(self, o)) }
    }
    #[inline(always)]
    fn or(self, o: Self) -> Self {
        unsafe { both!(_mm256_or_pd(self, o)) }
    }
    #[inline(always)]
    fn and_not(self, o: Self) -> Self {
        unsafe { both!(_mm256_andnot_pd(self, o)) }
    }
    #[inline(always)]
    fn select(mask: Self, t: Self, f: Self) -> Self {
        unsafe { both!(_mm256_blendv_pd(f, t, mask)) }
    }
    #[inline(always)]
    fn any(self) -> bool {
        unsafe { _mm256_movemask_pd(_mm256_or_pd(self.0, self.1)) != 0 }
    }
    #[inline(always)]
    fn all(self) -> bool {
        unsafe { _mm256_movemask_pd(_mm256_and_pd(self.0, self.1)) == 0b1111 }
    }
    #[inline(always)]
    fn copysign(self, sign: Self) -> Self {
        let s = Self::splat(-0.0);
        self.abs().or(s.and(sign))
    }
    #[inline(always)]
    fn pow2(n: Self) -> Self {
        // n + 1023 + 2⁵² puts the integer n + 1023 in the low mantissa
        // bits; shifted into the exponent field it is the bits of 2ⁿ
        let magic = n + Self::splat(1023.0 + 4_503_599_627_370_496.0);
        unsafe {
            let shift =
                |v: __m256d| _mm256_castsi256_pd(_mm256_slli_epi64::<52>(_mm256_castpd_si256(v)));
            Avx2(shift(magic.0), shift(magic.1))
        }
    }
    #[inline(always)]
    fn split_exponent(self) -> (Self, Self) {
        unsafe {
            let half = |v: __m256d| {
                let bits = _mm256_castpd_si256(v);
                let mantissa = _mm256_or_si256(
                    _mm256_and_si256(bits, _mm256_set1_epi64x(!(0x7ff_i64 << 52))),
                    _mm256_set1_epi64x(1023_i64 << 52),
                );
                // the exponent field as the low bits of 2⁵², then as a number
                let field = _mm256_srli_epi64::<52>(_mm256_and_si256(
                    bits,
                    _mm256_set1_epi64x(0x7ff_i64 << 52),
                ));
                let two52 = _mm256_set1_pd(4_503_599_627_370_496.0);
                let as_f64 = _mm256_sub_pd(
                    _mm256_castsi256_pd(_mm256_or_si256(field, _mm256_castpd_si256(two52))),
                    two52,
                );
                (_mm256_castsi256_pd(mantissa), _mm256_sub_pd(as_f64, _mm256_set1_pd(1023.0)))
            };
            let (m0, e0) = half(self.0);
            let (m1, e1) = half(self.1);
            (Avx2(m0, m1), Avx2(e0, e1))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{exp, ln, Portable};
    use super::*;

    #[target_feature(enable = "avx2")]
    fn both(x: [f64; LANES]) -> ([f64; LANES], [f64; LANES]) {
        let a = Avx2::from_array(x);
        (exp(a).to_array(), ln(a).to_array())
    }

    /// The AVX2 build gives the portable build's bits, special values too.
    #[test]
    fn avx2_equals_portable_bit_for_bit() {
        if !is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        for k in 0..50_000 {
            let base = -700.0 + 1400.0 * k as f64 / 50_000.0;
            let x = [
                base,
                base * 0.37 + 1e-3,
                (base / 100.0).exp(),
                if k % 2 == 0 { 0.0 } else { f64::NAN },
                -base,
                1.0 / base,
                f64::INFINITY,
                -1e-300,
            ];
            // SAFETY: AVX2 detected above
            let (e, l) = unsafe { both(x) };
            let p = Portable(x);
            let (pe, pl) = (exp(p).0, ln(p).0);
            for i in 0..LANES {
                assert_eq!(e[i].to_bits(), pe[i].to_bits(), "exp({})", x[i]);
                assert_eq!(l[i].to_bits(), pl[i].to_bits(), "ln({})", x[i]);
            }
        }
    }
}
