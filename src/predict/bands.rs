//! The bands of one run: posterior draws of the B-P parameters and of the
//! noise, each integrated along the run's strain history, give the credible
//! band of the model stress and the predictive band of a new measurement.
//!
//! Model band: quantiles over draws of τ_model(t_k; θ_d). Predictive band:
//! quantiles over draws and noise replicates of τ_model(t_k; θ_d) + e_k,
//! with e a new record's noise from the run's fitted noise model (simulated
//! along the record, so a correlated noise keeps its correlation).

use std::sync::Arc;

use rayon::prelude::*;

use serde::{Deserialize, Serialize};

use crate::data::{Run, RunData};
use crate::error::{Error, Result};
use crate::model::{tangent_stiffness, Integrator, LANES};
use crate::noise::{Explained, NoiseModel, NoiseValues};
use crate::posterior::Draw;
use crate::rng;

/// How the bands are computed.
#[derive(Clone, Debug)]
pub struct PredictSettings {
    /// The integrator the likelihood used.
    pub integrator: Integrator,
    /// The likelihood's noise model.
    pub noise: Arc<dyn NoiseModel>,
    /// Noise replicates per draw in the predictive band.
    pub replicates: usize,
    pub seed: u64,
}

/// Probabilities of the model band and of the predictive band.
pub const MODEL_PROBS: [f64; 5] = [0.025, 0.25, 0.5, 0.75, 0.975];
pub const PREDICTIVE_PROBS: [f64; 2] = [0.025, 0.975];

/// The bands of one run at every sample of its record.
#[derive(Clone, Debug)]
pub struct Bands {
    pub run: String,
    /// q025, q25, q50, q75, q975 of the model stress (Pa).
    pub model: [Vec<f64>; 5],
    /// p025, p975 of a new measurement (Pa).
    pub predictive: [Vec<f64>; 2],
    /// Draws used, and draws whose integration failed (left out).
    pub draws: usize,
    pub failed: usize,
    /// Log pointwise predictive density of the record, Σ_k ln mean_d
    /// p(τ_obs,k | draw d), over the samples after the first (nat): the
    /// score of held-out predictions (higher is better).
    pub lppd: f64,
    /// What the noise model makes of the residuals about the median model
    /// (q50) at the draws' median noise, where it models a force of its
    /// own (the discrepancy model).
    pub explained: Option<Explained>,
    /// The share of the draws whose own path misses the record by more
    /// than [`FAR`] times the median path's RMS (NaN without a measured
    /// force): a posterior that reaches where its likelihood does not score
    /// the path itself (the adjusted likelihood along a parameter the
    /// records do not fix, docs/calibration.md) widens the bands past what
    /// the records warrant.
    pub far_draws: f64,
}

/// How many times the median path's RMS miss a draw's path may miss the
/// record by before it counts as far: a posterior of the records puts its
/// draws' paths within a small share of the noise of each other, so their
/// misses are the median's within a few per cent.
pub const FAR: f64 = 1.5;

/// The share of draws far from the record ([`Bands::far_draws`]).
pub const FAR_DRAWS_WARN: f64 = 0.025;

/// How well the bands hold the observations of one run (samples after the
/// first, which is the fixed initial state).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coverage {
    pub samples: usize,
    /// Share of observations inside the 95 % predictive band.
    pub inside_predictive: f64,
    /// Share inside the 95 % model band (small when noise dominates).
    pub inside_model: f64,
    /// Root-mean-square of τ_obs − q50 (Pa).
    pub rmse_median: f64,
    /// The bands' log pointwise predictive density (nat).
    pub lppd: f64,
    /// The 95 % predictive band's mean width over the record's largest
    /// |τ_obs|: how much a band says (as a share of the peak force).
    pub band_width: f64,
}

impl Bands {
    pub fn coverage(&self, tau_obs: &[f64]) -> Coverage {
        let n = tau_obs.len().saturating_sub(1).max(1);
        let (mut inside_p, mut inside_m, mut sq, mut width) = (0usize, 0usize, 0.0, 0.0);
        for (k, &y) in tau_obs.iter().enumerate().skip(1) {
            inside_p += (y >= self.predictive[0][k] && y <= self.predictive[1][k]) as usize;
            inside_m += (y >= self.model[0][k] && y <= self.model[4][k]) as usize;
            sq += (y - self.model[2][k]).powi(2);
            width += self.predictive[1][k] - self.predictive[0][k];
        }
        let peak = tau_obs.iter().skip(1).fold(0.0f64, |m, y| m.max(y.abs()));
        Coverage {
            samples: n,
            inside_predictive: inside_p as f64 / n as f64,
            inside_model: inside_m as f64 / n as f64,
            rmse_median: (sq / n as f64).sqrt(),
            lppd: self.lppd,
            band_width: width / n as f64 / peak,
        }
    }
}

/// Integrates every draw along `run` and forms the bands. `run_index` keys
/// the noise stream, so each run's replicates are independent of the others
/// and of the thread count. `tick` is called once per finished draw.
pub fn bands(
    run: &RunData,
    run_index: usize,
    draws: &[Draw],
    settings: &PredictSettings,
    tick: &(dyn Fn() + Sync),
) -> Result<Bands> {
    let paths = model_paths(run, draws, &settings.integrator, tick);
    let kept: Vec<(&Draw, &[f64])> =
        draws.iter().zip(&paths).filter_map(|(d, p)| p.as_deref().map(|p| (d, p))).collect();
    bands_of(run, run_index, &kept, draws.len() - kept.len(), settings)
}

/// The model stress along `run` for each draw, [`LANES`] at a time in
/// SIMD lanes and in parallel (following the run's current where it
/// varies and the draws are a law's); `None` where the integration failed.
pub fn model_paths(
    run: &RunData,
    draws: &[Draw],
    integrator: &Integrator,
    tick: &(dyn Fn() + Sync),
) -> Vec<Option<Vec<f64>>> {
    let n = run.time.len();
    draws
        .par_chunks(LANES)
        .flat_map_iter(|chunk| {
            let mut tau = vec![vec![0.0; n]; chunk.len()];
            let outcome = Draw::lanes(chunk, run).integrate(integrator, run, |k, s| {
                for (lane, path) in tau.iter_mut().enumerate() {
                    path[k] = s[lane];
                }
            });
            for _ in chunk {
                tick();
            }
            tau.into_iter()
                .zip(outcome)
                .map(|(p, o)| o.ok().filter(|_| p.iter().all(|v| v.is_finite())).map(|_| p))
        })
        .collect()
}

/// The bands of `run` from draws and their model stress paths (`failed`
/// more draws could not be integrated).
pub fn bands_of(
    run: &RunData,
    run_index: usize,
    kept: &[(&Draw, &[f64])],
    failed: usize,
    settings: &PredictSettings,
) -> Result<Bands> {
    let n = run.time.len();
    if kept.is_empty() {
        return Err(Error::Compute(format!(
            "run {}: the integration failed for every posterior draw",
            run.id
        )));
    }
    let reps = settings.replicates.max(1);
    let mut rng = rng::stream(settings.seed, &[0x0b5e, run_index as u64]);
    let noise = settings.noise.as_ref();
    let stiff = noise.uses_stiffness(run);
    // the noise of every draw's replicates, sample by sample (a correlated
    // noise carries its state along time)
    let noise_of: Vec<_> = kept.iter().map(|(d, _)| d.noise).collect();
    let mut simulator = noise.simulator(run, &noise_of, reps);
    let mut model = [(); 5].map(|_| vec![0.0; n]);
    let mut predictive = [(); 2].map(|_| vec![0.0; n]);
    let g_bound: Vec<f64> =
        kept.iter().map(|(d, _)| if stiff { d.g_bound(run) } else { 0.0 }).collect();
    let mut at_k = vec![0.0; kept.len()];
    let mut stiffness = vec![0.0; kept.len()];
    let mut noise_k = vec![0.0; kept.len() * reps];
    let mut pred_k = vec![0.0; kept.len() * reps];
    let mut log_p = vec![0.0; kept.len()];
    let mut miss = vec![0.0; kept.len()];
    let mut lppd = 0.0;
    for k in 0..n {
        let dg = if k > 0 { run.gamma[k] - run.gamma[k - 1] } else { 0.0 };
        for (i, (d, path)) in kept.iter().enumerate() {
            at_k[i] = path[k] + run.terms_stress(k, d.spring_n_per_m, d.offset_n);
            // the law's tangent stiffness, where the noise model takes it
            let g = g_bound[i];
            stiffness[i] = if !stiff {
                0.0
            } else if k > 0 {
                tangent_stiffness(path[k] - path[k - 1], dg, g)
            } else {
                g
            };
            log_p[i] = noise.marginal_ln_pdf(run, run.tau[k] - at_k[i], stiffness[i], &d.noise);
            if k > 0 {
                miss[i] += (run.tau[k] - at_k[i]).powi(2);
            }
        }
        simulator.next(&stiffness, &mut rng, &mut noise_k);
        for (i, model) in at_k.iter().enumerate() {
            for r in 0..reps {
                pred_k[i * reps + r] = model + noise_k[i * reps + r];
            }
        }
        if k > 0 && run.tau[k].is_finite() {
            lppd += crate::numeric::log_mean_exp(&log_p);
        }
        for (band, q) in model.iter_mut().zip(selected_quantiles(&mut at_k, &MODEL_PROBS)) {
            band[k] = q;
        }
        for (band, q) in
            predictive.iter_mut().zip(selected_quantiles(&mut pred_k, &PREDICTIVE_PROBS))
        {
            band[k] = q;
        }
    }
    // no measured force (a simulated excitation): nothing to explain
    let measured = run.tau.iter().all(|t| t.is_finite());
    let explained = if measured { explain_median(run, kept, &model[2], noise) } else { None };
    let far_draws = if measured && n > 1 {
        let median: f64 = (1..n).map(|k| (run.tau[k] - model[2][k]).powi(2)).sum();
        let far = miss.iter().filter(|m| **m > FAR * FAR * median).count();
        far as f64 / kept.len() as f64
    } else {
        f64::NAN
    };
    Ok(Bands {
        run: run.id.clone(),
        model,
        predictive,
        draws: kept.len(),
        failed,
        lppd,
        explained,
        far_draws,
    })
}

/// The quantiles `probs` (increasing) of `v`, as [`crate::sampler::quantile_sorted`] of
/// `v` sorted gives them — the same values — by selection instead of a
/// sort: each needs the order statistics at ⌊h⌋ and ⌊h⌋ + 1, and those of
/// increasing probabilities lie ever further right. Reorders `v`.
fn selected_quantiles<const N: usize>(v: &mut [f64], probs: &[f64; N]) -> [f64; N] {
    let n = v.len();
    let mut out = [f64::NAN; N];
    if n == 0 {
        return out;
    }
    let mut start = 0;
    for (o, &p) in out.iter_mut().zip(probs) {
        let h = (n - 1) as f64 * p.clamp(0.0, 1.0);
        let lo = (h.floor() as usize).max(start);
        let (_, at, right) = v[start..].select_nth_unstable_by(lo - start, f64::total_cmp);
        let low = *at;
        let high = if lo + 1 < n {
            right.iter().copied().min_by(f64::total_cmp).unwrap_or(low)
        } else {
            low
        };
        *o = low + (h - lo as f64) * (high - low);
        start = lo;
    }
    out
}

/// [`NoiseModel::explain`] at the median: the residuals about the median
/// model stress `median`, the stiffness along it with the draws' median G,
/// each noise value the draws' median.
fn explain_median(
    run: &RunData,
    kept: &[(&Draw, &[f64])],
    median: &[f64],
    noise: &dyn NoiseModel,
) -> Option<Explained> {
    let median_of = |v: Vec<f64>| crate::sampler::quantile(&v, 0.5);
    let values: NoiseValues =
        std::array::from_fn(|p| median_of(kept.iter().map(|(d, _)| d.noise[p]).collect()));
    let g = median_of(kept.iter().map(|(d, _)| d.stiffness(run)).collect());
    let stiffness = crate::noise::stiffness_path(run, median, g);
    let residuals: Vec<f64> = (1..run.time.len()).map(|k| run.tau[k] - median[k]).collect();
    noise.explain(run, &residuals, &stiffness, &values)
}

/// One run's bands with the record they describe: what `bands.parquet`
/// holds for the run, and what the figures draw.
#[derive(Clone, Debug, PartialEq)]
pub struct RunBands {
    pub run: String,
    pub current_a: f64,
    pub time: Vec<f64>,
    /// The measured strain.
    pub gamma: Vec<f64>,
    /// The smoothed strain that drove the model.
    pub gamma_model: Vec<f64>,
    pub tau_obs: Vec<f64>,
    /// q025, q25, q50, q75, q975 of the model stress (Pa).
    pub model: [Vec<f64>; 5],
    /// p025, p975 of a new measurement (Pa).
    pub predictive: [Vec<f64>; 2],
    pub displacement: Vec<f64>,
    pub force: Vec<f64>,
    /// Where the noise model has a force of its own (the discrepancy
    /// model), per sample (NaN at the first): the smoothed discrepancy and
    /// its sd (Pa), and the standardised one-step-ahead innovation.
    pub discrepancy: Option<[Vec<f64>; 3]>,
    /// The coil current at every sample (A), where it varies within the
    /// record (the manifest's `current_varies`).
    pub coil_current_a: Option<Vec<f64>>,
}

impl RunBands {
    /// The bands of `run`, whose model was driven by `data`.
    pub fn of(run: &Run, data: &RunData, bands: Bands) -> RunBands {
        let n = data.time.len();
        RunBands {
            run: run.id().to_string(),
            current_a: run.spec.current_a,
            time: data.time.clone(),
            gamma: run.shear.gamma[..n].to_vec(),
            gamma_model: data.gamma.clone(),
            tau_obs: data.tau.clone(),
            model: bands.model,
            predictive: bands.predictive,
            displacement: run.record.displacement[..n].to_vec(),
            force: run.record.force[..n].to_vec(),
            discrepancy: bands.explained.map(|e| {
                [e.mean, e.sd, e.innovations].map(|v| std::iter::once(f64::NAN).chain(v).collect())
            }),
            coil_current_a: data.current.as_ref().map(|c| c[..n].to_vec()),
        }
    }
}

/// The coverage of one run, as `coverage.parquet` holds it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CoverageRow {
    pub run: String,
    pub current_a: f64,
    pub samples: usize,
    pub inside_p95: f64,
    pub inside_q95: f64,
    pub rmse_q50_pa: f64,
    pub draws: usize,
    pub failed_draws: usize,
    /// Whether the calibration saw this run (false: a true prediction).
    #[serde(default = "yes")]
    pub calibrated: bool,
    /// Log pointwise predictive density of the record (nat; see [`Bands`]).
    #[serde(default = "not_known")]
    pub lppd: f64,
    /// The share of draws whose path misses the record by more than 1.5
    /// times the median path's RMS ([`Bands::far_draws`]; NaN: not known).
    #[serde(default = "not_known")]
    pub far_draws: f64,
    /// The 95 % predictive band's mean width over the record's peak
    /// ([`Coverage::band_width`]; NaN: not known).
    #[serde(default = "not_known")]
    pub band_width: f64,
}

fn not_known() -> f64 {
    f64::NAN
}

fn yes() -> bool {
    true
}

impl CoverageRow {
    pub fn of(run: &Run, bands: &Bands, coverage: &Coverage, calibrated: bool) -> Self {
        CoverageRow {
            run: run.id().to_string(),
            current_a: run.spec.current_a,
            samples: coverage.samples,
            inside_p95: coverage.inside_predictive,
            inside_q95: coverage.inside_model,
            rmse_q50_pa: coverage.rmse_median,
            draws: bands.draws,
            failed_draws: bands.failed,
            calibrated,
            lppd: coverage.lppd,
            far_draws: bands.far_draws,
            band_width: coverage.band_width,
        }
    }

    /// The share of all the rows' samples inside their 95 % predictive
    /// band, each row weighed by its count of samples; `None` without
    /// samples. For bands of new tests this is the number to judge: a right
    /// band holds about 95 % of the samples pooled over many tests, while
    /// one test is inside nearly everywhere or, if its parameters lie in
    /// the population's tails, outside over much of its record
    /// (docs/calibration.md, "Does a new test fall in its band?").
    pub fn pooled_inside_p95<'a>(rows: impl IntoIterator<Item = &'a CoverageRow>) -> Option<f64> {
        let (inside, samples) = rows
            .into_iter()
            .fold((0.0, 0usize), |(i, n), r| (i + r.inside_p95 * r.samples as f64, n + r.samples));
        (samples > 0).then(|| inside / samples as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Params, Scheme};
    use crate::noise::{NoiseKind, NoiseOptions};

    #[test]
    fn pooled_share_weighs_each_run_by_its_samples() {
        let row =
            |samples, inside_p95| CoverageRow { samples, inside_p95, ..CoverageRow::default() };
        // 1000 samples all inside and 250 a fifth inside: (1000 + 50) / 1250
        let rows = [row(1000, 1.0), row(250, 0.2)];
        assert!((CoverageRow::pooled_inside_p95(&rows).unwrap() - 0.84).abs() < 1e-12);
        assert_eq!(CoverageRow::pooled_inside_p95(&[]), None);
        assert_eq!(CoverageRow::pooled_inside_p95(&[row(0, 1.0)]), None);
    }

    fn ramp_run() -> RunData {
        ramp_run_with(vec![0.0; 400])
    }

    /// The ramp's 400 samples with the stress record `tau`.
    fn ramp_run_with(tau: Vec<f64>) -> RunData {
        let time: Vec<f64> = (0..400).map(|k| k as f64 * 5e-4).collect();
        let gamma: Vec<f64> = time
            .iter()
            .map(|t| 0.5 * (1.0 - (2.0 * std::f64::consts::PI * 2.5 * t).cos()))
            .collect();
        RunData::new("r".into(), time, gamma, tau, 0.0, 1.0, (0.05, 1e-3), (0.0, 1.0))
    }

    fn settings(
        integrator: Integrator,
        noise: NoiseKind,
        replicates: usize,
        seed: u64,
    ) -> PredictSettings {
        let noise =
            noise.model(&NoiseOptions { errors_in_variables: false, ..NoiseOptions::default() });
        PredictSettings { integrator, noise, replicates, seed }
    }

    /// Quantiles by selection equal those of the sorted values, bit for bit,
    /// ties and all.
    #[test]
    fn selected_quantiles_equal_sorted_ones() {
        use crate::sampler::quantile_sorted;
        let mut rng = crate::rng::stream(5, &[]);
        for n in [1usize, 2, 3, 10, 400, 4001] {
            let v: Vec<f64> = (0..n)
                .map(|i| if i % 7 == 0 { 1.5 } else { rand::RngExt::random::<f64>(&mut rng) })
                .collect();
            let mut sorted = v.clone();
            sorted.sort_unstable_by(f64::total_cmp);
            let probs = [0.025, 0.25, 0.5, 0.75, 0.975];
            let mut w = v.clone();
            let got = selected_quantiles(&mut w, &probs);
            for (g, p) in got.iter().zip(probs) {
                assert_eq!(g.to_bits(), quantile_sorted(&sorted, p).to_bits(), "n {n}, p {p}");
            }
        }
    }

    /// One fixed parameter set: the model band collapses onto the
    /// trajectory, and the predictive band is that trajectory ± 1.96 σ up to
    /// the Monte Carlo error of the 2.5 % quantile of 4000 normals
    /// (sd ≈ 0.05 σ; 0.2 σ is four of them).
    #[test]
    fn fixed_parameters_give_the_trajectory_and_normal_quantiles() {
        let run = ramp_run();
        let integ = Integrator { scheme: Scheme::Explicit, substeps: 2, ..Integrator::default() };
        let p = Params::reference_1a();
        let sigma = 500.0;
        let draws = vec![Draw::of_law(p, [sigma, 0.0, 0.0, 0.0]); 40];
        let settings = settings(integ, NoiseKind::Gaussian, 100, 3);
        let b = bands(&run, 0, &draws, &settings, &|| {}).unwrap();
        let truth = integ.run(&p, &run.time, &run.gamma).unwrap().tau;
        for k in (0..400).step_by(37) {
            for q in &b.model {
                assert_eq!(q[k], truth[k]);
            }
            assert!((b.predictive[0][k] - (truth[k] - 1.96 * sigma)).abs() < 0.2 * sigma, "k {k}");
            assert!((b.predictive[1][k] - (truth[k] + 1.96 * sigma)).abs() < 0.2 * sigma, "k {k}");
        }
        assert_eq!((b.draws, b.failed), (40, 0));
        // identical draws: the lppd is the Gaussian log-likelihood of the
        // record (zeros) about the trajectory, summed by hand
        let by_hand: f64 = truth[1..]
            .iter()
            .map(|m| {
                -0.5 * (2.0 * std::f64::consts::PI).ln() - sigma.ln() - 0.5 * (m / sigma).powi(2)
            })
            .sum();
        assert!((b.lppd - by_hand).abs() < 1e-9 * by_hand.abs(), "{} vs {by_hand}", b.lppd);
    }

    /// Draws whose own path misses the record far more than the median
    /// path's are counted, and only they: a record of the reference path
    /// plus a ±300 Pa wave (the median path's RMS miss 212 Pa); 34 draws
    /// at the reference, 2 with G 0.1 % higher (their paths within a few
    /// pascals of it), 4 with twice the yield stresses (missing by about
    /// the stress itself, ~1e5 Pa): 4 of 40 far.
    #[test]
    fn draws_far_from_the_record_are_counted() {
        let ramp = ramp_run();
        let integ = Integrator { scheme: Scheme::Explicit, substeps: 2, ..Integrator::default() };
        let p = Params::reference_1a();
        let truth = integ.run(&p, &ramp.time, &ramp.gamma).unwrap().tau;
        let tau: Vec<f64> =
            truth.iter().enumerate().map(|(k, t)| t + 300.0 * (0.3 * k as f64).sin()).collect();
        let run = ramp_run_with(tau);
        let near = Params { g: p.g * 1.001, ..p };
        let far = Params { r0: 2.0 * p.r0, r1: 2.0 * p.r1, ..p };
        let mut draws = vec![Draw::of_law(p, [300.0, 0.0, 0.0, 0.0]); 34];
        draws.extend(vec![Draw::of_law(near, [300.0, 0.0, 0.0, 0.0]); 2]);
        draws.extend(vec![Draw::of_law(far, [300.0, 0.0, 0.0, 0.0]); 4]);
        let b =
            bands(&run, 0, &draws, &settings(integ, NoiseKind::Gaussian, 4, 3), &|| {}).unwrap();
        assert_eq!(b.far_draws, 0.1);
        // a record without a measured force has nothing to miss
        let b = bands(
            &ramp_run_with(vec![f64::NAN; 400]),
            0,
            &draws,
            &settings(integ, NoiseKind::Gaussian, 4, 3),
            &|| {},
        )
        .unwrap();
        assert!(b.far_draws.is_nan());
    }

    /// AR(1) noise keeps its stationary variance σ²/(1 − ρ²) along the record.
    #[test]
    fn ar1_noise_has_the_stationary_spread() {
        let run = ramp_run();
        let integ = Integrator { substeps: 1, ..Integrator::default() };
        let (sigma, rho) = (300.0f64, 0.8f64);
        let draws = vec![Draw::of_law(Params::reference_1a(), [sigma, rho, 0.0, 0.0]); 40];
        let settings = settings(integ, NoiseKind::Ar1, 100, 9);
        let b = bands(&run, 0, &draws, &settings, &|| {}).unwrap();
        let sd = sigma / (1.0 - rho * rho).sqrt();
        for k in [1, 200, 399] {
            let half = 0.5 * (b.predictive[1][k] - b.predictive[0][k]);
            assert!((half / (1.96 * sd) - 1.0).abs() < 0.1, "k {k}: {half} vs {}", 1.96 * sd);
        }
    }

    #[test]
    fn coverage_counts_observations_inside() {
        let b = Bands {
            run: "r".into(),
            model: [(); 5].map(|_| vec![0.0; 5]),
            predictive: [vec![-1.0; 5], vec![1.0; 5]],
            draws: 1,
            failed: 0,
            lppd: 0.0,
            explained: None,
            far_draws: 0.0,
        };
        let c = b.coverage(&[9.0, 0.5, 2.0, -0.5, -3.0]);
        assert_eq!(c.samples, 4);
        assert_eq!(c.inside_predictive, 0.5);
        // the band is 2 wide at every sample; the largest |τ| after the
        // first sample (which is not compared) is 3
        assert_eq!(c.band_width, 2.0 / 3.0);
    }
}
