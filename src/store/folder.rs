//! A calibration folder as a whole: the files that make a
//! [`Calibration`] — `config.toml`, `calibration.toml`, `summary.parquet`,
//! `chains.parquet` — written and read.

use std::path::Path;

use super::{chains, record, summary};
use crate::calibrate::{Calibration, CalibrationSettings};
use crate::error::{Error, Result};
use crate::posterior::Layout;

/// The files of a calibration folder, by name.
pub const CHAINS: &str = "chains.parquet";
pub const SUMMARY: &str = "summary.parquet";
pub const RECORD: &str = "calibration.toml";
pub const CONFIG: &str = "config.toml";
/// The sampler's checkpoint, while a calibration runs or after it was stopped.
pub const CHECKPOINT: &str = "sampler.checkpoint";

/// Reads the calibration in `dir`; every missing or malformed file is a
/// clear input error.
pub fn read(dir: &Path) -> Result<Calibration> {
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
    let settings = CalibrationSettings::read(&need(CONFIG)?)?;
    let record = record::read(&need(RECORD)?)?;
    let summary = summary::read(&need(SUMMARY)?)?;
    let model = settings.parameter_model();
    let layout = Layout::new(&model, &record.runs, settings.noise_model().as_ref(), settings.sampler.coordinates, &settings.terms);
    let sample = chains::read(&need(CHAINS)?, &layout, model)?;
    Ok(Calibration { dir: dir.to_path_buf(), settings, record, summary, sample })
}

/// Writes `cal` into `dir` (chains, summary, settings, then the record)
/// and makes `dir` its folder.
pub fn write(dir: &Path, cal: &mut Calibration) -> Result<()> {
    chains::write(&dir.join(CHAINS), &cal.sample)?;
    summary::write(&dir.join(SUMMARY), &cal.summary, cal.record.burn_in, cal.record.steps, cal.sample.chains.chains())?;
    cal.settings.write(&dir.join(CONFIG))?;
    record::write(&dir.join(RECORD), &cal.record)?;
    cal.dir = dir.to_path_buf();
    Ok(())
}
