//! The command line (docs/contract.md): the arguments, their mapping onto
//! the [`crate::pipeline`] stages, and what is printed ([`print`]).

mod args;
mod print;

use std::path::{Path, PathBuf};

use clap::{CommandFactory, Parser};

use crate::data::Manifest;
use crate::error::{Error, Result};
use crate::pipeline::{Pipeline, RunOptions};
use crate::synth;
pub use args::{Cli, Command, StudyCommand};

/// Runs the command line and returns the process exit status.
pub fn main() -> i32 {
    let cli = Cli::parse();
    crate::interrupt::install();
    crate::error::install_panic_hook();
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
    let mut listener = print::event;
    let mut pipeline = Pipeline::new(&mut listener, true);
    match cli.command {
        None => bundled_job(&mut pipeline),
        Some(Command::Check { manifest }) => pipeline.check(&manifest).map(drop),
        Some(Command::Synth(args)) => {
            let manifest = synth::write_campaign(&args.options.settings(args.config.as_deref(), args.seed)?, &args.out)?;
            println!("wrote {} virtual runs and campaign.toml to {}", manifest.runs.len(), args.out.display());
            Ok(())
        }
        Some(Command::Run(args)) => {
            let options = RunOptions {
                sample: args.options.request()?,
                predict: args.predict.options(),
                leave_one_out: args.validation.leave_one_out.then_some(args.validation.loo_steps),
                current_law: args.current_law,
            };
            whole_job(&mut pipeline, &args.manifest, &args.out, &options)
        }
        Some(Command::Identify(args)) => {
            let settings = args.identify.settings()?;
            let campaign = pipeline.load(&args.manifest)?;
            pipeline.identify(&campaign, &args.out, &settings, args.force).map(drop)
        }
        Some(Command::Sample(args)) => {
            let request = args.options.request()?;
            let campaign = pipeline.load(&args.manifest)?;
            pipeline.sample(&campaign, &args.out, &request).map(drop)
        }
        Some(Command::Predict(args)) => {
            let cal = crate::store::StoredCalibration::open(&args.dir)?;
            match &args.campaign {
                Some(manifest) => {
                    let campaign = pipeline.load(manifest)?;
                    let out = args.out.clone().unwrap_or_else(|| args.dir.join(format!("on-{}", campaign.name)));
                    pipeline.predict_campaign(&cal, &campaign, &out, &args.options.options()).map(drop)
                }
                None => {
                    let campaign = cal.full_campaign()?;
                    pipeline.predict(&cal, &campaign, args.out.as_deref().unwrap_or(&args.dir), &args.options.options()).map(drop)
                }
            }
        }
        Some(Command::Report(args)) => {
            let predict = args.predict.options();
            let loo = args.validation.leave_one_out.then(|| pipeline.loo_settings(args.validation.loo_steps, &predict));
            pipeline.report(&args.dir, &predict, loo.as_ref()).map(drop)
        }
        Some(Command::Study(command)) => study(&mut pipeline, command),
        Some(Command::Compare { dirs, out, rpm }) => {
            pipeline.compare(&dirs, out.as_deref().unwrap_or(Path::new("comparison")), rpm).map(drop)
        }
    }
}

/// `mrbp study …`.
fn study(pipeline: &mut Pipeline, command: StudyCommand) -> Result<()> {
    use crate::study;
    match command {
        StudyCommand::Plan(args) => {
            let o = &args.sample;
            if o.resume || o.force || !o.hold_out_current.is_empty() || o.model.is_some() {
                return Err(Error::Usage("study plan: --resume, --force, --hold-out-current and --model are not options of a study (each task resumes by itself)".into()));
            }
            let settings = o.settings()?;
            let synth = || -> Result<synth::SynthSettings> {
                let mut s = args.synth.settings(args.synth_config.as_deref(), args.noise_seed)?;
                if args.synth_config.is_none() && args.synth.currents.is_none() {
                    s.currents_a = vec![o.current.unwrap_or(1.0)];
                }
                Ok(s)
            };
            let design = match (args.replicates, args.sbc) {
                (Some(n), _) => study::Design::Replicates { n, synth: synth()? },
                (_, Some(n)) => study::Design::Sbc { n, synth: synth()? },
                _ => study::Design::Campaigns { manifests: args.campaigns.clone(), currents: o.current.into_iter().collect() },
            };
            let name = match &args.name {
                Some(n) => n.clone(),
                None => args.dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "study".into()),
            };
            let tasks = study::plan(&args.dir, &name, &design, &settings)?;
            println!("planned study {name}: {} task(s) in {}", tasks.len(), args.dir.display());
            println!("run them here with `mrbp study run {}`, or on a cluster (docs/studies.md)", args.dir.display());
            Ok(())
        }
        StudyCommand::RunTask { dir, id } => {
            let (outcome, ran) = study::run_task(pipeline, &dir, &id)?;
            let when = if ran { "" } else { " (done before: skipped)" };
            let note = if outcome.message.is_empty() { String::new() } else { format!(": {}", outcome.message) };
            println!("task {id}: {}{when} in {:.1} s{note}", outcome.status, outcome.seconds);
            Ok(())
        }
        StudyCommand::Run { dir, jobs } => {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            let jobs = jobs.unwrap_or(cores);
            let threads = (cores / jobs.max(1)).max(1);
            study::run_local(&dir, jobs, threads, &|line: &str| println!("{line}"))?;
            collect_study(&dir)
        }
        StudyCommand::Collect { dir } => collect_study(&dir),
    }
}

fn collect_study(dir: &Path) -> Result<()> {
    let found = crate::study::collect(dir)?;
    println!(
        "collected {} of {} task(s) into {} ({} failed, {} without a result yet)",
        found.ok,
        found.tasks,
        dir.join("collected").display(),
        found.failed,
        found.missing.len()
    );
    if !found.missing.is_empty() {
        println!("without a result: {}", found.missing.join(", "));
    }
    if let Some(first) = found.coverage.first() {
        println!("\nagainst the known truths (binomial se at the nominal share: 50 % ± {:.0}, 90 % ± {:.0}):", 100.0 * first.se_at(0.5), 100.0 * first.se_at(0.9));
        println!("{:<22} {:>6} {:>8} {:>8} {:>8} {:>7} {:>8}", "coordinate", "tasks", "in 50 %", "in 90 %", "mean z", "sd z", "rank p");
        for r in &found.coverage {
            println!("{:<22} {:>6} {:>7.0}% {:>7.0}% {:>8.2} {:>7.2} {:>8.3}", r.parameter, r.tasks, 100.0 * r.inside_50, 100.0 * r.inside_90, r.z_mean, r.z_sd, r.rank_p);
        }
    }
    Ok(())
}

/// `mrbp` alone, in the project folder: the whole job on the bundled
/// campaigns — the virtual paper replica (every current, leave-one-out and
/// the comparison) into `reports/<its name>`, then the measured damper at
/// 1 A (the B-P law alone, the variant that predicts held-out runs best;
/// docs/real-data.md) into `reports/utfsm-mts`. Its leave-one-out, which
/// refits most runs (half a minute), is left to `--leave-one-out`. Anywhere
/// else it prints the help: the bundled data lives in the project folder.
fn bundled_job(pipeline: &mut Pipeline) -> Result<()> {
    let manifest = PathBuf::from("data/campaign.toml");
    if !manifest.exists() {
        Cli::command().print_help().map_err(|e| Error::output("stdout", e))?;
        return Err(Error::Usage("no command given (and no data/campaign.toml here: the bundled job runs in the mrbp project folder)".into()));
    }
    let clock = std::time::Instant::now();
    // the current-law studies take minutes more: `just law` (README)
    let job = |sample: args::SampleOptions, leave_one_out: bool| -> Result<RunOptions> {
        Ok(RunOptions {
            sample: sample.request()?,
            predict: Default::default(),
            leave_one_out: leave_one_out.then_some(args::ValidationOptions::default().loo_steps),
            current_law: false,
        })
    };
    // the bundled job is the demo: it replaces its own earlier results
    let replace = args::SampleOptions { force: true, ..Default::default() };
    let mut reports = pipeline.run(&manifest, &Path::new("reports").join(Manifest::read(&manifest)?.name), &job(replace.clone(), true)?)?;
    let measured = PathBuf::from("data/utfsm-mts/campaign.toml");
    if measured.exists() {
        let sample = args::SampleOptions { current: Some(1.0), ..replace };
        reports.extend(pipeline.run(&measured, &Path::new("reports").join(Manifest::read(&measured)?.name), &job(sample, false)?)?);
    }
    print_reports(&reports, clock);
    Ok(())
}

fn whole_job(pipeline: &mut Pipeline, manifest: &Path, out: &Path, options: &RunOptions) -> Result<()> {
    let clock = std::time::Instant::now();
    let reports = pipeline.run(manifest, out, options)?;
    print_reports(&reports, clock);
    Ok(())
}

fn print_reports(reports: &[PathBuf], clock: std::time::Instant) {
    println!("\nreports:");
    for r in reports {
        println!("  {}", r.display());
    }
    println!("whole job: {:.0} s", clock.elapsed().as_secs_f64());
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every option of every command has a distinct id and a valid shape.
    #[test]
    fn command_line_is_well_formed() {
        Cli::command().debug_assert();
    }

    /// No command has two options of one name (flattened option groups
    /// share ids silently: `study plan` once had two `--seed`).
    #[test]
    fn no_command_has_an_option_twice() {
        fn check(cmd: &clap::Command, path: &str) {
            let mut seen = std::collections::BTreeSet::new();
            for arg in cmd.get_arguments() {
                if let Some(long) = arg.get_long() {
                    assert!(seen.insert(long.to_string()), "{path}: --{long} twice");
                }
            }
            for sub in cmd.get_subcommands() {
                check(sub, &format!("{path} {}", sub.get_name()));
            }
        }
        let mut cli = Cli::command();
        cli.build();
        check(&cli, "mrbp");
    }
}
