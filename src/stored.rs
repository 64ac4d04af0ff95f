//! A calibration folder read back: settings, record, chains and summary,
//! and the campaign runs it was calibrated on. What `predict`, `report` and
//! `compare` start from, so each stage works from files alone.

use std::path::{Path, PathBuf};

use crate::data::{Campaign, Run};
use crate::error::{Error, Result};
use crate::model::{Integrator, Params};
use crate::output::calibration::CalibrationRecord;
use crate::output::{column_names, f64_column, read_parquet, str_column};
use crate::posterior::{CalibrationSettings, ModelKind, NoiseModel, RecordPart, RunData};
use crate::predict::{Draw, PredictSettings};
use crate::sampler::ParameterDiagnostics;

/// One row of `summary.parquet`: a parameter's name and its statistics
/// (read as fields of the row).
#[derive(Clone, Debug, PartialEq)]
pub struct SummaryRow {
    pub parameter: String,
    pub stats: ParameterDiagnostics,
}

impl std::ops::Deref for SummaryRow {
    type Target = ParameterDiagnostics;
    fn deref(&self) -> &ParameterDiagnostics {
        &self.stats
    }
}

/// The chains of `chains.parquet` in SI units, chain-major: the trace of
/// parameter `i` in chain `c` is `values[i][c * steps..(c + 1) * steps]`.
#[derive(Clone, Debug)]
pub struct StoredChains {
    pub names: Vec<String>,
    pub values: Vec<Vec<f64>>,
    pub log_prob: Vec<f64>,
    pub chains: usize,
    pub steps: usize,
    pub ensembles: usize,
}

impl StoredChains {
    pub fn trace(&self, i: usize, chain: usize) -> &[f64] {
        &self.values[i][chain * self.steps..(chain + 1) * self.steps]
    }

    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Every value of parameter `i` from step `from` on, all chains pooled.
    pub fn pooled(&self, i: usize, from: usize) -> Vec<f64> {
        (0..self.chains).flat_map(|c| self.trace(i, c)[from.min(self.steps)..].iter().copied()).collect()
    }

    /// The (step, chain) pairs after burn-in, thinned to every `thin`-th
    /// step, in step-major order.
    pub fn thinned(&self, burn_in: usize, thin: usize) -> Vec<(usize, usize)> {
        (burn_in..self.steps)
            .step_by(thin.max(1))
            .flat_map(|s| (0..self.chains).map(move |c| (s, c)))
            .collect()
    }

    pub fn at(&self, i: usize, step: usize, chain: usize) -> f64 {
        self.values[i][chain * self.steps + step]
    }
}

/// Everything in a calibration folder.
pub struct StoredCalibration {
    pub dir: PathBuf,
    pub settings: CalibrationSettings,
    pub record: CalibrationRecord,
    pub summary: Vec<SummaryRow>,
    pub chains: StoredChains,
}

impl StoredCalibration {
    /// Reads `dir`; every missing or malformed file is a clear input error.
    pub fn open(dir: &Path) -> Result<StoredCalibration> {
        if !dir.is_dir() {
            return Err(Error::input(dir, "not a folder (expected the output folder of `mrbp sample` or `mrbp run`)"));
        }
        let need = |name: &str| {
            let p = dir.join(name);
            if p.exists() {
                Ok(p)
            } else {
                Err(Error::input(&p, "missing: not a calibration folder (run `mrbp sample` into it first)"))
            }
        };
        let settings = CalibrationSettings::read(&need("config.toml")?)?;
        let record = CalibrationRecord::read(&need("calibration.toml")?)?;
        let summary = read_summary(&need("summary.parquet")?)?;
        let chains = read_chains(&need("chains.parquet")?)?;
        Ok(StoredCalibration { dir: dir.to_path_buf(), settings, record, summary, chains })
    }

    /// A short name for tables and legends: the folder's name.
    pub fn label(&self) -> String {
        self.dir.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_else(|| self.dir.display().to_string())
    }

    /// The campaign's runs that this calibration used.
    pub fn campaign(&self) -> Result<Campaign> {
        let campaign = self.full_campaign()?;
        let runs = &self.record.runs;
        let used = campaign.filtered(|r| runs.iter().any(|id| id == r.id()));
        if used.runs.len() != runs.len() {
            return Err(Error::input(&campaign.manifest_path, format!("does not hold every run of the calibration in {}: {runs:?}", self.dir.display())));
        }
        Ok(used)
    }

    /// Every run of the campaign's manifest (a current law predicts them all).
    pub fn full_campaign(&self) -> Result<Campaign> {
        let manifest = PathBuf::from(&self.record.manifest);
        if !manifest.exists() {
            return Err(Error::input(
                self.dir.join("calibration.toml"),
                format!("the campaign manifest {} it names is not there any more", manifest.display()),
            ));
        }
        Campaign::load(&manifest)
    }

    pub fn is_current_law(&self) -> bool {
        self.settings.model == ModelKind::CurrentLaw
    }

    /// Names of the θ coordinates: the seven B-P parameters or the law's.
    pub fn theta_names(&self) -> Vec<String> {
        self.settings.model.theta_names().iter().map(|s| s.to_string()).collect()
    }

    /// The largest R̂ and the smallest bulk or tail ESS of the summary.
    pub fn max_rhat(&self) -> f64 {
        self.summary.iter().map(|r| r.r_hat).fold(f64::NAN, f64::max)
    }

    pub fn min_ess(&self) -> f64 {
        self.summary.iter().map(|r| r.ess_bulk.min(r.ess_tail)).fold(f64::NAN, f64::min)
    }

    /// A run as a prediction sees it: the whole record, its strain smoothed
    /// as in the likelihood.
    pub fn prediction_data(&self, run: &Run) -> RunData {
        RunData::from_run(run, RecordPart::WholeRecord, self.settings.likelihood.smooth_strain_ms)
    }

    /// Band settings with this calibration's noise model.
    pub fn predict_settings(&self, replicates: usize, seed: u64) -> PredictSettings {
        let lik = &self.settings.likelihood;
        PredictSettings { noise: lik.noise, student_nu: lik.student_nu, replicates, seed }
    }

    /// The integrator the likelihood used.
    pub fn integrator(&self) -> Integrator {
        let s = &self.settings.integrator;
        Integrator {
            scheme: s.scheme,
            extrapolate: s.extrapolate,
            substeps: self.record.substeps.max(1),
            max_substeps: s.max_substeps,
            ..Integrator::default()
        }
    }

    pub fn burn_in(&self) -> usize {
        self.record.burn_in.min(self.chains.steps.saturating_sub(1))
    }

    /// The largest integrated autocorrelation time of the summary (steps).
    pub fn tau_max(&self) -> f64 {
        self.summary.iter().map(|r| r.tau_int).filter(|t| t.is_finite()).fold(1.0, f64::max)
    }

    /// Posterior draws after burn-in, thinned by τ_max, `count` of them
    /// spread evenly over what remains; each as the `(step, chain)` it came from.
    pub fn draw_positions(&self, count: usize) -> Vec<(usize, usize)> {
        let all = self.chains.thinned(self.burn_in(), self.tau_max().ceil() as usize);
        crate::predict::evenly_spaced(all.len(), count).into_iter().map(|i| all[i]).collect()
    }

    /// The B-P parameters at one position of the chains, at a coil current
    /// (which only a current law needs).
    pub fn params_at(&self, step: usize, chain: usize, current_a: f64) -> Result<Params> {
        let theta = self
            .theta_names()
            .iter()
            .map(|name| {
                let i = self.chains.index(name).ok_or_else(|| Error::input(self.dir.join("chains.parquet"), format!("no column '{name}'")))?;
                Ok(self.chains.at(i, step, chain))
            })
            .collect::<Result<Vec<f64>>>()?;
        Ok(if self.is_current_law() {
            self.settings.law().params(&theta, current_a)
        } else {
            Params::from_array(std::array::from_fn(|k| theta[k]))
        })
    }

    /// The draw as `run` sees it; a run the calibration did not see gets
    /// the noise of [`Draw::for_unseen_run`].
    pub fn draw_for_run(&self, step: usize, chain: usize, run: &Run) -> Result<Draw> {
        let params = self.params_at(step, chain, run.spec.current_a)?;
        let run = run.id();
        // the run's own column, or every run's
        let get = |prefix: &str| -> Vec<f64> {
            let own = format!("{prefix}_{run}");
            let any = format!("{prefix}_");
            let columns: Vec<usize> = match self.chains.index(&own) {
                Some(i) => vec![i],
                None => (0..self.chains.names.len()).filter(|&i| self.chains.names[i].starts_with(&any)).collect(),
            };
            columns.into_iter().map(|i| self.chains.at(i, step, chain)).collect()
        };
        let sigmas = get("sigma");
        if sigmas.is_empty() {
            return Err(Error::input(self.dir.join("chains.parquet"), "no sigma_<run> column"));
        }
        let rhos = if self.settings.likelihood.noise == NoiseModel::Ar1 { get("rho") } else { vec![] };
        Ok(Draw::for_unseen_run(params, &sigmas, &rhos))
    }
}

fn read_summary(path: &Path) -> Result<Vec<SummaryRow>> {
    let df = read_parquet(path)?;
    let names = str_column(&df, "parameter", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (mean, sd, q05, q50, q95) = (col("mean")?, col("sd")?, col("q05")?, col("q50")?, col("q95")?);
    let (eb, et, rh, tau, mcse) = (col("ess_bulk")?, col("ess_tail")?, col("r_hat")?, col("tau_int")?, col("mcse_mean")?);
    Ok((0..names.len())
        .map(|i| SummaryRow {
            parameter: names[i].clone(),
            stats: ParameterDiagnostics {
                mean: mean[i],
                sd: sd[i],
                q05: q05[i],
                q50: q50[i],
                q95: q95[i],
                ess_bulk: eb[i],
                ess_tail: et[i],
                r_hat: rh[i],
                tau_int: tau[i],
                mcse_mean: mcse[i],
            },
        })
        .collect())
}

fn read_chains(path: &Path) -> Result<StoredChains> {
    let df = read_parquet(path)?;
    let chain = f64_column(&df, "chain", path)?;
    let draw = f64_column(&df, "draw", path)?;
    let ensemble = f64_column(&df, "ensemble", path)?;
    let log_prob = f64_column(&df, "log_prob", path)?;
    let rows = chain.len();
    let chains = chain.iter().fold(0.0f64, |m, c| m.max(*c)) as usize + 1;
    let steps = rows / chains.max(1);
    // the layout written by `mrbp sample`: chain-major, steps in order
    let ordered = rows > 0
        && steps * chains == rows
        && (0..rows).all(|r| chain[r] as usize == r / steps && draw[r] as usize == r % steps);
    if !ordered {
        return Err(Error::input(path, "rows are not ordered by chain and draw as `mrbp sample` writes them"));
    }
    let skip = ["ensemble", "chain", "draw", "log_prob", "accepted"];
    let names: Vec<String> = column_names(&df).into_iter().filter(|n| !skip.contains(&n.as_str())).collect();
    let values = names.iter().map(|n| f64_column(&df, n, path)).collect::<Result<Vec<_>>>()?;
    let ensembles = ensemble.iter().fold(0.0f64, |m, e| m.max(*e)) as usize + 1;
    Ok(StoredChains { names, values, log_prob, chains, steps, ensembles })
}
