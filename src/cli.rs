//! The command line (contract.md): parsing, and one function per command.

use std::path::{Path, PathBuf};

use clap::{Args, Parser, Subcommand};

use crate::data::{Campaign, Manifest};
use crate::error::{Error, Result};
use crate::calibrate::{calibrate_with, Checkpointing};
use crate::identify::{identify_campaign, CurrentIdentification, IdentifySettings};
use crate::posterior::CalibrationSettings;
use crate::output;
use crate::output::prediction::{CoverageRow, PredictionRecord, RunPrediction};
use crate::posterior::{ModelKind, RunData};
use crate::predict;
use crate::report;
use crate::validate::{self, LooSettings};
use crate::stored::StoredCalibration;
use crate::synth::{self, SynthSettings};

#[derive(Parser, Debug)]
#[command(
    name = "mrbp",
    version,
    about = "Bayesian calibration of the Bodner-Partom model of MR fluid in MR dampers",
    long_about = "Bayesian calibration of the Bodner-Partom model of MR fluid in MR dampers.\n\n\
                  Without a command, runs the whole pipeline on the bundled campaign in data/ \
                  and writes the results into reports/."
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
    /// The whole pipeline: identify, sample, predict, report
    Run(RunArgs),
    /// Validate a campaign and print one line per run
    Check {
        /// The campaign manifest (TOML)
        manifest: PathBuf,
    },
    /// Virtual experiments: stand records from the B-P model, in the campaign format
    Synth(SynthArgs),
    /// The paper's deterministic identification
    Identify(StageArgs),
    /// Posterior sampling from all runs, started from the identification
    Sample(SampleArgs),
    /// Posterior propagation through the Euler integrator: credible bands
    Predict(PredictArgs),
    /// Plots and the HTML report from what is in DIR
    Report(ReportArgs),
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
    pub predict: PredictOptions,
    #[command(flatten)]
    pub validation: ValidationOptions,
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
    /// With several currents: also calibrate the current law, holding out
    /// the middle current when there are three or more, and predict it
    #[arg(long)]
    pub current_law: bool,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        ValidationOptions { leave_one_out: false, loo_steps: 600, current_law: false }
    }
}

#[derive(Args, Debug)]
pub struct ReportArgs {
    /// A calibration folder (of `mrbp sample` or `mrbp run`)
    pub dir: PathBuf,
    #[command(flatten)]
    pub predict: PredictOptions,
    #[command(flatten)]
    pub validation: ValidationOptions,
}

#[derive(Args, Debug)]
pub struct StageArgs {
    /// The campaign manifest (TOML)
    pub manifest: PathBuf,
    /// Output folder
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub identify: IdentifyArgs,
}

/// Options of the deterministic identification.
#[derive(Args, Debug, Clone)]
pub struct IdentifyArgs {
    /// Loading branch of each record to identify from (0: the first, from rest)
    #[arg(long, default_value_t = 0)]
    pub branch: usize,
    /// Half-width (ms) of the smoothing of τ, γ and their derivatives
    #[arg(long, default_value_t = 0.5)]
    pub smooth_ms: f64,
}

impl IdentifyArgs {
    pub fn settings(&self) -> Result<IdentifySettings> {
        if !(self.smooth_ms > 0.0) {
            return Err(Error::Usage(format!("--smooth-ms must be positive, got {}", self.smooth_ms)));
        }
        Ok(IdentifySettings {
            branch: self.branch,
            smooth_ms: self.smooth_ms,
            ..IdentifySettings::default()
        })
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
    /// per-current: seven B-P parameters per current level (default);
    /// current-law: R0, R1, D1 and G as saturating functions of the current,
    /// one posterior from the runs of every current
    #[arg(long, value_parser = ["per-current", "current-law"])]
    pub model: Option<String>,
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
    #[arg(long)]
    pub seed: Option<u64>,
    /// Residual model: gaussian (default), student-t, ar1
    #[arg(long, value_parser = ["gaussian", "student-t", "ar1"])]
    pub noise: Option<String>,
    /// Samples in the likelihood: whole-record (default), all-branches, first-branch
    #[arg(long, value_parser = ["whole-record", "all-branches", "first-branch"])]
    pub part: Option<String>,
    /// Integrator sub-steps per sample (default: chosen by the step rule)
    #[arg(long)]
    pub substeps: Option<u32>,
    /// Continue an interrupted run from OUT/sampler.checkpoint (saved every
    /// 100 steps); the chains equal those of an uninterrupted run
    #[arg(long)]
    pub resume: bool,
}

impl SampleOptions {
    pub fn settings(&self) -> Result<CalibrationSettings> {
        let mut s = match &self.config {
            Some(path) => CalibrationSettings::read(path)?,
            None => CalibrationSettings::default(),
        };
        if let Some(v) = self.walkers {
            s.sampler.walkers = v;
        }
        if let Some(v) = self.ensembles {
            s.sampler.ensembles = v;
        }
        if let Some(v) = self.steps {
            s.sampler.steps = v;
        }
        if let Some(v) = self.seed {
            s.sampler.seed = v;
        }
        if let Some(v) = &self.noise {
            s.likelihood.noise = toml::Value::String(v.clone()).try_into().map_err(|e| Error::Usage(format!("--noise: {e}")))?;
        }
        if let Some(v) = &self.part {
            s.likelihood.part = toml::Value::String(v.clone()).try_into().map_err(|e| Error::Usage(format!("--part: {e}")))?;
        }
        if let Some(v) = self.substeps {
            s.integrator.substeps = v;
        }
        if let Some(v) = &self.model {
            s.model = toml::Value::String(v.clone()).try_into().map_err(|e| Error::Usage(format!("--model: {e}")))?;
        }
        if !self.hold_out_current.is_empty() && s.model != ModelKind::CurrentLaw {
            return Err(Error::Usage("--hold-out-current needs --model current-law".into()));
        }
        s.check().map_err(Error::Usage)?;
        Ok(s)
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
pub struct PredictOptions {
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

impl Default for PredictOptions {
    fn default() -> Self {
        PredictOptions { draws: 400, replicates: 10, seed: 1 }
    }
}

#[derive(Args, Debug)]
pub struct PredictArgs {
    /// A calibration folder (of `mrbp sample` or `mrbp run`)
    pub dir: PathBuf,
    /// Where to write the bands (default: DIR)
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub options: PredictOptions,
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
    #[arg(long)]
    pub seed: Option<u64>,
}

/// Runs the command line and returns the process exit status.
pub fn main() -> i32 {
    let cli = Cli::parse();
    match dispatch(cli) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("mrbp: error: {e}");
            e.exit_code()
        }
    }
}

fn dispatch(cli: Cli) -> Result<()> {
    if let Some(n) = cli.threads {
        if n == 0 {
            return Err(Error::Usage("--threads must be at least 1".into()));
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| Error::Usage(format!("--threads: {e}")))?;
    }
    match cli.command {
        None => default_job(),
        Some(Command::Check { manifest }) => check(&manifest).map(|_| ()),
        Some(Command::Synth(args)) => synth_cmd(args),
        Some(Command::Run(args)) => run_pipeline(&args.manifest, &args.out, &args.options, &args.predict, &args.validation),
        Some(Command::Identify(args)) => identify_cmd(&args.manifest, &args.out, &args.identify).map(|_| ()),
        Some(Command::Sample(args)) => sample_cmd(&args.manifest, &args.out, &args.options).map(|_| ()),
        Some(Command::Predict(args)) => {
            predict_cmd(&args.dir, args.out.as_deref().unwrap_or(&args.dir), &args.options, true).map(|_| ())
        }
        Some(Command::Report(args)) => report_cmd(&args.dir, &args.predict, &args.validation).map(|_| ()),
        Some(Command::Compare { dirs, out, rpm }) => {
            compare_cmd(&dirs, out.as_deref().unwrap_or(Path::new("comparison")), rpm).map(|_| ())
        }
    }
}

/// The bundled campaign: `data/campaign.toml` of the working directory, or
/// of the source tree this binary was built from.
pub fn bundled_manifest() -> PathBuf {
    let local = Path::new("data/campaign.toml");
    if local.exists() {
        return local.to_path_buf();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/campaign.toml")
}

fn default_job() -> Result<()> {
    let manifest = bundled_manifest();
    let reports = manifest
        .parent()
        .and_then(Path::parent)
        .unwrap_or(Path::new("."))
        .join("reports");
    let name = Manifest::read(&manifest)?.name;
    // the current-law study takes another ~15 min here: `just law` (README)
    let validation = ValidationOptions { leave_one_out: true, ..ValidationOptions::default() };
    run_pipeline(&manifest, &reports.join(name), &SampleOptions::default(), &PredictOptions::default(), &validation)
}

/// The whole pipeline on one campaign, one calibration per current level in
/// `out/I<current>A/`: check, identify, sample, predict, (leave-one-out),
/// report; then, with several currents, (the current law in
/// `out/current-law…/`) and the comparison in `out/comparison/`.
fn run_pipeline(
    manifest: &Path,
    out: &Path,
    options: &SampleOptions,
    predict: &PredictOptions,
    validation: &ValidationOptions,
) -> Result<()> {
    let clock = std::time::Instant::now();
    let campaign = check(manifest)?;
    let currents = match options.current {
        Some(c) => vec![c],
        None => campaign.currents(),
    };
    // always one folder per current, even for a single one
    let mut reports = Vec::new();
    let mut dirs = Vec::new();
    for c in currents {
        let opts = SampleOptions { current: Some(c), ..options.clone() };
        for dir in sample_cmd(manifest, &out.join(output::identification::current_tag(c)), &opts)? {
            predict_cmd(&dir, &dir, predict, true)?;
            reports.push(report_cmd(&dir, predict, validation)?);
            dirs.push(dir);
        }
    }
    let all = campaign.currents();
    if options.current.is_none() && all.len() >= 2 {
        if validation.current_law {
            // hold out the middle current: the law must predict it
            let held: Vec<f64> = if all.len() >= 3 { vec![all[all.len() / 2]] } else { vec![] };
            let name = match held.first() {
                Some(h) => format!("current-law-without-{}", output::identification::current_tag(*h)),
                None => "current-law".to_string(),
            };
            let opts = SampleOptions { model: Some("current-law".into()), hold_out_current: held, ..options.clone() };
            for dir in sample_cmd(manifest, &out.join(name), &opts)? {
                predict_cmd(&dir, &dir, predict, true)?;
                reports.push(report_cmd(&dir, predict, &ValidationOptions { leave_one_out: false, ..*validation })?);
                dirs.push(dir);
            }
        }
        reports.push(compare_cmd(&dirs, &out.join("comparison"), None)?);
    }
    println!("\nreports:");
    for r in &reports {
        println!("  {}", r.display());
    }
    println!("whole job: {:.0} s", clock.elapsed().as_secs_f64());
    Ok(())
}

/// `mrbp identify`: the paper's identification for every current level.
pub fn identify_cmd(manifest: &Path, out: &Path, args: &IdentifyArgs) -> Result<Vec<CurrentIdentification>> {
    let settings = args.settings()?;
    let campaign = Campaign::load(manifest)?;
    let results = identify_campaign(&campaign, &settings);
    std::fs::create_dir_all(out).map_err(|e| Error::output(out, e))?;
    output::identification::write_table(&out.join("identification.parquet"), &results)?;
    output::identification::write_figures(out, &campaign, &results)?;
    output::identification::print_table(&results);
    println!("
wrote identification.parquet and figures fig1–fig5 to {}", out.display());
    Ok(results)
}

/// `mrbp sample`: one calibration per current level of the campaign (or
/// the one chosen), into `out` (or `out/I<current>A/` when there are several).
pub fn sample_cmd(manifest: &Path, out: &Path, options: &SampleOptions) -> Result<Vec<PathBuf>> {
    let settings = options.settings()?;
    let campaign = Campaign::load(manifest)?;
    if settings.model == ModelKind::CurrentLaw {
        return Ok(vec![sample_law(&campaign, out, &settings, options)?]);
    }
    let mut currents = campaign.currents();
    if let Some(c) = options.current {
        if !currents.iter().any(|x| (x - c).abs() < 1e-3) {
            return Err(Error::Usage(format!("no run at {c} A in {} (currents: {currents:?})", manifest.display())));
        }
        currents = vec![c];
    }
    let mut dirs = Vec::new();
    for &c in &currents {
        let dir = if currents.len() > 1 { out.join(output::identification::current_tag(c)) } else { out.to_path_buf() };
        let group = campaign.at_current(c);
        println!("\ncalibrating {} run(s) at {c} A into {}", group.runs.len(), dir.display());
        write_calibration(&group, &dir, &settings, options.resume)?;
        dirs.push(dir);
    }
    Ok(dirs)
}

/// `mrbp predict`: posterior draws of a calibration folder through the
/// integrator on every run; bands and coverage into `out`.
pub fn predict_cmd(dir: &Path, out: &Path, options: &PredictOptions, progress: bool) -> Result<Vec<CoverageRow>> {
    if options.draws == 0 || options.replicates == 0 {
        return Err(Error::Usage("--draws and --replicates must be at least 1".into()));
    }
    let clock = std::time::Instant::now();
    let stored = StoredCalibration::open(dir)?;
    // a current law predicts every run of the campaign, seen or not
    let campaign = if stored.is_current_law() { stored.full_campaign()? } else { stored.campaign()? };
    let positions = stored.draw_positions(options.draws);
    let integrator = stored.integrator();
    let settings = stored.predict_settings(options.replicates, options.seed);
    let bar = if progress {
        let bar = indicatif::ProgressBar::new((positions.len() * campaign.runs.len()) as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("predicting {bar:30} {pos}/{len} run draws  ETA {eta}").expect("valid template"),
        );
        bar
    } else {
        indicatif::ProgressBar::hidden()
    };
    let data: Vec<RunData> = campaign.runs.iter().map(|r| stored.prediction_data(r)).collect();
    let mut predictions = Vec::new();
    for (j, (run, data)) in campaign.runs.iter().zip(&data).enumerate() {
        let draws = positions
            .iter()
            .map(|&(s, c)| stored.draw_for_run(s, c, run))
            .collect::<Result<Vec<_>>>()?;
        let bands = predict::bands(data, j, &draws, &integrator, &settings, &|| bar.inc(1))?;
        let coverage = bands.coverage(&data.tau);
        predictions.push(RunPrediction { run, data, bands, coverage });
    }
    bar.finish_and_clear();
    std::fs::create_dir_all(out).map_err(|e| Error::output(out, e))?;
    let rows: Vec<CoverageRow> = predictions
        .iter()
        .map(|p| CoverageRow { calibrated: stored.record.runs.iter().any(|r| r == p.run.id()), ..CoverageRow::of(p) })
        .collect();
    output::prediction::write_bands(&out.join("bands.parquet"), &predictions)?;
    output::prediction::write_coverage(&out.join("coverage.parquet"), &rows)?;
    let record = PredictionRecord {
        mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
        command: output::calibration::command_line(),
        draws: positions.len(),
        burn_in: stored.burn_in(),
        thin: stored.tau_max().ceil() as usize,
        noise_replicates: options.replicates,
        seed: options.seed,
        substeps: integrator.substeps,
        seconds: clock.elapsed().as_secs_f64(),
        coverage: rows.clone(),
    };
    output::prediction::write_record(&out.join("prediction.toml"), &record)?;
    println!(
        "\n{} posterior draws (after a burn-in of {} steps, thinned by {} steps) through {} run(s) in {:.1} s",
        record.draws, record.burn_in, record.thin, rows.len(), record.seconds
    );
    println!("{:<16} {:>8} {:>12} {:>12} {:>12} {:>10}", "run", "samples", "in_p95_%", "in_q95_%", "rmse_q50_pa", "");
    for r in &rows {
        println!(
            "{:<16} {:>8} {:>12.1} {:>12.1} {:>12.1} {:>10}",
            r.run,
            r.samples,
            100.0 * r.inside_p95,
            100.0 * r.inside_q95,
            r.rmse_q50_pa,
            if r.calibrated { "" } else { "held out" }
        );
    }
    println!("wrote bands.parquet, coverage.parquet and prediction.toml to {}", out.display());
    Ok(rows)
}

/// `mrbp report`: figures and report.html of a calibration folder (the
/// bands are computed first if the folder has none).
pub fn report_cmd(dir: &Path, options: &PredictOptions, validation: &ValidationOptions) -> Result<PathBuf> {
    if !dir.join("bands.parquet").exists() || !dir.join("coverage.parquet").exists() {
        println!("no bands in {} yet: predicting first", dir.display());
        predict_cmd(dir, dir, options, true)?;
    }
    if validation.leave_one_out {
        loo_cmd(dir, options, validation)?;
    }
    let path = report::write(dir)?;
    println!("wrote {}", path.display());
    Ok(path)
}

/// The leave-one-out study of a calibration folder: `loo.parquet` (coverage
/// of each held-out run) and `loo_bands.parquet`.
pub fn loo_cmd(dir: &Path, options: &PredictOptions, validation: &ValidationOptions) -> Result<Vec<CoverageRow>> {
    if validation.loo_steps < 10 {
        return Err(Error::Usage("--loo-steps must be at least 10".into()));
    }
    let clock = std::time::Instant::now();
    let stored = StoredCalibration::open(dir)?;
    let campaign = stored.campaign()?;
    if campaign.runs.len() < 2 {
        println!("leave-one-out skipped: the calibration in {} has a single run", dir.display());
        return Ok(vec![]);
    }
    let settings = LooSettings { steps: validation.loo_steps, draws: options.draws, replicates: options.replicates, seed: options.seed };
    let held = validate::leave_one_out(&stored, &campaign, &settings, true)?;
    let predictions: Vec<RunPrediction> = held
        .iter()
        .zip(&campaign.runs)
        .map(|(h, run)| RunPrediction { run, data: &h.data, coverage: h.bands.coverage(&h.data.tau), bands: h.bands.clone() })
        .collect();
    let rows: Vec<CoverageRow> = predictions.iter().map(CoverageRow::of).collect();
    output::prediction::write_bands(&dir.join("loo_bands.parquet"), &predictions)?;
    output::prediction::write_coverage(&dir.join("loo.parquet"), &rows)?;
    println!("\nleave-one-out ({} steps per held-out calibration, {:.0} s):", validation.loo_steps, clock.elapsed().as_secs_f64());
    println!("{:<16} {:>12} {:>12} {:>8}", "held out", "in_p95_%", "rmse_q50_pa", "max_R̂");
    for (r, h) in rows.iter().zip(&held) {
        println!("{:<16} {:>12.1} {:>12.1} {:>8.4}", r.run, 100.0 * r.inside_p95, r.rmse_q50_pa, h.max_rhat);
    }
    Ok(rows)
}

/// A current-law calibration of every run of the campaign but those at the
/// held-out currents, into `out`.
fn sample_law(campaign: &Campaign, out: &Path, settings: &CalibrationSettings, options: &SampleOptions) -> Result<PathBuf> {
    let held = &options.hold_out_current;
    for h in held {
        if !campaign.currents().iter().any(|c| (c - h).abs() < 1e-3) {
            return Err(Error::Usage(format!("--hold-out-current {h}: no run at {h} A (currents: {:?})", campaign.currents())));
        }
    }
    let used = campaign.filtered(|r| !held.iter().any(|h| (r.spec.current_a - h).abs() < 1e-3));
    println!(
        "\ncalibrating the current law on {} run(s) at {:?} A{} into {}",
        used.runs.len(),
        used.currents(),
        if held.is_empty() { String::new() } else { format!(" (holding out {held:?} A)") },
        out.display()
    );
    write_calibration(&used, out, settings, options.resume)
}

/// Calibrates `campaign` into `dir`: identification, chains, summary, records.
fn write_calibration(campaign: &Campaign, dir: &Path, settings: &CalibrationSettings, resume: bool) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    let checkpointing = Checkpointing { path: Some(dir.join("sampler.checkpoint")), every: 100, resume };
    if resume && !dir.join("sampler.checkpoint").exists() {
        return Err(Error::Usage(format!("--resume: no sampler.checkpoint in {}", dir.display())));
    }
    let cal = calibrate_with(campaign, settings, true, &checkpointing)?;
    let group = campaign.at_current(cal.current_a);
    output::identification::write_table(&dir.join("identification.parquet"), std::slice::from_ref(&cal.identification))?;
    output::identification::write_figures(dir, &group, std::slice::from_ref(&cal.identification))?;
    output::calibration::write_chains(&dir.join("chains.parquet"), &cal)?;
    output::calibration::write_summary(&dir.join("summary.parquet"), &cal)?;
    output::calibration::write_records(dir, &cal)?;
    // the chains are complete in chains.parquet: the checkpoint has done its job
    let _ = std::fs::remove_file(dir.join("sampler.checkpoint"));
    output::calibration::print_summary(&cal);
    Ok(dir.to_path_buf())
}

/// `mrbp compare`: comparison tables, figures and report of calibrations.
pub fn compare_cmd(dirs: &[PathBuf], out: &Path, rpm: Option<f64>) -> Result<PathBuf> {
    let path = report::comparison::write(dirs, out, rpm)?;
    println!("wrote comparison.parquet, differences.parquet, figures and {}", path.display());
    Ok(path)
}

/// `mrbp check`: loads and validates a campaign, prints one line per run.
pub fn check(manifest: &Path) -> Result<Campaign> {
    let campaign = Campaign::load(manifest)?;
    println!(
        "campaign '{}' ({}): {} runs",
        campaign.name,
        manifest.display(),
        campaign.runs.len()
    );
    println!(
        "{:<16} {:>8} {:>11} {:>13} {:>10} {:>9}",
        "run", "samples", "duration_s", "peak_force_n", "current_a", "branches"
    );
    for run in &campaign.runs {
        let rec = &run.record;
        let peak = rec.force.iter().fold(0.0f64, |m, f| m.max(f.abs()));
        println!(
            "{:<16} {:>8} {:>11.3} {:>13.1} {:>10.2} {:>9}",
            run.id(),
            rec.len(),
            rec.time[rec.len() - 1] - rec.time[0],
            peak,
            run.spec.current_a,
            run.branches.len()
        );
    }
    Ok(campaign)
}

fn synth_cmd(args: SynthArgs) -> Result<()> {
    let mut s = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
            toml::from_str::<SynthSettings>(&text)
                .map_err(|e| Error::input(path, format!("invalid synth settings: {}", e.message())))?
        }
        None => SynthSettings::default(),
    };
    if let Some(v) = args.currents {
        s.currents_a = v;
    }
    if let Some(v) = args.rpm {
        s.rpms = v;
    }
    if let Some(v) = args.cycles {
        s.cycles = v;
    }
    if let Some(v) = args.rate {
        s.rate_hz = v;
    }
    if let Some(v) = args.noise_force {
        s.noise_force_n = v;
    }
    if let Some(v) = args.noise_displacement {
        s.noise_displacement_m = v;
    }
    if let Some(v) = args.seed {
        s.seed = v;
    }
    let manifest = synth::write_campaign(&s, &args.out)?;
    println!(
        "wrote {} virtual runs and campaign.toml to {}",
        manifest.runs.len(),
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// Every option of every command has a distinct id and a valid shape.
    #[test]
    fn command_line_is_well_formed() {
        Cli::command().debug_assert();
    }
}
