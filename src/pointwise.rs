//! Pointwise log-likelihood and replicated records of posterior draws: what
//! ArviZ's `log_likelihood` and `posterior_predictive` groups hold, and what
//! PSIS-LOO (`az.loo`, `az.compare`) needs to compare noise models and model
//! variants.
//!
//! The terms of one draw sum to the likelihood the sampler used. Where the
//! residuals are independent (Gaussian, Student-t) each term is the density
//! of one residual. Where they are not, the joint density is factorised
//! sample by sample into conditionals, which sum to it exactly: AR(1) noise
//! as r_k | r_{k−1}; errors in variables as r_k given the earlier residuals
//! of its branch, through the branch's shared offset (its posterior after
//! them is Gaussian, so each conditional is too). PSIS-LOO on such terms
//! leaves out one sample's new information, not the sample itself.

use rand::{Rng, RngExt};
use rand_distr::{StandardNormal, StudentT};

use rayon::prelude::*;

use crate::model::Integrator;
use crate::posterior::{evenly_spaced, normal_ln_pdf, student_t_log_constant, tangent_stiffness, Draw, LikelihoodSettings, NoiseModel, PosteriorSample, RunData};
use crate::predict::model_paths;
use crate::rng;

/// One draw along one run: a term per compared sample (k = 1..n−1).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pointwise {
    /// ln p(y_k | y_earlier, θ), constants included.
    pub log_likelihood: Vec<f64>,
    /// A new record drawn from the noise model around the draw's path.
    pub replicate: Vec<f64>,
}

/// The pointwise terms of `draw` along `run`, whose model stress (the B-P
/// law alone, as the integrator returns it) is `path`; the replicate's
/// noise comes from `rng`.
pub fn pointwise(run: &RunData, path: &[f64], draw: &Draw, likelihood: &LikelihoodSettings, rng: &mut impl Rng) -> Pointwise {
    let n = run.time.len().min(path.len());
    let sigma = draw.sigma;
    let sigma2 = sigma * sigma;
    let nu = likelihood.student_nu;
    let t_const = student_t_log_constant(nu);
    let student = StudentT::new(nu).ok();
    // errors in variables, as the likelihood has them
    let strain_var = if likelihood.eiv() { run.strain_noise_var } else { 0.0 };
    let v = strain_var * run.strain_smoothing_share;
    // the branch's information on its offset so far: Σ c²/d and Σ c r/d
    let (mut info, mut score) = (0.0f64, 0.0f64);
    let mut offset = 0.0f64;
    let mut direction = 0.0f64;
    let mut new_branch = true;
    let (mut prev_res, mut prev_noise) = (0.0f64, 0.0f64);
    let mut out = Pointwise { log_likelihood: Vec::with_capacity(n.saturating_sub(1)), replicate: Vec::with_capacity(n.saturating_sub(1)) };
    for k in 1..n {
        let model = path[k] + run.terms_stress(k, draw.spring_n_per_m, draw.offset_n);
        let res = run.tau[k] - model;
        let z: f64 = rng.sample(StandardNormal);
        let (ll, noise) = match likelihood.noise {
            NoiseModel::Gaussian if strain_var > 0.0 => {
                let dg = run.gamma[k] - run.gamma[k - 1];
                if dg != 0.0 && direction != 0.0 && dg.signum() != direction {
                    new_branch = true;
                }
                if dg != 0.0 {
                    direction = dg.signum();
                }
                if new_branch {
                    // a new branch: nothing known of its offset yet; the
                    // replicate draws its own
                    (info, score, new_branch) = (0.0, 0.0, false);
                    offset = v.sqrt() * rng.sample::<f64, _>(StandardNormal);
                }
                let before = if k == 1 { run.initial_tau } else { path[k - 1] };
                let c = tangent_stiffness(path[k] - before, dg, draw.params.g);
                let d = sigma2 + c * c * strain_var;
                // the offset given the branch so far: mean vB/(1+vA), variance v/(1+vA)
                let shrink = 1.0 + v * info;
                let mean = c * v * score / shrink;
                let var = d + c * c * v / shrink;
                info += c * c / d;
                score += c * res / d;
                (normal_ln_pdf(res - mean, var.sqrt()), d.sqrt() * z + c * offset)
            }
            NoiseModel::Gaussian => (normal_ln_pdf(res, sigma), sigma * z),
            NoiseModel::StudentT => {
                let t = student.as_ref().map_or(z, |t| rng.sample(t));
                (t_const - sigma.ln() - 0.5 * (nu + 1.0) * (res * res / (nu * sigma2)).ln_1p(), sigma * t)
            }
            NoiseModel::Ar1 => {
                let rho = draw.rho;
                if k == 1 {
                    let s = sigma / (1.0 - rho * rho).max(1e-12).sqrt();
                    (normal_ln_pdf(res, s), s * z)
                } else {
                    (normal_ln_pdf(res - rho * prev_res, sigma), rho * prev_noise + sigma * z)
                }
            }
        };
        prev_res = res;
        prev_noise = noise;
        out.log_likelihood.push(ll);
        out.replicate.push(model + noise);
    }
    out
}

/// The pointwise terms of a thinned set of posterior draws along every run
/// of a calibration: every chain at each of `steps`.
#[derive(Clone, Debug)]
pub struct PointwiseDraws {
    /// The steps of the chains kept (the same for every chain).
    pub steps: Vec<usize>,
    pub chains: usize,
    /// The runs, in the order of their observations.
    pub runs: Vec<String>,
    /// Per observation: its run (index into `runs`), time (s) and measured
    /// shear stress (Pa).
    pub run: Vec<usize>,
    pub time: Vec<f64>,
    pub observed: Vec<f64>,
    /// `[chain][step][observation]`
    pub log_likelihood: Vec<f64>,
    /// `[chain][step][observation]`, single precision (a record's noise is
    /// far above its rounding)
    pub replicate: Vec<f32>,
    /// Draws whose integration failed on some run (their terms are −∞).
    pub failed: usize,
}

/// Integrates every chain at each of `steps` along `runs` (as the
/// likelihood sees them) and forms the pointwise terms. The replicates'
/// noise is keyed by (seed, run, step, chain): the same whatever the
/// thread count.
pub fn pointwise_draws(
    sample: &PosteriorSample,
    runs: &[RunData],
    steps: &[usize],
    integrator: &Integrator,
    likelihood: &LikelihoodSettings,
    seed: u64,
) -> PointwiseDraws {
    let chains = sample.chains.chains();
    let positions: Vec<(usize, usize)> = (0..chains).flat_map(|c| steps.iter().map(move |&s| (s, c))).collect();
    let mut set = PointwiseDraws {
        steps: steps.to_vec(),
        chains,
        runs: runs.iter().map(|r| r.id.clone()).collect(),
        run: Vec::new(),
        time: Vec::new(),
        observed: Vec::new(),
        log_likelihood: Vec::new(),
        replicate: Vec::new(),
        failed: 0,
    };
    // every run's observations side by side: run j's start in each row
    let offsets: Vec<usize> = runs.iter().scan(0, |at, r| { let o = *at; *at += r.time.len() - 1; Some(o) }).collect();
    let total: usize = runs.iter().map(|r| r.time.len() - 1).sum();
    set.log_likelihood = vec![f64::NEG_INFINITY; positions.len() * total];
    set.replicate = vec![f32::NAN; positions.len() * total];
    let mut failed = vec![false; positions.len()];
    for (j, run) in runs.iter().enumerate() {
        let draws = sample.draws(&positions, &run.id, run.current_a);
        let params: Vec<_> = draws.iter().map(|d| d.params).collect();
        let paths = model_paths(run, &params, integrator, &|| {});
        let terms: Vec<Pointwise> = positions
            .par_iter()
            .zip(&draws)
            .zip(&paths)
            .map(|((&(s, c), draw), path)| match path {
                Some(path) => pointwise(run, path, draw, likelihood, &mut rng::stream(seed, &[0x9a7e, j as u64, s as u64, c as u64])),
                None => Pointwise::default(),
            })
            .collect();
        let n = run.time.len() - 1;
        // into place at once: one run's terms at a time are all that is held twice
        for (i, t) in terms.iter().enumerate() {
            let at = i * total + offsets[j];
            if t.log_likelihood.len() == n {
                set.log_likelihood[at..at + n].copy_from_slice(&t.log_likelihood);
                for (out, v) in set.replicate[at..at + n].iter_mut().zip(&t.replicate) {
                    *out = *v as f32;
                }
            } else {
                failed[i] = true;
            }
        }
        set.run.extend(std::iter::repeat_n(j, n));
        set.time.extend_from_slice(&run.time[1..]);
        set.observed.extend_from_slice(&run.tau[1..]);
    }
    set.failed = failed.iter().filter(|f| **f).count();
    set
}

/// How many draws the pointwise groups hold by default: enough for PSIS-LOO,
/// few enough that a 10 000-sample campaign stays at ~15 MB per group.
pub const POINTWISE_DRAWS: usize = 192;

/// About `count` draws' worth of steps, evenly spaced from `burn_in` to the
/// last step and at least `stride` steps apart (nearly independent when
/// `stride` ≥ τ): at least one step, every chain at each.
pub fn thinned_steps(burn_in: usize, steps: usize, chains: usize, count: usize, stride: usize) -> Vec<usize> {
    let available = steps.saturating_sub(burn_in).max(1);
    let per_chain = count.div_ceil(chains.max(1)).min(available.div_ceil(stride.max(1))).max(1);
    evenly_spaced(available, per_chain).into_iter().map(|i| (burn_in + i).min(steps.saturating_sub(1))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Params;
    use crate::posterior::HALF_LN_2PI;
    use nalgebra::{DMatrix, DVector};

    /// A short run with two branches and a path that yields (so the tangent
    /// stiffness varies).
    fn run() -> (RunData, Vec<f64>) {
        let n = 41;
        let time: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        let gamma: Vec<f64> = (0..n).map(|k| 0.02 * (k as f64 * 0.15).sin()).collect();
        let path: Vec<f64> = gamma.iter().map(|g| 4e4 * (g / 0.01).tanh()).collect();
        let tau: Vec<f64> = path.iter().enumerate().map(|(k, p)| p + 300.0 * ((k as f64) * 1.7).sin()).collect();
        let run = RunData {
            id: "r".into(),
            time,
            gamma,
            tau,
            initial_tau: path[0],
            current_a: 1.0,
            area_m2: 1.0,
            gap_m: 1.0,
            strain_noise_var: 1e-8,
            strain_smoothing_share: 0.3,
        };
        (run, path)
    }

    /// Errors in variables: the conditional terms sum to the multivariate
    /// normal density of the residuals with covariance D + v c cᵀ per
    /// branch, by Cholesky (an independent computation).
    #[test]
    fn errors_in_variables_terms_sum_to_the_joint_density() {
        let (run, path) = run();
        let draw = Draw::of_law(Params { g: 5e6, ..Params::reference_1a() }, 250.0);
        let settings = LikelihoodSettings::default();
        let mut rng = crate::rng::stream(1, &[]);
        let p = pointwise(&run, &path, &draw, &settings, &mut rng);
        let n = run.time.len() - 1;
        let (s2, sv, v) = (250.0f64 * 250.0, run.strain_noise_var, run.strain_noise_var * run.strain_smoothing_share);
        // residuals, stiffness and branch of every compared sample
        let mut cov = DMatrix::zeros(n, n);
        let mut c = vec![0.0; n];
        let mut branch = vec![0usize; n];
        let (mut b, mut dir) = (0usize, 0.0f64);
        for k in 1..=n {
            let dg = run.gamma[k] - run.gamma[k - 1];
            if dg.signum() != dir && dir != 0.0 {
                b += 1;
            }
            dir = dg.signum();
            branch[k - 1] = b;
            c[k - 1] = tangent_stiffness(path[k] - path[k - 1], dg, draw.params.g);
            cov[(k - 1, k - 1)] = s2 + c[k - 1] * c[k - 1] * sv;
        }
        for i in 0..n {
            for j in 0..n {
                if branch[i] == branch[j] {
                    cov[(i, j)] += v * c[i] * c[j];
                }
            }
        }
        let r = DVector::from_fn(n, |i, _| run.tau[i + 1] - path[i + 1]);
        let chol = cov.cholesky().unwrap();
        let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
        let direct = -(n as f64) * HALF_LN_2PI - 0.5 * log_det - 0.5 * r.dot(&chol.solve(&r));
        let sum: f64 = p.log_likelihood.iter().sum();
        assert!(b >= 1, "the test run must have two branches");
        assert!((sum - direct).abs() < 1e-8 * direct.abs(), "{sum} vs {direct}");
    }

    /// The replicate of a noise-free draw is the path itself.
    #[test]
    fn replicates_centre_on_the_path() {
        let (run, path) = run();
        let draw = Draw::of_law(Params::reference_1a(), 1e-9);
        let settings = LikelihoodSettings { errors_in_variables: false, ..LikelihoodSettings::default() };
        let p = pointwise(&run, &path, &draw, &settings, &mut crate::rng::stream(2, &[]));
        for (rep, m) in p.replicate.iter().zip(&path[1..]) {
            assert!((rep - m).abs() < 1e-6);
        }
    }
}
