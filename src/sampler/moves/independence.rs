//! An independence proposal fitted to the complementary half: a
//! multivariate Student-t (or Gaussian) with its mean and covariance.
//!
//! The proposal does not depend on the walker's position, so the
//! Metropolis-Hastings factor is q(x)/q(y). Where the posterior is close to
//! the fitted shape (a posterior of thousands of samples in well-chosen
//! coordinates), almost every proposal is accepted and consecutive draws are
//! nearly independent; where it is not, fewer are accepted, but the chain
//! stays exact.

use super::super::elliptical::{Elliptical, Moments};

/// Share of each variance added to the diagonal before the Cholesky
/// factorisation: keeps a covariance of a few points positive definite.
const RIDGE: f64 = 1e-9;

/// The complementary half's mean and covariance (`others`: its points of
/// `d` coordinates one after another); with fewer points than coordinates,
/// or a singular covariance, only its diagonal.
pub(super) fn fitted(others: &[f64], d: usize) -> Option<Elliptical> {
    let n = others.len() / d;
    Elliptical::or_diagonal(Moments::of(others, d).ridged(RIDGE)?, n)
}

/// y from `fit`, the Student-t (`df`; Gaussian without) fitted to the
/// complementary half by [`fitted`], its covariance scaled by `scale`²; the
/// factor q(x)/q(y). Without a fit (a degenerate half: every walker at one
/// point) the walker stays.
pub fn propose(
    df: Option<f64>,
    scale: f64,
    fit: Option<&Elliptical>,
    x: &[f64],
    rng: &mut impl rand::Rng,
    y: &mut [f64],
) -> f64 {
    let Some(fit) = fit else {
        y.copy_from_slice(x);
        return 0.0;
    };
    fit.draw(df, scale, rng, y);
    fit.log_kernel(df, x, scale) - fit.log_kernel(df, y, scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The factor is q(x)/q(y): exchanging x and y negates it.
    #[test]
    fn factor_is_the_ratio_of_proposal_densities() {
        let others = [0.0, 0.0, 2.0, 1.0, 1.0, 3.0, -1.0, 1.0];
        let mut rng = crate::rng::stream(5, &[]);
        let x = [0.3, -0.2];
        let mut y = [0.0; 2];
        let fit = fitted(&others, 2).unwrap();
        let f = propose(Some(5.0), 1.2, Some(&fit), &x, &mut rng, &mut y);
        let expected = fit.log_kernel(Some(5.0), &x, 1.2) - fit.log_kernel(Some(5.0), &y, 1.2);
        assert!((f - expected).abs() < 1e-12);
    }
}
