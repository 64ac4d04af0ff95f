//! The command line (docs/contract.md): it parses the arguments
//! ([`args`]), hands them to the [`crate::pipeline`] stages, and prints
//! what they did ([`print`]).

mod args;
mod print;

use std::path::{Path, PathBuf};

use clap::{CommandFactory, Parser};

use crate::error::{Error, Result};
use crate::pipeline::bundled::BUNDLED;
use crate::pipeline::{Pipeline, RunOptions};
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
    let mut pipeline = Pipeline::new(&mut listener, true).rendering(print::render);
    let clock = std::time::Instant::now();
    match cli.command {
        None if !Path::new(BUNDLED).exists() => {
            Cli::command().print_help().map_err(|e| Error::output("stdout", e))?;
            Err(Error::Usage(format!("no command given (and no {BUNDLED} here: the bundled job runs in the mrbp project folder)")))
        }
        // the measured damper's part runs beside the virtual one; what it
        // says is shown after the virtual part's, in its own order
        None => pipeline.bundled().map(|reports| print::reports(&reports, clock)),
        Some(Command::Check { manifest }) => pipeline.check(&manifest).map(drop),
        Some(Command::Status { dir }) => status(&dir),
        Some(Command::Synth { out, config, seed, law, options }) => {
            let options = crate::synth::Overrides { law, ..options };
            let manifest =
                crate::synth::write_campaign(&options.settings(config.as_deref(), seed)?, &out)?;
            println!(
                "wrote {} virtual runs and campaign.toml to {}",
                manifest.runs.len(),
                out.display()
            );
            Ok(())
        }
        Some(Command::Run { manifest, out, options, predict, validation, current_law }) => {
            let sample = options.request()?;
            note_unread_settings(&manifest, options.settings.config.as_deref());
            // `--model current-law` or `current-curves` (or the settings'
            // `model`) names the law stage's model, and so asks for it
            let current_law = current_law || sample.settings.model.is_law();
            let options =
                RunOptions { sample, predict, leave_one_out: validation.request(), current_law };
            pipeline.run(&manifest, &out, &options).map(|reports| print::reports(&reports, clock))
        }
        Some(Command::Identify { manifest, out, force, law, identify }) => {
            if let Some(law) = law.filter(|l| !l.is_bodner_partom()) {
                return Err(Error::Usage(format!(
                    "identify is the paper's identification of the B-P law; the {0} law has none: `mrbp sample --law {0}` starts from a deterministic fit of it from a few starts",
                    law.name()
                )));
            }
            identify.check()?;
            let settings = identify;
            let campaign = pipeline.load(&manifest)?;
            pipeline.identify(&campaign, &out, &settings, force).map(drop)
        }
        Some(Command::Sample { manifest, out, options }) => {
            let request = options.request()?;
            if request.laws.len() > 1 {
                return Err(Error::Usage(
                    "sample calibrates one law; `mrbp run --law A,B,…` calibrates several and ranks them".into(),
                ));
            }
            let campaign = pipeline.load(&manifest)?;
            note_unread_settings(&manifest, options.settings.config.as_deref());
            pipeline.sample(&campaign, &out, &request).map(drop)
        }
        Some(Command::Predict { dir, campaign, out, options }) => {
            let cal = crate::store::folder::read(&dir)?;
            match &campaign {
                Some(manifest) => {
                    let campaign = pipeline.load(manifest)?;
                    let out = out.unwrap_or_else(|| dir.join(format!("on-{}", campaign.name)));
                    pipeline.predict_campaign(&cal, &campaign, &out, &options).map(drop)
                }
                None => pipeline
                    .predict(&cal, &cal.full_campaign()?, out.as_deref().unwrap_or(&dir), &options)
                    .map(drop),
            }
        }
        Some(Command::Simulate { dir, input, current, out, options, new_test }) => {
            let cal = crate::store::folder::read(&dir)?;
            let stem = input
                .file_stem()
                .map_or_else(|| "input".to_string(), |s| s.to_string_lossy().into_owned());
            let out = out.unwrap_or_else(|| dir.join(format!("simulation-{stem}")));
            pipeline.simulate(&cal, &input, current, &out, &options, new_test).map(drop)
        }
        Some(Command::Report { dir, predict, validation }) => {
            let loo = validation.request().map(|r| pipeline.loo_settings(r, &predict));
            pipeline.report(&dir, &predict, loo.as_ref()).map(drop)
        }
        Some(Command::Evidence { dirs }) => evidence(&dirs),
        Some(Command::Study(command)) => study(&mut pipeline, command),
        Some(Command::Compare { dirs, out, rpm }) => pipeline
            .compare(&dirs, out.as_deref().unwrap_or(Path::new("comparison")), rpm)
            .map(drop),
    }
}

/// The settings file a campaign folder keeps beside its manifest.
const SETTINGS_BESIDE: &str = "mrbp.toml";

/// Says so where the campaign's folder holds a settings file that this call
/// does not read (settings are read only from `--config`, never found by
/// name): the measured records' `mrbp.toml` switches on the model terms
/// their damper needs, and a calibration without it is another model.
fn note_unread_settings(manifest: &Path, config: Option<&Path>) {
    if let Some(note) = unread_settings(manifest, config) {
        eprintln!("{note}");
    }
}

fn unread_settings(manifest: &Path, config: Option<&Path>) -> Option<String> {
    let beside = manifest.parent().unwrap_or(Path::new("")).join(SETTINGS_BESIDE);
    let named = config.is_some_and(|c| {
        c == beside || matches!((c.canonicalize(), beside.canonicalize()), (Ok(a), Ok(b)) if a == b)
    });
    (beside.is_file() && !named).then(|| {
        let other = if config.is_some() { "another settings file" } else { "the default settings" };
        format!(
            "mrbp: note: {} beside the campaign is not read unless named: this calibration takes {other}; `--config {}` takes its settings",
            beside.display(),
            beside.display()
        )
    })
}

/// `mrbp evidence DIR…`: each calibration's log evidence, one line each.
fn evidence(dirs: &[PathBuf]) -> Result<()> {
    for dir in dirs {
        let cal = crate::store::folder::read(dir)?;
        let e = crate::calibrate::evidence::estimate(&cal, &cal.campaign()?)?;
        let how = match e.draws {
            Some(n) => format!("{} from {n} draws of the chains", e.by),
            None => e.by.to_string(),
        };
        println!(
            "{}: log evidence {:.3} ± {:.3} ({how}), of {}",
            dir.display(),
            e.log_evidence,
            e.se,
            e.of
        );
    }
    Ok(())
}

/// `mrbp status DIR`: one line per results folder; an error if any is not
/// complete.
fn status(dir: &Path) -> Result<()> {
    if !dir.is_dir() {
        return Err(Error::input(dir, "not a folder"));
    }
    let found = crate::store::status::status(dir)?;
    if found.is_empty() {
        return Err(Error::input(
            dir,
            "no mrbp results here (no calibration, prediction, comparison or virtual campaign)",
        ));
    }
    print::status(&found);
    let bad = found.iter().filter(|f| !f.complete()).count();
    match bad {
        0 => Ok(()),
        _ => Err(Error::Usage(format!(
            "{bad} of {} folder(s) in {} not complete (see above)",
            found.len(),
            dir.display()
        ))),
    }
}

/// `mrbp study …`.
fn study(pipeline: &mut Pipeline, command: StudyCommand) -> Result<()> {
    use crate::study;
    match command {
        StudyCommand::Plan { dir, options } => {
            let (name, tasks) = options.plan(&dir)?;
            println!("planned study {name}: {} task(s) in {}", tasks.len(), dir.display());
            for note in options.notes() {
                eprintln!("{note}");
            }
            println!(
                "run them here with `mrbp study run {}`, or on a cluster (docs/studies.md)",
                dir.display()
            );
            Ok(())
        }
        StudyCommand::RunTask { dir, id } => {
            let (outcome, ran) = study::run_task(pipeline, &dir, &id)?;
            let when = if ran { "" } else { " (done before: skipped)" };
            let note = if outcome.message.is_empty() {
                String::new()
            } else {
                format!(": {}", outcome.message)
            };
            println!("task {id}: {}{when} in {:.1} s{note}", outcome.status, outcome.seconds);
            Ok(())
        }
        StudyCommand::Run { dir, jobs } => {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
            let jobs = jobs.unwrap_or(cores);
            study::run_local(&dir, jobs, (cores / jobs.max(1)).max(1), &|line: &str| {
                println!("{line}")
            })?;
            print::study(&study::collect(&dir)?, &dir);
            Ok(())
        }
        StudyCommand::Collect { dir } => {
            print::study(&study::collect(&dir)?, &dir);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_settings_file_beside_the_campaign_not_named_is_noted() {
        let dir = std::env::temp_dir().join(format!("mrbp-unread-settings-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let manifest = dir.join("campaign.toml");
        // no settings file beside: nothing to say
        assert_eq!(unread_settings(&manifest, None), None);
        let beside = dir.join(SETTINGS_BESIDE);
        std::fs::write(&beside, "[terms]\nforce_offset = true\n").unwrap();
        let note = unread_settings(&manifest, None).expect("a note");
        assert!(note.contains("the default settings"), "{note}");
        assert!(note.contains(&format!("--config {}", beside.display())), "{note}");
        // named, by the same path or another spelling of it: read, no note
        assert_eq!(unread_settings(&manifest, Some(&beside)), None);
        let spelt = dir.join(".").join(SETTINGS_BESIDE);
        assert_eq!(unread_settings(&manifest, Some(&spelt)), None);
        // another file named: the one beside is still not read
        let other = dir.join("other.toml");
        std::fs::write(&other, "").unwrap();
        let note = unread_settings(&manifest, Some(&other)).expect("a note");
        assert!(note.contains("another settings file"), "{note}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
