//! The command line as a user meets it: exit status and one-line messages
//! for bad input, and the bundled campaign.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn mrbp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mrbp"))
        .args(args)
        .output()
        .expect("run mrbp")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

const GOOD_CSV: &str = "time_s,displacement_m,force_n\n0,0,0\n0.001,0.0001,10\n0.002,0.0002,20\n0.003,0.0003,30\n";

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
    assert!(out.contains("r1") && out.contains("4"), "{out}");
}

#[test]
fn missing_manifest() {
    let dir = tempfile::tempdir().unwrap();
    assert_bad_input(&dir.path().join("nope.toml"), "nope.toml", &["not found"]);
}

#[test]
fn missing_data_file() {
    let (_d, m) = campaign(None, GEOMETRY, "");
    assert_bad_input(&m, "run1.csv", &["not found"]);
}

#[test]
fn missing_column() {
    let (_d, m) = campaign(Some("time_s,displacement_m\n0,0\n1,1\n"), GEOMETRY, "");
    assert_bad_input(&m, "run1.csv", &["column 'force_n'"]);
}

#[test]
fn text_in_a_number() {
    let csv = "time_s,displacement_m,force_n\n0,0,0\n0.001,abc,10\n";
    let (_d, m) = campaign(Some(csv), GEOMETRY, "");
    assert_bad_input(&m, "run1.csv", &["row 2", "column 'displacement_m'", "'abc'"]);
}

#[test]
fn nan_in_a_number() {
    let csv = "time_s,displacement_m,force_n\n0,0,0\n0.001,0,NaN\n0.002,0,1\n";
    let (_d, m) = campaign(Some(csv), GEOMETRY, "");
    assert_bad_input(&m, "run1.csv", &["row 2", "column 'force_n'", "finite"]);
}

#[test]
fn non_increasing_time() {
    let csv = "time_s,displacement_m,force_n\n0,0,0\n0.001,0,1\n0.001,0,2\n";
    let (_d, m) = campaign(Some(csv), GEOMETRY, "");
    assert_bad_input(&m, "run1.csv", &["row 3", "column 'time_s'", "does not increase"]);
}

#[test]
fn empty_record() {
    let (_d, m) = campaign(Some("time_s,displacement_m,force_n\n"), GEOMETRY, "");
    assert_bad_input(&m, "run1.csv", &["0 data rows"]);
}

#[test]
fn duplicate_run_id() {
    let extra = "\n[[run]]\nid = \"r1\"\nfile = \"run1.csv\"\ncurrent_a = 0.5\n";
    let (_d, m) = campaign(Some(GOOD_CSV), GEOMETRY, extra);
    assert_bad_input(&m, "campaign.toml", &["duplicate run id 'r1'"]);
}

#[test]
fn non_positive_geometry() {
    let (_d, m) = campaign(Some(GOOD_CSV), "area_m2 = 0.0\ngap_m = 0.001", "");
    assert_bad_input(&m, "campaign.toml", &["area_m2", "positive"]);
    let (_d, m) = campaign(Some(GOOD_CSV), "area_m2 = 0.05\ngap_m = -1e-3", "");
    assert_bad_input(&m, "campaign.toml", &["gap_m", "positive"]);
}

#[test]
fn malformed_manifest() {
    let (_d, m) = campaign(Some(GOOD_CSV), "area_m2 = \"big\"\ngap_m = 0.001", "");
    assert_bad_input(&m, "campaign.toml", &["invalid manifest"]);
}

#[test]
fn parquet_records_are_read_and_checked() {
    use mrbp::store::{write_parquet, Table};
    let dir = tempfile::tempdir().unwrap();
    let good = Table::new()
        .f64("time_s", vec![0.0, 0.1, 0.2])
        .f64("displacement_m", vec![0.0, 1e-4, 2e-4])
        .f64("force_n", vec![0.0, 5.0, 10.0]);
    write_parquet(&dir.path().join("run1.parquet"), good).unwrap();
    let manifest = dir.path().join("campaign.toml");
    std::fs::write(
        &manifest,
        format!("name = \"p\"\n[geometry]\n{GEOMETRY}\n[[run]]\nid = \"r1\"\nfile = \"run1.parquet\"\ncurrent_a = 1.0\n"),
    )
    .unwrap();
    let o = mrbp(&["check", manifest.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));

    let bad = Table::new()
        .f64("time_s", vec![0.0, 0.1, 0.2])
        .f64("displacement_m", vec![0.0, f64::NAN, 2e-4])
        .f64("force_n", vec![0.0, 5.0, 10.0]);
    write_parquet(&dir.path().join("run1.parquet"), bad).unwrap();
    assert_bad_input(&manifest, "run1.parquet", &["row 2", "column 'displacement_m'"]);
}

#[test]
fn column_names_and_units_are_configurable() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("r.csv"), "t_ms,x_mm,F_kN\n0,0,0\n1,0.1,0.01\n2,0.2,0.02\n").unwrap();
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
    assert_eq!(rec.time, vec![0.0, 0.001, 0.002]);
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
