//! What the command line prints: each event of a stage, its tables from
//! [`crate::report::text`].

use crate::pipeline::Event;
use crate::report::text;

/// Prints what a pipeline stage did.
pub fn event(e: Event) {
    let (to_stderr, text) = render(e);
    show(to_stderr, &text);
}

/// What [`event`] prints: whether to standard error, and the text.
pub fn render(e: Event) -> (bool, String) {
    let out = |text: String| (false, text);
    match e {
        Event::Note(line) => (true, format!("{line}\n")),
        Event::Checked(campaign) => out(text::campaign(campaign)),
        Event::Identified(results) => out(text::identification(results)),
        Event::Calibrating { what, dir } => {
            out(format!("\ncalibrating {what} into {}\n", dir.display()))
        }
        Event::Calibrated { cal, alone: false } => out(text::calibration(cal)),
        Event::Calibrated { cal, alone: true } => out(text::calibration_alone(cal)),
        Event::Predicted { record, dir } => out(format!(
            "{}wrote bands.parquet, coverage.parquet and prediction.toml to {}\n",
            text::prediction(record),
            dir.display()
        )),
        Event::LeftOneOut { rows, seconds } => out(text::leave_one_out(rows, seconds)),
        Event::Consistency(parameters) => out(text::consistency(parameters)),
        Event::NewTestLeftOut { rows, seconds } => out(text::new_test_left_out(rows, seconds)),
        Event::Wrote(path) => out(format!("wrote {}\n", path.display())),
        Event::Said { to_stderr, text } => (to_stderr, text.to_string()),
    }
}

/// Prints text that [`render`] made.
pub fn show(to_stderr: bool, text: &str) {
    match to_stderr {
        true => eprint!("{text}"),
        false => print!("{text}"),
    }
}

/// The reports a whole job wrote, and its wall time.
pub fn reports(reports: &[std::path::PathBuf], clock: std::time::Instant) {
    println!("\nreports:");
    for r in reports {
        println!("  {}", r.display());
    }
    println!("whole job: {:.0} s", clock.elapsed().as_secs_f64());
}

/// What collecting a study found, and the coverage of its known truths.
/// The state of results folders (`mrbp status`).
pub fn status(found: &[crate::store::status::FolderStatus]) {
    for f in found {
        let state = match (&f.writer, f.problems.is_empty()) {
            (Some(pid), _) => format!("being written (process {pid})"),
            (None, true) => "complete".to_string(),
            (None, false) => "NOT COMPLETE".to_string(),
        };
        println!("{:<12} {:<22} {}", f.kind.label(), state, f.dir.display());
        for p in &f.problems {
            println!("    {p}");
        }
    }
}

pub fn study(found: &crate::study::Collected, dir: &std::path::Path) {
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
        println!(
            "{:<22} {:>6} {:>8} {:>8} {:>8} {:>7} {:>8}",
            "coordinate", "tasks", "in 50 %", "in 90 %", "mean z", "sd z", "rank p"
        );
        for r in &found.coverage {
            println!(
                "{:<22} {:>6} {:>7.0}% {:>7.0}% {:>8.2} {:>7.2} {:>8.3}",
                r.parameter,
                r.tasks,
                100.0 * r.inside_50,
                100.0 * r.inside_90,
                r.z_mean,
                r.z_sd,
                r.rank_p
            );
        }
    }
}
