//! An independence proposal that follows a curved ridge.
//!
//! A posterior whose mass lies along a curve (one parameter poorly fixed,
//! the others following it nonlinearly) is covered by an ellipsoid only
//! with much empty volume, so a Student-t fitted to the complementary half
//! proposes mostly off the ridge. The *tube* fitted here describes such a
//! posterior by one coordinate along the ridge and the others across it:
//! in the half's whitened coordinates z = L⁻¹(x − m), the direction u of
//! one of the original coordinates gives t = u·z, and the coordinates w
//! across it (an orthonormal basis of u's complement) follow
//!
//! w | t ~ Student-t(μ(t), v(t) S),  μ polynomial in t, v quadratic in t,
//!
//! fitted by least squares (μ), the residuals' covariance (S) and a
//! regression of each residual's squared norm (v, the tube's width along
//! it); t itself is drawn from a Gaussian kernel density of the half's t,
//! and a share of it from a heavy-tailed Student-t ([`REACH`]).
//! Kernel, tails and cross-section are widened by the history mixture's
//! factor (an independence proposal must not be lighter than the target:
//! on a log-normal the unwidened tube left the upper tail short by 5–6
//! Monte Carlo se in 1 of 32 seeds, widened in none).
//! The direction is the coordinate whose square explains the most of the
//! other coordinates' variance: the one the ridge bends along. The map
//! z → (t, w) is a rotation, so q(x) = q(t) q(w | t) / |L|.
//!
//! The proposal is an equal mixture of the tube, the half's own Student-t
//! (the independence move's) and, where the reference is near, the
//! anchored fit: where the posterior is not curved the tube is an ellipsoid
//! too, and where the tube fits badly the others still propose. Everything
//! depends on the complementary half and the fixed reference only, so the
//! factor q(x)/q(y) keeps the chain exact.
//!
//! A few dozen points carry a quadratic centre curve and a rough kernel
//! density. The ensemble's own history holds thousands: from step 8 the
//! sampler fits a tube to it as well ([`Tube::of_history`], cubic, on the
//! history move's schedule), and the move proposes from that tube 70 % of
//! the time and from the half's mixture the rest
//! ([`super::mixture::propose`]; fixed between fits, so each stretch is an
//! exact Metropolis-Hastings chain). A history tube also carries *local
//! kernels* ([`LOCAL`]): its centres' own residuals about the centre curve,
//! which follow a cross-section that changes shape along the ridge.

use nalgebra::{DMatrix, DVector};
use rand::RngExt;

use super::super::elliptical::{standard_log_density, t_factor, Elliptical};
use super::mixture::{distinct, thinned, SPREAD};
use super::Independent;
use crate::numeric::{log_sum_exp, mean, variance};

/// The narrowest and widest the tube may become along the ridge, as a
/// share of its mean width² (v(t) is clamped to this range): a quadratic
/// fitted to a few dozen squared norms must not pinch the tube shut or
/// blow it up where it extrapolates.
const WIDTH_RANGE: (f64, f64) = (0.25, 4.0);

/// Share of each variance added to the residual covariance's diagonal.
const RIDGE: f64 = 1e-9;

/// The degree of the centre curve of a tube fitted to an ensemble's
/// history (thousands of points; the complementary half's few dozen carry
/// a quadratic).
const HISTORY_DEGREE: usize = 3;

/// The share of t drawn from a Student-t with [`REACH_DF`] degrees of
/// freedom and the points' mean and sd (widened by the history mixture's
/// factor) instead of the kernel density. Beyond its outermost centres a
/// Gaussian kernel density falls off like a Gaussian, faster than a ridge
/// whose far end thins out exponentially, and an independence proposal
/// lighter than its target leaves that end short (on a Gumbel ridge,
/// `tests/it/sampler.rs`, the 99 % quantile by 4–5 standard errors in 3 of 12
/// seeds).
const REACH: f64 = 0.2;
const REACH_DF: f64 = 3.0;

/// The share of a history tube's proposals whose cross-section is a kernel
/// density of the points' own residuals about the centre curve (each
/// centre's, moved along the curve with its t) instead of one Student-t
/// shape scaled along the ridge: where the ridge's cross-section changes
/// shape toward an end (a coordinate's spread growing as the others'
/// narrow), one scaled shape proposes too rarely there. On the slow record
/// of docs/performance.md the far end of m1 (its last 2 % of mass) was a
/// third short against an independent importance-sampling estimate; with
/// half of the kernel share local, a sixth. A share of the kernel density's,
/// not of the heavy-tailed [`REACH`]: local kernels end where the points
/// end.
const LOCAL: f64 = 0.5;

/// The most points of an ensemble's history a tube is fitted to.
const MAX_HISTORY_POINTS: usize = 2000;

/// The most centres of the kernel density along the ridge (evenly thinned
/// from the points fitted): each density costs as many exponentials.
const MAX_CENTRES: usize = 256;

/// The tube fitted to a complementary half.
#[derive(Clone, Debug)]
pub struct Tube {
    /// The half's mean and the Cholesky factor of its covariance.
    frame: Elliptical,
    /// The direction along the ridge, in whitened coordinates.
    along: DVector<f64>,
    /// An orthonormal basis of the directions across it (d × (d − 1)).
    across: DMatrix<f64>,
    /// μ(t) = c₀ + c₁ t + c₂ t² (+ c₃ t³): rows c₀, c₁, … ((degree + 1) ×
    /// (d − 1)).
    centre: DMatrix<f64>,
    /// The Cholesky factor of the residuals' covariance S.
    spread: DMatrix<f64>,
    /// v(t) = a₀ + a₁ t + a₂ t², clamped to [`WIDTH_RANGE`].
    width: DVector<f64>,
    /// The half's t, the kernel density's centres, and its bandwidth.
    ts: Vec<f64>,
    bandwidth: f64,
    /// The mean and sd of the points' t, for the heavy-tailed share of t
    /// ([`REACH`]).
    spread_t: (f64, f64),
    /// A history tube's kernel density of its centres' (t, residual).
    local: Option<Local>,
}

/// The kernels of a history tube's local share ([`LOCAL`]): one per centre
/// (t_i, ρ_i), ρ_i its residual about the centre curve whitened by S;
/// (t, w) ~ N(t_i, h_t²) · N(μ(t) + S^{1/2}(ρ_i + κ e)), e standard normal.
/// h_t and κ are Scott's factor n^(−1/(d+4)) of the spreads (t's sd, and
/// 1 for the whitened residuals), widened by [`SPREAD`].
#[derive(Clone, Debug)]
struct Local {
    residuals: Vec<DVector<f64>>,
    bandwidth_t: f64,
    kappa: f64,
}

impl Tube {
    /// The tube of the half `others` (points of `d` coordinates one after
    /// another); `None` with fewer than d + 4 points, in one dimension, or
    /// where a fit is singular.
    pub fn fit(others: &[f64], d: usize) -> Option<Tube> {
        Tube::fit_curve(others, d, 2, false)
    }

    /// The tube of `others` with a centre polynomial in t of `degree`, and
    /// with [`Local`] kernels if `local`.
    fn fit_curve(others: &[f64], d: usize, degree: usize, local: bool) -> Option<Tube> {
        let n = others.len() / d;
        if d < 2 || n < d + 2 + degree {
            return None;
        }
        let frame = super::independence::fitted(others, d)?;
        let l = frame.factor();
        let z: Vec<DVector<f64>> = others
            .chunks_exact(d)
            .map(|p| l.solve_lower_triangular(&(DVector::from_column_slice(p) - &frame.mean)))
            .collect::<Option<_>>()?;
        let along = bending_direction(&z, l)?;
        let across = complement(&along);
        let ts: Vec<f64> = z.iter().map(|v| v.dot(&along)).collect();
        // μ(t) by least squares on the basis 1, t, …, t^degree
        let powers = |k: usize| DMatrix::from_fn(n, k + 1, |i, j| ts[i].powi(j as i32));
        let basis = powers(degree);
        let across_z = DMatrix::from_fn(n, d - 1, |i, j| across.column(j).dot(&z[i]));
        let centre = basis.tr_mul(&basis).try_inverse()? * basis.tr_mul(&across_z);
        let residuals: Vec<DVector<f64>> =
            (0..n).map(|i| (across_z.row(i) - basis.row(i) * &centre).transpose()).collect();
        let mut cov =
            residuals.iter().fold(DMatrix::zeros(d - 1, d - 1), |acc, r| acc + r * r.transpose())
                / (n - degree - 1) as f64;
        for i in 0..d - 1 {
            cov[(i, i)] *= 1.0 + RIDGE;
        }
        let spread = cov.cholesky()?.l();
        // the width along the ridge: each residual's squared norm per coordinate
        let norms: Vec<f64> = residuals
            .iter()
            .map(|r| {
                spread
                    .solve_lower_triangular(r)
                    .map_or(f64::NAN, |s| s.norm_squared() / (d - 1) as f64)
            })
            .collect();
        let quadratic = powers(2);
        let width = quadratic.tr_mul(&quadratic).try_inverse()?
            * quadratic.tr_mul(&DVector::from_vec(norms));
        if !width.iter().all(|v| v.is_finite()) {
            return None;
        }
        let every = n.div_ceil(MAX_CENTRES);
        let ts: Vec<f64> = ts.iter().copied().step_by(every).collect();
        let bandwidth = 1.06 * variance(&ts).sqrt() * (ts.len() as f64).powf(-0.2) * SPREAD;
        let spread_t = (mean(&ts), variance(&ts).sqrt() * SPREAD);
        let scott = (ts.len() as f64).powf(-1.0 / (d as f64 + 4.0)) * SPREAD;
        let local = match local {
            true => Some(Local {
                residuals: residuals
                    .iter()
                    .step_by(every)
                    .map(|r| spread.solve_lower_triangular(r))
                    .collect::<Option<_>>()?,
                bandwidth_t: scott * variance(&ts).sqrt(),
                kappa: scott,
            }),
            false => None,
        };
        (bandwidth > 0.0 && spread_t.0.is_finite()).then_some(Tube {
            frame,
            along,
            across,
            centre,
            spread,
            width,
            ts,
            bandwidth,
            spread_t,
            local,
        })
    }

    /// The tube of an ensemble's history: its walkers' positions (per
    /// walker, points of `d` coordinates in time order), a repeated
    /// position (a rejected proposal) counted once, evenly thinned to
    /// [`MAX_HISTORY_POINTS`].
    pub fn of_history(walkers: &[Vec<f64>], d: usize) -> Option<Tube> {
        let points =
            thinned(walkers.iter().flat_map(|w| distinct(w, d)).collect(), MAX_HISTORY_POINTS);
        let flat: Vec<f64> = points.iter().flat_map(|p| p.iter().copied()).collect();
        Tube::fit_curve(&flat, d, HISTORY_DEGREE, true)
    }

    fn width_at(&self, t: f64) -> f64 {
        (self.width[0] + self.width[1] * t + self.width[2] * t * t)
            .clamp(WIDTH_RANGE.0, WIDTH_RANGE.1)
            * SPREAD
            * SPREAD
    }

    fn centre_at(&self, t: f64) -> DVector<f64> {
        self.centre.tr_mul(&DVector::from_fn(self.centre.nrows(), |k, _| t.powi(k as i32)))
    }
}

impl Independent for Tube {
    /// Normalised, with Student-t (`df`) or Gaussian cross-sections (and a
    /// history tube's local kernels, [`LOCAL`]).
    fn log_q(&self, df: Option<f64>, x: &[f64]) -> f64 {
        let Some(z) = self
            .frame
            .factor()
            .solve_lower_triangular(&(DVector::from_column_slice(x) - &self.frame.mean))
        else {
            return f64::NEG_INFINITY;
        };
        let t = z.dot(&self.along);
        let Some(r) =
            self.spread.solve_lower_triangular(&(self.across.tr_mul(&z) - self.centre_at(t)))
        else {
            return f64::NEG_INFINITY;
        };
        let h = self.bandwidth;
        let kernels: Vec<f64> = self.ts.iter().map(|c| -0.5 * ((t - c) / h).powi(2)).collect();
        let log_kde = log_sum_exp(&kernels)
            - (self.ts.len() as f64).ln()
            - h.ln()
            - 0.5 * (2.0 * std::f64::consts::PI).ln();
        let (c, s) = self.spread_t;
        let log_reach = standard_log_density(Some(REACH_DF), 1.0, ((t - c) / s).powi(2)) - s.ln();
        let v = self.width_at(t);
        let k = r.len() as f64;
        let log_s = self.spread.diagonal().iter().map(|s| s.ln()).sum::<f64>();
        let cross = standard_log_density(df, k, r.norm_squared() / v) - 0.5 * k * v.ln();
        // the heavy-tailed share of t keeps its weight; the kernel density's
        // is split with the local kernels where there are any
        let local_share = if self.local.is_some() { LOCAL } else { 0.0 };
        let mut parts = vec![
            REACH.ln() + log_reach + cross,
            ((1.0 - REACH) * (1.0 - local_share)).ln() + log_kde + cross,
        ];
        if let Some(local) = &self.local {
            let (ht, kappa) = (local.bandwidth_t, local.kappa);
            let terms: Vec<f64> = self
                .ts
                .iter()
                .zip(&local.residuals)
                .map(|(ti, ri)| {
                    -0.5 * (((t - ti) / ht).powi(2)
                        + r.iter().zip(ri.iter()).map(|(a, b)| (a - b) * (a - b)).sum::<f64>()
                            / (kappa * kappa))
                })
                .collect();
            let log_local = log_sum_exp(&terms)
                - (self.ts.len() as f64).ln()
                - 0.5 * (k + 1.0) * (2.0 * std::f64::consts::PI).ln()
                - ht.ln()
                - k * kappa.ln();
            parts.push(((1.0 - REACH) * local_share).ln() + log_local);
        }
        log_sum_exp(&parts) - log_s - self.frame.half_log_det()
    }

    /// t from the kernel density (or the heavy-tailed share), then w given
    /// t; or, a history tube's local share, a centre's kernel.
    fn draw(&self, df: Option<f64>, rng: &mut impl rand::Rng, y: &mut [f64]) {
        let z: f64 = rng.sample(rand_distr::StandardNormal);
        let k = self.across.ncols();
        let e = DVector::from_iterator(
            k,
            (0..k).map(|_| rng.sample::<f64, _>(rand_distr::StandardNormal)),
        );
        let reach = rng.random::<f64>() < REACH;
        let (t, w) = match self.local.as_ref().filter(|_| !reach && rng.random::<f64>() < LOCAL) {
            Some(local) => {
                let i = rng.random_range(0..self.ts.len());
                let t = self.ts[i] + local.bandwidth_t * z;
                (t, self.centre_at(t) + &self.spread * (&local.residuals[i] + e * local.kappa))
            }
            None => {
                let t = if reach {
                    self.spread_t.0 + self.spread_t.1 * z * t_factor(Some(REACH_DF), rng)
                } else {
                    self.ts[rng.random_range(0..self.ts.len())] + self.bandwidth * z
                };
                (
                    t,
                    self.centre_at(t)
                        + &self.spread * e * (self.width_at(t).sqrt() * t_factor(df, rng)),
                )
            }
        };
        let z = &self.along * t + &self.across * w;
        self.frame.point_into(z.as_slice(), 1.0, y);
    }
}

/// Of the directions of the original coordinates in whitened space (rows
/// of L, normalised), the one whose square, less its linear part, has the
/// largest summed squared covariance with the whitened coordinates: the
/// coordinate along which the others bend.
fn bending_direction(z: &[DVector<f64>], l: &DMatrix<f64>) -> Option<DVector<f64>> {
    let d = l.nrows();
    let n = z.len() as f64;
    let mean_z = z.iter().fold(DVector::zeros(d), |acc, v| acc + v) / n;
    let mut best: Option<(f64, DVector<f64>)> = None;
    for k in 0..d {
        let u = l.row(k).transpose();
        let norm = u.norm();
        if !(norm > 0.0) {
            continue;
        }
        let u = u / norm;
        let t: Vec<f64> = z.iter().map(|v| v.dot(&u)).collect();
        let mt = mean(&t);
        let sq: Vec<f64> = t.iter().map(|v| v * v).collect();
        let ms = mean(&sq);
        let tt: f64 = t.iter().map(|v| (v - mt) * (v - mt)).sum();
        let st: f64 = t.iter().zip(&sq).map(|(a, b)| (a - mt) * (b - ms)).sum();
        let q: Vec<f64> = t.iter().zip(&sq).map(|(a, b)| b - ms - st / tt * (a - mt)).collect();
        let qq: f64 = q.iter().map(|v| v * v).sum();
        if !(qq > 0.0) {
            continue;
        }
        let cov =
            z.iter().zip(&q).fold(DVector::zeros(d), |acc, (v, qv)| acc + (v - &mean_z) * *qv);
        let gain = cov.norm_squared() / qq;
        if best.as_ref().is_none_or(|(g, _)| gain > *g) {
            best = Some((gain, u));
        }
    }
    best.map(|(_, u)| u)
}

/// An orthonormal basis of the directions orthogonal to the unit vector
/// `u`: the last d − 1 columns of the Householder reflection taking the
/// first axis to ±u.
fn complement(u: &DVector<f64>) -> DMatrix<f64> {
    let d = u.len();
    let mut v = u.clone();
    v[0] += if u[0] >= 0.0 { 1.0 } else { -1.0 };
    let h = DMatrix::identity(d, d) - &v * v.transpose() * (2.0 / v.norm_squared());
    h.columns(1, d - 1).into_owned()
}

/// The curved move's proposal: an equal mixture of the tube and the
/// ellipsoids (the half's own Student-t, and the anchored fit where the
/// reference is near).
#[derive(Clone, Debug)]
pub struct Proposal {
    tube: Option<Tube>,
    parts: Vec<Elliptical>,
}

impl Proposal {
    /// The proposal for the half `others` (points of `d` coordinates) and
    /// the sampler's `reference`, if it has one; `None` if not even the
    /// half's own Student-t can be fitted.
    pub fn fit(others: &[f64], d: usize, reference: Option<&Elliptical>) -> Option<Proposal> {
        let mut parts = vec![super::independence::fitted(others, d)?];
        if let Some(a) = reference.and_then(|r| super::anchored::anchored_fit(others, d, r)) {
            parts.push(a);
        }
        Some(Proposal { tube: Tube::fit(others, d), parts })
    }

    fn count(&self) -> usize {
        self.parts.len() + usize::from(self.tube.is_some())
    }
}

impl Independent for Proposal {
    /// A part chosen uniformly (the tube last), then its draw.
    fn draw(&self, df: Option<f64>, rng: &mut impl rand::Rng, y: &mut [f64]) {
        match self.parts.get(rng.random_range(0..self.count())) {
            Some(p) => p.draw(df, 1.0, rng, y),
            None => self.tube.as_ref().expect("counted").draw(df, rng, y),
        }
    }

    /// Normalised.
    fn log_q(&self, df: Option<f64>, x: &[f64]) -> f64 {
        let mut terms: Vec<f64> = self.parts.iter().map(|p| p.log_density(df, x, 1.0)).collect();
        if let Some(tube) = &self.tube {
            terms.push(tube.log_q(df, x));
        }
        log_sum_exp(&terms) - (self.count() as f64).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::elliptical::Moments;

    /// Points of a banana: x1 ~ N(0, 1), x2 = x1² + N(0, 0.1²), x3 ~ N(0, 1).
    fn banana(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = crate::rng::stream(seed, &[]);
        let mut out = Vec::with_capacity(3 * n);
        for _ in 0..n {
            let a: f64 = rng.sample(rand_distr::StandardNormal);
            let b: f64 = rng.sample(rand_distr::StandardNormal);
            let c: f64 = rng.sample(rand_distr::StandardNormal);
            out.extend_from_slice(&[a, a * a + 0.1 * b, c]);
        }
        out
    }

    /// ∫ q over draws from g, a broad Student-t (ν = 2, heavier-tailed than
    /// every part of the tube) that covers it: E_g[q/g], and its Monte
    /// Carlo standard error, from 200 000 draws.
    fn integral(tube: &Tube, seed: u64) -> (f64, f64) {
        let g = Elliptical::new(Moments {
            mean: DVector::from_vec(vec![0.0, 1.0, 0.0]),
            cov: DMatrix::from_diagonal(&DVector::from_vec(vec![9.0, 16.0, 9.0])),
        })
        .unwrap();
        let mut rng = crate::rng::stream(seed, &[]);
        let mut y = [0.0; 3];
        let ratios: Vec<f64> = (0..200_000)
            .map(|_| {
                g.draw(Some(2.0), 1.0, &mut rng, &mut y);
                (tube.log_q(Some(10.0), &y) - g.log_density(Some(2.0), &y, 1.0)).exp()
            })
            .collect();
        (mean(&ratios), (variance(&ratios) / ratios.len() as f64).sqrt())
    }

    /// The tube's density integrates to one, within 5 Monte Carlo standard
    /// errors ([`integral`]). Catches a missing Jacobian or constant, which
    /// the factor q(x)/q(y) would not show.
    #[test]
    fn the_tube_density_is_normalised() {
        let tube = Tube::fit(&banana(40, 3), 3).unwrap();
        let (m, se) = integral(&tube, 4);
        assert!((m - 1.0).abs() < 5.0 * se, "∫q = {m} ± {se}");
    }

    /// The tube of a history (cubic centre; 8 walkers whose rejected
    /// proposals repeat their positions, counted once; 400 points, every
    /// second one a kernel centre) integrates to one as well.
    #[test]
    fn the_history_tube_density_is_normalised() {
        let pts = banana(400, 9);
        let walkers: Vec<Vec<f64>> = (0..8)
            .map(|w| pts.chunks(3).skip(w).step_by(8).flat_map(|p| [p, p].concat()).collect())
            .collect();
        let tube = Tube::of_history(&walkers, 3).unwrap();
        assert_eq!((tube.centre.nrows(), tube.ts.len()), (HISTORY_DEGREE + 1, 200));
        let (m, se) = integral(&tube, 10);
        assert!((m - 1.0).abs() < 5.0 * se, "∫q = {m} ± {se}");
    }

    /// On a banana the tube bends along x1 and its draws have the banana's
    /// distribution, widened by [`SPREAD`]: the quartiles of x2 = x1² +
    /// noise are those of 1.15² χ²₁ (0.135, 0.60, 1.75) within 0.05, 0.1,
    /// 0.3 (a fit to 200 points, [`REACH`] of t heavy-tailed), where an
    /// ellipsoid with the banana's mean and covariance would put its median
    /// near 1.
    #[test]
    fn the_tube_follows_a_banana() {
        let pts = banana(200, 5);
        let tube = Tube::fit(&pts, 3).unwrap();
        let mut rng = crate::rng::stream(6, &[]);
        let mut y = [0.0; 3];
        let n = 100_000;
        let mut x2 = Vec::with_capacity(n);
        let mut inside = 0;
        for _ in 0..n {
            tube.draw(None, &mut rng, &mut y);
            x2.push(y[1]);
            inside += usize::from((y[1] - y[0] * y[0]).abs() < 0.3);
        }
        x2.sort_by(f64::total_cmp);
        let q = |p: f64| x2[(p * n as f64) as usize];
        let (q1, q2, q3) = (q(0.25), q(0.5), q(0.75));
        assert!(
            (q1 - 0.135).abs() < 0.05 && (q2 - 0.60).abs() < 0.1 && (q3 - 1.75).abs() < 0.3,
            "x2 quartiles {q1} {q2} {q3}"
        );
        // most draws lie on the curve (an ellipsoid puts about a third there)
        assert!(inside as f64 / n as f64 > 0.8, "{inside} of {n} within 3 widths of the curve");
    }

    /// The factor is q(x)/q(y) of the mixture: exchanging x and y negates it.
    #[test]
    fn factor_is_the_ratio_of_the_mixture_densities() {
        let pts = banana(30, 7);
        let q = Proposal::fit(&pts, 3, None).unwrap();
        let mut rng = crate::rng::stream(8, &[]);
        let x = [0.2, 0.1, -0.3];
        let mut y = [0.0; 3];
        let f = q.propose(Some(10.0), &x, &mut rng, &mut y);
        assert!((f - (q.log_q(Some(10.0), &x) - q.log_q(Some(10.0), &y))).abs() < 1e-12);
        assert!(q.tube.is_some() && q.count() == 2);
    }
}
