//! The start of the sampler: maximum a posteriori (MAP) refinement of the
//! identification, the Laplace approximation around it, and the rule that
//! chooses the integrator's step.

use nalgebra::{DMatrix, DVector};
use rand_distr::{Distribution, StandardNormal};

use super::{NoiseModel, Posterior};
use crate::fit::least_squares;
use crate::model::Integrator;
use crate::sampler::LogDensity;

/// The MAP point and the Laplace approximation of θ around it.
#[derive(Clone, Debug)]
pub struct MapEstimate {
    /// Every coordinate (θ in logs, ln σ, atanh ρ).
    pub x: Vec<f64>,
    /// Covariance of the ln θ coordinates (Laplace, Gaussian surrogate).
    pub cov: DMatrix<f64>,
    pub log_density: f64,
    pub converged: bool,
}

impl MapEstimate {
    /// Posterior sd of each ln θ from the Laplace approximation.
    pub fn sd(&self) -> Vec<f64> {
        (0..self.cov.nrows()).map(|i| self.cov[(i, i)].max(0.0).sqrt()).collect()
    }
}

/// Residuals τ_obs − τ_model of every run at the θ coordinates `x` (None
/// where the integration fails), run by run.
fn residuals(post: &Posterior, x: &[f64]) -> Option<Vec<Vec<f64>>> {
    post.runs
        .iter()
        .map(|r| {
            let p = &post.params_at_current(x, r.current_a);
            let mut out = Vec::with_capacity(r.compared());
            let init = crate::model::State { tau: r.initial_tau, w: 0.0 };
            post.integrator
                .run_with(p, &r.time, &r.gamma, init, |k, s| {
                    if k > 0 {
                        out.push(r.tau[k] - s.tau);
                    }
                })
                .ok()?;
            Some(out)
        })
        .collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|r| r * r).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Whitened residuals of the Gaussian surrogate: (τ_obs − τ_model)/σ_run,
/// then (ln θ − centre)/scale for every log-normal prior. Points outside the
/// prior support are infeasible.
fn whitened(post: &Posterior, sigmas: &[f64], x: &[f64]) -> Option<Vec<f64>> {
    if post.priors.iter().zip(x).any(|(p, v)| p.log_density(*v) == f64::NEG_INFINITY) {
        return None;
    }
    let res = residuals(post, x)?;
    let mut out: Vec<f64> = res.iter().zip(sigmas).flat_map(|(r, s)| r.iter().map(move |v| v / s)).collect();
    for (prior, v) in post.priors.iter().zip(x) {
        if let Some((c, s)) = prior.centre() {
            out.push((v - c) / s);
        }
    }
    Some(out)
}

/// Maximises the posterior over θ from `start`, with each run's σ profiled
/// (set to its RMS residual and the fit repeated until σ settles), by
/// Levenberg-Marquardt on the whitened residuals. Then sets the noise
/// coordinates from the residuals at the optimum: σ = RMS (AR(1): ρ = lag-one
/// correlation, σ the innovation sd) and computes the Laplace covariance
/// (JᵀJ)⁻¹ of ln θ.
pub fn refine(post: &Posterior, start: &[f64]) -> Option<MapEstimate> {
    let nt = post.layout.theta.len();
    let mut x: Vec<f64> = start[..nt].to_vec();
    let mut sigmas: Vec<f64> = residuals(post, &x)?.iter().map(|r| rms(r).max(1e-9)).collect();
    let mut converged = false;
    for _ in 0..4 {
        let f = |p: &[f64]| whitened(post, &sigmas, p);
        let fit = least_squares(&x, &f, None);
        let moved = fit.params.iter().zip(&x).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        x = fit.params;
        converged = fit.converged;
        let new_sigmas: Vec<f64> = residuals(post, &x)?.iter().map(|r| rms(r).max(1e-9)).collect();
        let sigma_change = new_sigmas.iter().zip(&sigmas).map(|(a, b)| (a / b).ln().abs()).fold(0.0, f64::max);
        sigmas = new_sigmas;
        if moved < 1e-6 && sigma_change < 1e-3 {
            break;
        }
    }
    // Laplace covariance from the Jacobian of the whitened residuals
    let f = |p: &[f64]| whitened(post, &sigmas, p);
    let r0 = f(&x)?;
    let mut jac = DMatrix::zeros(r0.len(), nt);
    for j in 0..nt {
        let h = 1e-6;
        let mut q = x.clone();
        q[j] += h;
        let r1 = f(&q)?;
        for i in 0..r0.len() {
            jac[(i, j)] = (r1[i] - r0[i]) / h;
        }
    }
    let cov = (jac.transpose() * &jac).try_inverse()?;

    let res = residuals(post, &x)?;
    let mut full = x.clone();
    let mut rhos = Vec::new();
    for r in &res {
        let s = rms(r).max(1e-9);
        let rho = if post.likelihood.noise == NoiseModel::Ar1 {
            let num: f64 = r.windows(2).map(|w| w[0] * w[1]).sum();
            let den: f64 = r.iter().map(|v| v * v).sum();
            (num / den).clamp(-0.98, 0.98)
        } else {
            0.0
        };
        let s = if post.likelihood.noise == NoiseModel::Ar1 { s * (1.0 - rho * rho).sqrt() } else { s };
        full.push(s.ln());
        rhos.push(rho.atanh());
    }
    if post.likelihood.noise == NoiseModel::Ar1 {
        full.extend(rhos);
    }
    let log_density = post.log_density(&full);
    Some(MapEstimate { x: full, cov, log_density, converged })
}

/// The best MAP from several starts (θ coordinates), by log-density.
pub fn best_map(post: &Posterior, starts: &[Vec<f64>]) -> Option<MapEstimate> {
    starts
        .iter()
        .filter_map(|s| refine(post, s))
        .filter(|m| m.log_density.is_finite())
        .max_by(|a, b| a.log_density.total_cmp(&b.log_density))
}

/// One row of the step study: the MAP with `substeps` and with twice as
/// many, and the largest shift in units of the posterior sd.
#[derive(Clone, Debug)]
pub struct StepCheck {
    pub substeps: u32,
    /// |ln θ(m) − ln θ(2m)| / sd per parameter.
    pub shifts: Vec<f64>,
}

impl StepCheck {
    pub fn worst(&self) -> (usize, f64) {
        self.shifts.iter().copied().enumerate().fold((0, 0.0), |b, (i, v)| if v > b.1 { (i, v) } else { b })
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

/// Chooses the sub-steps per sample: the smallest m (1, 2, 4, …, at most
/// `max_m`) for which halving the step moves no MAP coordinate of θ by
/// [`step_shift_limit`] sd or more. Returns the chosen m, the MAP with it,
/// and the study.
pub fn choose_substeps(post: &Posterior, start: &MapEstimate, base: Integrator, max_m: u32) -> (u32, MapEstimate, Vec<StepCheck>) {
    let mut m = base.substeps.max(1);
    let mut current = start.clone();
    let mut study = Vec::new();
    loop {
        let finer = post.with_integrator(Integrator { substeps: 2 * m, ..base });
        let Some(next) = refine(&finer, &current.x) else {
            return (m, current, study);
        };
        let sd = current.sd();
        let shifts: Vec<f64> = post.layout.theta.clone().map(|i| (current.x[i] - next.x[i]).abs() / sd[i].max(1e-300)).collect();
        let check = StepCheck { substeps: m, shifts };
        let ok = check.worst().1 < step_shift_limit(base.extrapolate);
        study.push(check);
        if ok || 2 * m > max_m {
            return (m, current, study);
        }
        m *= 2;
        current = next;
    }
}

/// Initial walker positions: θ from the Laplace approximation around the MAP,
/// the noise coordinates in a small ball, every one with a finite
/// log-density (redrawn up to 100 times, then a tiny ball around the MAP).
pub fn initial_walkers(post: &Posterior, map: &MapEstimate, count: usize, seed: u64) -> Vec<Vec<f64>> {
    let (d, nt) = (post.dim(), post.layout.theta.len());
    let chol = map.cov.clone().cholesky();
    (0..count)
        .map(|c| {
            let mut rng = crate::rng::stream(seed, &[u64::MAX - 1, c as u64]);
            for attempt in 0..100 {
                let z: Vec<f64> = (0..d).map(|_| StandardNormal.sample(&mut rng)).collect();
                let mut x = map.x.clone();
                let theta = match &chol {
                    Some(ch) if attempt < 90 => ch.l() * DVector::from_column_slice(&z[..nt]),
                    _ => DVector::from_column_slice(&z[..nt]) * 1e-4,
                };
                for i in 0..nt {
                    x[i] += theta[i];
                }
                for i in nt..d {
                    x[i] += 0.01 * z[i];
                }
                if post.log_density(&x).is_finite() {
                    return x;
                }
            }
            map.x.clone()
        })
        .collect()
}
