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
pub use args::{Cli, Command};

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
            let manifest = synth::write_campaign(&args.settings()?, &args.out)?;
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
        Some(Command::Compare { dirs, out, rpm }) => {
            pipeline.compare(&dirs, out.as_deref().unwrap_or(Path::new("comparison")), rpm).map(drop)
        }
    }
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
}
