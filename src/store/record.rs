//! `calibration.toml` (what a calibration did: start, step study, sampler,
//! timings, warnings) and `config.toml` (the settings it used, which
//! `--config` takes back to repeat it).

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::atomic;
use crate::calibrate::{Calibration, CalibrationSettings};
use crate::error::{Error, Result};
use crate::data::Geometry;
use crate::model::PARAM_NAMES;
use crate::data::RecordPart;
use crate::noise::NoiseKind;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StepRow {
    pub substeps: u32,
    pub largest_shift_sd: f64,
    pub parameter: String,
}

/// `calibration.toml`, read back by `predict`, `report` and `compare`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CalibrationRecord {
    pub mrbp_version: String,
    /// The command line that made it.
    #[serde(default)]
    pub command: String,
    pub campaign: String,
    /// The coil currents of the runs calibrated on.
    #[serde(default)]
    pub currents: Vec<f64>,
    /// The manifest, as an absolute path where it could be resolved.
    pub manifest: String,
    /// The current the parameters describe (a current law's reference).
    pub current_a: f64,
    pub runs: Vec<String>,
    pub noise: NoiseKind,
    pub part: RecordPart,
    pub substeps: u32,
    #[serde(default)]
    pub seed: u64,
    pub step_study: Vec<StepRow>,
    pub identification: BTreeMap<String, f64>,
    pub map: BTreeMap<String, f64>,
    pub map_log_density: f64,
    pub laplace_sd_log: BTreeMap<String, f64>,
    pub walkers: usize,
    pub ensembles: usize,
    pub steps: usize,
    pub burn_in: usize,
    pub seconds_start: f64,
    pub seconds_sampling: f64,
    /// Bulk ESS per second of the whole calibration's wall time, per
    /// parameter: what the calibration's cost bought.
    #[serde(default)]
    pub ess_bulk_per_second: BTreeMap<String, f64>,
    /// The sampler's warnings (convergence, stuck walkers).
    pub warnings: Vec<String>,
    /// What the start found about the model's fit (residuals with memory).
    #[serde(default)]
    pub model_warnings: Vec<String>,
    /// The campaign's geometry (A, h): what turns the bands into forces.
    #[serde(default)]
    pub geometry: Option<Geometry>,
    /// Names this calibration: files derived from it record it, so a later
    /// stage can tell them from those of an earlier calibration.
    #[serde(default)]
    pub calibration_id: String,
}

/// A name for a new calibration: when and by which process it was made.
fn new_calibration_id() -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    format!("{nanos:x}-{:x}", std::process::id())
}

impl CalibrationRecord {
    pub fn of(cal: &Calibration) -> CalibrationRecord {
        let names = &cal.start.posterior.layout.names;
        let coordinates = cal.start.posterior.layout.coordinate_names();
        let named = |v: &[f64]| names.iter().zip(v).map(|(n, v)| (n.clone(), *v)).collect();
        let manifest = std::fs::canonicalize(&cal.campaign.manifest_path).unwrap_or(cal.campaign.manifest_path.clone());
        CalibrationRecord {
            mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
            command: command_line(),
            campaign: cal.campaign.name.clone(),
            currents: cal.campaign.currents(),
            manifest: manifest.display().to_string(),
            current_a: cal.start.posterior.model.describes_current(cal.start.current_a),
            runs: cal.campaign.runs.iter().map(|r| r.id().to_string()).collect(),
            noise: cal.start.settings.likelihood.noise,
            part: cal.start.settings.likelihood.part,
            substeps: cal.start.settings.integrator.substeps,
            seed: cal.start.settings.sampler.seed,
            step_study: cal
                .start
                .step_study
                .iter()
                .map(|s| {
                    let (i, v) = s.worst();
                    StepRow { substeps: s.substeps, largest_shift_sd: v, parameter: coordinates[i].clone() }
                })
                .collect(),
            identification: PARAM_NAMES.iter().zip(cal.start.identification.params.to_array()).map(|(n, v)| (n.to_string(), v)).collect(),
            map: named(&cal.start.posterior.layout.to_si(&cal.start.map.x)),
            map_log_density: cal.start.map.log_density,
            laplace_sd_log: named(&cal.start.map.log_theta_sd(&cal.start.posterior.layout)),
            walkers: cal.start.settings.sampler.walkers,
            ensembles: cal.start.settings.sampler.ensembles,
            steps: cal.diagnostics.steps,
            burn_in: cal.diagnostics.burn_in,
            seconds_start: cal.start.seconds,
            seconds_sampling: cal.sampling_seconds,
            ess_bulk_per_second: names.iter().zip(&cal.diagnostics.coordinates).map(|(n, d)| (n.clone(), d.ess_bulk / cal.seconds())).collect(),
            warnings: cal.diagnostics.warnings.clone(),
            model_warnings: cal.start.warnings.clone(),
            geometry: Some(cal.campaign.geometry),
            calibration_id: new_calibration_id(),
        }
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        let text = toml::to_string(self).map_err(|e| Error::Compute(format!("writing calibration.toml: {e}")))?;
        atomic::write(path, format!("# What this calibration did (mrbp).\n{text}").as_bytes())
    }

    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        toml::from_str(&text).map_err(|e| Error::input(path, format!("not a calibration record: {}", e.message())))
    }
}

/// Writes `config.toml`: the settings actually used.
pub fn write_config(path: &Path, settings: &CalibrationSettings) -> Result<()> {
    let header = "# Settings actually used by this calibration; pass back with --config to repeat it.\n";
    atomic::write(path, format!("{header}{}", settings.to_toml()?).as_bytes())
}

/// Reads `config.toml` (or any settings file).
pub fn read_config(path: &Path) -> Result<CalibrationSettings> {
    CalibrationSettings::read(path)
}

/// The command line of this process, for the records.
pub fn command_line() -> String {
    let mut args = std::env::args();
    let program = args.next().map(|p| Path::new(&p).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or(p));
    program.into_iter().chain(args).collect::<Vec<_>>().join(" ")
}
