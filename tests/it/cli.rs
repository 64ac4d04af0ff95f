//! The command line as a user meets it: exit status and one-line messages
//! for bad input, and the bundled campaign.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::mrbp;

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Twelve samples of a stroke out and back: the smallest record accepted.
const GOOD_CSV: &str = "time_s,displacement_m,force_n\n0,0,0\n0.001,0.0001,10\n0.002,0.0002,20\n0.003,0.0003,30\n0.004,0.0004,35\n0.005,0.0005,38\n\
                        0.006,0.0004,10\n0.007,0.0003,-20\n0.008,0.0002,-30\n0.009,0.0001,-35\n0.010,0,-38\n0.011,-0.0001,-39\n";

/// A campaign folder with one run whose data file is `csv`, and a manifest
/// with `geometry` and `extra` manifest text.
fn campaign(csv: Option<&str>, geometry: &str, extra: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    if let Some(csv) = csv {
        std::fs::write(dir.path().join("run1.csv"), csv).unwrap();
    }
    let manifest = dir.path().join("campaign.toml");
    std::fs::write(
        &manifest,
        format!(
            "name = \"t\"\n[geometry]\n{geometry}\n\n[[run]]\nid = \"r1\"\nfile = \"run1.csv\"\ncurrent_a = 1.0\n{extra}"
        ),
    )
    .unwrap();
    (dir, manifest)
}

const GEOMETRY: &str = "area_m2 = 0.05\ngap_m = 0.001";

/// `mrbp check` fails with status 2 and a single line naming `file` (and
/// any other `parts`).
fn assert_bad_input(manifest: &Path, file: &str, parts: &[&str]) {
    let o = mrbp(&["check", manifest.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(err.contains(file), "names {file}: {err}");
    for p in parts {
        assert!(err.contains(p), "mentions {p}: {err}");
    }
}

#[test]
fn good_campaign_checks() {
    let (_d, m) = campaign(Some(GOOD_CSV), GEOMETRY, "");
    let o = mrbp(&["check", m.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("r1") && out.contains("12"), "{out}");
}

#[test]
fn parquet_records_are_read_and_checked() {
    use mrbp::store::{write_parquet, Table};
    let dir = tempfile::tempdir().unwrap();
    let t: Vec<f64> = (0..12).map(|k| 0.1 * k as f64).collect();
    let x: Vec<f64> = t.iter().map(|t| 1e-3 * (2.0 * t).sin()).collect();
    let f: Vec<f64> = x.iter().map(|x| 1e5 * x).collect();
    let good = Table::new()
        .f64("time_s", t.clone())
        .f64("displacement_m", x.clone())
        .f64("force_n", f.clone());
    write_parquet(&dir.path().join("run1.parquet"), good).unwrap();
    let manifest = dir.path().join("campaign.toml");
    std::fs::write(
        &manifest,
        format!("name = \"p\"\n[geometry]\n{GEOMETRY}\n[[run]]\nid = \"r1\"\nfile = \"run1.parquet\"\ncurrent_a = 1.0\n"),
    )
    .unwrap();
    let o = mrbp(&["check", manifest.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));

    let mut x_nan = x;
    x_nan[1] = f64::NAN;
    let bad = Table::new().f64("time_s", t).f64("displacement_m", x_nan).f64("force_n", f);
    write_parquet(&dir.path().join("run1.parquet"), bad).unwrap();
    assert_bad_input(&manifest, "run1.parquet", &["row 2", "column 'displacement_m'"]);
}

#[test]
fn column_names_and_units_are_configurable() {
    let dir = tempfile::tempdir().unwrap();
    let rows: String = (0..12)
        .map(|k| format!("{k},{},{}\n", 0.1 * (6 - (k - 6i32).abs()) as f64, 0.01 * k as f64))
        .collect();
    std::fs::write(dir.path().join("r.csv"), format!("t_ms,x_mm,F_kN\n{rows}")).unwrap();
    let manifest = dir.path().join("c.toml");
    std::fs::write(
        &manifest,
        format!(
            "name = \"u\"\n[geometry]\n{GEOMETRY}\n[columns]\ntime = \"t_ms\"\ntime_scale = 0.001\n\
             displacement = \"x_mm\"\ndisplacement_scale = 0.001\nforce = \"F_kN\"\nforce_scale = 1000.0\n\
             [[run]]\nid = \"r\"\nfile = \"r.csv\"\ncurrent_a = 1.0\n"
        ),
    )
    .unwrap();
    let c = mrbp::data::Campaign::load(&manifest).unwrap();
    let rec = &c.runs[0].record;
    assert_eq!(rec.time[..3], [0.0, 0.001, 0.002]);
    assert!((rec.displacement[2] - 2e-4).abs() < 1e-15);
    assert!((rec.force[2] - 20.0).abs() < 1e-12);
    assert!((c.runs[0].shear.tau[2] - 400.0).abs() < 1e-9);
}

#[test]
fn bundled_campaign_is_reproduced_bit_for_bit_by_synth() {
    let dir = tempfile::tempdir().unwrap();
    let o = mrbp(&["synth", "--out", dir.path().to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let data = repo().join("data");
    let mut compared = 0;
    for entry in std::fs::read_dir(&data).unwrap() {
        let path = entry.unwrap().path();
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if ext == "csv" || ext == "toml" {
            let name = path.file_name().unwrap();
            let made = std::fs::read(dir.path().join(name)).unwrap();
            assert!(made == std::fs::read(&path).unwrap(), "{name:?} differs");
            compared += 1;
        }
    }
    assert_eq!(compared, 11, "9 records, campaign.toml, synth.toml");
}

#[test]
fn bundled_campaign_checks_with_four_branches_per_run() {
    let o = mrbp(&["check", repo().join("data/campaign.toml").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let rows: Vec<&str> = out.lines().filter(|l| l.starts_with('I')).collect();
    assert_eq!(rows.len(), 9, "{out}");
    // two crank revolutions: up, down, up, down
    assert!(rows.iter().all(|r| r.trim_end().ends_with(" 4")), "{out}");
}

#[test]
fn usage_errors_exit_2() {
    let o = mrbp(&["sample"]);
    assert_eq!(o.status.code(), Some(2));
    let o = mrbp(&["--no-such-flag"]);
    assert_eq!(o.status.code(), Some(2));
}

/// `mrbp` alone outside the project folder prints the help, not a job.
#[test]
fn bare_command_outside_the_project_prints_help() {
    let dir = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_mrbp")).current_dir(dir.path()).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stdout).contains("Usage"), "help printed");
    assert!(stderr(&o).contains("data/campaign.toml"), "{}", stderr(&o));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "nothing written");
}

/// Every option of every command has a distinct id and a valid shape.
#[test]
fn command_line_is_well_formed() {
    use clap::CommandFactory;
    mrbp::cli::Cli::command().debug_assert();
}

/// No command has two options of one name (flattened option groups share
/// ids silently: `study plan` once had two `--seed`).
#[test]
fn no_command_has_an_option_twice() {
    use clap::CommandFactory;
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
    let mut cli = mrbp::cli::Cli::command();
    cli.build();
    check(&cli, "mrbp");
}
