//! `calibration.toml`: what a calibration did ([`CalibrationRecord`]),
//! written and read.

use std::path::Path;

use crate::atomic;
use crate::calibrate::CalibrationRecord;
use crate::error::{Error, Result};

pub fn write(path: &Path, record: &CalibrationRecord) -> Result<()> {
    let text = toml::to_string(record)
        .map_err(|e| Error::Compute(format!("writing calibration.toml: {e}")))?;
    atomic::write(path, format!("# What this calibration did (mrbp).\n{text}").as_bytes())
}

pub fn read(path: &Path) -> Result<CalibrationRecord> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    toml::from_str(&text)
        .map_err(|e| Error::input(path, format!("not a calibration record: {}", e.message())))
}
