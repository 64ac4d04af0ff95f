//! Studies: a plan of independent calibrations, run here (`mrbp study run`)
//! and on a loopback Dask cluster that loses a worker mid-study
//! (scripts/dask_loopback_check.py), with the same results.

use std::path::Path;
use std::process::Command;

use crate::common::{mrbp, said, slow_tier};

use mrbp::store::{column_names, f64_column, read_parquet, str_column};

/// Eight short replicate calibrations (one run, 1 kHz, fixed 150 steps).
fn plan(dir: &Path) {
    let o = mrbp(&[
        "study",
        "plan",
        dir.to_str().unwrap(),
        "--replicates",
        "8",
        "--cycles",
        "1",
        "--rate",
        "1000",
        "--rpm",
        "200",
        "--steps",
        "150",
    ]);
    assert!(o.status.success(), "{}", said(&o));
}

#[test]
fn a_study_runs_here_once_per_task_and_collects_one_dataset() {
    let root = tempfile::tempdir().unwrap();
    let local = root.path().join("local");
    plan(&local);
    // planning twice into one folder is refused
    let o = mrbp(&["study", "plan", local.to_str().unwrap(), "--replicates", "2"]);
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    assert!(said(&o).contains("already holds a study"));

    let o = mrbp(&["study", "run", local.to_str().unwrap(), "--jobs", "2"]);
    assert!(o.status.success(), "{}", said(&o));
    assert!(said(&o).contains("collected 8 of 8"), "{}", said(&o));

    // a finished task is skipped, its result untouched
    let result = local.join("tasks/t003/result.parquet");
    let before = std::fs::read(&result).unwrap();
    let o = mrbp(&["study", "run-task", local.to_str().unwrap(), "t003"]);
    assert!(o.status.success() && said(&o).contains("skipped"), "{}", said(&o));
    assert_eq!(before, std::fs::read(&result).unwrap());

    // one partition per task, one row per coordinate, the truth beside it
    for k in 0..8 {
        let part = local.join(format!("collected/results/study=local/task=t00{k}/part-0.parquet"));
        let df = read_parquet(&part).unwrap();
        let names = column_names(&df);
        for c in [
            "parameter", "mean", "sd", "truth", "z", "inside_50", "inside_90", "rank",
            "rank_draws", "seed", "seconds", "steps", "warnings",
        ] {
            assert!(names.contains(&c.to_string()), "{c} missing: {names:?}");
        }
        let params = str_column(&df, "parameter", &part).unwrap();
        let truth = f64_column(&df, "truth", &part).unwrap();
        let g = params.iter().position(|p| p == "G").unwrap();
        assert_eq!(truth[g], 2.0e5, "the reference G is the truth of a replicate");
        // each task's own sampler seed: task k uses 1 + k
        assert_eq!(f64_column(&df, "seed", &part).unwrap()[0], 1.0 + k as f64);
    }
    let tasks = read_parquet(&local.join("collected/tasks.parquet")).unwrap();
    let status = str_column(&tasks, "status", &local).unwrap();
    assert_eq!(status, vec!["ok".to_string(); 8]);

    // the same plan on a loopback Dask cluster that loses a worker
    if !slow_tier("the study on a loopback Dask cluster") {
        return;
    }
    let cluster = root.path().join("cluster");
    plan(&cluster);
    let mrbp_path = Path::new(env!("CARGO_BIN_EXE_mrbp"));
    crate::common::python_check(
        "dask_loopback_check.py",
        &[mrbp_path, &local, &cluster],
        "dask.distributed, pandas, pyarrow",
        "MRBP_DASK_CHECK",
    );
}

/// A replicate study of another damper law (`--law`): its records are the
/// law's, the truth beside each result is the law's parameter at the
/// task's current (Bingham's typical c0, fc, v0 at 1 A, from `synth`'s
/// own `synth.toml`, not from the study's code), and SBC, which draws the
/// B-P parameters from their prior, is refused for it.
#[test]
fn a_replicate_study_of_another_law_holds_that_laws_truth() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("bingham");
    let args = ["--cycles", "1", "--rate", "1000", "--rpm", "200", "--steps", "60"];
    let mut plan =
        vec!["study", "plan", dir.to_str().unwrap(), "--replicates", "2", "--law", "bingham"];
    plan.extend(args);
    let o = mrbp(&plan);
    assert!(o.status.success(), "{}", said(&o));
    let o = mrbp(&["study", "run", dir.to_str().unwrap(), "--jobs", "2"]);
    assert!(o.status.success(), "{}", said(&o));
    // the law's truth as `synth --law bingham` writes it
    let synth = root.path().join("synth");
    let o = mrbp(&["synth", "--out", synth.to_str().unwrap(), "--law", "bingham"]);
    assert!(o.status.success(), "{}", said(&o));
    let written: toml::Table =
        std::fs::read_to_string(synth.join("synth.toml")).unwrap().parse().unwrap();
    let at_1a = written["damper"]["at_1a"].as_table().unwrap();
    let part = dir.join("collected/results/study=bingham/task=t000/part-0.parquet");
    let df = read_parquet(&part).unwrap();
    let params = str_column(&df, "parameter", &part).unwrap();
    let truth = f64_column(&df, "truth", &part).unwrap();
    for name in ["c0", "fc", "v0"] {
        let i =
            params.iter().position(|p| p == name).unwrap_or_else(|| panic!("{name}: {params:?}"));
        assert_eq!(truth[i], at_1a[name].as_float().unwrap(), "{name}");
    }
    assert!(!params.iter().any(|p| p == "G"), "no B-P parameter in a Bingham study: {params:?}");
}

/// SBC of another law draws that law's parameters from its prior: at 0.5 A
/// each task's truth is its own draw (every parameter different between
/// tasks, inside the law's physical range), and the stand's damper gives
/// that truth at 0.5 A: its forces and dashpots at 1 A are the truth over
/// tanh(0.5/I_s)/tanh(1/I_s), its other parameters the truth itself. A
/// replicate study of a law named only by the settings file makes that
/// law's records.
#[test]
fn sbc_of_another_law_draws_that_laws_parameters() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("sbc");
    let o = mrbp(&[
        "study",
        "plan",
        dir.to_str().unwrap(),
        "--sbc",
        "3",
        "--law",
        "bp-spencer",
        "--current",
        "0.5",
    ]);
    assert!(o.status.success(), "{}", said(&o));
    // drawn from the default priors: said, with the way to a realistic box
    assert!(said(&o).contains("here the defaults (no --config)"), "{}", said(&o));
    let law = mrbp::laws::LawKind::BpSpencer.law();
    let mut seen: Vec<Vec<f64>> = Vec::new();
    for k in 0..3 {
        let spec = task_spec(&dir, &format!("t00{k}"));
        let synth = &spec["source"]["synth"];
        let is = synth["law"]["saturation_a"].as_float().unwrap();
        let scale = (0.5 / is).tanh() / (1.0 / is).tanh();
        assert_eq!(synth["damper"]["law"].as_str(), Some("bp-spencer"));
        let at_1a = synth["damper"]["at_1a"].as_table().unwrap();
        let mut truths = Vec::new();
        for p in law.parameters() {
            let truth = spec["truth"][p.name].as_float().unwrap();
            let stand = at_1a[p.name].as_float().unwrap();
            let follows = p.unit == "N" || p.unit == "N s/m";
            let expected = if follows { stand * scale } else { stand };
            assert!(
                (truth / expected - 1.0).abs() < 1e-12,
                "{}: truth {truth}, stand {expected}",
                p.name
            );
            assert!(
                p.range.0 <= truth && truth <= p.range.1,
                "{}: {truth} outside {:?}",
                p.name,
                p.range
            );
            truths.push(truth);
        }
        for earlier in &seen {
            for (i, (a, b)) in earlier.iter().zip(&truths).enumerate() {
                assert_ne!(a, b, "{} drawn once for two tasks", law.parameters()[i].name);
            }
        }
        seen.push(truths);
    }
    // the law named only by the settings file makes the records too
    let rep = root.path().join("rep");
    let config = format!("{}/studies/sbc-prior-bp-spencer.toml", env!("CARGO_MANIFEST_DIR"));
    let o =
        mrbp(&["study", "plan", rep.to_str().unwrap(), "--replicates", "1", "--config", &config]);
    assert!(o.status.success(), "{}", said(&o));
    assert!(!said(&o).contains("here the defaults"), "{}", said(&o));
    let spec = task_spec(&rep, "t000");
    assert_eq!(spec["source"]["synth"]["damper"]["law"].as_str(), Some("bp-spencer"));
    assert!(spec["truth"].get("c0").is_some(), "{}", spec["truth"]);
}

#[test]
fn study_commands_refuse_what_is_not_a_study() {
    let empty = tempfile::tempdir().unwrap();
    for args in [
        vec!["study", "run-task", empty.path().to_str().unwrap(), "t000"],
        vec!["study", "collect", empty.path().to_str().unwrap()],
    ] {
        let o = mrbp(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", said(&o));
        assert!(said(&o).contains("mrbp study plan"), "{}", said(&o));
    }
    let o = mrbp(&[
        "study",
        "plan",
        empty.path().join("s").to_str().unwrap(),
        "--replicates",
        "2",
        "--resume",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
    // --seed is the sampler's, --noise-seed the stand's, each + k for task k
    let seeded = empty.path().join("seeded");
    let o = mrbp(&[
        "study",
        "plan",
        seeded.to_str().unwrap(),
        "--replicates",
        "2",
        "--seed",
        "10",
        "--noise-seed",
        "500",
    ]);
    assert!(o.status.success(), "{}", said(&o));
    let task = std::fs::read_to_string(seeded.join("tasks/t001/task.toml")).unwrap();
    assert!(task.contains("seed = 11\n") && task.contains("seed = 501\n"), "{task}");
    // a design is required
    let o = mrbp(&["study", "plan", empty.path().join("t").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
}

/// scripts/slurm_study.sh runs the task of its array index (no Slurm here:
/// the variables a job array sets, set by hand).
#[test]
fn the_slurm_array_script_runs_the_task_of_its_index() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("s");
    let o = mrbp(&[
        "study",
        "plan",
        dir.to_str().unwrap(),
        "--replicates",
        "2",
        "--cycles",
        "1",
        "--rate",
        "1000",
        "--rpm",
        "200",
        "--steps",
        "60",
    ]);
    assert!(o.status.success(), "{}", said(&o));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm_study.sh");
    let element = |index: &str| {
        Command::new("bash")
            .arg(&script)
            .arg(&dir)
            .env("SLURM_ARRAY_TASK_ID", index)
            .env("SLURM_CPUS_PER_TASK", "1")
            .env("MRBP", env!("CARGO_BIN_EXE_mrbp"))
            .output()
            .unwrap()
    };
    let o = element("2");
    assert!(o.status.success(), "{}", said(&o));
    assert!(
        dir.join("tasks/t001/status.toml").exists() && !dir.join("tasks/t000/status.toml").exists()
    );
    let o = element("3");
    assert_eq!(o.status.code(), Some(2), "{}", said(&o));
}

/// SBC with the discrepancy model draws every run's discrepancy from its
/// prior: the stand's smooth force per crank speed (scale in N = σ_δ ×
/// area, time scale within [2 Δt, ¼ period]) and the truths of
/// discrepancy_sd_<run> and discrepancy_time_<run> beside θ and σ.
#[test]
fn sbc_with_the_discrepancy_model_draws_each_runs_discrepancy() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("sbc");
    let o = mrbp(&[
        "study",
        "plan",
        dir.to_str().unwrap(),
        "--sbc",
        "4",
        "--noise",
        "discrepancy",
        "--rpm",
        "100,400",
        "--rate",
        "1000",
    ]);
    assert!(o.status.success(), "{}", said(&o));
    let mut times = Vec::new();
    for k in 0..4 {
        let spec = task_spec(&dir, &format!("t00{k}"));
        let synth = &spec["source"]["synth"];
        let area = synth["geometry"]["area_m2"].as_float().unwrap();
        let extra = &synth["extra_force"];
        let sd: Vec<f64> = extra["smooth_sd_n"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_float().unwrap())
            .collect();
        let ell: Vec<f64> = extra["smooth_time_s"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_float().unwrap())
            .collect();
        assert_eq!((sd.len(), ell.len()), (2, 2));
        assert_eq!(extra["viscous_n_s_per_m"].as_float(), Some(0.0));
        for (i, rpm) in [100.0, 400.0].iter().enumerate() {
            let run = format!("I1.0_{rpm:.0}rpm");
            let truth = &spec["truth"];
            assert_eq!(truth[&format!("discrepancy_sd_{run}")].as_float().unwrap(), sd[i] / area);
            assert_eq!(truth[&format!("discrepancy_time_{run}")].as_float().unwrap(), ell[i]);
            assert!((1.0..=1e6).contains(&(sd[i] / area)), "σ_δ {}", sd[i] / area);
            assert!(ell[i] >= 2e-3 && ell[i] <= 0.25 * 60.0 / rpm, "ℓ {} at {rpm} rpm", ell[i]);
            times.push(ell[i]);
        }
    }
    // drawn, not one value copied
    times.sort_by(f64::total_cmp);
    times.dedup();
    assert_eq!(times.len(), 8);
}

/// The task.toml of task `id` of the study in `dir`.
fn task_spec(dir: &std::path::Path, id: &str) -> toml::Value {
    toml::from_str(&std::fs::read_to_string(dir.join("tasks").join(id).join("task.toml")).unwrap())
        .unwrap()
}
