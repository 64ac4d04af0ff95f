//! An independence proposal fitted to the complementary half: a
//! multivariate Student-t (or Gaussian) with its mean and covariance.
//!
//! The proposal does not depend on the walker's position, so the
//! Metropolis-Hastings factor is q(x)/q(y). Where the posterior is close to
//! the fitted shape (a posterior of thousands of samples in well-chosen
//! coordinates), almost every proposal is accepted and consecutive draws are
//! nearly independent; where it is not, fewer are accepted, but the chain
//! stays exact.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use rand::RngExt;
use rand_distr::{ChiSquared, StandardNormal};

use super::point;

/// Share of each variance added to the diagonal before the Cholesky
/// factorisation: keeps a covariance of a few points positive definite.
const RIDGE: f64 = 1e-9;

/// The fitted proposal: mean, Cholesky factor of the scaled covariance.
pub(super) struct Fitted {
    pub(super) mean: DVector<f64>,
    pub(super) chol: Cholesky<f64, Dyn>,
}

impl Fitted {
    /// Mean and covariance (scaled by `scale`²) of the points in `others`;
    /// with fewer points than coordinates, or a singular covariance, only
    /// its diagonal.
    pub(super) fn of(others: &[f64], d: usize, scale: f64) -> Option<Fitted> {
        let n = others.len() / d;
        let mean = DVector::from_fn(d, |i, _| (0..n).map(|j| point(others, d, j)[i]).sum::<f64>() / n as f64);
        let mut cov = DMatrix::zeros(d, d);
        for j in 0..n {
            let v = DVector::from_column_slice(point(others, d, j)) - &mean;
            cov += &v * v.transpose();
        }
        cov *= scale * scale / (n as f64 - 1.0);
        for i in 0..d {
            cov[(i, i)] *= 1.0 + RIDGE;
        }
        let diagonal = || DMatrix::from_diagonal(&cov.diagonal());
        let chol = if n > d { cov.clone().cholesky().or_else(|| diagonal().cholesky()) } else { diagonal().cholesky() }?;
        Some(Fitted { mean, chol })
    }

    /// (v − μ)ᵀ Σ⁻¹ (v − μ).
    fn mahalanobis(&self, v: &[f64]) -> f64 {
        let r = DVector::from_column_slice(v) - &self.mean;
        let z = self.chol.l().solve_lower_triangular(&r).unwrap_or(r);
        z.norm_squared()
    }
}

/// ln q(v) up to a constant, for a Student-t with `df` (Gaussian: None).
fn log_q(df: Option<f64>, d: usize, mahalanobis: f64) -> f64 {
    match df {
        Some(nu) => -0.5 * (nu + d as f64) * (mahalanobis / nu).ln_1p(),
        None => -0.5 * mahalanobis,
    }
}

pub fn propose(df: Option<f64>, scale: f64, x: &[f64], others: &[f64], rng: &mut impl rand::Rng, y: &mut [f64]) -> f64 {
    let d = x.len();
    let Some(fit) = Fitted::of(others, d, scale) else {
        // a degenerate half (every walker at one point): stay
        y.copy_from_slice(x);
        return 0.0;
    };
    let z = DVector::from_fn(d, |_, _| rng.sample::<f64, _>(StandardNormal));
    let w = match df {
        Some(nu) => {
            let chi2: f64 = rng.sample(ChiSquared::new(nu).expect("df checked positive"));
            (nu / chi2).sqrt()
        }
        None => 1.0,
    };
    let step = fit.chol.l() * z * w;
    for i in 0..d {
        y[i] = fit.mean[i] + step[i];
    }
    log_q(df, d, fit.mahalanobis(x)) - log_q(df, d, fit.mahalanobis(y))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The proposal's draws have the fitted mean and covariance (Gaussian
    /// case): with 20 000 draws the mean's standard error is about 0.7 % of
    /// the sd, the variance's about 1 %; tolerances of 5 and 7 %.
    #[test]
    fn gaussian_proposal_has_the_halfs_moments() {
        let others = [0.0, 0.0, 2.0, 1.0, 1.0, 3.0, -1.0, 1.0, 3.0, 3.0];
        let fit = Fitted::of(&others, 2, 1.0).unwrap();
        let mut rng = crate::rng::stream(4, &[]);
        let n = 20_000;
        let mut y = [0.0; 2];
        let (mut s, mut ss) = ([0.0; 2], [0.0; 2]);
        for _ in 0..n {
            propose(None, 1.0, &[0.0, 0.0], &others, &mut rng, &mut y);
            for i in 0..2 {
                s[i] += y[i];
                ss[i] += y[i] * y[i];
            }
        }
        for i in 0..2 {
            let mean = s[i] / n as f64;
            let var = ss[i] / n as f64 - mean * mean;
            let (m, v) = (fit.mean[i], (fit.chol.l() * fit.chol.l().transpose())[(i, i)]);
            assert!((mean - m).abs() < 0.05 * v.sqrt(), "mean {i}: {mean} vs {m}");
            assert!((var / v - 1.0).abs() < 0.07, "variance {i}: {var} vs {v}");
        }
    }

    /// The factor is q(x)/q(y): exchanging x and y negates it.
    #[test]
    fn factor_is_the_ratio_of_proposal_densities() {
        let others = [0.0, 0.0, 2.0, 1.0, 1.0, 3.0, -1.0, 1.0];
        let mut rng = crate::rng::stream(5, &[]);
        let x = [0.3, -0.2];
        let mut y = [0.0; 2];
        let f = propose(Some(5.0), 1.2, &x, &others, &mut rng, &mut y);
        let fit = Fitted::of(&others, 2, 1.2).unwrap();
        let expected = log_q(Some(5.0), 2, fit.mahalanobis(&x)) - log_q(Some(5.0), 2, fit.mahalanobis(&y));
        assert!((f - expected).abs() < 1e-12);
    }
}
