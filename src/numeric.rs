//! Numerical building blocks that several modules share, one home each:
//! a covariance's Cholesky factor with its fallback, a sample's mean and
//! variance, sums of exponentials in log space, and draws' rank-normal
//! scores.

use nalgebra::DMatrix;
use statrs::distribution::{ContinuousCDF, Normal};

/// The lower Cholesky factor of the covariance `cov`; where rounding or too
/// few points left it not positive definite, the factor of its diagonal
/// alone (each coordinate's own spread, no correlation); `None` where a
/// variance is not positive (or not a number).
pub fn cholesky_or_diagonal(cov: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    if let Some(c) = cov.clone().cholesky() {
        return Some(c.l());
    }
    diagonal_factor(cov)
}

/// A factor to draw with that never fails: [`cholesky_or_diagonal`], or
/// with no spread along a variance that rounding took to zero or below.
pub fn draw_factor(cov: &DMatrix<f64>) -> DMatrix<f64> {
    cholesky_or_diagonal(cov)
        .unwrap_or_else(|| DMatrix::from_diagonal(&cov.diagonal().map(|v| v.max(0.0).sqrt())))
}

/// The factor of `cov`'s diagonal alone; `None` where a variance is not
/// positive.
pub fn diagonal_factor(cov: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let d = cov.diagonal();
    d.iter().all(|v| *v > 0.0 && v.is_finite()).then(|| DMatrix::from_diagonal(&d.map(f64::sqrt)))
}

/// The mean of `x`.
pub fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

/// The sample variance of `x` (divisor n − 1).
pub fn variance(x: &[f64]) -> f64 {
    let m = mean(x);
    x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() as f64 - 1.0)
}

/// ln Σ exp(vᵢ), without overflow; −∞ for no terms (or all −∞), +∞ or NaN
/// where a term is.
pub fn log_sum_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return m;
    }
    m + v.iter().map(|t| (t - m).exp()).sum::<f64>().ln()
}

/// ln of the mean of exp(vᵢ), without overflow.
pub fn log_mean_exp(v: &[f64]) -> f64 {
    let m = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return m;
    }
    m + (v.iter().map(|x| (x - m).exp()).sum::<f64>() / v.len() as f64).ln()
}

/// Ranks of all draws pooled (ties averaged), mapped to normal scores
/// Φ⁻¹((r − 3/8)/(S + 1/4)).
pub fn rank_normalize(chains: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let mut all: Vec<(f64, usize, usize)> = chains
        .iter()
        .enumerate()
        .flat_map(|(c, v)| v.iter().enumerate().map(move |(i, x)| (*x, c, i)))
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    let s = all.len() as f64;
    let normal = Normal::standard();
    let mut out: Vec<Vec<f64>> = chains.iter().map(|c| vec![0.0; c.len()]).collect();
    let mut i = 0;
    while i < all.len() {
        let mut j = i;
        while j + 1 < all.len() && all[j + 1].0 == all[i].0 {
            j += 1;
        }
        let rank = (i + j) as f64 / 2.0 + 1.0;
        let z = normal.inverse_cdf((rank - 0.375) / (s + 0.25));
        for &(_, c, k) in &all[i..=j] {
            out[c][k] = z;
        }
        i = j + 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_factor_falls_back_to_the_diagonal_and_then_to_none() {
        let full = DMatrix::from_row_slice(2, 2, &[4.0, 2.0, 2.0, 5.0]);
        let l = cholesky_or_diagonal(&full).unwrap();
        assert!((&l * l.transpose() - &full).norm() < 1e-12);
        assert_eq!((l[(0, 0)], l[(1, 0)], l[(1, 1)]), (2.0, 1.0, 2.0));
        // correlation above 1: the diagonal alone
        let indefinite = DMatrix::from_row_slice(2, 2, &[4.0, 7.0, 7.0, 9.0]);
        let l = cholesky_or_diagonal(&indefinite).unwrap();
        assert_eq!(l, DMatrix::from_row_slice(2, 2, &[2.0, 0.0, 0.0, 3.0]));
        let zero = DMatrix::from_row_slice(2, 2, &[4.0, 0.0, 0.0, 0.0]);
        assert!(cholesky_or_diagonal(&zero).is_none());
    }

    #[test]
    fn sums_of_exponentials_do_not_overflow() {
        // ln(e^1000 + e^1000) = 1000 + ln 2; the mean: 1000
        assert!((log_sum_exp(&[1000.0, 1000.0]) - (1000.0 + 2f64.ln())).abs() < 1e-12);
        assert!((log_mean_exp(&[1000.0, 1000.0]) - 1000.0).abs() < 1e-12);
        // ln(1 + e) by hand
        assert!((log_sum_exp(&[0.0, 1.0]) - (1.0 + 1f64.exp()).ln()).abs() < 1e-15);
        assert_eq!(log_sum_exp(&[]), f64::NEG_INFINITY);
        assert_eq!(log_sum_exp(&[f64::NEG_INFINITY, f64::NEG_INFINITY]), f64::NEG_INFINITY);
    }
}
