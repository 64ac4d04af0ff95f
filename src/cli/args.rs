//! The commands and their arguments. Option groups live with the settings
//! they fill: [`SampleOptions`] and the sampler's overrides in `pipeline`
//! and `calibrate`, the bands' [`PredictOptions`] in `predict`, the stand's
//! [`Overrides`] in `synth`, a study's [`PlanOptions`] in `study`.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use crate::identify::IdentifySettings;
use crate::pipeline::{LooOptions, PredictOptions, SampleOptions};
use crate::study::PlanOptions;
use crate::synth::Overrides;

#[derive(Parser, Debug)]
#[command(
    name = "mrbp",
    version,
    about = "Bayesian calibration of the Bodner-Partom model of MR fluid in MR dampers",
    long_about = "Bayesian calibration of the Bodner-Partom model of MR fluid in MR dampers.\n\n\
                  Beside the B-P law it calibrates the damper models the field uses (Bouc-Wen, \
                  Spencer et al.'s modified Bouc-Wen, Bingham) and the B-P law as a damper model \
                  (--law), and ranks them by what they predict of tests they did not see (run --law A,B \
                  --leave-one-out).\n\n\
                  Without a command, in the mrbp project folder, runs the whole job on the bundled \
                  campaigns in data/ (virtual and measured) and writes the results into reports/."
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
    Run {
        /// The campaign manifest (TOML)
        manifest: PathBuf,
        /// Output folder: one calibration folder per current level inside
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        options: SampleOptions,
        #[command(flatten)]
        predict: PredictOptions,
        #[command(flatten)]
        validation: LooOptions,
        /// With several currents: also calibrate the current law (or, with
        /// `--model current-curves`, the current curves), holding out the
        /// middle current when there are three or more, and predict it
        /// (`--model current-law` or `current-curves` asks for it too)
        #[arg(long)]
        current_law: bool,
    },
    /// Validate a campaign and print one line per run
    Check {
        /// The campaign manifest (TOML)
        manifest: PathBuf,
    },
    /// Whether the results in DIR (and the folders under it) are complete:
    /// one line per folder; exit 2 if any is incomplete, stale or being written
    Status {
        /// A results folder (`reports/<name>`, a calibration, a comparison)
        dir: PathBuf,
    },
    /// Virtual experiments: stand records from a damper law (the B-P model unless --law names another), in the campaign format
    Synth {
        /// Output folder for the manifest and the records
        #[arg(long)]
        out: PathBuf,
        /// Settings file (TOML, the format of the synth.toml that synth writes);
        /// the options below override it
        #[arg(long)]
        config: Option<PathBuf>,
        /// Seed of the sensor noise (default: that of the bundled campaign)
        #[arg(long)]
        seed: Option<u64>,
        /// The damper law the records are made with (default: the B-P fluid
        /// of the settings' `[law]`; another law with its typical parameters
        /// at 1 A unless the settings' `[damper]` names them)
        #[arg(long, value_enum)]
        law: Option<crate::laws::LawKind>,
        #[command(flatten)]
        options: Overrides,
    },
    /// The paper's deterministic identification
    Identify {
        /// The campaign manifest (TOML)
        manifest: PathBuf,
        /// Output folder
        #[arg(long)]
        out: PathBuf,
        /// Replace an earlier identification in OUT
        #[arg(long)]
        force: bool,
        /// The damper law: the identification is the B-P law's (the
        /// paper's); another law starts `sample` from a fit of its own
        #[arg(long, value_enum)]
        law: Option<crate::laws::LawKind>,
        #[command(flatten)]
        identify: IdentifySettings,
    },
    /// Posterior sampling from all runs, started from the identification (the B-P law) or a deterministic fit from a few starts (another law)
    Sample {
        /// The campaign manifest (TOML)
        manifest: PathBuf,
        /// Output folder (one sub-folder per current if the campaign has several)
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        options: SampleOptions,
    },
    /// Posterior propagation through the calibration's integrator: credible bands
    Predict {
        /// A calibration folder (of `mrbp sample` or `mrbp run`)
        dir: PathBuf,
        /// Predict the runs of this campaign instead of the calibration's own
        /// (another excitation, a later test, an unseen current for a current
        /// law), with a report of their coverage and adequacy
        #[arg(long, value_name = "MANIFEST")]
        campaign: Option<PathBuf>,
        /// Where to write the bands (default: DIR, or DIR/on-<campaign name>
        /// with --campaign)
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        options: PredictOptions,
    },
    /// The force of a calibrated damper along an excitation of your own
    /// (no measured force needed): model and predictive bands
    Simulate {
        /// A calibration folder (per-current: at its current; a current law:
        /// at any current near the calibrated ones)
        dir: PathBuf,
        /// The excitation: CSV or Parquet with time_s, displacement_m and
        /// optionally current_a (SI units)
        #[arg(long, value_name = "FILE")]
        input: PathBuf,
        /// The coil current (A), if the file has no current_a column
        #[arg(long)]
        current: Option<f64>,
        /// Where to write simulation.parquet and the figure (default:
        /// DIR/simulation-<input file name>)
        #[arg(long)]
        out: Option<PathBuf>,
        /// Draw new tests of the damper from the folder's between-run layer
        /// (between_runs.parquet, made with --per-run) instead of the
        /// calibration's posterior: the band a test not yet run would fall in
        #[arg(long)]
        new_test: bool,
        #[command(flatten)]
        options: PredictOptions,
    },
    /// Plots and the HTML report from what is in DIR
    Report {
        /// A calibration folder (of `mrbp sample` or `mrbp run`)
        dir: PathBuf,
        #[command(flatten)]
        predict: PredictOptions,
        #[command(flatten)]
        validation: LooOptions,
    },
    /// The log evidence (marginal likelihood) of calibrations: sequential
    /// Monte Carlo's where they were sampled so, else by bridge sampling
    /// from their chains; one line per folder
    Evidence {
        /// Calibration folders (of `mrbp sample` or `mrbp run`)
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
    },
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
    Plan {
        /// Folder of the new study
        dir: PathBuf,
        #[command(flatten)]
        options: Box<PlanOptions>,
    },
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
