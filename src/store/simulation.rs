//! `simulation.parquet` (one row per sample of the excitation: the model
//! and predictive bands of the stress and of the force) and
//! `simulation.toml` (how it was made; written last, removed first).

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::parquet::{f64_column, read_parquet, write_parquet, Table};
use crate::error::{Error, Result};

pub const FILE: &str = "simulation.parquet";
pub const RECORD: &str = "simulation.toml";

/// The force of a calibrated damper along an excitation of the user's.
#[derive(Clone, Debug, PartialEq)]
pub struct Simulation {
    pub time: Vec<f64>,
    pub displacement: Vec<f64>,
    /// The coil current at every sample (A): the one current simulated, or
    /// the excitation's own where it changes.
    pub current: Vec<f64>,
    /// The shear strain that drove the model (smoothed as in calibration).
    pub gamma_model: Vec<f64>,
    /// q025, q25, q50, q75, q975 of the model stress (Pa).
    pub model: [Vec<f64>; 5],
    /// p025, p975 of a measured stress (Pa).
    pub predictive: [Vec<f64>; 2],
    pub record: SimulationRecord,
}

/// How a simulation was made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimulationRecord {
    pub mrbp_version: String,
    pub command: String,
    /// The excitation's file.
    pub input: String,
    /// The current simulated (A); where it changes, its mean.
    pub current_a: f64,
    /// Whether the current changes along the excitation (its column in
    /// `simulation.parquet` then holds it sample by sample).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub current_varies: bool,
    /// The damper's working area (m²): force = stress × area.
    pub area_m2: f64,
    pub draws: usize,
    /// Draws whose integration failed (left out).
    pub failed_draws: usize,
    pub noise_replicates: usize,
    pub seed: u64,
    pub seconds: f64,
    pub calibration_id: String,
    /// Whether a current law extrapolates beyond its calibrated currents.
    pub extrapolated: bool,
    /// For new tests of the damper (`--new-test`): the run-alone
    /// calibrations of the between-run layer they came from (its
    /// `mrbp.layer_runs`); empty for the calibration's posterior.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub layer_runs: String,
    /// Where the current changes, where its coil lag came from:
    /// `posterior` (a law calibrated on records whose current changes) or
    /// `prior` (one calibrated without: each draw takes a lag from the
    /// lag's prior); empty where the current does not change.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub coil_lag: String,
    /// The excitation's peak velocity (m/s) and stroke (m, half its
    /// range), as the law sees it (the strain smoothed as in calibration).
    #[serde(default = "nan")]
    pub peak_velocity_m_s: f64,
    #[serde(default = "nan")]
    pub stroke_m: f64,
    /// The largest of the calibration's records (NaN where they could not
    /// be read).
    #[serde(default = "nan")]
    pub records_peak_velocity_m_s: f64,
    #[serde(default = "nan")]
    pub records_stroke_m: f64,
    /// What of the excitation lies beyond the records by more than a
    /// quarter: `velocity`, `stroke`; the band extrapolates the law there.
    #[serde(default)]
    pub beyond_records: Vec<String>,
    /// Sub-steps of the integrator per sample of the excitation: the
    /// calibration's, times how many of the records' longest sample
    /// interval the excitation's longest spans (rounded up), so that no
    /// sub-step is longer than those the calibration's step rule checked
    /// (0 in files written before 2026-12-04).
    #[serde(default)]
    pub substeps: u32,
}

fn nan() -> f64 {
    f64::NAN
}

/// The columns of `simulation.parquet`, in order: what the file and the
/// Python package's frame hold.
pub fn columns(s: &Simulation) -> Vec<(String, Vec<f64>)> {
    let r = &s.record;
    let mut columns = vec![
        ("time_s".to_string(), s.time.clone()),
        ("displacement_m".to_string(), s.displacement.clone()),
        ("current_a".to_string(), s.current.clone()),
        ("gamma_model".to_string(), s.gamma_model.clone()),
    ];
    let bands = || MODEL.iter().zip(&s.model).chain(PREDICTIVE.iter().zip(&s.predictive));
    columns.extend(bands().map(|(name, band)| (name.to_string(), band.clone())));
    columns.extend(bands().map(|(name, band)| {
        (format!("force_{name}_n"), band.iter().map(|t| t * r.area_m2).collect())
    }));
    columns
}

/// Writes the simulation into `dir`, the record last.
pub fn write(dir: &Path, s: &Simulation) -> Result<()> {
    let r = &s.record;
    crate::atomic::remove(&dir.join(RECORD))?;
    let mut t = Table::new().derived_from(&r.calibration_id);
    for (name, values) in columns(s) {
        t = t.f64(&name, values);
    }
    write_parquet(&dir.join(FILE), t)?;
    let text = toml::to_string(r).map_err(|e| Error::Compute(format!("writing {RECORD}: {e}")))?;
    crate::atomic::write(
        &dir.join(RECORD),
        format!("# How simulation.parquet was made (mrbp simulate).\n{text}").as_bytes(),
    )
}

const MODEL: [&str; 5] = ["q025", "q25", "q50", "q75", "q975"];
const PREDICTIVE: [&str; 2] = ["p025", "p975"];

/// The record of the simulation in `dir`.
pub fn read_record(dir: &Path) -> Result<SimulationRecord> {
    let path = dir.join(RECORD);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| Error::input(&path, format!("cannot read: {e}")))?;
    toml::from_str(&text)
        .map_err(|e| Error::input(&path, format!("not a simulation record: {}", e.message())))
}

/// Reads the simulation in `dir` back.
pub fn read(dir: &Path) -> Result<Simulation> {
    let record = read_record(dir)?;
    let table = dir.join(FILE);
    super::check_derived(
        &table,
        &record.calibration_id,
        "mrbp simulate CALIBRATION --input FILE --out DIR",
    )?;
    let df = read_parquet(&table)?;
    let col = |n: &str| f64_column(&df, n, &table);
    Ok(Simulation {
        time: col("time_s")?,
        displacement: col("displacement_m")?,
        current: col("current_a")?,
        gamma_model: col("gamma_model")?,
        model: [col(MODEL[0])?, col(MODEL[1])?, col(MODEL[2])?, col(MODEL[3])?, col(MODEL[4])?],
        predictive: [col(PREDICTIVE[0])?, col(PREDICTIVE[1])?],
        record,
    })
}
