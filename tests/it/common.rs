//! What the test files share: running the command line, the small virtual
//! campaigns they calibrate, and the checks that run only where their
//! tools are (Python, a browser) or only in the slow tier.

#![allow(dead_code)] // each test file uses its own part of this module

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use mrbp::data::Campaign;
use mrbp::synth::{write_campaign, ExtraForce, SynthSettings};

/// Runs the `mrbp` binary of this build with `args`.
pub fn mrbp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mrbp")).args(args).output().expect("run mrbp")
}

/// Runs the `mrbp` binary in `dir`.
pub fn mrbp_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mrbp")).current_dir(dir).args(args).output().expect("run mrbp")
}

/// Everything a command said, standard output then standard error.
pub fn said(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// `mrbp args`, which must succeed; its output.
pub fn ok(args: &[&str]) -> Output {
    let o = mrbp(args);
    assert!(o.status.success(), "mrbp {}:\n{}", args.join(" "), said(&o));
    o
}

/// A path as a command-line argument.
pub fn arg(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 path")
}

/// Says on the terminal, past the test harness's capture, that `what` was
/// skipped and why: a skipped check is never silent.
pub fn skipped(what: &str, why: &str) {
    let _ = writeln!(std::io::stderr(), "skipped: {what} ({why})");
}

/// Whether the slow tier runs (`cargo test --release -- --include-ignored`,
/// or `-- --ignored`): a fast test does its slow part only then, and says
/// so otherwise.
pub fn slow_tier(what: &str) -> bool {
    let on = std::env::args().any(|a| a == "--include-ignored" || a == "--ignored");
    if !on {
        skipped(what, "slow tier: cargo test --release -- --include-ignored");
    }
    on
}

/// One crank revolution per crank speed (100, 200, 400 rpm) at 2 kHz and
/// 1 A, force noise as in the bundled records: small enough to calibrate
/// in a test, large enough to identify every parameter.
pub fn one_revolution() -> SynthSettings {
    SynthSettings {
        currents_a: vec![1.0],
        cycles: 1.0,
        rate_hz: 2000.0,
        ..SynthSettings::default()
    }
}

/// `settings` with a smooth random force of `newtons` (20 ms time scale)
/// that the law does not have: residuals with memory.
pub fn with_smooth_force(settings: SynthSettings, newtons: f64) -> SynthSettings {
    SynthSettings {
        extra_force: ExtraForce {
            smooth_sd_n: vec![newtons],
            smooth_time_s: vec![0.02],
            ..ExtraForce::default()
        },
        ..settings
    }
}

/// The virtual campaign of `settings` written into `dir`; its manifest.
pub fn write_virtual(settings: &SynthSettings, dir: &Path) -> PathBuf {
    write_campaign(settings, dir).unwrap();
    dir.join("campaign.toml")
}

/// The virtual campaign of `settings` in a folder of its own, loaded.
pub fn virtual_campaign(settings: &SynthSettings) -> (tempfile::TempDir, Campaign) {
    let dir = tempfile::tempdir().unwrap();
    let manifest = write_virtual(settings, dir.path());
    let campaign = Campaign::load(&manifest).unwrap();
    (dir, campaign)
}

/// `mrbp synth` of a small campaign into `dir/data` (crank at 200 rpm, one
/// revolution at 400 Hz, at each of `currents`, e.g. "0.5,1.0"); its
/// manifest.
pub fn synth_small(dir: &Path, currents: &str) -> PathBuf {
    synth_runs(dir, currents, "200")
}

/// As [`synth_small`], a run for each crank speed of `rpms` (comma
/// separated) at each current: the smallest campaign a leave-one-out
/// holds a run out of.
pub fn synth_runs(dir: &Path, currents: &str, rpms: &str) -> PathBuf {
    let data = dir.join("data");
    ok(&[
        "synth",
        "--out",
        arg(&data),
        "--currents",
        currents,
        "--rpm",
        rpms,
        "--cycles",
        "1",
        "--rate",
        "400",
    ]);
    data.join("campaign.toml")
}

/// Runs `scripts/<script>` with `args` under the Python of `MRBP_PYTHON`
/// (default `python3`) when it can import `imports`; panics with the
/// script's output if it fails. Without those packages the check is
/// skipped with a line on the terminal, unless the environment variable
/// `required` is 1 (CI sets it), which makes their absence a failure.
pub fn python_check(script: &str, args: &[&Path], imports: &str, required: &str) {
    let Some(python) = python_with(imports, script, required) else { return };
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts").join(script);
    let o = Command::new(&python).arg(&path).args(args).output().expect("run python");
    assert!(o.status.success(), "{script} failed:\n{}", said(&o));
    eprintln!("{}", said(&o));
}

/// `MRBP_PYTHON` (or `python3`) if it imports `modules`; `None`, with a
/// line saying that `what` was skipped, where it does not and the
/// environment variable `required` is not 1.
pub fn python_with(modules: &str, what: &str, required: &str) -> Option<String> {
    let must = std::env::var(required).is_ok_and(|v| v == "1");
    let python = std::env::var("MRBP_PYTHON").unwrap_or_else(|_| "python3".into());
    let ready = Command::new(&python)
        .args(["-c", &format!("import {modules}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ready {
        assert!(
            !must,
            "{required}=1 but {python} cannot import {modules} \
             (pip install ./python; scripts/requirements-checks.txt)"
        );
        skipped(
            what,
            &format!("{python} cannot import {modules}; {required}=1 makes it a failure"),
        );
        return None;
    }
    Some(python)
}
