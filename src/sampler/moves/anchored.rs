//! An independence proposal fitted to the complementary half and anchored
//! on a fixed reference distribution (the calibration's Laplace
//! approximation at the mode).
//!
//! The independence move estimates a full covariance from the complementary
//! half: about three points per coordinate. Such an estimate spreads its
//! eigenvalues (the smallest come out several times too small), so the
//! proposal is too narrow in some directions and, as the dimension grows,
//! fewer and fewer proposals are accepted (on exact Gaussians 0.23 at 11
//! coordinates, 0.07 at 33). A reference that knows the posterior's
//! correlations, even roughly, removes most of that noise: in its whitened
//! coordinates the posterior is close to uncorrelated, so the half's
//! variances are kept there and its covariances shrunk toward zero by the
//! Ledoit–Wolf weight (the share of their sum of squares that sampling
//! noise explains, estimated from the half itself).
//!
//! The proposal is an equal mixture of that anchored fit and the
//! independence move's own fit: where the reference is good the anchored
//! part is accepted often, where it is poor the half's own fit still
//! proposes as the independence move does (a mixture's weight p/q is at
//! most twice either part's). Both parts depend on the complementary half
//! and the fixed reference only, so the factor q(x)/q(y) keeps the chain
//! exact. Without a reference, or where the half lies far from it (a
//! Laplace approximation describes the posterior near its mode only), it
//! is the independence move.

use nalgebra::{DMatrix, DVector};

use super::super::elliptical::Elliptical;
use super::mixture::Mixture;

/// How far (in the reference's sds, whitened) the half's mean may lie from
/// the reference's mean before the reference is taken to describe another
/// place: a Laplace approximation is local to its mode, and a posterior
/// whose mean lies two of its sds from the mode is not the Gaussian it
/// describes. On the measured 1 A records together the halves sit 0.3–0.9
/// from it; on the one record whose posterior is curved and has a second
/// basin, 0.5–2.6 while the walkers contract and 6–24 once they settle.
const FAR: f64 = 2.0;

/// The proposal for a complementary half `others` (points of `d`
/// coordinates) and a `reference`: the equal mixture of the half's own
/// Student-t and the anchored one; `None` where either cannot be fitted or
/// the half lies far from the reference (then the independence move
/// proposes).
pub(super) fn proposal(others: &[f64], d: usize, reference: &Elliptical) -> Option<Mixture> {
    Some(Mixture::equal(vec![
        super::independence::fitted(others, d)?,
        anchored_fit(others, d, reference)?,
    ]))
}

/// The half's mean, and its covariance in the whitened coordinates of
/// `reference` (z = L⁻¹(x − μ)) with the off-diagonal part shrunk by the
/// Ledoit–Wolf weight, mapped back. `None` where the half lies more than
/// [`FAR`] from the reference, a variance is not positive or the reference
/// does not match.
pub(super) fn anchored_fit(others: &[f64], d: usize, reference: &Elliptical) -> Option<Elliptical> {
    let n = others.len() / d;
    if n < 2 || reference.dim() != d {
        return None;
    }
    let l = reference.factor();
    let z: Vec<DVector<f64>> = others
        .chunks_exact(d)
        .map(|p| l.solve_lower_triangular(&(DVector::from_column_slice(p) - &reference.mean)))
        .collect::<Option<_>>()?;
    let nf = n as f64;
    let mean_z = z.iter().fold(DVector::zeros(d), |acc, v| acc + v) / nf;
    if mean_z.norm() > FAR {
        return None;
    }
    let centred: Vec<DVector<f64>> = z.iter().map(|v| v - &mean_z).collect();
    // biased covariance s and the estimated variance of each of its entries
    let mut s = DMatrix::zeros(d, d);
    for c in &centred {
        s += c * c.transpose();
    }
    s /= nf;
    let mut noise = 0.0;
    let mut signal = 0.0;
    for i in 0..d {
        for j in 0..i {
            let var: f64 =
                centred.iter().map(|c| (c[i] * c[j] - s[(i, j)]).powi(2)).sum::<f64>() / (nf * nf);
            noise += var;
            signal += s[(i, j)].powi(2);
        }
    }
    let shrink = if signal > 0.0 { (noise / signal).clamp(0.0, 1.0) } else { 1.0 };
    let unbiased = nf / (nf - 1.0);
    let cov = DMatrix::from_fn(d, d, |i, j| {
        s[(i, j)] * unbiased * if i == j { 1.0 } else { 1.0 - shrink }
    });
    if (0..d).any(|i| !(cov[(i, i)] > 0.0)) {
        return None;
    }
    let lz = crate::numeric::cholesky_or_diagonal(&cov)?;
    let mean = &reference.mean + l * mean_z;
    Some(Elliptical::from_factor(mean, l * lz))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::elliptical::Moments;
    use crate::sampler::moves::{Independent, Learned};

    fn points(rng: &mut impl rand::Rng, truth: &Elliptical, n: usize) -> Vec<f64> {
        let mut out = vec![0.0; n * truth.dim()];
        for p in out.chunks_exact_mut(truth.dim()) {
            truth.draw(None, 1.0, rng, p);
        }
        out
    }

    /// Points of N(μ, Σ) seen through a reference equal to N(μ, Σ): the
    /// whitened points are uncorrelated, almost all of their sample
    /// covariance is noise, and the anchored covariance is close to Σ
    /// (each variance within its sampling error; 200 points: a variance's
    /// relative sd is 10 %, tolerance 40 %), while its mean is the points'.
    #[test]
    fn a_good_reference_recovers_the_covariance() {
        let mut rng = crate::rng::stream(21, &[]);
        let cov = DMatrix::from_row_slice(3, 3, &[4.0, 1.9, 0.5, 1.9, 1.0, 0.2, 0.5, 0.2, 0.25]);
        let truth = Elliptical::new(Moments {
            mean: DVector::from_vec(vec![1.0, -2.0, 0.5]),
            cov: cov.clone(),
        })
        .unwrap();
        let pts = points(&mut rng, &truth, 200);
        let fit = anchored_fit(&pts, 3, &truth).unwrap();
        let m = Moments::of(&pts, 3);
        for i in 0..3 {
            assert!((fit.mean[i] - m.mean[i]).abs() < 1e-12);
            assert!(
                (fit.covariance()[(i, i)] / cov[(i, i)] - 1.0).abs() < 0.4,
                "{}",
                fit.covariance()
            );
        }
        // the correlation of coordinates 0 and 1 (0.95) survives the shrinkage
        let c = fit.covariance();
        let r = c[(0, 1)] / (c[(0, 0)] * c[(1, 1)]).sqrt();
        assert!((r - 0.95).abs() < 0.05, "correlation {r}");
    }

    /// Without a reference, or with a half far from it (its mean 10 sds
    /// away), the move is the independence move: same draw, same factor
    /// from the same stream.
    #[test]
    fn without_a_reference_or_far_from_it_it_is_the_independence_move() {
        use crate::sampler::moves::Move;
        let mut rng = crate::rng::stream(3, &[]);
        let far = Elliptical::new(Moments {
            mean: DVector::from_vec(vec![10.0, 0.0]),
            cov: DMatrix::identity(2, 2),
        })
        .unwrap();
        let near =
            Elliptical::new(Moments { mean: DVector::zeros(2), cov: DMatrix::identity(2, 2) })
                .unwrap();
        let others = points(&mut rng, &near, 8);
        let x = [0.3, -0.2];
        let independence = Move::Independence { df: Some(5.0), scale: 1.0 };
        let anchored = Move::Anchored { df: Some(5.0) };
        for reference in [None, Some(&far)] {
            let (mut y1, mut y2) = ([0.0; 2], [0.0; 2]);
            let f1 = anchored.propose(
                &anchored.fit(&others, 2, &Learned::default(), reference),
                &x,
                &others,
                &mut crate::rng::stream(5, &[]),
                &mut y1,
            );
            let f2 = independence.propose(
                &independence.fit(&others, 2, &Learned::default(), None),
                &x,
                &others,
                &mut crate::rng::stream(5, &[]),
                &mut y2,
            );
            assert_eq!((f1, y1), (f2, y2));
        }
        assert!(proposal(&others, 2, &near).is_some() && proposal(&others, 2, &far).is_none());
    }

    /// The factor is q(x)/q(y) of the equal mixture: exchanging x and y
    /// negates it, and it equals the mixture's density ratio computed here.
    #[test]
    fn factor_is_the_ratio_of_the_mixture_densities() {
        let mut rng = crate::rng::stream(9, &[]);
        let reference = Elliptical::new(Moments {
            mean: DVector::from_vec(vec![0.5, 0.5]),
            cov: DMatrix::from_row_slice(2, 2, &[2.0, 0.6, 0.6, 1.0]),
        })
        .unwrap();
        let others = points(&mut rng, &reference, 6);
        let x = [0.3, -0.2];
        let mut y = [0.0; 2];
        let f = proposal(&others, 2, &reference).unwrap().propose(Some(5.0), &x, &mut rng, &mut y);
        let parts = [
            super::super::independence::fitted(&others, 2).unwrap(),
            anchored_fit(&others, 2, &reference).unwrap(),
        ];
        let ln_q = |v: &[f64]| {
            let a: Vec<f64> = parts
                .iter()
                .map(|p| 0.5f64.ln() - p.half_log_det() + p.log_kernel(Some(5.0), v, 1.0))
                .collect();
            crate::numeric::log_sum_exp(&a)
        };
        assert!((f - (ln_q(&x) - ln_q(&y))).abs() < 1e-10, "{f} vs {}", ln_q(&x) - ln_q(&y));
    }
}
