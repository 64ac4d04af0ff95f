//! The Laplace approximation of the posterior: one home.
//!
//! The MAP search ([`super::map`]) fits a Gaussian surrogate: each run's
//! noise is held fixed while θ moves and its curvature is Gauss-Newton's;
//! [`surrogate`] is the Gaussian about its optimum (θ's covariance from
//! that curvature, each run's noise from its noise model's
//! `NoiseModel::laplace_sd`). Where the noise depends on θ (errors in
//! variables: the strain's noise reaches the stress through G) the
//! surrogate's optimum is not the mode, and where the posterior is not
//! Gaussian its width is not the surrogate's: on the measured 0.25 A
//! records a posterior without one run lies 3.5–4.4 of its sds from the
//! surrogate's optimum in G and is up to 1.7× wider in one direction, so
//! importance sampling from the surrogate fails; walkers started there
//! spent most of a calibration's steps drifting in G (and a chain judged
//! converged still carried 4 MCSE of that start).
//!
//! [`mode`] therefore goes on from the surrogate by Newton's method on the
//! log-density itself ([`crate::newton`]), and [`at_mode`] is the Laplace
//! approximation there: where a calibration's walkers start and
//! leave-one-out draws its importance samples.

use nalgebra::{DMatrix, DVector};

use super::map::MapEstimate;
use super::Posterior;
use crate::newton::{mode_only, newton, Mode};
use crate::sampler::{Elliptical, LogDensity};

/// The Laplace approximation of `post` at its mode, reached by Newton's
/// method from the MAP's surrogate; the surrogate's own where the
/// differences cannot be taken.
pub fn at_mode(post: &Posterior, map: &MapEstimate) -> Elliptical {
    mode(post, map).map_or_else(|| surrogate(post, map), |m| m.laplace)
}

/// The mode of `post` reached by Newton's method from the MAP's
/// surrogate; `None` where the differences cannot be taken.
pub fn mode(post: &Posterior, map: &MapEstimate) -> Option<Mode> {
    newton(post, &surrogate(post, map))
}

/// [`mode`]'s point without the curvature there (one Hessian fewer):
/// where only the mode is wanted.
pub fn mode_point(post: &Posterior, map: &MapEstimate) -> Option<Vec<f64>> {
    mode_only(post, &surrogate(post, map))
}

/// The Laplace approximation of the MAP search's surrogate: a Gaussian around the
/// MAP with the covariance of θ from the surrogate's Hessian and, for the
/// noise of each run, the sd its noise model gives for n residuals (1/√(2n)
/// for ln σ, say; nearly independent of θ; √k times that where the run's
/// likelihood is tempered by k).
pub fn surrogate(post: &Posterior, map: &MapEstimate) -> Elliptical {
    let (d, l) = (post.dim(), &post.layout);
    let nt = l.fitted.len();
    let mut chol = DMatrix::zeros(d, d);
    // a θ covariance that is not positive definite: its diagonal, or
    // without that a tiny ball
    let theta = crate::numeric::cholesky_or_diagonal(&map.cov)
        .unwrap_or_else(|| DMatrix::identity(nt, nt) * 1e-4);
    chol.view_mut((0, 0), (nt, nt)).copy_from(&theta);
    let nr = post.runs.len();
    for i in l.noise.clone() {
        let (p, j) = ((i - l.noise.start) / nr, (i - l.noise.start) % nr);
        // a tempered run's noise is known as from n/k samples
        chol[(i, i)] = post.noise.laplace_sd(&post.runs[j], &l.noise_values(&map.x, j))[p]
            / post.weight(j).sqrt();
    }
    Elliptical::from_factor(DVector::from_column_slice(&map.x), chol)
}

/// Draws of a Laplace approximation that [`si_intervals`] takes: the 5 and
/// 95 % quantiles of 4 000 draws lie within about 0.03 sd of their own
/// (Monte Carlo error √(p(1−p)/n)/φ(z_p) ≈ 0.027 sd), well below the
/// printed digits' meaning for an approximation.
pub const INTERVAL_DRAWS: usize = 4000;

/// Coordinate by coordinate in SI units, as a posterior summary states a
/// sample's: the sd and the 5, 50 and 95 % quantiles of `q` (a Laplace
/// approximation in the sampler's coordinates of `post`), from
/// [`INTERVAL_DRAWS`] draws of a fixed stream (`seed`): the same numbers
/// every time. A parameter sampled in ln keeps its skew.
pub fn si_intervals(post: &Posterior, q: &Elliptical, seed: u64) -> Vec<IntervalRow> {
    let mut rng = crate::rng::stream(seed, &[0x1a91ace]);
    let mut y = vec![0.0; q.dim()];
    let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(INTERVAL_DRAWS); post.dim()];
    for _ in 0..INTERVAL_DRAWS {
        q.draw(None, 1.0, &mut rng, &mut y);
        for (c, v) in columns.iter_mut().zip(post.layout.to_si(&y)) {
            c.push(v);
        }
    }
    post.layout
        .names
        .iter()
        .zip(columns)
        .map(|(name, mut c)| {
            let n = c.len() as f64;
            let mean = c.iter().sum::<f64>() / n;
            let sd = (c.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            c.sort_by(f64::total_cmp);
            let at = |p| crate::sampler::diagnostics::quantile_sorted(&c, p);
            IntervalRow { parameter: name.clone(), sd, q05: at(0.05), q50: at(0.5), q95: at(0.95) }
        })
        .collect()
}

/// One coordinate's interval from an approximation (SI units).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IntervalRow {
    pub parameter: String,
    pub sd: f64,
    pub q05: f64,
    pub q50: f64,
    pub q95: f64,
}
