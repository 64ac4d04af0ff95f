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

use rayon::prelude::*;

use crate::data::RunData;
use crate::model::Integrator;
use crate::noise::{stiffness_path, NoiseModel, Pointwise};
use crate::posterior::{Draw, PosteriorSample};
use crate::predict::model_paths;
use crate::rng;

/// The pointwise terms of `draw` along `run`, whose model stress (the B-P
/// law alone, as the integrator returns it) is `path`; the replicate's
/// noise comes from `rng`.
pub fn pointwise(
    noise: &dyn NoiseModel,
    run: &RunData,
    path: &[f64],
    draw: &Draw,
    rng: &mut dyn rand::Rng,
) -> Pointwise {
    let model: Vec<f64> = path
        .iter()
        .enumerate()
        .map(|(k, p)| p + run.terms_stress(k, draw.spring_n_per_m, draw.offset_n))
        .collect();
    let stiffness = if noise.uses_stiffness(run) {
        stiffness_path(run, path, draw.stiffness(run))
    } else {
        vec![0.0; path.len()]
    };
    noise.pointwise(run, &model, &stiffness, &draw.noise, rng)
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
    noise: &dyn NoiseModel,
    seed: u64,
) -> PointwiseDraws {
    let chains = sample.chains.chains();
    let positions: Vec<(usize, usize)> =
        (0..chains).flat_map(|c| steps.iter().map(move |&s| (s, c))).collect();
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
    let offsets: Vec<usize> = runs
        .iter()
        .scan(0, |at, r| {
            let o = *at;
            *at += r.time.len() - 1;
            Some(o)
        })
        .collect();
    let total: usize = runs.iter().map(|r| r.time.len() - 1).sum();
    set.log_likelihood = vec![f64::NEG_INFINITY; positions.len() * total];
    set.replicate = vec![f32::NAN; positions.len() * total];
    let mut failed = vec![false; positions.len()];
    for (j, run) in runs.iter().enumerate() {
        let draws = sample.draws(&positions, &run.id, run.current_a);
        let paths = model_paths(run, &draws, integrator, &|| {});
        let terms: Vec<Pointwise> = positions
            .par_iter()
            .zip(&draws)
            .zip(&paths)
            .map(|((&(s, c), draw), path)| match path {
                Some(path) => pointwise(
                    noise,
                    run,
                    path,
                    draw,
                    &mut rng::stream(seed, &[0x9a7e, j as u64, s as u64, c as u64]),
                ),
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
