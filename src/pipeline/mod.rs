//! The stages of a study as library calls, each reading and writing the
//! folders of the outside contract: identify a campaign, calibrate it into
//! one folder per current, predict a calibration folder, validate it by
//! leave-one-out, report it, compare folders, and the whole job.
//!
//! A stage tells what it did through [`Event`]s to a listener (the command
//! line prints them); a Rust user can pass a closure that ignores them. The
//! whole job ([`Pipeline::run`]) hands each stage's results to the next in
//! memory, while still writing every folder as the separate commands would.

mod calibrate;
mod compare;
pub mod folders;
mod predict;

use std::path::{Path, PathBuf};

use crate::calibrate::{Calibration, CalibrationSettings};
use crate::data::{current_tag, Campaign};
use crate::error::Result;
use crate::identify::CurrentIdentification;
use crate::posterior::ModelKind;
use crate::sampler::{Observer, Progress};
use crate::store::PredictionRecord;
use crate::validate::{LooRow, LooSettings};

pub use calibrate::CHECKPOINT;
pub use predict::Prediction;

/// What a stage did, for the listener.
pub enum Event<'a> {
    /// A line about progress.
    Note(&'a str),
    /// A campaign was loaded and checked.
    Checked(&'a Campaign),
    Identified(&'a [CurrentIdentification]),
    /// A calibration (of `what`: runs and currents) is about to start.
    Calibrating { what: &'a str, dir: &'a Path },
    Calibrated(&'a Calibration),
    Predicted { record: &'a PredictionRecord, dir: &'a Path },
    LeftOneOut { rows: &'a [LooRow], seconds: f64 },
    /// A file of results (a report) was written.
    Wrote(&'a Path),
}

/// Which runs to calibrate and how: the settings, and the choices the
/// command line adds to them.
#[derive(Clone, Debug)]
pub struct SampleRequest {
    pub settings: CalibrationSettings,
    /// Only the runs at this current (per-current model).
    pub current: Option<f64>,
    /// Currents left out of a current-law calibration, to be predicted.
    pub hold_out_current: Vec<f64>,
    /// Continue from the folder's sampler checkpoint.
    pub resume: bool,
    /// Replace the results of an earlier calibration in the folder.
    pub force: bool,
}

/// How posterior draws are propagated into bands.
#[derive(Clone, Copy, Debug)]
pub struct PredictOptions {
    /// Posterior draws (after burn-in, thinned by τ, spread evenly).
    pub draws: usize,
    /// Noise replicates per draw in the predictive band.
    pub replicates: usize,
    pub seed: u64,
}

impl Default for PredictOptions {
    fn default() -> Self {
        PredictOptions { draws: 400, replicates: 10, seed: 1 }
    }
}

/// The whole job's choices.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub sample: SampleRequest,
    pub predict: PredictOptions,
    /// Leave-one-out validation with this many sampler steps per held-out run.
    pub leave_one_out: Option<usize>,
    /// With several currents, also the current law, holding out the middle
    /// current when there are three or more.
    pub current_law: bool,
}

/// The stages, with a listener for their events.
pub struct Pipeline<'a> {
    listener: &'a mut dyn FnMut(Event<'_>),
    /// Progress bars on the terminal while sampling and predicting.
    pub progress: bool,
}

impl<'a> Pipeline<'a> {
    pub fn new(listener: &'a mut dyn FnMut(Event<'_>), progress: bool) -> Self {
        Pipeline { listener, progress }
    }

    fn emit(&mut self, event: Event<'_>) {
        (self.listener)(event)
    }

    fn note(&mut self, line: &str) {
        self.emit(Event::Note(line))
    }

    /// The observers of a sampler run: a progress bar where wanted.
    fn observers(&self) -> Vec<Box<dyn Observer>> {
        Self::observers_for(self.progress)
    }

    fn observers_for(progress: bool) -> Vec<Box<dyn Observer>> {
        if progress {
            vec![Box::new(Progress::default())]
        } else {
            vec![]
        }
    }

    /// Loads a campaign and tells what loading noticed but did not refuse.
    pub fn load(&mut self, manifest: &Path) -> Result<Campaign> {
        let campaign = Campaign::load(manifest)?;
        for n in &campaign.notes {
            self.note(&format!("note: {n}"));
        }
        Ok(campaign)
    }

    /// Loads and checks a campaign.
    pub fn check(&mut self, manifest: &Path) -> Result<Campaign> {
        let campaign = self.load(manifest)?;
        self.emit(Event::Checked(&campaign));
        Ok(campaign)
    }

    /// The whole job on one campaign: one calibration folder per current in
    /// `out/I<current>A/` (identification, posterior, bands, leave-one-out,
    /// report); then, with several currents, the current law in
    /// `out/current-law…/` and the comparison in `out/comparison/`.
    /// Returns the reports written.
    pub fn run(&mut self, manifest: &Path, out: &Path, options: &RunOptions) -> Result<Vec<PathBuf>> {
        let campaign = self.check(manifest)?;
        let all = campaign.currents();
        let currents = match options.sample.current {
            Some(c) => vec![c],
            None => all.clone(),
        };
        let loo = options.leave_one_out.map(|steps| self.loo_settings(steps, &options.predict));
        let mut reports = Vec::new();
        let mut entries = Vec::new();
        for c in currents {
            let request = SampleRequest { current: Some(c), ..options.sample.clone() };
            for cal in self.sample(&campaign, &out.join(current_tag(c)), &request)? {
                let (report, prediction) = self.predict_and_report(&cal, &campaign, &options.predict, loo.as_ref())?;
                reports.push(report);
                entries.push(compare::entry(cal, Some(prediction)));
            }
        }
        if options.sample.current.is_none() && all.len() >= 2 {
            if options.current_law {
                // hold out the middle current: the law must predict it
                let held: Vec<f64> = if all.len() >= 3 { vec![all[all.len() / 2]] } else { vec![] };
                let name = match held.first() {
                    Some(h) => format!("current-law-without-{}", current_tag(*h)),
                    None => "current-law".to_string(),
                };
                let mut settings = options.sample.settings.clone();
                settings.model = ModelKind::CurrentLaw;
                let request = SampleRequest { settings, hold_out_current: held, ..options.sample.clone() };
                for cal in self.sample(&campaign, &out.join(name), &request)? {
                    let (report, prediction) = self.predict_and_report(&cal, &campaign, &options.predict, None)?;
                    reports.push(report);
                    entries.push(compare::entry(cal, Some(prediction)));
                }
            }
            reports.push(self.compare_entries(entries, &out.join("comparison"), None)?);
        }
        Ok(reports)
    }

    /// Leave-one-out settings with `steps` per held-out run and the bands'
    /// draws, replicates and seed.
    pub fn loo_settings(&self, steps: usize, predict: &PredictOptions) -> LooSettings {
        LooSettings { steps, draws: predict.draws, replicates: predict.replicates, seed: predict.seed, ..LooSettings::default() }
    }
}
