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
//! leave-one-out draws its importance samples. The adjusted likelihood's
//! posterior ([`super::memory`]) has its own from the independent
//! posterior's at the adjustment's centre ([`adjusted_mode`]), without a
//! search.

use nalgebra::{DMatrix, DVector};

use super::map::MapEstimate;
use super::{Layout, Posterior};
use crate::newton::{newton, Mode};
use crate::sampler::{Elliptical, LogDensity};

/// The second difference of the log-density over ±1 sd of a Laplace
/// approximation above which [`too_narrow_widened`] takes the posterior
/// for more than twice as wide along that axis (a Gaussian r times wider
/// gives −1/r²).
const NARROW_DROP: f64 = 0.25;

/// The farthest [`too_narrow_widened`] looks along an axis, in the
/// approximation's sds.
const NARROW_LOOK: f64 = 64.0;

/// `q` (a Laplace approximation of `post` at its mode, where the walkers
/// start; `top` the log-density at its mean) with every principal axis
/// along which the posterior is more than twice as wide as `q` widened to
/// the posterior's own spread there.
/// A Gaussian r times wider than `q` has the log-density's second
/// difference over ±s sd at −s²/r²; where it lies above −[`NARROW_DROP`]
/// at s = 1, s doubles (at most to [`NARROW_LOOK`]) until the fall is a
/// nat or more, well above the integrator's ruggedness, and the axis
/// takes r = s/√(fall). A Hessian of finite differences can sit on a kink
/// of the explicit scheme's likelihood (its step cuts switch): on
/// Spencer's model at 0.25 A of the measured records one Newton mode gave
/// ln c1 a Laplace sd of 0.0014 where the posterior's is about 0.08, and
/// walkers started there stopped after 20 steps with c1's sd 40× too
/// small, R̂ and ESS content (docs/performance.md, "A Laplace
/// approximation too narrow"). Every other axis, and every `q` that fits,
/// is kept bit for bit. Costs 2d log-densities, and two per widened axis
/// and doubling. With it, how many times wider each widened axis became,
/// largest first (none: `q` as it was).
pub fn too_narrow_widened<T: LogDensity>(
    post: &T,
    q: Elliptical,
    top: f64,
) -> (Elliptical, Vec<f64>) {
    if !top.is_finite() {
        return (q, Vec::new());
    }
    let axes = Axes::of(&q);
    // the second difference of the log-density over ±s sd along each axis k
    let second = |look: &[(usize, f64)]| -> Vec<f64> {
        let f = crate::sampler::density::log_densities(post, &axes.points(look));
        (0..look.len()).map(|i| f[2 * i] + f[2 * i + 1] - 2.0 * top).collect()
    };
    let first: Vec<(usize, f64)> = (0..q.dim()).map(|k| (k, 1.0)).collect();
    let mut look: Vec<(usize, f64)> = first
        .iter()
        .zip(second(&first))
        .filter(|(_, v)| v.is_finite() && *v > -NARROW_DROP)
        .map(|(&(k, _), _)| (k, 2.0))
        .collect();
    let mut widened: Vec<(usize, f64)> = Vec::new();
    while !look.is_empty() {
        let drops = second(&look);
        let mut next = Vec::new();
        for (&(k, s), v) in look.iter().zip(drops) {
            if !v.is_finite() {
                // past the support: as wide as the last look, at least
                widened.push((k, s / 2.0));
            } else if v <= -1.0 || s >= NARROW_LOOK {
                widened.push((k, (s / (-v).max(f64::MIN_POSITIVE).sqrt()).clamp(2.0, s)));
            } else {
                next.push((k, 2.0 * s));
            }
        }
        look = next;
    }
    if widened.is_empty() {
        return (q, Vec::new());
    }
    let mut variances = axes.eigen.eigenvalues.clone();
    for &(k, r) in &widened {
        variances[k] *= r * r;
    }
    let mut factors: Vec<f64> = widened.iter().map(|&(_, r)| r).collect();
    factors.sort_by(|a, b| b.total_cmp(a));
    match axes.with_variances(&variances) {
        Some(widened) => (widened, factors),
        None => (q, Vec::new()),
    }
}

/// The principal axes of an approximation, where [`bulk_spread`] and
/// [`too_narrow_widened`] measure the log-density's fall.
struct Axes {
    eigen: nalgebra::SymmetricEigen<f64, nalgebra::Dyn>,
    mean: DVector<f64>,
}

impl Axes {
    fn of(q: &Elliptical) -> Axes {
        Axes { eigen: nalgebra::SymmetricEigen::new(q.covariance()), mean: q.mean.clone() }
    }

    /// For each (axis k, s): the points s sd either side of the mean along
    /// k (+ then −), one after another.
    fn points(&self, look: &[(usize, f64)]) -> Vec<f64> {
        let mut points = Vec::with_capacity(2 * look.len() * self.mean.len());
        for &(k, s) in look {
            let axis =
                self.eigen.eigenvectors.column(k) * self.eigen.eigenvalues[k].max(0.0).sqrt();
            for sign in [1.0, -1.0] {
                points.extend((&self.mean + &axis * (sign * s)).iter());
            }
        }
        points
    }

    /// The Gaussian about the mean with these axes and `variances` along
    /// them; `None` where it is not positive definite.
    fn with_variances(&self, variances: &DVector<f64>) -> Option<Elliptical> {
        let v = &self.eigen.eigenvectors;
        let cov = v * DMatrix::from_diagonal(variances) * v.transpose();
        let factor = ((&cov + cov.transpose()) * 0.5).cholesky()?.l();
        Some(Elliptical::from_factor(self.mean.clone(), factor))
    }
}

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

/// The mode of the adjusted posterior `post` and its Laplace approximation
/// there, from `independent`, that of its independent posterior at the
/// adjustment's centre ([`adjusted`]), each principal axis's spread then
/// measured over the posterior's bulk ([`bulk_spread`]): 2d + 1
/// log-densities. Newton's method on the adjusted posterior from a
/// search's surrogate (a search and two Hessians of 2d² log-densities)
/// reaches the same mode and spreads (on the measured 0.25 A records
/// within 0.03 sd and 6 %; over the fifteen measured posteriors, each
/// current and each run alone, within 0.18 sd and 20 %). The mode is
/// `converged`: no search stopped short of it. `None` where [`adjusted`]
/// is, or the log-density at its mode is not finite.
pub fn adjusted_mode(post: &Posterior, independent: &Elliptical) -> Option<Mode> {
    let derived = adjusted(post, independent)?;
    let (laplace, log_density) = bulk_spread(post, &derived)?;
    let x = laplace.mean.as_slice().to_vec();
    Some(Mode { x, log_density, converged: true, steps: 0, short_by: 0.0, laplace })
}

/// Bounds of [`bulk_spread`]'s change of an axis's spread.
const BULK_SCALE: (f64, f64) = (0.5, 2.0);

/// `q` with each principal axis's spread set by the log-density's drop
/// over one sd either side of the mean (its curvature over the
/// posterior's bulk, where a curvature measured closer to the mode can
/// make an approximation too narrow: [`adjusted`]'s, from the independent
/// posterior's, is up to 20 % narrower than the adjusted posterior's own
/// in m1 and R0 on the measured 0.25 A records), changed by at most
/// [`BULK_SCALE`]; and the log-density at the mean. An axis along which
/// the drop is not a fall either side keeps its spread. `None` where the
/// log-density at the mean is not finite.
fn bulk_spread(post: &Posterior, q: &Elliptical) -> Option<(Elliptical, f64)> {
    let axes = Axes::of(q);
    let mut points: Vec<f64> = q.mean.iter().copied().collect();
    points.extend(axes.points(&(0..q.dim()).map(|k| (k, 1.0)).collect::<Vec<_>>()));
    let f = crate::sampler::density::log_densities(post, &points);
    let top = f[0];
    if !top.is_finite() {
        return None;
    }
    let mut variances = axes.eigen.eigenvalues.clone();
    for (k, v) in variances.iter_mut().enumerate() {
        // a Gaussian's second difference over ±1 sd is −1
        let second = f[1 + 2 * k] + f[2 + 2 * k] - 2.0 * top;
        if second.is_finite() && second < 0.0 {
            let scale = (1.0 / (-second).sqrt()).clamp(BULK_SCALE.0, BULK_SCALE.1);
            *v *= scale * scale;
        }
    }
    Some((axes.with_variances(&variances)?, top))
}

/// The Laplace approximation of the adjusted posterior `post` (its
/// likelihood the independent one at x* = c + C (x − c),
/// [`super::memory`]) from `independent`, that of its independent
/// posterior at the adjustment's centre c, without a log-density: there
/// the likelihood's curvature is the independent posterior's less the
/// prior's, the adjusted likelihood's is TᵀHT (T is C on θ, the identity
/// on the noise and the model terms), and the prior's is added back; the
/// mode is one Newton step from c, where the likelihood's score balances
/// the prior's. The prior's derivatives are Newton's method's central
/// differences in the coordinates `independent` whitens
/// ([`crate::newton::derivatives`]), which integrate nothing. `None` where `post` is not adjusted in its own
/// coordinates about `independent`'s mean, or a difference leaves the
/// prior's support: the caller goes on by Newton's method.
fn adjusted(post: &Posterior, independent: &Elliptical) -> Option<Elliptical> {
    let a = post.likelihood.adjustment()?;
    let (d, theta) = (post.dim(), post.layout.theta.clone());
    let c = independent.mean.as_slice();
    let centred = a.centre.len() == theta.len()
        && a.centre
            .iter()
            .zip(&c[theta.clone()])
            .all(|(u, v)| (u - v).abs() <= 1e-9 * (1.0 + v.abs()));
    if !centred || a.coordinates != post.layout.theta_names() || independent.dim() != d {
        return None;
    }
    let l = independent.factor();
    let (g, h) = crate::newton::derivatives(&LogPrior(post), independent)?;
    let mut t = DMatrix::<f64>::identity(d, d);
    for (i, row) in a.matrix.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            t[(theta.start + i, theta.start + j)] = *v;
        }
    }
    // T in the whitened coordinates: L⁻¹ T L
    let t = l.solve_lower_triangular(&(t * l))?;
    // minus the likelihood's Hessian there: the posterior's (the identity
    // in these coordinates) less the prior's
    let likelihood = DMatrix::<f64>::identity(d, d) + &h;
    let hessian = -(t.transpose() * likelihood * &t) + &h;
    // the score: the likelihood's, −∇ prior at the independent mode, through T
    let score = &g - t.transpose() * &g;
    let cov = crate::newton::covariance(&hessian);
    let step = &cov * score;
    let cov_x = l * cov * l.transpose();
    let factor = cov_x.cholesky()?.l();
    Some(Elliptical::from_factor(&independent.mean + l * step, factor))
}

/// The log-prior of a posterior as a density of its own: what
/// [`adjusted`] differentiates (no integration).
struct LogPrior<'a>(&'a Posterior);

impl LogDensity for LogPrior<'_> {
    fn dim(&self) -> usize {
        self.0.dim()
    }

    fn log_density(&self, x: &[f64]) -> f64 {
        self.0.log_prior(x)
    }
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
/// approximation in the sampler's coordinates, `layout`), from
/// [`INTERVAL_DRAWS`] draws of a fixed stream (`seed`): the same numbers
/// every time. A parameter sampled in ln keeps its skew. A draw with no θ
/// (past a coordinate's wall: a shifted parameter below zero, a drag
/// stress with no positive R1) is drawn again: the approximation is
/// truncated to the support, as the posterior is (at most 100
/// [`INTERVAL_DRAWS`] tries, then what was drawn; none: no rows).
pub fn si_intervals(layout: &Layout, q: &Elliptical, seed: u64) -> Vec<IntervalRow> {
    let mut rng = crate::rng::stream(seed, &[0x1a91ace]);
    let mut y = vec![0.0; q.dim()];
    let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(INTERVAL_DRAWS); layout.dim()];
    let mut tries = 0;
    while columns[0].len() < INTERVAL_DRAWS && tries < 100 * INTERVAL_DRAWS {
        tries += 1;
        q.draw(None, 1.0, &mut rng, &mut y);
        let si = layout.to_si(&y);
        if !si[layout.theta.clone()].iter().all(|v| *v > 0.0 && v.is_finite()) {
            continue;
        }
        for (c, v) in columns.iter_mut().zip(si) {
            c.push(v);
        }
    }
    if columns[0].is_empty() {
        return Vec::new();
    }
    layout
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laws::LawKind;
    use crate::noise::{NoiseKind, NoiseOptions};
    use crate::posterior::{Coordinates, ParameterModel};

    /// A centred Gaussian with the given sds, as a log-density.
    struct Gaussian(Vec<f64>);

    impl LogDensity for Gaussian {
        fn dim(&self) -> usize {
            self.0.len()
        }

        fn log_density(&self, x: &[f64]) -> f64 {
            -0.5 * x.iter().zip(&self.0).map(|(v, s)| (v / s).powi(2)).sum::<f64>()
        }
    }

    fn sds(q: &Elliptical) -> Vec<f64> {
        let c = q.covariance();
        (0..q.dim()).map(|i| c[(i, i)].sqrt()).collect()
    }

    /// Against a Gaussian whose sds are known: an approximation 50× too
    /// narrow along one axis and 300× along another (past the farthest
    /// look, 64 sd) takes the posterior's sd 50 in the first, exactly
    /// (a Gaussian's second difference over ±64 sd is −(64/50)², whose
    /// root gives 50 back), and 64 in the second (the most it may take);
    /// an axis 1.5× too narrow, and one that fits, keep their widths; an
    /// approximation that fits everywhere comes back bit for bit.
    #[test]
    fn an_axis_too_narrow_takes_the_posterior_s_spread() {
        let target = Gaussian(vec![1.0, 50.0, 1.5, 300.0]);
        let q = Elliptical::from_factor(DVector::zeros(4), DMatrix::identity(4, 4));
        let (q, factors) = too_narrow_widened(&target, q, 0.0);
        assert_eq!(factors.len(), 2, "{factors:?}");
        let widened = sds(&q);
        let want = [1.0, 50.0, 1.0, 64.0];
        for (got, want) in widened.iter().zip(want) {
            assert!((got - want).abs() < 1e-9 * want, "{widened:?}");
        }
        let fits = Elliptical::from_factor(
            DVector::zeros(4),
            DMatrix::from_diagonal(&DVector::from_vec(vec![1.0, 50.0, 1.5, 300.0])),
        );
        let (back, factors) = too_narrow_widened(&target, fits.clone(), 0.0);
        assert!(factors.is_empty(), "{factors:?}");
        assert_eq!(back.factor(), fits.factor());
    }

    /// A Laplace approximation a third of whose mass lies past `bp-spencer`'s
    /// wall for c0 (u = ln(c0 + 1 kN s/m) ≤ ln 1 kN s/m: no dashpot) gives
    /// intervals of the truncated approximation: no c0 at or below zero,
    /// and the median of a normal in u truncated at the wall, computed here
    /// from the normal's quantile function (statrs). Its Monte Carlo error
    /// over 4 000 draws is about 1.25 √(0.25/2 700)/φ ≈ 0.03 of u's sd
    /// (2 700 draws kept); asserted within 0.1 sd.
    #[test]
    fn intervals_keep_to_the_support() {
        use statrs::distribution::{ContinuousCDF, Normal};
        let runs = vec!["a".to_string()];
        let l = Layout::new(
            &ParameterModel::Law { law: LawKind::BpSpencer },
            &runs,
            NoiseKind::Gaussian.model(&NoiseOptions::default()).as_ref(),
            Coordinates::Log,
            &Default::default(),
        );
        let si = [2e5, 1.2e5, 0.9e5, 3e4, 4e-6, 2e-4, 1.2, 20.0, 4e4, 2e3, 300.0];
        let centre = l.from_si(&si);
        let (mu, sd) = (centre[7], 0.05);
        let mut chol = DMatrix::identity(si.len(), si.len()) * 1e-3;
        chol[(7, 7)] = sd;
        let q = Elliptical::from_factor(DVector::from_column_slice(&centre), chol);
        let rows = si_intervals(&l, &q, 11);
        let c0 = &rows[7];
        assert_eq!(c0.parameter, "c0");
        assert!(c0.q05 > 0.0, "{c0:?}");
        let unit = Normal::new(0.0, 1.0).unwrap();
        let wall = unit.cdf((1e3f64.ln() - mu) / sd);
        assert!(wall > 0.3, "a third of the mass past the wall: {wall}");
        let median_u = mu + sd * unit.inverse_cdf(wall + 0.5 * (1.0 - wall));
        let median = median_u.exp() - 1e3;
        let u_of = |c: f64| (c + 1e3).ln();
        assert!(
            ((u_of(c0.q50) - median_u) / sd).abs() < 0.1,
            "median {} against the truncated normal's {median}",
            c0.q50
        );
    }
}
