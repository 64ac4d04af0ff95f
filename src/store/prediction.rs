//! A prediction in a folder: `bands.parquet`, `coverage.parquet`,
//! `adequacy.parquet` and `prediction.toml` (how they were made), written
//! and read together.

use std::path::Path;

use super::{adequacy, bands, coverage};
use crate::atomic;
use crate::error::{Error, Result};
use crate::predict::{Prediction, PredictionRecord};

/// The files of a prediction, by name.
pub const BANDS: &str = "bands.parquet";
pub const COVERAGE: &str = "coverage.parquet";
pub const ADEQUACY: &str = "adequacy.parquet";
pub const RECORD: &str = "prediction.toml";

/// Writes the prediction's files into `dir`: the record, which says the
/// prediction is complete, goes first and comes back last.
pub fn write(dir: &Path, p: &Prediction) -> Result<()> {
    let id = &p.record.calibration_id;
    atomic::remove(&dir.join(RECORD))?;
    bands::write(&dir.join(BANDS), &p.bands, id)?;
    coverage::write(&dir.join(COVERAGE), &p.coverage, id)?;
    adequacy::write(&dir.join(ADEQUACY), &p.adequacy, id)?;
    write_record(&dir.join(RECORD), &p.record)
}

/// The three tables of a prediction as the bytes of their Parquet files,
/// by file name: what [`write`] writes, in memory.
pub fn tables(p: &Prediction) -> Result<Vec<(&'static str, Vec<u8>)>> {
    let id = &p.record.calibration_id;
    Ok(vec![
        (BANDS, super::parquet::parquet_bytes(bands::table(&p.bands, id))?),
        (COVERAGE, super::parquet::parquet_bytes(coverage::table(&p.coverage).derived_from(id))?),
        (ADEQUACY, super::parquet::parquet_bytes(adequacy::table(&p.adequacy, id))?),
    ])
}

/// The prediction in `dir`, if it has a complete one (all four files);
/// tables from another calibration than its record's are refused.
pub fn read(dir: &Path) -> Result<Option<Prediction>> {
    if ![BANDS, COVERAGE, ADEQUACY, RECORD].iter().all(|f| dir.join(f).exists()) {
        return Ok(None);
    }
    let record = read_record(&dir.join(RECORD))?;
    for file in [BANDS, COVERAGE, ADEQUACY] {
        super::check_derived(&dir.join(file), &record.calibration_id, "mrbp predict DIR")?;
    }
    Ok(Some(Prediction {
        bands: bands::read(&dir.join(BANDS))?,
        coverage: coverage::read(&dir.join(COVERAGE))?,
        adequacy: adequacy::read(&dir.join(ADEQUACY))?,
        record,
    }))
}

pub fn write_record(path: &Path, rec: &PredictionRecord) -> Result<()> {
    let text = toml::to_string(rec)
        .map_err(|e| Error::Compute(format!("writing prediction.toml: {e}")))?;
    atomic::write(path, format!("# How bands.parquet was made (mrbp predict).\n{text}").as_bytes())
}

pub fn read_record(path: &Path) -> Result<PredictionRecord> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    toml::from_str(&text)
        .map_err(|e| Error::input(path, format!("not a prediction record: {}", e.message())))
}
