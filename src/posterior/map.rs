//! The start of the sampler: maximum a posteriori (MAP) refinement of the
//! identification, the Laplace approximation around it, and the rule that
//! chooses the integrator's step.
//!
//! Everything here works on θ in the sampler's coordinates (the noise is
//! profiled), on the whitened residuals of a Gaussian surrogate: the
//! residuals of every run divided by its σ (its noise model's whitening),
//! where the variances follow the model a log-variance pseudo-residual per
//! sample, and one pseudo-residual per log-normal prior. Residuals of several points are integrated together,
//! four per SIMD batch and runs in parallel, so a Jacobian costs about two
//! integrations of the records rather than one per coordinate.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Arc;

use nalgebra::{DMatrix, DVector};
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use super::{Layout, Posterior};
use crate::data::RunData;
use crate::fit::{least_squares_to, PATIENCE};
use crate::model::{Integrator, LANES};
use crate::noise::{Profile, Whiten};
use crate::sampler::density::log_densities;
use crate::sampler::{Elliptical, LogDensity};

/// The MAP point and the Laplace approximation of θ around it.
#[derive(Clone, Debug)]
pub struct MapEstimate {
    /// Every coordinate (θ, ln σ, atanh ρ), in the sampler's coordinates.
    pub x: Vec<f64>,
    /// Covariance of the θ coordinates (Laplace, Gaussian surrogate).
    pub cov: DMatrix<f64>,
    /// The Jacobian of the whitened residuals at the MAP (for the step rule).
    jacobian: DMatrix<f64>,
    /// How each run's residuals are whitened at the profiled noise.
    whitening: Vec<Arc<dyn Whiten>>,
    pub log_density: f64,
    /// Whether its search stopped on its budget of evaluations.
    pub exhausted: bool,
}

impl MapEstimate {
    /// This estimate's Laplace approximation around the optimum `moved`
    /// found by another integrator: the explicit scheme's likelihood can be
    /// rugged on the scale of a finite-difference step (its step cuts
    /// switch), so its Jacobian is not a curvature; a smooth scheme's is.
    pub fn curvature_at(&self, moved: MapEstimate) -> MapEstimate {
        MapEstimate { cov: self.cov.clone(), jacobian: self.jacobian.clone(), ..moved }
    }

    /// This estimate moved to `x` (every coordinate), where the posterior's
    /// log-density is `log_density`: a mode reached otherwise than by the
    /// search ([`super::laplace::adjusted_mode`]); the search's curvature kept.
    pub fn moved_to(&self, x: Vec<f64>, log_density: f64) -> MapEstimate {
        MapEstimate { x, log_density, ..self.clone() }
    }

    /// The Jacobian of the whitened residuals at the MAP: each run's
    /// residuals in order, then the runs' log-variance terms (if any), then
    /// the priors' pseudo-residuals; a column per fitted coordinate.
    pub fn jacobian(&self) -> &DMatrix<f64> {
        &self.jacobian
    }

    /// Posterior sd of each θ coordinate from the Laplace approximation.
    pub fn sd(&self) -> Vec<f64> {
        (0..self.cov.nrows()).map(|i| self.cov[(i, i)].max(0.0).sqrt()).collect()
    }

    /// Posterior sd of each ln θ from the Laplace approximation (the delta
    /// method through the map from the sampler's coordinates).
    pub fn log_theta_sd(&self, layout: &Layout) -> Vec<f64> {
        let (nt, nf) = (layout.theta.len(), self.cov.nrows());
        let at = layout.log_theta(&self.x);
        let h = 1e-7;
        let a = DMatrix::from_fn(nt, nf, |i, j| {
            let mut y = self.x.clone();
            y[j] += h;
            (layout.log_theta(&y)[i] - at[i]) / h
        });
        let cov = &a * &self.cov * a.transpose();
        (0..nt).map(|i| cov[(i, i)].max(0.0).sqrt()).collect()
    }
}

/// Forward-difference step of the Jacobian in the θ coordinates (logs):
/// large against the integrator's rounding, small against the posterior's
/// width.
const JACOBIAN_STEP: f64 = 1e-6;

/// The law's path (stress at every sample after the first) along run `r`
/// for up to [`LANES`] likelihood points (`None` where an integration
/// fails).
fn run_paths(post: &Posterior, r: &RunData, xs: &[&[f64]]) -> Vec<Option<Vec<f64>>> {
    let params = post.lane_params(xs, r);
    let mut out = vec![Vec::with_capacity(r.compared()); xs.len()];
    let outcome = params.integrate(&post.integrator, r, |k, s| {
        if k > 0 {
            for (lane, o) in out.iter_mut().enumerate() {
                o.push(s[lane]);
            }
        }
    });
    out.into_iter().zip(outcome).map(|(o, ok)| ok.ok().map(|_| o)).collect()
}

/// Residuals of every run at each of the θ points `xs` (`None` where an
/// integration fails), `[point][run]`. The model terms (gas spring, force
/// offset) are added to the law's path, not integrated: points that
/// differ only in them share one integration (a Jacobian's columns of
/// the terms cost none; the lanes are independent, so each path has the
/// same bits as when integrated on its own).
fn residuals_many(post: &Posterior, xs: &[Vec<f64>]) -> Vec<Option<Vec<Vec<f64>>>> {
    let l = &post.layout;
    // the likelihood's points (the adjusted likelihood's ln θ*), and which
    // of them the law's path depends on: all but the terms
    let moved: Vec<Cow<[f64]>> = xs.iter().map(|x| post.likelihood_point(x)).collect();
    let key = |x: &[f64]| -> Vec<u64> {
        let mut k: Vec<u64> = x.iter().map(|v| v.to_bits()).collect();
        for i in l.spring.clone().chain(l.offset.clone()) {
            k[i] = 0;
        }
        k
    };
    let mut distinct: Vec<usize> = Vec::new();
    let mut seen: HashMap<Vec<u64>, usize> = HashMap::new();
    let path_of: Vec<usize> = moved
        .iter()
        .enumerate()
        .map(|(i, x)| {
            *seen.entry(key(x)).or_insert_with(|| {
                distinct.push(i);
                distinct.len() - 1
            })
        })
        .collect();
    let groups: Vec<(usize, usize)> = (0..post.runs.len())
        .flat_map(|r| (0..distinct.len()).step_by(LANES).map(move |g| (r, g)))
        .collect();
    let pieces: Vec<Vec<Option<Vec<f64>>>> = groups
        .par_iter()
        .map(|&(r, g)| {
            let group = &distinct[g..(g + LANES).min(distinct.len())];
            let points: Vec<&[f64]> = group.iter().map(|&i| moved[i].as_ref()).collect();
            run_paths(post, &post.runs[r], &points)
        })
        .collect();
    // paths[run][distinct point]
    let mut paths: Vec<Vec<Option<Vec<f64>>>> = vec![Vec::new(); post.runs.len()];
    for (&(r, _), piece) in groups.iter().zip(pieces) {
        paths[r].extend(piece);
    }
    xs.iter()
        .zip(&path_of)
        .map(|(x, &p)| {
            paths
                .iter()
                .zip(&post.runs)
                .enumerate()
                .map(|(j, (of_run, run))| {
                    let path = of_run[p].as_ref()?;
                    let (spring, offset) = l.terms(x, j);
                    Some(
                        path.iter()
                            .enumerate()
                            .map(|(k, s)| {
                                run.tau[k + 1] - s - run.terms_stress(k + 1, spring, offset)
                            })
                            .collect(),
                    )
                })
                .collect()
        })
        .collect()
}

/// Each run's root-mean-square residual (the law's path against the record,
/// model terms included) at `x` and how many residuals it is over (`None`
/// where an integration fails).
pub fn residual_rms(post: &Posterior, x: &[f64]) -> Option<Vec<(f64, usize)>> {
    let res = residuals_many(post, &[x.to_vec()]).pop()??;
    Some(res.iter().map(|r| (crate::noise::rms(r), r.len())).collect())
}

/// [`residual_rms`] at each of `xs`, integrated together (`None` where a
/// point's paths fail).
pub fn residual_rms_many(post: &Posterior, xs: &[Vec<f64>]) -> Vec<Option<Vec<f64>>> {
    residuals_many(post, xs)
        .into_iter()
        .map(|res| Some(res?.iter().map(|r| crate::noise::rms(r)).collect()))
        .collect()
}

/// The noise model's whitening of each run's residuals.
type Whitening = [Arc<dyn Whiten>];

/// Where the MAP search may evaluate the posterior.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Support {
    /// Inside the priors' truncation bounds only: points outside are
    /// infeasible (the curvature at a MAP on a bound differences backwards).
    Truncated,
    /// Anywhere the model integrates, the log-normal priors continued past
    /// their bounds: a search path that must pass outside the box (a
    /// truncated prior narrower than the road from the start) is not
    /// walled in.
    Open,
}

/// Whitened residuals at the fitted point `x` (θ and the model terms) from
/// its run residuals: each run's as its noise model whitens them (divided
/// by σ, say), then each run's log-variance terms where its variances
/// follow the model (errors in variables: without them the search's
/// optimum is not the likelihood's: with the discrepancy model on the
/// measured 0.5 A records it stopped 105 nats below where it now does,
/// docs/performance.md),
/// then (ln θ − centre)/scale for every log-normal prior, the coordinates'
/// Jacobian where they walk above a floor ([`Layout::floor_residuals`]),
/// and value/sd for every term's: their squares sum to −2 ln p up to a constant, at the
/// noise the search holds. With [`Support::Truncated`], points outside
/// the prior support are infeasible.
fn whiten(
    post: &Posterior,
    whitening: &Whitening,
    x: &[f64],
    residuals: Option<Vec<Vec<f64>>>,
    support: Support,
) -> Option<Vec<f64>> {
    let log_theta = post.layout.log_theta(x);
    // outside what the coordinates can reach (no positive R1, say)
    if log_theta.iter().any(|v| !v.is_finite()) {
        return None;
    }
    if support == Support::Truncated && !post.inside_priors(&log_theta) {
        return None;
    }
    let res = residuals?;
    let mut out: Vec<f64> =
        Vec::with_capacity(res.iter().map(Vec::len).sum::<usize>() + log_theta.len());
    // every run's whitened residuals, then every run's log-variance terms
    // (the rows of the whitened residuals first and together, as
    // [`super::memory`] reads them); a tempered run's count by the square
    // root of its weight
    let mut terms = Vec::new();
    for (j, ((r, w), g)) in res.iter().zip(whitening).zip(moduli(post, x)).enumerate() {
        let (from, terms_from) = (out.len(), terms.len());
        w.whiten(r, g, &mut out, &mut terms);
        let weight = post.weight(j);
        if weight != 1.0 {
            let scale = weight.sqrt();
            out[from..].iter_mut().chain(&mut terms[terms_from..]).for_each(|v| *v *= scale);
        }
    }
    out.append(&mut terms);
    for (prior, v) in post.priors.iter().zip(&log_theta) {
        if let Some((c, s)) = prior.centre() {
            out.push((v - c) / s);
        }
    }
    let l = &post.layout;
    out.extend(l.floor_residuals(x, &log_theta));
    out.extend(x[l.spring.clone()].iter().map(|v| v / post.terms.gas_spring_sd_n_per_m));
    out.extend(x[l.offset.clone()].iter().map(|v| v / post.terms.force_offset_sd_n));
    Some(out)
}

fn whitened(
    post: &Posterior,
    whitening: &Whitening,
    x: &[f64],
    support: Support,
) -> Option<Vec<f64>> {
    let res = residuals_many(post, std::slice::from_ref(&x.to_vec())).pop().flatten();
    whiten(post, whitening, x, res, support)
}

/// The Jacobian of the whitened residuals at `x` by forward differences,
/// every point integrated in one batch; a coordinate whose forward point
/// leaves the prior's support (a MAP at a truncation bound) is
/// differenced backwards instead.
fn jacobian(
    post: &Posterior,
    whitening: &Whitening,
    x: &[f64],
    support: Support,
) -> Option<DMatrix<f64>> {
    let n = x.len();
    let displaced = |sign: f64, which: &[usize]| -> Vec<Vec<f64>> {
        which
            .iter()
            .map(|&j| {
                let mut q = x.to_vec();
                if j > 0 {
                    q[j - 1] += sign * JACOBIAN_STEP;
                }
                q
            })
            .collect()
    };
    let all: Vec<usize> = (0..=n).collect();
    let points = displaced(1.0, &all);
    let mut white: Vec<Option<Vec<f64>>> = residuals_many(post, &points)
        .into_iter()
        .zip(&points)
        .map(|(r, q)| whiten(post, whitening, q, r, support))
        .collect();
    let r0 = white[0].take()?;
    let outside: Vec<usize> = (1..=n).filter(|&j| white[j].is_none()).collect();
    let back_points = displaced(-1.0, &outside);
    let back: Vec<Option<Vec<f64>>> = residuals_many(post, &back_points)
        .into_iter()
        .zip(&back_points)
        .map(|(r, q)| whiten(post, whitening, q, r, support))
        .collect();
    let mut jac = DMatrix::zeros(r0.len(), n);
    for j in 1..=n {
        let column: Vec<f64> = match &white[j] {
            Some(r1) => r1.iter().zip(&r0).map(|(a, b)| (a - b) / JACOBIAN_STEP).collect(),
            None => {
                let k = outside.iter().position(|&o| o == j).expect("listed");
                let rb = back[k].as_ref()?;
                r0.iter().zip(rb).map(|(a, b)| (a - b) / JACOBIAN_STEP).collect()
            }
        };
        for (i, v) in column.into_iter().enumerate() {
            jac[(i, j - 1)] = v;
        }
    }
    Some(jac)
}

/// Maximises the posterior over θ from `start` (θ coordinates), with each
/// run's noise profiled (fitted to its residuals and the fit repeated until
/// the noise scales settle), by Levenberg-Marquardt on the whitened
/// residuals, in the layout's search coordinates ([`Layout::searched`]).
/// Then sets the noise coordinates from the residuals at the optimum and
/// computes the Laplace covariance (JᵀJ)⁻¹ of θ in the layout's own.
pub fn refine(post: &Posterior, start: &[f64]) -> Option<MapEstimate> {
    refine_fitting(post, start, SETTLING_FITS, PATIENCE)
}

/// [`refine`] with the budget of a screened start ([`SCREEN_PATIENCE`]):
/// for a search from a MAP of a neighbouring likelihood (the same records
/// with their residuals' memory allowed for, or another integrator's
/// step), where Newton's method then climbs to the mode. Such a search
/// converges within it, to the same bits as [`refine`]'s, except where
/// the likelihood's ridge makes it creep: the tempered likelihood of
/// `bp-viscous` at 0.5 A on the measured records, whose full search spent
/// 82 s to rise 0.19 nats above where this one stops after 9.6 s.
pub fn refine_near(post: &Posterior, start: &[f64]) -> Option<MapEstimate> {
    refine_fitting(post, start, SETTLING_FITS, SCREEN_PATIENCE)
}

/// Levenberg-Marquardt fits at most, each with the noise profiled afresh,
/// until the noise scales settle.
const SETTLING_FITS: usize = 4;

/// One Levenberg-Marquardt fit from `start` with the noise profiled there:
/// a point in the basin of the posterior's mode, with its Gauss-Newton
/// curvature, for [`crate::newton::newton`] to finish (which reaches the
/// mode itself, where the noise's dependence on θ moves it).
pub fn basin(post: &Posterior, start: &[f64]) -> Option<MapEstimate> {
    refine_fitting(post, start, 1, PATIENCE).filter(|m| m.log_density.is_finite())
}

/// [`refine`] with each Levenberg-Marquardt fit allowed `patience` (n + 1)
/// evaluations of the residuals ([`least_squares_to`]).
fn refine_fitting(
    post: &Posterior,
    start: &[f64],
    fits: usize,
    patience: usize,
) -> Option<MapEstimate> {
    let nt = post.layout.fitted.len();
    let searched = post.layout.searched().map(|layout| post.in_layout(layout));
    let search = searched.as_ref().unwrap_or(post);
    let mut x: Vec<f64> = start[..nt].to_vec();
    carry(&mut x, &post.layout, &search.layout);
    let Found { mut x, whitening, exhausted } = search_from(search, x, fits, patience)?;
    carry(&mut x, &search.layout, &post.layout);
    let jac = jacobian(post, &whitening, &x, Support::Truncated)?;
    let cov = (jac.transpose() * &jac).try_inverse()?;
    let full = with_noise(post, &x)?;
    let log_density = post.log_density(&full);
    Some(MapEstimate { x: full, cov, jacobian: jac, whitening, log_density, exhausted })
}

/// The θ block of `x` carried from the coordinates of `from` to those of `to`.
fn carry(x: &mut [f64], from: &Layout, to: &Layout) {
    if from != to {
        let theta = to.theta_coordinates(&from.log_theta(x));
        x[to.theta.clone()].copy_from_slice(&theta);
    }
}

/// The optimum of a Levenberg-Marquardt search, its runs' whitening and
/// whether a fit spent its budget.
struct Found {
    x: Vec<f64>,
    whitening: Vec<Arc<dyn Whiten>>,
    exhausted: bool,
}

/// The relative gain in ½ Σ r² below which a Levenberg-Marquardt fit of
/// the search stops (MINPACK's √ε). The whitened residuals of a real
/// record sum to thousands and carry the integrator's rounding: with the
/// solver's default, 30 ε, each fit crept on for 200–500 iterations along
/// the posterior's ridges (a single measured record's MAP and refit: 21 s
/// of its 23 s wall) for a few tenths of a nat that the Newton steps of
/// [`super::mode`] take anyway; with √ε the mode they reach is the same to
/// 1e-4 nats and the posterior to 4e-4 of a sd (docs/performance.md).
const SEARCH_FTOL: f64 = 1.49e-8;

/// The Levenberg-Marquardt search of [`refine`] from the fitted point `x`.
fn search_from(post: &Posterior, mut x: Vec<f64>, fits: usize, patience: usize) -> Option<Found> {
    let whitening_of = |profiles: Vec<Profile>| -> (Vec<f64>, Vec<Arc<dyn Whiten>>) {
        profiles.into_iter().map(|p| (p.scale, p.whitening)).unzip()
    };
    let (mut scales, mut whitening) = whitening_of(profiles(post, &x)?);
    let mut exhausted = false;
    // the search crosses the box where it must; an optimum outside it is
    // brought to the box's edge and searched again inside
    for support in [Support::Open, Support::Truncated] {
        if support == Support::Truncated {
            let log_theta = post.layout.log_theta(&x);
            let inside = project(post, &log_theta);
            if inside == log_theta {
                break;
            }
            x[post.layout.theta.clone()].copy_from_slice(&post.layout.theta_coordinates(&inside));
            (scales, whitening) = whitening_of(profiles(post, &x)?);
        }
        for _ in 0..fits {
            let f = |p: &[f64]| whitened(post, &whitening, p, support);
            let j = |p: &[f64]| jacobian(post, &whitening, p, support);
            let fit = least_squares_to(SEARCH_FTOL, patience, &x, &f, Some(&j));
            let moved = fit.params.iter().zip(&x).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            x = fit.params;
            exhausted |= fit.exhausted;
            let (new_scales, new_whitening) = whitening_of(profiles(post, &x)?);
            let scale_change =
                new_scales.iter().zip(&scales).map(|(a, b)| (a / b).ln().abs()).fold(0.0, f64::max);
            (scales, whitening) = (new_scales, new_whitening);
            // a fit that spent its budget is not settled by more fits (a
            // screening search of [`best_map`] goes on only if it is the best)
            if fit.exhausted || (moved < 1e-6 && scale_change < 1e-3) {
                break;
            }
        }
    }
    Some(Found { x, whitening, exhausted })
}

/// ln θ brought into the priors' truncation bounds, coordinate by
/// coordinate.
fn project(post: &Posterior, log_theta: &[f64]) -> Vec<f64> {
    post.priors
        .iter()
        .zip(log_theta)
        .map(|(p, v)| {
            let (lo, hi) = p.bounds();
            v.clamp(lo.ln(), hi.ln())
        })
        .collect()
}

/// Each run's noise fitted to its residuals at the fitted point `x`.
fn profiles(post: &Posterior, x: &[f64]) -> Option<Vec<Profile>> {
    let res = residuals_many(post, &[x.to_vec()]).pop()??;
    Some(
        res.iter()
            .zip(&post.runs)
            .zip(moduli(post, x))
            .map(|((r, run), g)| post.noise.profile(run, r, g))
            .collect(),
    )
}

/// Each run's shear modulus at the fitted point `x` (`g_bound`: where the
/// law's stiffness starts and what caps it), for the noise models whose
/// variances follow that stiffness (errors in variables).
fn moduli(post: &Posterior, x: &[f64]) -> Vec<f64> {
    let at = post.likelihood_point(x);
    post.runs.iter().map(|run| post.lane_params(&[&at], run).g_bound(run)[0]).collect()
}

/// θ extended by the noise coordinates that maximise the likelihood of the
/// residuals at θ, in the layout's order (parameter by parameter, each for
/// every run).
fn with_noise(post: &Posterior, theta: &[f64]) -> Option<Vec<f64>> {
    let profiles = profiles(post, theta)?;
    let mut full = theta.to_vec();
    for p in 0..post.layout.noise_parameters.len() {
        full.extend(profiles.iter().map(|pr| pr.coordinates[p]));
    }
    Some(full)
}

/// Lag-1 autocorrelation of every run's residuals at the MAP, whitened as
/// its noise model whitens them (`None` where an integration fails): the
/// memory the noise model leaves unexplained. For independent noise that
/// is the residuals' own memory (divided by σ); for a model of memory,
/// what its one-step-ahead innovations keep.
pub fn whitened_autocorrelation(post: &Posterior, map: &MapEstimate) -> Option<Vec<f64>> {
    let white = whitened_residuals(post, map)?;
    Some(
        white
            .iter()
            .map(|w| {
                crate::sampler::diagnostics::autocorrelation(w).get(1).copied().unwrap_or(f64::NAN)
            })
            .collect(),
    )
}

/// Each run's integrated autocorrelation time (samples) of its residuals
/// at the MAP, whitened as its noise model whitens them: by how much the
/// residuals' memory shrinks the run's evidence (the variance of a mean
/// of n such residuals is k/n of one's). The chains' estimator (Sokal's
/// window, [`crate::sampler::diagnostics::integrated_time`]), at least 1.
pub fn memory_times(post: &Posterior, map: &MapEstimate) -> Option<Vec<f64>> {
    let white = whitened_residuals(post, map)?;
    Some(white.into_iter().map(|w| crate::sampler::diagnostics::integrated_time(&[w])).collect())
}

/// Each run's residuals at the MAP, whitened by its noise model.
pub(super) fn whitened_residuals(post: &Posterior, map: &MapEstimate) -> Option<Vec<Vec<f64>>> {
    let res = residuals_many(post, std::slice::from_ref(&map.x)).pop()??;
    Some(
        res.iter()
            .zip(&map.whitening)
            .zip(moduli(post, &map.x))
            .map(|((r, w), g)| {
                let mut white = Vec::with_capacity(r.len());
                w.whiten(r, g, &mut white, &mut Vec::new());
                white
            })
            .collect(),
    )
}

/// The best MAP from several starts (θ coordinates), by log-density. Each
/// start's search has a budget of [`SCREEN_PATIENCE`]; where the best one
/// ran out of it, its search goes on from where it stopped with the full
/// budget. A start that creeps along a ridge for thousands of evaluations
/// (Bouc-Wen at 0.5 A on the measured records: one start 2 200
/// evaluations and 59 s, another 64 s in all, to end below the others)
/// no longer holds up the others (and is not finished unless it is the
/// best, though it might have become so: Spencer at 1 A ended 5.7 nats
/// lower); where every start converges within the budget (the B-P law's
/// searches of the main job take 8–105 evaluations) the result is the
/// same bits as an unbudgeted search's.
pub fn best_map(post: &Posterior, starts: &[Vec<f64>]) -> Option<MapEstimate> {
    best_map_within(post, starts, SCREEN_PATIENCE)
}

/// [`best_map`] from tiers of starts, with `fallback` (the prior medians,
/// say) searched too where there is a single start, or where no start's
/// search converges within its budget. The tiers are searched in turn,
/// each only where no search of the ones before converged. A law whose
/// starts are read off the records (three of them) finds its MAP from one
/// of them: on the measured records the prior medians' search spent its
/// whole budget and ended 0.7–56 nats below the best (Bouc-Wen and
/// Spencer at 0.25 A), a third to two fifths of the screen's wall time on
/// two cores. One start and the fallback run side by side, as before.
pub fn best_map_or(
    post: &Posterior,
    tiers: &[Vec<Vec<f64>>],
    fallback: &[f64],
) -> Option<MapEstimate> {
    if tiers.iter().map(Vec::len).sum::<usize>() <= 1 {
        let beside: Vec<Vec<f64>> =
            tiers.iter().flatten().cloned().chain([fallback.to_vec()]).collect();
        return best_map(post, &beside);
    }
    // the fallback is the last tier
    let last = [fallback.to_vec()];
    let mut found = Vec::new();
    for tier in tiers.iter().map(Vec::as_slice).chain([&last[..]]) {
        found.extend(screen(post, tier, SCREEN_PATIENCE));
        if found.iter().flatten().any(|m| m.log_density.is_finite() && !m.exhausted) {
            break;
        }
    }
    finish(post, found)
}

/// [`best_map`] with each start's search allowed `patience` (n + 1)
/// evaluations a fit.
pub fn best_map_within(
    post: &Posterior,
    starts: &[Vec<f64>],
    patience: usize,
) -> Option<MapEstimate> {
    finish(post, screen(post, starts, patience))
}

/// Each start's search, with `patience` (n + 1) evaluations a fit.
fn screen(post: &Posterior, starts: &[Vec<f64>], patience: usize) -> Vec<Option<MapEstimate>> {
    // the searches side by side: each leaves a core idle where its own
    // work is serial (the solver's linear algebra, the noise's profile)
    starts.par_iter().map(|s| refine_fitting(post, s, SETTLING_FITS, patience)).collect()
}

/// The best of the `found` searches' optima, its search finished with the
/// full budget where it ran out of its own.
fn finish(post: &Posterior, found: Vec<Option<MapEstimate>>) -> Option<MapEstimate> {
    let best = found
        .into_iter()
        .flatten()
        .filter(|m| m.log_density.is_finite())
        .max_by(|a, b| a.log_density.total_cmp(&b.log_density))?;
    if !best.exhausted {
        return Some(best);
    }
    let fitted = post.layout.fitted.len();
    refine(post, &best.x[..fitted]).filter(|m| m.log_density >= best.log_density).or(Some(best))
}

/// The budget of each start's search in [`best_map`], in (n + 1)
/// evaluations: a tenth of the solver's [`PATIENCE`]. The searches that
/// converge take 8–110 evaluations on the bundled and measured records
/// (7–12 coordinates), within 20 (n + 1) = 160–260.
const SCREEN_PATIENCE: usize = 20;

/// One row of the step study: how far the MAP moves when the step halves
/// from `substeps`, in units of the posterior sd.
#[derive(Clone, Debug)]
pub struct StepCheck {
    pub substeps: u32,
    /// |θ(m) − θ(2m)| / sd per θ coordinate.
    pub shifts: Vec<f64>,
}

impl StepCheck {
    pub fn worst(&self) -> (usize, f64) {
        self.shifts
            .iter()
            .copied()
            .enumerate()
            .fold((0, 0.0), |b, (i, v)| if v > b.1 { (i, v) } else { b })
    }
}

/// The largest discretisation error of a posterior mean the step rule
/// accepts, in posterior sd.
pub const STEP_ERROR_LIMIT: f64 = 0.1;

/// The shift of the MAP when the step halves, as a share of the posterior
/// sd, below which the step is fine. A scheme of order p at step h errs by
/// about shift × 2^p/(2^p − 1): twice the shift for plain Euler (p = 1),
/// 4/3 of it for the Richardson-extrapolated one (p = 2). The limit keeps
/// that error below [`STEP_ERROR_LIMIT`].
pub fn step_shift_limit(extrapolated: bool) -> f64 {
    let gain = if extrapolated { 4.0 } else { 2.0 };
    STEP_ERROR_LIMIT * (gain - 1.0) / gain
}

/// The MAP's shift when the integrator changes from `post`'s to `finer`:
/// one Gauss-Newton step of the surrogate, (JᵀJ)⁻¹ Jᵀ Δr, with Δr the
/// change of the whitened residuals at the MAP. The shift is a small
/// fraction of the posterior sd, where the linearisation holds, and it
/// costs one integration instead of a new MAP search.
fn shift(map: &MapEstimate, post: &Posterior, finer: &Posterior) -> Option<DVector<f64>> {
    let nt = post.layout.fitted.len();
    let theta = &map.x[..nt];
    let coarse = whitened(post, &map.whitening, theta, Support::Truncated)?;
    let fine = whitened(finer, &map.whitening, theta, Support::Truncated)?;
    let delta = DVector::from_iterator(coarse.len(), fine.iter().zip(&coarse).map(|(f, c)| f - c));
    // the residuals are data minus model: the optimum moves by −(JᵀJ)⁻¹ Jᵀ Δr
    Some(-(&map.cov * (map.jacobian.transpose() * delta)))
}

/// Chooses the sub-steps per sample: the smallest m (1, 2, 4, …, at most
/// `max_m`) for which halving the step moves no MAP coordinate of θ by
/// [`step_shift_limit`] sd or more. Returns the chosen m, the MAP moved to
/// it, and the study.
pub fn choose_substeps(
    post: &Posterior,
    start: &MapEstimate,
    base: Integrator,
    max_m: u32,
) -> (u32, MapEstimate, Vec<StepCheck>) {
    let mut m = base.substeps.max(1);
    let mut current = start.clone();
    let mut coarse = post.with_integrator(Integrator { substeps: m, ..base });
    let mut study = Vec::new();
    loop {
        let finer = post.with_integrator(Integrator { substeps: 2 * m, ..base });
        let Some(step) = shift(&current, &coarse, &finer) else {
            return (m, current, study);
        };
        let sd = current.sd();
        let shifts: Vec<f64> = (0..step.len()).map(|i| step[i].abs() / sd[i].max(1e-300)).collect();
        let check = StepCheck { substeps: m, shifts };
        let ok = check.worst().1 < step_shift_limit(base.extrapolate);
        study.push(check);
        if ok || 2 * m > max_m {
            return (m, current, study);
        }
        // the MAP with the finer step: moved by the shift, noise re-profiled
        let theta: Vec<f64> =
            current.x[..step.len()].iter().zip(step.iter()).map(|(x, s)| x + s).collect();
        if let Some(full) = with_noise(&finer, &theta) {
            current.log_density = finer.log_density(&full);
            current.x = full;
        }
        m *= 2;
        coarse = finer;
    }
}

/// The Euler steps of one log-density at `x` (all runs): what the
/// integrator costs there.
pub fn euler_steps(post: &Posterior, x: &[f64]) -> u64 {
    let at = post.likelihood_point(x);
    post.runs.iter().map(|r| post.lane_params(&[&at], r).euler_steps(&post.integrator, r)).sum()
}

/// Spread of the initial walkers over the approximation's: its own. The
/// walkers start on the approximate posterior; what R̂ then compares is
/// how the ensembles move from there (the SBC studies and the 160-step
/// check of docs/performance.md found no bias left by this start).
pub const START_SPREAD: f64 = 1.0;

/// Initial walker positions from a Gaussian approximation of the
/// posterior (the [`laplace`] one, say), spread by [`START_SPREAD`], every
/// one with a finite log-density (redrawn up to 100 times, then a tiny ball
/// around its mean). Each walker draws from its own stream, attempt after
/// attempt; the attempts of all walkers still without a position are
/// evaluated together, in batches on every thread (one at a time they cost
/// a real calibration seconds: 264 walkers × 30 ms at 0.25 A). Their
/// log-densities come with them, for [`crate::sampler::Sampler::from_state`]
/// (evaluated again they cost as much once more).
pub fn initial_walkers(post: &Posterior, start: &Elliptical, count: usize, seed: u64) -> Walkers {
    let d = post.dim();
    let mut rngs: Vec<_> =
        (0..count).map(|c| crate::rng::stream(seed, &[u64::MAX - 1, c as u64])).collect();
    let mut placed: Vec<Option<(Vec<f64>, f64)>> = vec![None; count];
    for attempt in 0..100 {
        let waiting: Vec<usize> = (0..count).filter(|&c| placed[c].is_none()).collect();
        if waiting.is_empty() {
            break;
        }
        let spread = if attempt < 90 { START_SPREAD } else { 1e-4 };
        let points: Vec<f64> = waiting
            .iter()
            .flat_map(|&c| {
                let z: Vec<f64> = (0..d).map(|_| StandardNormal.sample(&mut rngs[c])).collect();
                start.point(&z, spread)
            })
            .collect();
        let values = log_densities(post, &points);
        for ((&c, x), v) in waiting.iter().zip(points.chunks_exact(d)).zip(values) {
            if v.is_finite() {
                placed[c] = Some((x.to_vec(), v));
            }
        }
    }
    let mut walkers = Walkers { positions: Vec::with_capacity(count * d), log_prob: Vec::new() };
    for p in placed {
        let (x, v) = p.unwrap_or_else(|| {
            let mean = start.mean.as_slice().to_vec();
            let v = log_densities(post, &mean)[0];
            (mean, v)
        });
        walkers.positions.extend(x);
        walkers.log_prob.push(v);
    }
    walkers
}

/// Walkers' positions (one after another) and their log-densities.
pub struct Walkers {
    pub positions: Vec<f64>,
    pub log_prob: Vec<f64>,
}
