//! Outputs of the posterior propagation: `bands.parquet` (one row per run
//! and sample), `coverage.parquet` (one row per run) and `prediction.toml`.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{atomic_write, f64_column, read_parquet, str_column, write_parquet, Table};
use crate::data::Run;
use crate::error::{Error, Result};
use crate::posterior::RunData;
use crate::predict::{Bands, Coverage};

/// One run's prediction with what it is compared against.
pub struct RunPrediction<'a> {
    pub run: &'a Run,
    /// The strain history that drove the model (smoothed as in the likelihood).
    pub data: &'a RunData,
    pub bands: Bands,
    pub coverage: Coverage,
}

/// `bands.parquet`.
pub fn write_bands(path: &Path, runs: &[RunPrediction]) -> Result<()> {
    let mut t = Cols::default();
    for p in runs {
        let sh = &p.run.shear;
        for k in 0..p.data.time.len() {
            t.run.push(p.run.id().to_string());
            t.current.push(p.run.spec.current_a);
            t.time.push(p.data.time[k]);
            t.gamma.push(sh.gamma[k]);
            t.gamma_model.push(p.data.gamma[k]);
            t.tau_obs.push(p.data.tau[k]);
            for (col, band) in t.q.iter_mut().zip(&p.bands.model) {
                col.push(band[k]);
            }
            for (col, band) in t.p.iter_mut().zip(&p.bands.predictive) {
                col.push(band[k]);
            }
            t.displacement.push(p.run.record.displacement[k]);
            t.force.push(p.run.record.force[k]);
        }
    }
    let [q025, q25, q50, q75, q975] = t.q;
    let [p025, p975] = t.p;
    write_parquet(
        path,
        Table::new()
            .str("run", t.run)
            .f64("current_a", t.current)
            .f64("time_s", t.time)
            .f64("gamma", t.gamma)
            .f64("gamma_model", t.gamma_model)
            .f64("tau_obs", t.tau_obs)
            .f64("q025", q025)
            .f64("q25", q25)
            .f64("q50", q50)
            .f64("q75", q75)
            .f64("q975", q975)
            .f64("p025", p025)
            .f64("p975", p975)
            .f64("displacement_m", t.displacement)
            .f64("force_n", t.force),
    )
}

#[derive(Default)]
struct Cols {
    run: Vec<String>,
    current: Vec<f64>,
    time: Vec<f64>,
    gamma: Vec<f64>,
    gamma_model: Vec<f64>,
    tau_obs: Vec<f64>,
    q: [Vec<f64>; 5],
    p: [Vec<f64>; 2],
    displacement: Vec<f64>,
    force: Vec<f64>,
}

/// The coverage of one run, as written to and read from `coverage.parquet`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}

fn yes() -> bool {
    true
}

impl CoverageRow {
    pub fn of(p: &RunPrediction) -> Self {
        CoverageRow {
            run: p.run.id().to_string(),
            current_a: p.run.spec.current_a,
            samples: p.coverage.samples,
            inside_p95: p.coverage.inside_predictive,
            inside_q95: p.coverage.inside_model,
            rmse_q50_pa: p.coverage.rmse_median,
            draws: p.bands.draws,
            failed_draws: p.bands.failed,
            calibrated: true,
        }
    }
}

/// `coverage.parquet` (also the format of `loo.parquet`).
pub fn write_coverage(path: &Path, rows: &[CoverageRow]) -> Result<()> {
    write_parquet(
        path,
        Table::new()
            .str("run", rows.iter().map(|r| r.run.clone()).collect())
            .f64("current_a", rows.iter().map(|r| r.current_a).collect())
            .i64("samples", rows.iter().map(|r| r.samples as i64).collect())
            .f64("inside_p95", rows.iter().map(|r| r.inside_p95).collect())
            .f64("inside_q95", rows.iter().map(|r| r.inside_q95).collect())
            .f64("rmse_q50_pa", rows.iter().map(|r| r.rmse_q50_pa).collect())
            .i64("draws", rows.iter().map(|r| r.draws as i64).collect())
            .i64("failed_draws", rows.iter().map(|r| r.failed_draws as i64).collect())
            .bool("calibrated", rows.iter().map(|r| r.calibrated).collect()),
    )
}

pub fn read_coverage(path: &Path) -> Result<Vec<CoverageRow>> {
    let df = read_parquet(path)?;
    let run = str_column(&df, "run", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let calibrated = f64_column(&df, "calibrated", path).unwrap_or_else(|_| vec![1.0; run.len()]);
    let (cur, samples, p, q, rmse, draws, failed) =
        (col("current_a")?, col("samples")?, col("inside_p95")?, col("inside_q95")?, col("rmse_q50_pa")?, col("draws")?, col("failed_draws")?);
    Ok((0..run.len())
        .map(|i| CoverageRow {
            run: run[i].clone(),
            current_a: cur[i],
            samples: samples[i] as usize,
            inside_p95: p[i],
            inside_q95: q[i],
            rmse_q50_pa: rmse[i],
            draws: draws[i] as usize,
            failed_draws: failed[i] as usize,
            calibrated: calibrated[i] != 0.0,
        })
        .collect())
}

/// `prediction.toml`: how the bands were made.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PredictionRecord {
    pub mrbp_version: String,
    pub command: String,
    pub draws: usize,
    pub burn_in: usize,
    pub thin: usize,
    pub noise_replicates: usize,
    pub seed: u64,
    pub substeps: u32,
    pub seconds: f64,
    pub coverage: Vec<CoverageRow>,
}

pub fn write_record(path: &Path, rec: &PredictionRecord) -> Result<()> {
    let text = toml::to_string(rec).map_err(|e| Error::Compute(format!("writing prediction.toml: {e}")))?;
    atomic_write(path, format!("# How bands.parquet was made (mrbp predict).\n{text}").as_bytes())
}

pub fn read_record(path: &Path) -> Result<PredictionRecord> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    toml::from_str(&text).map_err(|e| Error::input(path, format!("not a prediction record: {}", e.message())))
}

/// The bands of every run, as read back from `bands.parquet`.
pub struct StoredBands {
    pub run: String,
    pub current_a: f64,
    pub time: Vec<f64>,
    pub gamma: Vec<f64>,
    /// The smoothed strain that drove the model.
    pub gamma_model: Vec<f64>,
    pub tau_obs: Vec<f64>,
    /// q025, q25, q50, q75, q975
    pub model: [Vec<f64>; 5],
    /// p025, p975
    pub predictive: [Vec<f64>; 2],
    pub displacement: Vec<f64>,
    pub force: Vec<f64>,
}

pub fn read_bands(path: &Path) -> Result<Vec<StoredBands>> {
    let df = read_parquet(path)?;
    let run = str_column(&df, "run", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (cur, time, gamma, tau) = (col("current_a")?, col("time_s")?, col("gamma")?, col("tau_obs")?);
    let gamma_model = col("gamma_model")?;
    let q = [col("q025")?, col("q25")?, col("q50")?, col("q75")?, col("q975")?];
    let p = [col("p025")?, col("p975")?];
    let (disp, force) = (col("displacement_m")?, col("force_n")?);
    let mut out: Vec<StoredBands> = Vec::new();
    let mut start = 0;
    for i in 1..=run.len() {
        if i == run.len() || run[i] != run[start] {
            let r = start..i;
            out.push(StoredBands {
                run: run[start].clone(),
                current_a: cur[start],
                time: time[r.clone()].to_vec(),
                gamma: gamma[r.clone()].to_vec(),
                gamma_model: gamma_model[r.clone()].to_vec(),
                tau_obs: tau[r.clone()].to_vec(),
                model: q.clone().map(|c| c[r.clone()].to_vec()),
                predictive: p.clone().map(|c| c[r.clone()].to_vec()),
                displacement: disp[r.clone()].to_vec(),
                force: force[r.clone()].to_vec(),
            });
            start = i;
        }
    }
    Ok(out)
}
