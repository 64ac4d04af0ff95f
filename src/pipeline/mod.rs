//! The stages of a study as library calls, each reading and writing the
//! folders of the outside contract: identify a campaign, calibrate it into
//! one folder per current, predict a calibration folder, validate it by
//! leave-one-out, report it, compare folders, and the whole job.
//!
//! A stage tells what it did through [`Event`]s to a listener (the command
//! line prints them); a Rust user can pass a closure that ignores them. The
//! whole job ([`Pipeline::run`]) hands each stage's results to the next in
//! memory, while still writing every folder as the separate commands would.

pub mod bundled;
mod calibrate;
mod compare;
pub mod folders;
pub mod laws;
mod predict;
mod run;
mod simulate;

use std::path::Path;

use crate::calibrate::settings::Overrides;
use crate::calibrate::{Calibration, CalibrationSettings};
use crate::data::Campaign;
use crate::error::{Error, Result};
use crate::identify::CurrentIdentification;
use crate::laws::LawKind;
use crate::posterior::ModelKind;
use crate::predict::PredictionRecord;
use crate::sampler::{Observer, Progress};
use crate::validate::between_runs::NewTestRow;
use crate::validate::consistency::ParameterConsistency;
use crate::validate::{LooRow, LooSettings};

pub use crate::predict::{PredictOptions, Prediction};
pub use calibrate::{check_resumable, CHECKPOINT_EVERY};

/// What a stage did, for the listener.
pub enum Event<'a> {
    /// A line about progress.
    Note(&'a str),
    /// A campaign was loaded and checked.
    Checked(&'a Campaign),
    Identified(&'a [CurrentIdentification]),
    /// A calibration (of `what`: runs and currents) is about to start.
    Calibrating {
        what: &'a str,
        dir: &'a Path,
    },
    /// A calibration is done; `alone`: one run of a `--per-run` study
    /// calibrated by itself (its summary is in its folder; a listener may
    /// say less of it).
    Calibrated {
        cal: &'a Calibration,
        alone: bool,
    },
    Predicted {
        record: &'a PredictionRecord,
        dir: &'a Path,
    },
    LeftOneOut {
        rows: &'a [LooRow],
        seconds: f64,
    },
    /// The runs of a calibration, each calibrated alone, against the joint one.
    Consistency(&'a [ParameterConsistency]),
    /// Each run predicted as a new test by the between-run layer fitted
    /// without it, or without its current.
    NewTestLeftOut {
        rows: &'a [NewTestRow],
        seconds: f64,
    },
    /// A file of results (a report) was written.
    Wrote(&'a Path),
    /// What a stage that ran beside another said, as the pipeline's
    /// [`Render`] put it: shown after the stage it ran beside.
    Said {
        to_stderr: bool,
        text: &'a str,
    },
}

/// How a listener puts an event into words: whether for standard error,
/// and the text. A pipeline given one ([`Pipeline::rendering`]) may run
/// stages side by side, keeping what each says in words until its turn.
pub type Render = fn(Event<'_>) -> (bool, String);

/// What a stage that ran on a thread of its own returned and said, and the
/// folders it held.
struct Beside<T> {
    result: Result<T>,
    said: Vec<(bool, String)>,
    held: Vec<folders::Held>,
}

/// Which runs to calibrate and how, as the command line says it.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct SampleOptions {
    #[command(flatten)]
    pub settings: Overrides,
    /// Calibrate only the runs at this coil current (A)
    #[arg(long)]
    pub current: Option<f64>,
    /// Leave the runs at these currents (A, comma separated) out of a
    /// current-law calibration, to predict them
    #[arg(long, value_delimiter = ',')]
    pub hold_out_current: Vec<f64>,
    /// Continue an interrupted run from OUT/sampler.checkpoint (saved every
    /// 100 steps and at Ctrl-C); the chains equal those of an uninterrupted run
    #[arg(long)]
    pub resume: bool,
    /// Replace the results of an earlier calibration in OUT (and remove
    /// what was derived from them)
    #[arg(long)]
    pub force: bool,
    /// Also calibrate each run alone (into OUT/runs/<run>/) and check that
    /// the runs agree: χ²/ν per parameter, and a between-run layer's
    /// interval for a new test (consistency.parquet, the report). `run`
    /// does so by itself at a current of three runs or more whose
    /// residuals have memory (measured records)
    #[arg(long)]
    pub per_run: bool,
    /// `run`: never calibrate each run alone, not even where the residuals
    /// have memory
    #[arg(long, conflicts_with = "per_run")]
    pub no_per_run: bool,
}

impl SampleOptions {
    /// The request: the settings file with the options applied, checked.
    pub fn request(&self) -> Result<SampleRequest> {
        let settings = self.settings.settings()?;
        let is_law = settings.model.is_law();
        if !self.hold_out_current.is_empty() && !is_law {
            return Err(Error::Usage(
                "--hold-out-current needs --model current-law or current-curves".into(),
            ));
        }
        if self.per_run && is_law {
            return Err(Error::Usage("--per-run calibrates each run alone, which a current law cannot (one run has one current): use the per-current model".into()));
        }
        // each law once (`--law a,b,a` is a and b), in the order given
        let mut laws: Vec<LawKind> = Vec::new();
        for law in &self.settings.law {
            if !laws.contains(law) {
                laws.push(*law);
            }
        }
        Ok(SampleRequest {
            settings,
            laws,
            current: self.current,
            hold_out_current: self.hold_out_current.clone(),
            resume: self.resume,
            force: self.force,
            per_run: self.per_run,
            per_run_where_memory: !self.no_per_run && !is_law,
        })
    }
}

/// Which runs to calibrate and how: the settings, and the choices the
/// command line adds to them.
#[derive(Clone, Debug)]
pub struct SampleRequest {
    pub settings: CalibrationSettings,
    /// The laws asked for (`--law A,B`): empty or one, the settings' law;
    /// several, a comparison of laws (`run`), which the settings' first.
    pub laws: Vec<LawKind>,
    /// Only the runs at this current (per-current model).
    pub current: Option<f64>,
    /// Currents left out of a current-law calibration, to be predicted.
    pub hold_out_current: Vec<f64>,
    /// Continue from the folder's sampler checkpoint.
    pub resume: bool,
    /// Replace the results of an earlier calibration in the folder.
    pub force: bool,
    /// Also calibrate each run alone and compare.
    pub per_run: bool,
    /// `run`: calibrate each run alone too at a current of
    /// [`PER_RUN_WHERE_MEMORY`] runs or more whose joint calibration found
    /// memory in its residuals (`memory = "auto"` chose to allow for it):
    /// there the between-run layer gives the interval for a new test.
    pub per_run_where_memory: bool,
}

/// The fewest runs at a current for which `run` calibrates each alone by
/// itself where their residuals have memory: the between-run layer needs
/// a spread between tests, which two runs barely show.
pub const PER_RUN_WHERE_MEMORY: usize = 3;

/// Refuses `--current` beside a model across currents (`model`: the
/// settings' choice): it would pick the runs of one current for a model
/// that spans them all.
pub(crate) fn one_current_or_a_law(current: Option<f64>, model: ModelKind) -> Result<()> {
    match (current, model) {
        (Some(c), ModelKind::CurrentLaw | ModelKind::CurrentCurves) => {
            let what = match model {
                ModelKind::CurrentCurves => "the current curves",
                _ => "the current law",
            };
            Err(Error::Usage(format!(
                "--current {c} picks the runs of one current, and {what} (`--model`, or `model` in the settings) spans every current: leave --current out (--hold-out-current leaves a current out of it)"
            )))
        }
        _ => Ok(()),
    }
}

/// Leave-one-out validation, as the command line asks for it.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct LooOptions {
    /// Also calibrate without each run in turn and predict it (warm-started
    /// from the full calibration)
    #[arg(long)]
    pub leave_one_out: bool,
    /// Sampler steps of each leave-one-out calibration
    #[arg(long, default_value_t = LooSettings::default().steps)]
    pub loo_steps: usize,
    /// Refit every held-out run by sampling (exact leave-one-out: slower;
    /// a check of the cheaper routes, which reweight the full posterior's
    /// draws or its Laplace approximation where they can be trusted)
    #[arg(long)]
    pub loo_refit: bool,
}

/// Leave-one-out as asked for on the command line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LooRequest {
    /// Most sampler steps of each held-out calibration sampled afresh.
    pub steps: usize,
    /// Every held-out run sampled afresh, none reweighted.
    pub refit: bool,
}

impl LooOptions {
    /// What leave-one-out is asked for, if it is.
    pub fn request(&self) -> Option<LooRequest> {
        self.leave_one_out.then_some(LooRequest { steps: self.loo_steps, refit: self.loo_refit })
    }
}

/// The whole job's choices.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub sample: SampleRequest,
    pub predict: PredictOptions,
    /// Leave-one-out validation, as asked for.
    pub leave_one_out: Option<LooRequest>,
    /// With several currents, also the current law, holding out the middle
    /// current when there are three or more.
    pub current_law: bool,
}

/// The stages, with a listener for their events.
pub struct Pipeline<'a> {
    listener: &'a mut dyn FnMut(Event<'_>),
    /// Progress bars on the terminal while sampling and predicting.
    pub progress: bool,
    /// The folders the stages have written, held until the pipeline ends:
    /// no other process writes them, nor reads them half-written.
    held: folders::HeldAll,
    /// The listener's words for an event, where stages may run side by side.
    render: Option<Render>,
}

impl<'a> Pipeline<'a> {
    pub fn new(listener: &'a mut dyn FnMut(Event<'_>), progress: bool) -> Self {
        Pipeline { listener, progress, held: folders::HeldAll::default(), render: None }
    }

    /// The pipeline, allowed to run independent stages side by side (the
    /// currents of [`Pipeline::run`], the bundled job's two parts): each
    /// stage beside the first tells its events in `render`'s words, after
    /// the first, in order. Without it every stage runs in turn. Either
    /// way the results are the same bits.
    pub fn rendering(mut self, render: Render) -> Self {
        self.render = Some(render);
        self
    }

    /// `work` on every item, in the items' order: with a renderer side by
    /// side (the first on this pipeline, telling its events as they come;
    /// each other on a thread of its own, told whole after the one before),
    /// else in turn, stopping at the first error. The first error ends the
    /// whole; what the later items met is told as notes.
    fn side_by_side<I: Sync, T: Send>(
        &mut self,
        items: &[I],
        work: impl Fn(&mut Pipeline<'_>, &I) -> Result<T> + Sync,
    ) -> Result<Vec<T>> {
        let done: Vec<Result<T>> = match (self.render, items.split_first()) {
            (Some(render), Some((first, rest))) if !rest.is_empty() => {
                std::thread::scope(|scope| {
                    let work = &work;
                    let others: Vec<_> = rest
                        .iter()
                        .map(|item| {
                            scope.spawn(move || Pipeline::beside(render, |p| work(p, item)))
                        })
                        .collect();
                    let mut done = vec![work(self, first)];
                    done.extend(others.into_iter().map(|o| self.join_beside(o.join())));
                    done
                })
            }
            _ => {
                let mut done = Vec::new();
                for item in items {
                    done.push(work(self, item));
                    if done.last().is_some_and(|d| d.is_err()) {
                        break;
                    }
                }
                done
            }
        };
        let mut results = Vec::new();
        let mut failed = None;
        for d in done {
            match d {
                Ok(t) => results.push(t),
                Err(e) if failed.is_none() => failed = Some(e),
                Err(e) => self.note(&format!("mrbp: error: {e}")),
            }
        }
        match failed {
            Some(e) => Err(e),
            None => Ok(results),
        }
    }

    /// Runs `work` on a pipeline of its own on the current thread, keeping
    /// what it says in `render`'s words (no progress bars).
    fn beside<T>(render: Render, work: impl FnOnce(&mut Pipeline<'_>) -> Result<T>) -> Beside<T> {
        let mut said = Vec::new();
        let mut keep = |e: Event<'_>| said.push(render(e));
        let mut side = Pipeline::new(&mut keep, false);
        let result = work(&mut side);
        let held = std::mem::take(&mut side.held.0);
        drop(side);
        Beside { result, said, held }
    }

    /// Tells what a stage run [`Pipeline::beside`] said, keeps its folders
    /// held, and returns its result.
    fn join_beside<T>(&mut self, done: std::thread::Result<Beside<T>>) -> Result<T> {
        let done = done.map_err(|_| {
            Error::Compute("a part of the job running beside another stopped unexpectedly".into())
        })?;
        for (to_stderr, text) in &done.said {
            self.emit(Event::Said { to_stderr: *to_stderr, text });
        }
        self.held.0.extend(done.held);
        done.result
    }

    /// [`folders::prepare`]: `out` made ready for results and held until
    /// the pipeline ends.
    fn prepare(
        &mut self,
        out: &Path,
        option: &str,
        inputs: &[&Campaign],
        results: &[&str],
        force: bool,
    ) -> Result<()> {
        let held = folders::prepare(out, option, inputs, results, force)?;
        self.held.0.push(held);
        Ok(())
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

    /// Leave-one-out settings with `steps` per held-out run and the bands'
    /// draws, replicates and seed.
    pub fn loo_settings(&self, request: LooRequest, predict: &PredictOptions) -> LooSettings {
        LooSettings {
            steps: request.steps,
            refit: request.refit,
            draws: predict.draws,
            replicates: predict.replicates,
            seed: predict.seed,
            ..LooSettings::default()
        }
    }
}
