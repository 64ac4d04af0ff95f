//! An independence proposal from a Student-t mixture fitted to the
//! ensemble's own recent history.
//!
//! The complementary half of an ensemble is a few dozen points: in twenty
//! dimensions it pins down a covariance poorly, and not a skew or a curve
//! at all. The ensemble's last steps hold thousands of points of the same
//! distribution. At steps 8, 16, 32, … up to [`LAST_FIT`] (a doubling
//! schedule, then none: adaptation stops) each ensemble fits a Gaussian
//! mixture by EM to its walkers' positions over the second half of the
//! steps so far — the number of components (one to [`MAX_COMPONENTS`])
//! chosen by held-out likelihood — and proposes from the same mixture with
//! Student-t components until the next fit. Between fits the proposal is
//! fixed, so each stretch is an exact Metropolis-Hastings independence
//! sampler (factor q(x)/q(y)); each fit depends on the stored chains only,
//! so a resumed run refits the same.

use nalgebra::DVector;
use rand::RngExt;

use super::super::elliptical::{Elliptical, Moments};
use super::Independent;
use crate::numeric::log_sum_exp;

/// The most components a fit may have.
pub const MAX_COMPONENTS: usize = 4;

/// The held-out log-likelihood per point a further component must add.
pub const MIN_GAIN: f64 = 0.02;

/// The most points a fit uses (evenly thinned beyond).
const MAX_POINTS: usize = 4000;

/// The proposal's components are the fitted ones widened by this factor:
/// an independence proposal must not be lighter than the target in any
/// direction, or a walker that reaches such a tail stays there.
pub(super) const SPREAD: f64 = 1.15;

/// Share of each variance added to a covariance's diagonal: keeps a
/// component of few points positive definite.
const RIDGE: f64 = 1e-6;

/// The last step at which the fits to the history are made: from then on
/// the proposal is fixed and the chain an exact Metropolis-Hastings chain,
/// and the burn-in (at least half the last fit's step) stops growing with
/// the run.
pub const LAST_FIT: usize = 1024;

/// The last step at or before `step` at which the proposal is fitted anew
/// (8, 16, 32, …, [`LAST_FIT`]; 0: none yet).
pub fn last_fit_step(step: usize) -> usize {
    if step < 8 {
        0
    } else {
        (1usize << (usize::BITS - 1 - step.leading_zeros())).min(LAST_FIT)
    }
}

/// A walker's points (`d` coordinates one after another, in time order)
/// with each repeated position (a rejected proposal) counted once.
pub(super) fn distinct(walker: &[f64], d: usize) -> Vec<DVector<f64>> {
    let mut out: Vec<DVector<f64>> = Vec::new();
    for p in walker.chunks_exact(d) {
        if out.last().is_none_or(|last| last.as_slice() != p) {
            out.push(DVector::from_column_slice(p));
        }
    }
    out
}

/// At most `max` of `points`, evenly thinned.
pub(super) fn thinned(points: Vec<DVector<f64>>, max: usize) -> Vec<DVector<f64>> {
    let stride = points.len().div_ceil(max).max(1);
    points.into_iter().step_by(stride).collect()
}

/// One component: weight, and its mean and covariance.
#[derive(Clone, Debug)]
struct Component {
    log_weight: f64,
    shape: Elliptical,
}

/// A fitted mixture, used with Student-t components of `df` degrees of
/// freedom (Gaussian without).
#[derive(Clone, Debug)]
pub struct Mixture {
    components: Vec<Component>,
}

impl Mixture {
    /// Fits a mixture to the walkers' positions `walkers` (per walker, its
    /// points of `d` coordinates one after another, in time order): EM from
    /// k-means++ starts drawn from `rng`. A walker's repeated position (a
    /// rejected proposal) counts once, or clusters of copies would pass for
    /// components. The number of components is the one whose fit to the
    /// even walkers predicts the odd ones best (held-out log-likelihood,
    /// by more than [`MIN_GAIN`] nat per point for each added component);
    /// it is then fitted to all. `None` if the points cannot carry even one
    /// full-covariance component.
    pub fn fit(walkers: &[Vec<f64>], d: usize, rng: &mut impl rand::Rng) -> Option<Mixture> {
        let per: Vec<Vec<DVector<f64>>> = walkers.iter().map(|w| distinct(w, d)).collect();
        let thin = |v: Vec<DVector<f64>>| thinned(v, MAX_POINTS);
        let all = thin(per.iter().flatten().cloned().collect());
        if all.len() < 2 * d + 2 {
            return None;
        }
        let train = thin(per.iter().step_by(2).flatten().cloned().collect());
        let test = thin(per.iter().skip(1).step_by(2).flatten().cloned().collect());
        let mut k_best = 1;
        let mut score_best = f64::NEG_INFINITY;
        for k in 1..=MAX_COMPONENTS {
            // each component needs several points per coordinate
            if train.len() < 5 * d * k || test.is_empty() {
                break;
            }
            let Some((_, m)) = em(&train, k, rng) else { break };
            let score =
                test.iter().map(|p| m.log_q(None, p.as_slice())).sum::<f64>() / test.len() as f64;
            if score > score_best + if k == 1 { 0.0 } else { MIN_GAIN } {
                (k_best, score_best) = (k, score);
            } else {
                break;
            }
        }
        let (_, m) = em(&all, k_best, rng).or_else(|| em(&all, 1, rng))?;
        Some(m.widened(SPREAD))
    }

    /// The mixture with every component's spread multiplied by `factor`.
    fn widened(self, factor: f64) -> Mixture {
        let components = self
            .components
            .into_iter()
            .filter_map(|c| {
                let cov = c.shape.covariance() * (factor * factor);
                let shape = Elliptical::new(Moments { mean: c.shape.mean.clone(), cov })?;
                Some(Component { shape, ..c })
            })
            .collect();
        Mixture { components }
    }

    /// One component: the mean and covariance of `points` (each of `d`
    /// coordinates), as the independence move fits the complementary half.
    pub(super) fn of_points(points: &[f64], d: usize) -> Option<Mixture> {
        if points.len() < 2 * d {
            return None;
        }
        let shape = super::independence::fitted(points, d)?;
        Some(Mixture { components: vec![Component { log_weight: 0.0, shape }] })
    }
}

impl Independent for Mixture {
    /// A component by weight, then its Student-t (or Gaussian).
    fn draw(&self, df: Option<f64>, rng: &mut impl rand::Rng, y: &mut [f64]) {
        let u: f64 = rng.random();
        let mut acc = 0.0;
        let mut pick = &self.components[self.components.len() - 1];
        for c in &self.components {
            acc += c.log_weight.exp();
            if u < acc {
                pick = c;
                break;
            }
        }
        pick.shape.draw(df, 1.0, rng, y);
    }

    /// Up to a constant shared by every mixture of Student-t components
    /// with `df` (or Gaussian ones) in the same dimension.
    fn log_q(&self, df: Option<f64>, v: &[f64]) -> f64 {
        let terms: Vec<f64> = self
            .components
            .iter()
            .map(|c| c.log_weight - c.shape.half_log_det() + c.shape.log_kernel(df, v, 1.0))
            .collect();
        log_sum_exp(&terms)
    }
}

/// The history fit's share of the proposal; the rest is the complementary
/// half's own fit (a defensive mixture: while the ensemble still expands
/// or moves, its current spread keeps the proposal from being narrower
/// than the target).
pub const HISTORY_SHARE: f64 = 0.7;

/// The proposal of a move that learns from its history: y from the
/// history's fit (share [`HISTORY_SHARE`]: the history move's mixture, the
/// curved move's tube) or from `current`, the move's fit to the
/// complementary half; factor q(x)/q(y) of the two together.
pub fn propose(
    history: &impl Independent,
    current: Option<&impl Independent>,
    df: Option<f64>,
    x: &[f64],
    rng: &mut impl rand::Rng,
    y: &mut [f64],
) -> f64 {
    let Some(current) = current else {
        return history.propose(df, x, rng, y);
    };
    if rng.random::<f64>() < HISTORY_SHARE {
        history.draw(df, rng, y);
    } else {
        current.draw(df, rng, y);
    }
    let q = |v: &[f64]| {
        log_sum_exp(&[
            HISTORY_SHARE.ln() + history.log_q(df, v),
            (1.0 - HISTORY_SHARE).ln() + current.log_q(df, v),
        ])
    };
    q(x) - q(y)
}

/// A component of weight `w` with the `moments` (ridged).
fn component(w: f64, moments: Moments) -> Option<Component> {
    Some(Component { log_weight: w.ln(), shape: Elliptical::new(moments.ridged(RIDGE)?)? })
}

/// EM for a k-component Gaussian mixture from a k-means++ start; the
/// log-likelihood (up to −n d/2 ln 2π) and the mixture.
fn em(x: &[DVector<f64>], k: usize, rng: &mut impl rand::Rng) -> Option<(f64, Mixture)> {
    let (n, d) = (x.len(), x[0].len());
    // k-means++ seeds
    let mut centres = vec![x[rng.random_range(0..n)].clone()];
    while centres.len() < k {
        let dist: Vec<f64> = x
            .iter()
            .map(|p| centres.iter().map(|c| (p - c).norm_squared()).fold(f64::INFINITY, f64::min))
            .collect();
        let total: f64 = dist.iter().sum();
        let mut u = rng.random::<f64>() * total;
        let mut pick = n - 1;
        for (i, w) in dist.iter().enumerate() {
            if u < *w {
                pick = i;
                break;
            }
            u -= w;
        }
        centres.push(x[pick].clone());
    }
    // hard assignment to the nearest seed, then EM
    let mut resp = vec![vec![0.0; k]; n];
    for (i, p) in x.iter().enumerate() {
        let j = (0..k)
            .min_by(|&a, &b| {
                (p - &centres[a]).norm_squared().total_cmp(&(p - &centres[b]).norm_squared())
            })
            .unwrap_or(0);
        resp[i][j] = 1.0;
    }
    let mut ll = f64::NEG_INFINITY;
    let mut mixture = None;
    for _ in 0..60 {
        // M step
        let mut comps = Vec::with_capacity(k);
        for j in 0..k {
            let nj: f64 = resp.iter().map(|r| r[j]).sum();
            if nj < (d + 2) as f64 {
                return None;
            }
            let moments =
                Moments::weighted(x.iter().zip(&resp).map(|(p, r)| (p.as_slice(), r[j])), d);
            comps.push(component(nj / n as f64, moments)?);
        }
        let m = Mixture { components: comps };
        // E step
        let mut new_ll = 0.0;
        // ln w − ln |Σ|^{1/2} of each component, once per step
        let base: Vec<f64> =
            m.components.iter().map(|c| c.log_weight - c.shape.half_log_det()).collect();
        for (p, r) in x.iter().zip(resp.iter_mut()) {
            let t: Vec<f64> = m
                .components
                .iter()
                .zip(&base)
                .map(|(c, b)| b + c.shape.log_kernel(None, p.as_slice(), 1.0))
                .collect();
            let total = log_sum_exp(&t);
            new_ll += total;
            for (rj, tj) in r.iter_mut().zip(&t) {
                *rj = (tj - total).exp();
            }
        }
        let done = (new_ll - ll).abs() < 1e-6 * new_ll.abs().max(1.0);
        ll = new_ll;
        mixture = Some(m);
        if done || k == 1 {
            break;
        }
    }
    mixture.map(|m| (ll, m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::StandardNormal;

    /// `points` split among 8 walkers, as the sampler hands them over.
    fn walkers(points: &[f64], d: usize) -> Vec<Vec<f64>> {
        let n = points.len() / d;
        (0..8)
            .map(|w| (w..n).step_by(8).flat_map(|i| points[i * d..(i + 1) * d].to_vec()).collect())
            .collect()
    }

    fn two_blobs(n: usize) -> Vec<f64> {
        let mut rng = crate::rng::stream(3, &[]);
        (0..n)
            .flat_map(|i| {
                let centre = if i % 3 == 0 { [6.0, 0.0] } else { [0.0, 0.0] };
                let z: [f64; 2] = std::array::from_fn(|_| rng.sample(StandardNormal));
                [centre[0] + z[0], centre[1] + 0.5 * z[1]]
            })
            .collect()
    }

    /// Two separated clusters: BIC picks two components, with the clusters'
    /// weights (1/3, 2/3) within 0.03 (a binomial sd of 0.01 for 2000 points).
    #[test]
    fn em_finds_two_clusters() {
        let pts = two_blobs(2000);
        let m = Mixture::fit(&walkers(&pts, 2), 2, &mut crate::rng::stream(4, &[])).unwrap();
        assert_eq!(m.components.len(), 2);
        let mut w: Vec<f64> = m.components.iter().map(|c| c.log_weight.exp()).collect();
        w.sort_by(f64::total_cmp);
        assert!((w[0] - 1.0 / 3.0).abs() < 0.03 && (w[1] - 2.0 / 3.0).abs() < 0.03, "{w:?}");
    }

    /// The log density is that of the mixture of normalised Student-t
    /// components, up to one constant: the difference between two points
    /// equals that of a direct computation with statrs' 1-D Student-t.
    #[test]
    fn log_q_is_the_mixture_density() {
        use statrs::distribution::{Continuous, StudentsT};
        let pts: Vec<f64> = two_blobs(3000).chunks(2).map(|p| p[0]).collect();
        let m = Mixture::fit(&walkers(&pts, 1), 1, &mut crate::rng::stream(5, &[])).unwrap();
        let direct = |v: f64| {
            m.components
                .iter()
                .map(|c| {
                    let s = c.shape.factor()[(0, 0)];
                    c.log_weight.exp() * StudentsT::new(c.shape.mean[0], s, 7.0).unwrap().pdf(v)
                })
                .sum::<f64>()
                .ln()
        };
        let (a, b) = (0.3, 5.1);
        let ours = m.log_q(Some(7.0), &[a]) - m.log_q(Some(7.0), &[b]);
        assert!(
            (ours - (direct(a) - direct(b))).abs() < 1e-10,
            "{ours} vs {}",
            direct(a) - direct(b)
        );
    }

    /// One Gaussian, its walkers' points repeated (rejections): one
    /// component.
    #[test]
    fn a_gaussian_with_repeated_points_is_one_component() {
        let mut rng = crate::rng::stream(6, &[]);
        let pts: Vec<f64> = (0..3000)
            .flat_map(|i| {
                let z: [f64; 3] = std::array::from_fn(|_| rng.sample(StandardNormal));
                // every point three times in a row, as a walker that stays
                let _ = i;
                [z, z, z].concat()
            })
            .collect();
        let m = Mixture::fit(&walkers(&pts, 3), 3, &mut crate::rng::stream(7, &[])).unwrap();
        assert_eq!(m.components.len(), 1);
    }

    #[test]
    fn the_schedule_doubles() {
        assert_eq!(
            (last_fit_step(4), last_fit_step(7), last_fit_step(8), last_fit_step(12)),
            (0, 0, 8, 8)
        );
        assert_eq!(
            (last_fit_step(16), last_fit_step(31), last_fit_step(32), last_fit_step(1024)),
            (16, 16, 32, 1024)
        );
        assert_eq!(
            (last_fit_step(2047), last_fit_step(2048), last_fit_step(5000)),
            (1024, 1024, 1024)
        );
    }
}
