//! Ctrl-C during sampling: the step ends, a checkpoint is saved, the exit
//! status is 130 and the message says how to resume; resuming checks the
//! options against the checkpoint before any work and then gives the chains
//! of an uninterrupted run. A re-calibration into a folder with --force
//! removes the files derived from the old chains.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{mrbp_in, said};
use mrbp::store::read_parquet;

#[test]
#[ignore = "slow tier: Ctrl-C during sampling, then resumed"]
fn interrupted_sampling_saves_a_checkpoint_and_resumes_to_the_same_chains() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path();
    let o = mrbp_in(
        dir,
        &["synth", "--out", "data", "--currents", "1.0", "--rate", "2000", "--cycles", "1"],
    );
    assert!(o.status.success(), "{}", said(&o));

    // a run far longer than the test waits, interrupted while it samples
    let child = Command::new(env!("CARGO_BIN_EXE_mrbp"))
        .current_dir(dir)
        .args([
            "sample", "data/campaign.toml", "--out", "cal", "--steps", "100000", "--substeps", "1",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // sampling has begun once the folder exists and the MAP is done; a
    // signal during the MAP is honoured at the first step as well
    let clock = Instant::now();
    while !dir.join("cal").exists() && clock.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_secs(3));
    let status = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "{}", said(&out));
    assert!(said(&out).contains("--resume"), "{}", said(&out));
    assert!(dir.join("cal/sampler.checkpoint").exists());
    assert!(!dir.join("cal/chains.parquet").exists(), "no results from a half run");
    // `status` names the checkpoint and how to go on; the same command
    // without --resume or --force does not drop it
    let o = mrbp_in(dir, &["status", "cal"]);
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    assert!(said(&o).contains("sampler.checkpoint: the chains of an interrupted"), "{}", said(&o));
    let o = mrbp_in(dir, &["sample", "data/campaign.toml", "--out", "cal", "--substeps", "1"]);
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    assert!(dir.join("cal/sampler.checkpoint").exists());

    // options that do not match the checkpoint are refused at once
    let o = mrbp_in(
        dir,
        &[
            "sample", "data/campaign.toml", "--out", "cal", "--steps", "100000", "--substeps", "1",
            "--resume", "--seed", "7",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    assert!(said(&o).contains("--seed"), "{}", said(&o));
    let o = mrbp_in(
        dir,
        &[
            "sample", "data/campaign.toml", "--out", "cal", "--steps", "1", "--substeps", "1",
            "--resume",
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    assert!(said(&o).contains("fewer than"), "{}", said(&o));

    // resumed to a fixed length, the chains are those of a run never stopped
    let done = read_steps(&dir.join("cal/sampler.checkpoint"));
    let steps = (done + 5).to_string();
    let o = mrbp_in(
        dir,
        &[
            "sample", "data/campaign.toml", "--out", "cal", "--steps", &steps, "--substeps", "1",
            "--resume",
        ],
    );
    assert!(o.status.success(), "{}", said(&o));
    let o = mrbp_in(
        dir,
        &["sample", "data/campaign.toml", "--out", "whole", "--steps", &steps, "--substeps", "1"],
    );
    assert!(o.status.success(), "{}", said(&o));
    let resumed = read_parquet(&dir.join("cal/chains.parquet")).unwrap();
    let whole = read_parquet(&dir.join("whole/chains.parquet")).unwrap();
    assert!(resumed.equals(&whole), "resumed chains differ from an uninterrupted run");

    // a new calibration into the folder: refused without --force; with it,
    // the bands of the old one are gone
    let o = mrbp_in(dir, &["predict", "whole", "--draws", "50"]);
    assert!(o.status.success(), "{}", said(&o));
    assert!(dir.join("whole/bands.parquet").exists());
    let o = mrbp_in(
        dir,
        &["sample", "data/campaign.toml", "--out", "whole", "--steps", "20", "--substeps", "1"],
    );
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    let o = mrbp_in(
        dir,
        &[
            "sample", "data/campaign.toml", "--out", "whole", "--steps", "20", "--substeps", "1",
            "--force",
        ],
    );
    assert!(o.status.success(), "{}", said(&o));
    for stale in ["bands.parquet", "coverage.parquet", "prediction.toml", "adequacy.parquet"] {
        assert!(!dir.join("whole").join(stale).exists(), "{stale} of the old chains survived");
    }
}

/// Steps taken in a checkpoint (the draws after the initial state).
fn read_steps(path: &Path) -> usize {
    let (_, chains) = mrbp::sampler::checkpoint::read(path).unwrap();
    chains.steps() - 1
}

/// `run --resume` after a job that finished (or a long study stopped
/// between calibrations) keeps each calibration that is complete and of the
/// settings asked for, and calibrates afresh where the settings differ.
#[test]
fn resume_keeps_finished_calibrations_of_the_same_settings() {
    use crate::common::{arg, ok, synth_small};
    let dir = tempfile::tempdir().unwrap();
    let manifest = synth_small(dir.path(), "0.5,1.0");
    let out = dir.path().join("out");
    let id = |c: &str| {
        let record = std::fs::read_to_string(out.join(c).join("calibration.toml")).unwrap();
        let record: toml::Value = toml::from_str(&record).unwrap();
        record["calibration_id"].as_str().unwrap().to_string()
    };
    ok(&["run", arg(&manifest), "--out", arg(&out)]);
    let before = (id("I0.5A"), id("I1.0A"));
    let o = ok(&["run", arg(&manifest), "--out", arg(&out), "--resume"]);
    assert_eq!(said(&o).matches("already holds this calibration, complete: kept").count(), 2);
    assert!(!said(&o).contains("calibrating 1 run(s)"), "{}", said(&o));
    assert_eq!((id("I0.5A"), id("I1.0A")), before, "kept calibrations keep their ids");
    // the reports and the comparison are made again from them
    assert!(out.join("comparison/report.html").exists());
    let o = ok(&["run", arg(&manifest), "--out", arg(&out), "--resume", "--seed", "2"]);
    assert_eq!(said(&o).matches("other runs or settings: calibrating afresh").count(), 2);
    assert_ne!(id("I0.5A"), before.0);
    assert_ne!(id("I1.0A"), before.1);
}

/// `run --leave-one-out --resume` keeps a finished leave-one-out study of
/// the kept calibration made with the same settings (the held-out studies
/// of a long laws study are its dearest part); with other settings
/// (`--loo-steps`) it is made again.
#[test]
fn resume_keeps_a_finished_leave_one_out_of_the_same_settings() {
    use crate::common::{arg, ok};
    let dir = tempfile::tempdir().unwrap();
    let manifest = crate::common::synth_runs(dir.path(), "1.0", "100,200");
    let out = dir.path().join("out");
    let loo = out.join("I1.0A").join("loo.parquet");
    let run = |extra: &[&str]| {
        let mut args = vec!["run", arg(&manifest), "--out", arg(&out), "--leave-one-out"];
        args.extend_from_slice(extra);
        said(&ok(&args))
    };
    run(&[]);
    let first = std::fs::read(&loo).unwrap();
    let kept = "leave-one-out, made with the same settings: kept";
    let printed = run(&["--resume"]);
    assert!(printed.contains(kept), "{printed}");
    assert_eq!(std::fs::read(&loo).unwrap(), first, "the study is the one made before");
    let printed = run(&["--resume", "--loo-steps", "300"]);
    assert!(!printed.contains(kept), "{printed}");
    assert!(printed.contains("already holds this calibration, complete: kept"), "{printed}");
    let again = mrbp::store::parquet::parquet_meta(&loo, mrbp::store::coverage::LOO_SETTINGS);
    assert!(again.unwrap().unwrap().starts_with("steps=300,"));
}
