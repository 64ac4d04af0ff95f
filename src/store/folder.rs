//! A calibration folder as a whole: the files that make a
//! [`Calibration`] — `config.toml`, `calibration.toml`, `summary.parquet`,
//! `chains.parquet`, and for a law `against_current.parquet` — written and
//! read.

use std::path::Path;

use super::{against_current, chains, record, summary};
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
/// Sequential Monte Carlo's finished populations, while its populations
/// run or after they were stopped (`--sampler smc`).
pub const SMC_CHECKPOINT: &str = crate::sampler::checkpoint::SMC_FILE;

/// The checkpoint a calibration stopped while sampling left in `dir` (the
/// sampler's first), if any.
pub fn checkpoint_in(dir: &Path) -> Option<&'static str> {
    [CHECKPOINT, SMC_CHECKPOINT].into_iter().find(|f| dir.join(f).exists())
}

/// What such a checkpoint holds and how to go on, for messages.
pub const INTERRUPTED: &str = "the chains of an interrupted calibration: the same command with --resume continues them, --force starts afresh";

/// Posterior draws behind a law's `against_current.parquet`.
pub const CURRENT_DRAWS: usize = 4000;

/// The command that rebuilds a calibration folder, for messages.
pub const REBUILD: &str =
    "mrbp sample MANIFEST --out DIR --force (--resume continues from a checkpoint)";

/// Reads the calibration in `dir`; every missing or malformed file is a
/// clear input error, and so is a folder another process is writing, a
/// calibration interrupted while being written, and files of two
/// calibrations side by side.
pub fn read(dir: &Path) -> Result<Calibration> {
    if !dir.is_dir() {
        return Err(Error::input(
            dir,
            "not a folder (expected the output folder of `mrbp sample` or `mrbp run`)",
        ));
    }
    let _reading = crate::lock::read(dir)?;
    if !dir.join(RECORD).exists() && [CHAINS, SUMMARY, CONFIG].iter().any(|f| dir.join(f).exists())
    {
        return Err(Error::input(
            dir.join(RECORD),
            format!("missing: the calibration in this folder is incomplete (stopped while its files were written); make it again with `{REBUILD}`"),
        ));
    }
    let need = |name: &str| {
        let p = dir.join(name);
        if p.exists() {
            Ok(p)
        } else {
            Err(Error::input(
                &p,
                "missing: not a calibration folder (run `mrbp sample` into it first)",
            ))
        }
    };
    let settings = CalibrationSettings::read(&need(CONFIG)?)?;
    let record = record::read(&need(RECORD)?)?;
    for file in [CHAINS, SUMMARY] {
        super::check_derived(&need(file)?, &record.calibration_id, REBUILD)?;
    }
    let summary = summary::read(&need(SUMMARY)?)?;
    let model = settings.parameter_model();
    let layout = Layout::new(
        &model,
        &record.runs,
        settings.noise_model().as_ref(),
        settings.sampler.coordinates,
        &settings.terms,
    );
    let sample = chains::read(&need(CHAINS)?, &layout, model, &record.run_currents)?;
    Ok(Calibration { dir: dir.to_path_buf(), settings, record, summary, sample })
}

/// Makes the calibration in `dir` incomplete, before its files are
/// replaced: `calibration.toml`, which says a calibration folder is
/// complete, goes first.
pub fn retire(dir: &Path) -> Result<()> {
    crate::atomic::remove(&dir.join(RECORD))
}

/// Writes `cal` into `dir` (chains, summary, settings, then the record,
/// which makes the folder complete again) and makes `dir` its folder.
pub fn write(dir: &Path, cal: &mut Calibration) -> Result<()> {
    retire(dir)?;
    let id = &cal.record.calibration_id;
    chains::write(&dir.join(CHAINS), &cal.sample, id)?;
    summary::write(
        &dir.join(SUMMARY),
        &cal.summary,
        (cal.record.burn_in, cal.record.steps, cal.sample.chains.chains()),
        &cal.intervals_hold_for(),
        &cal.record.independent,
        cal.record.smc.as_ref(),
        id,
    )?;
    if cal.is_current_law() {
        let rows = crate::compare::against_current(
            &cal.sample,
            &cal.draw_positions(CURRENT_DRAWS),
            &cal.record.currents,
        );
        against_current::write(dir, &rows, id)?;
    } else {
        crate::atomic::remove(&dir.join(against_current::FILE))?;
    }
    cal.settings.write(&dir.join(CONFIG))?;
    record::write(&dir.join(RECORD), &cal.record)?;
    cal.dir = dir.to_path_buf();
    Ok(())
}
