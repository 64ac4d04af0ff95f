//! The arguments of every command, and how they become settings.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use crate::calibrate::CalibrationSettings;
use crate::error::{Error, Result};
use crate::identify::IdentifySettings;
use crate::pipeline::{PredictOptions, SampleRequest};
use crate::data::RecordPart;
use crate::noise::NoiseKind;
use crate::posterior::ModelKind;
use crate::synth::SynthSettings;

#[derive(Parser, Debug)]
#[command(
    name = "mrbp",
    version,
    about = "Bayesian calibration of the Bodner-Partom model of MR fluid in MR dampers",
    long_about = "Bayesian calibration of the Bodner-Partom model of MR fluid in MR dampers.\n\n\
                  Without a command, in the mrbp project folder, runs the whole job on the bundled \
                  campaign in data/ and writes the results into reports/."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
    /// Worker threads (default: RAYON_NUM_THREADS, else all cores); results
    /// do not depend on it
    #[arg(long, global = true)]
    pub threads: Option<usize>,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// The whole job: identify, sample, predict, report per current; then compare
    Run(RunArgs),
    /// Validate a campaign and print one line per run
    Check {
        /// The campaign manifest (TOML)
        manifest: PathBuf,
    },
    /// Virtual experiments: stand records from the B-P model, in the campaign format
    Synth(SynthArgs),
    /// The paper's deterministic identification
    Identify(IdentifyArgs),
    /// Posterior sampling from all runs, started from the identification
    Sample(SampleArgs),
    /// Posterior propagation through the Euler integrator: credible bands
    Predict(PredictArgs),
    /// Plots and the HTML report from what is in DIR
    Report(ReportArgs),
    /// Studies of many calibrations: plan, run (here or on a cluster), collect
    #[command(subcommand)]
    Study(StudyCommand),
    /// One report comparing calibrations, e.g. of different current levels
    Compare {
        /// Calibration folders to compare (two or more)
        dirs: Vec<PathBuf>,
        /// Output folder (default: ./comparison)
        #[arg(long)]
        out: Option<PathBuf>,
        /// Crank speed (rpm) whose predictive bands are overlaid (default: the median)
        #[arg(long)]
        rpm: Option<f64>,
    },
}

#[derive(Subcommand, Debug)]
pub enum StudyCommand {
    /// Write a study: one task per calibration (docs/studies.md)
    Plan(Box<StudyPlanArgs>),
    /// Run one task of a study (what a cluster worker runs); a finished task is skipped
    RunTask {
        /// The study folder
        dir: PathBuf,
        /// The task id (a line of DIR/tasks.csv)
        id: String,
    },
    /// Run the study's unfinished tasks on this machine, then collect
    Run {
        /// The study folder
        dir: PathBuf,
        /// Tasks at a time (default: one per core)
        #[arg(long)]
        jobs: Option<usize>,
    },
    /// Gather every task's result into DIR/collected/
    Collect {
        /// The study folder
        dir: PathBuf,
    },
}

#[derive(Args, Debug)]
#[command(group(clap::ArgGroup::new("design").required(true).args(["replicates", "sbc", "campaigns"])))]
pub struct StudyPlanArgs {
    /// Folder of the new study
    pub dir: PathBuf,
    /// Name of the study (default: the folder's name)
    #[arg(long)]
    pub name: Option<String>,
    /// N noise realisations of a virtual campaign with known parameters
    /// (coverage of the credible intervals)
    #[arg(long, value_name = "N")]
    pub replicates: Option<usize>,
    /// Simulation-based calibration: N virtual campaigns with parameters and
    /// noise drawn from the calibration's prior (--config)
    #[arg(long, value_name = "N")]
    pub sbc: Option<usize>,
    /// Calibrate this campaign at each of its currents (or at --current);
    /// repeat for a fleet
    #[arg(long = "campaign", value_name = "MANIFEST")]
    pub campaigns: Vec<PathBuf>,
    /// The virtual stand's settings (the synth.toml format) for --replicates
    /// and --sbc; the options below override it (default: the bundled
    /// campaign's stand at one current, --current or 1 A)
    #[arg(long, value_name = "FILE")]
    pub synth_config: Option<PathBuf>,
    /// Seed of the stand's sensor noise in the first task (task k: + k;
    /// default: that of the bundled campaign). --seed is the sampler's.
    #[arg(long, value_name = "SEED")]
    pub noise_seed: Option<u64>,
    #[command(flatten)]
    pub synth: SynthOptions,
    #[command(flatten)]
    pub sample: SampleOptions,
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The campaign manifest (TOML)
    pub manifest: PathBuf,
    /// Output folder: one calibration folder per current level inside
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub options: SampleOptions,
    #[command(flatten)]
    pub predict: BandOptions,
    #[command(flatten)]
    pub validation: ValidationOptions,
    /// With several currents: also calibrate the current law, holding out
    /// the middle current when there are three or more, and predict it
    #[arg(long)]
    pub current_law: bool,
}

/// Options of the leave-one-out validation.
#[derive(Args, Debug, Clone, Copy)]
pub struct ValidationOptions {
    /// Also calibrate without each run in turn and predict it (warm-started
    /// from the full calibration)
    #[arg(long)]
    pub leave_one_out: bool,
    /// Sampler steps of each leave-one-out calibration
    #[arg(long, default_value_t = 600)]
    pub loo_steps: usize,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        ValidationOptions { leave_one_out: false, loo_steps: 600 }
    }
}

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// A calibration folder (of `mrbp sample` or `mrbp run`)
    pub dir: PathBuf,
    #[command(flatten)]
    pub predict: BandOptions,
    #[command(flatten)]
    pub validation: ValidationOptions,
}

#[derive(Args, Debug)]
pub struct IdentifyArgs {
    /// The campaign manifest (TOML)
    pub manifest: PathBuf,
    /// Output folder
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an earlier identification in OUT
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub identify: IdentifyOptions,
}

/// Options of the deterministic identification.
#[derive(Args, Debug, Clone)]
pub struct IdentifyOptions {
    /// Loading branch of each record to identify from (0: the first, from rest)
    #[arg(long, default_value_t = 0)]
    pub branch: usize,
    /// Half-width (ms) of the smoothing of τ, γ and their derivatives
    #[arg(long, default_value_t = 0.5)]
    pub smooth_ms: f64,
}

impl IdentifyOptions {
    pub fn settings(&self) -> Result<IdentifySettings> {
        if !(self.smooth_ms > 0.0) {
            return Err(Error::Usage(format!("--smooth-ms must be positive, got {}", self.smooth_ms)));
        }
        Ok(IdentifySettings { branch: self.branch, smooth_ms: self.smooth_ms, ..IdentifySettings::default() })
    }
}

/// Options of `mrbp sample` (and `mrbp run`), in emcee's words where they exist.
#[derive(Args, Debug, Clone, Default)]
pub struct SampleOptions {
    /// Settings file (TOML): priors, likelihood, integrator, sampler; the
    /// options below override it
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Calibrate only the runs at this coil current (A)
    #[arg(long)]
    pub current: Option<f64>,
    /// How the B-P parameters relate to the runs (default: per-current)
    #[arg(long, value_enum)]
    pub model: Option<ModelKind>,
    /// Leave the runs at these currents (A, comma separated) out of a
    /// current-law calibration, to predict them
    #[arg(long, value_delimiter = ',')]
    pub hold_out_current: Vec<f64>,
    /// Walkers per ensemble (default: max(24, 2 × dimension))
    #[arg(long)]
    pub walkers: Option<usize>,
    /// Independent ensembles (default 4)
    #[arg(long)]
    pub ensembles: Option<usize>,
    /// A fixed number of steps (default: until converged, R̂ < 1.01, ESS ≥ 400)
    #[arg(long)]
    pub steps: Option<usize>,
    /// Seed of the sampler's random streams (default 1); the same seed gives
    /// the same chains on any number of threads
    #[arg(long)]
    pub seed: Option<u64>,
    /// Residual model (default: gaussian)
    #[arg(long, value_enum)]
    pub noise: Option<NoiseKind>,
    /// Samples in the likelihood (default: whole-record)
    #[arg(long, value_enum)]
    pub part: Option<RecordPart>,
    /// Take the measured displacement as exact (by default its noise,
    /// estimated from the record, reaches the stress through the model's
    /// stiffness: errors in variables, with gaussian noise; docs/calibration.md)
    #[arg(long)]
    pub exact_input: bool,
    /// Integrator sub-steps per sample, at least 1 (default: chosen by the step rule)
    #[arg(long)]
    pub substeps: Option<u32>,
    /// Continue an interrupted run from OUT/sampler.checkpoint (saved every
    /// 100 steps and at Ctrl-C); the chains equal those of an uninterrupted run
    #[arg(long)]
    pub resume: bool,
    /// Replace the results of an earlier calibration in OUT (and remove
    /// what was derived from them)
    #[arg(long)]
    pub force: bool,
}

impl SampleOptions {
    /// The settings file with the options applied, checked.
    pub fn settings(&self) -> Result<CalibrationSettings> {
        let mut s = match &self.config {
            Some(path) => CalibrationSettings::read(path)?,
            None => CalibrationSettings::default(),
        };
        let positive = |v: usize, name: &str| if v == 0 { Err(Error::Usage(format!("{name} must be at least 1"))) } else { Ok(v) };
        if let Some(v) = self.walkers {
            s.sampler.walkers = positive(v, "--walkers")?;
        }
        if let Some(v) = self.ensembles {
            s.sampler.ensembles = positive(v, "--ensembles")?;
        }
        if let Some(v) = self.steps {
            s.sampler.steps = positive(v, "--steps")?;
        }
        if let Some(v) = self.substeps {
            s.integrator.substeps = positive(v as usize, "--substeps")? as u32;
        }
        s.sampler.seed = self.seed.unwrap_or(s.sampler.seed);
        s.likelihood.noise = self.noise.unwrap_or(s.likelihood.noise);
        s.likelihood.part = self.part.unwrap_or(s.likelihood.part);
        if self.exact_input {
            s.likelihood.errors_in_variables = false;
        }
        s.model = self.model.unwrap_or(s.model);
        s.check().map_err(Error::Usage)?;
        Ok(s)
    }

    pub fn request(&self) -> Result<SampleRequest> {
        let settings = self.settings()?;
        if !self.hold_out_current.is_empty() && settings.model != ModelKind::CurrentLaw {
            return Err(Error::Usage("--hold-out-current needs --model current-law".into()));
        }
        Ok(SampleRequest { settings, current: self.current, hold_out_current: self.hold_out_current.clone(), resume: self.resume, force: self.force })
    }
}

#[derive(Args, Debug)]
pub struct SampleArgs {
    /// The campaign manifest (TOML)
    pub manifest: PathBuf,
    /// Output folder (one sub-folder per current if the campaign has several)
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub options: SampleOptions,
}

/// Options of `mrbp predict`.
#[derive(Args, Debug, Clone)]
pub struct BandOptions {
    /// Posterior draws to propagate (after burn-in, thinned by τ, spread evenly)
    #[arg(long, default_value_t = 400)]
    pub draws: usize,
    /// Noise replicates per draw in the predictive band
    #[arg(long, default_value_t = 10)]
    pub replicates: usize,
    /// Seed of the noise replicates
    #[arg(id = "predict_seed", long = "predict-seed", default_value_t = 1)]
    pub seed: u64,
}

impl BandOptions {
    pub fn options(&self) -> PredictOptions {
        PredictOptions { draws: self.draws, replicates: self.replicates, seed: self.seed }
    }
}

#[derive(Args, Debug)]
pub struct PredictArgs {
    /// A calibration folder (of `mrbp sample` or `mrbp run`)
    pub dir: PathBuf,
    /// Predict the runs of this campaign instead of the calibration's own
    /// (another excitation, a later test, an unseen current for a current
    /// law), with a report of their coverage and adequacy
    #[arg(long, value_name = "MANIFEST")]
    pub campaign: Option<PathBuf>,
    /// Where to write the bands (default: DIR, or DIR/on-<campaign name>
    /// with --campaign)
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub options: BandOptions,
}

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Output folder for the manifest and the records
    #[arg(long)]
    pub out: PathBuf,
    /// Settings file (TOML, the format of the synth.toml that synth writes);
    /// the options below override it
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Seed of the sensor noise (default: that of the bundled campaign)
    #[arg(long)]
    pub seed: Option<u64>,
    #[command(flatten)]
    pub options: SynthOptions,
}

/// The options that override the virtual stand's settings.
#[derive(Args, Debug, Clone, Default)]
pub struct SynthOptions {
    /// Coil currents (A), comma separated
    #[arg(long, value_delimiter = ',')]
    pub currents: Option<Vec<f64>>,
    /// Crank speeds (rpm), comma separated
    #[arg(long, value_delimiter = ',')]
    pub rpm: Option<Vec<f64>>,
    /// Crank revolutions per record
    #[arg(long)]
    pub cycles: Option<f64>,
    /// Sampling rate (Hz)
    #[arg(long)]
    pub rate: Option<f64>,
    /// Force sensor noise, standard deviation (N)
    #[arg(long)]
    pub noise_force: Option<f64>,
    /// Displacement sensor noise, standard deviation (m)
    #[arg(long)]
    pub noise_displacement: Option<f64>,
}

impl SynthOptions {
    /// The settings file `config` (or the bundled campaign's settings) with
    /// the options applied, and the sensor noise's `seed` if given.
    pub fn settings(&self, config: Option<&std::path::Path>, seed: Option<u64>) -> Result<SynthSettings> {
        let mut s = match config {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
                toml::from_str::<SynthSettings>(&text).map_err(|e| Error::input(path, format!("invalid synth settings: {}", e.message())))?
            }
            None => SynthSettings::default(),
        };
        if let Some(v) = &self.currents {
            s.currents_a = v.clone();
        }
        if let Some(v) = &self.rpm {
            s.rpms = v.clone();
        }
        s.cycles = self.cycles.unwrap_or(s.cycles);
        s.rate_hz = self.rate.unwrap_or(s.rate_hz);
        s.noise_force_n = self.noise_force.unwrap_or(s.noise_force_n);
        s.noise_displacement_m = self.noise_displacement.unwrap_or(s.noise_displacement_m);
        s.seed = seed.unwrap_or(s.seed);
        Ok(s)
    }
}
