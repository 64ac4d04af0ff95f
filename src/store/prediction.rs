//! `prediction.toml`: how `bands.parquet` was made.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::atomic;
use crate::error::{Error, Result};
use crate::predict::CoverageRow;

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
    /// The calibration the bands came from (its `calibration_id`).
    #[serde(default)]
    pub calibration_id: String,
    pub coverage: Vec<CoverageRow>,
}

pub fn write(path: &Path, rec: &PredictionRecord) -> Result<()> {
    let text = toml::to_string(rec).map_err(|e| Error::Compute(format!("writing prediction.toml: {e}")))?;
    atomic::write(path, format!("# How bands.parquet was made (mrbp predict).\n{text}").as_bytes())
}

pub fn read(path: &Path) -> Result<PredictionRecord> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    toml::from_str(&text).map_err(|e| Error::input(path, format!("not a prediction record: {}", e.message())))
}
