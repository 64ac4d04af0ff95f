//! A calibration folder: settings, record, summary and posterior sample,
//! and the campaign runs it was calibrated on. What `predict`, `report`,
//! `compare` and leave-one-out start from, whether read from the files or
//! handed on in memory by the process that wrote them.

use std::path::{Path, PathBuf};

use super::record::{read_config, CalibrationRecord};
use super::{chains, summary};
use crate::calibrate::{Calibration, CalibrationSettings};
use crate::data::{Campaign, Geometry, Manifest};
use crate::error::{Error, Result};
use crate::posterior::{Layout, PosteriorSample, SummaryRow};
use crate::predict::PredictSettings;

/// Everything in a calibration folder.
pub struct StoredCalibration {
    pub dir: PathBuf,
    pub settings: CalibrationSettings,
    pub record: CalibrationRecord,
    pub summary: Vec<SummaryRow>,
    pub sample: PosteriorSample,
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
        let settings = read_config(&need("config.toml")?)?;
        let record = CalibrationRecord::read(&need("calibration.toml")?)?;
        let summary = summary::read(&need("summary.parquet")?)?;
        let model = settings.parameter_model();
        let layout = Layout::new(&model, &record.runs, settings.noise_model().as_ref(), settings.sampler.coordinates, &settings.terms);
        let sample = chains::read(&need("chains.parquet")?, &layout, model)?;
        Ok(StoredCalibration { dir: dir.to_path_buf(), settings, record, summary, sample })
    }

    /// The folder `dir` that `cal` has just been written into, without
    /// reading it back.
    pub fn of(dir: &Path, cal: &Calibration) -> StoredCalibration {
        StoredCalibration {
            dir: dir.to_path_buf(),
            settings: cal.start.settings.clone(),
            record: CalibrationRecord::of(cal),
            summary: SummaryRow::rows(&cal.sample.layout, &cal.diagnostics),
            sample: cal.sample.clone(),
        }
    }

    /// A short name for tables and legends: the folder's name.
    pub fn label(&self) -> String {
        self.dir.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_else(|| self.dir.display().to_string())
    }

    /// The campaign's runs that this calibration used.
    pub fn campaign(&self) -> Result<Campaign> {
        Ok(self.used_runs(&self.full_campaign()?))
    }

    /// The runs of `campaign` this calibration used.
    pub fn used_runs(&self, campaign: &Campaign) -> Campaign {
        let runs = &self.record.runs;
        campaign.filtered(|r| runs.iter().any(|id| id == r.id()))
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
        let campaign = Campaign::load(&manifest)?;
        let used = self.used_runs(&campaign);
        if used.runs.len() != self.record.runs.len() {
            return Err(Error::input(&manifest, format!("does not hold every run of the calibration in {}: {:?}", self.dir.display(), self.record.runs)));
        }
        Ok(campaign)
    }

    /// The campaign's geometry: from calibration.toml, or (folders written
    /// before it was stored there) from the manifest it names.
    pub fn geometry(&self) -> Option<Geometry> {
        self.record.geometry.or_else(|| Manifest::read(Path::new(&self.record.manifest)).ok().map(|m| m.geometry))
    }

    pub fn is_current_law(&self) -> bool {
        self.sample.model.is_current_law()
    }

    /// The largest R̂ and the smallest bulk or tail ESS of the summary.
    pub fn max_rhat(&self) -> f64 {
        self.summary.iter().map(|r| r.r_hat).fold(f64::NAN, f64::max)
    }

    pub fn min_ess(&self) -> f64 {
        self.summary.iter().map(|r| r.ess_bulk.min(r.ess_tail)).fold(f64::NAN, f64::min)
    }

    /// Band settings with this calibration's integrator and noise model.
    pub fn predict_settings(&self, replicates: usize, seed: u64) -> PredictSettings {
        let integrator = self.settings.integrator.integrator(self.record.substeps);
        PredictSettings { integrator, noise: self.settings.noise_model(), replicates, seed }
    }

    pub fn burn_in(&self) -> usize {
        self.record.burn_in.min(self.sample.chains.steps().saturating_sub(1))
    }

    /// The largest integrated autocorrelation time of the summary (steps).
    pub fn tau_max(&self) -> f64 {
        self.summary.iter().map(|r| r.tau_int).filter(|t| t.is_finite()).fold(1.0, f64::max)
    }

    /// The thinning of draws: every ⌈τ_max⌉-th step.
    pub fn thin(&self) -> usize {
        self.tau_max().ceil() as usize
    }

    /// Posterior draws after burn-in, thinned by τ_max, `count` of them
    /// spread evenly over what remains; each as the `(step, chain)` it came from.
    pub fn draw_positions(&self, count: usize) -> Vec<(usize, usize)> {
        self.sample.positions(self.burn_in(), self.thin(), count)
    }
}
