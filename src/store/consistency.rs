//! `consistency.parquet`: every run calibrated alone beside the joint
//! calibration (`mrbp sample --per-run`), one row per parameter and
//! estimate — each run's, the joint one's and the between-run layer's
//! new test — with the parameter's χ²/ν, its p-value and the between-run
//! spread repeated on its rows.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::{Error, Result};
use crate::validate::consistency::{Estimate, ParameterConsistency, JOINT, NEW_TEST};

pub const FILE: &str = "consistency.parquet";

/// The kind of an estimate's row.
const RUN: &str = "run";

/// Writes the consistency of the runs of calibration `id` (the joint one),
/// each calibrated alone (`alone`: run and calibration id), into its folder.
/// `layer_runs` names the calibrations alone the between-run layer was
/// fitted to ([`super::between_runs::layer_runs`]).
pub fn write(
    dir: &Path,
    parameters: &[ParameterConsistency],
    id: &str,
    alone: &[(String, String)],
    layer_runs: &str,
) -> Result<()> {
    let alone: Vec<String> = alone.iter().map(|(run, id)| format!("{run}={id}")).collect();
    let rows: Vec<(&ParameterConsistency, &str, &Estimate)> = parameters
        .iter()
        .flat_map(|p| {
            p.runs
                .iter()
                .map(move |r| (p, RUN, r))
                .chain([(p, JOINT, &p.joint), (p, NEW_TEST, &p.new_test)])
        })
        .collect();
    let f = |g: &dyn Fn(&(&ParameterConsistency, &str, &Estimate)) -> f64| {
        rows.iter().map(g).collect::<Vec<f64>>()
    };
    write_parquet(
        &dir.join(FILE),
        Table::new()
            .derived_from(id)
            .meta(RUN_IDS, &alone.join(","))
            .meta(super::between_runs::LAYER_RUNS, layer_runs)
            .str("parameter", rows.iter().map(|r| r.0.parameter.clone()).collect())
            .str("kind", rows.iter().map(|r| r.1.to_string()).collect())
            .str("label", rows.iter().map(|r| r.2.label.clone()).collect())
            .f64("mean_log", f(&|r| r.2.mean_log))
            .f64("sd_log", f(&|r| r.2.sd_log))
            .f64("q05", f(&|r| r.2.q05))
            .f64("q50", f(&|r| r.2.q50))
            .f64("q95", f(&|r| r.2.q95))
            .f64("chi2_nu", f(&|r| r.0.chi2_nu))
            .f64("p_value", f(&|r| r.0.p_value))
            .f64("spread_log", f(&|r| r.0.spread_log)),
    )
}

/// The sub-folder of the run-alone calibrations (`--per-run`).
pub const RUNS: &str = "runs";

/// The metadata key naming the run-alone calibrations (`run=id,…`).
pub const RUN_IDS: &str = "mrbp.run_calibration_ids";

/// Refuses the consistency table in `dir` unless it was derived from
/// calibration `id` and from the run-alone calibrations now in `runs/` (and,
/// for its new test, in every folder the between-run layer took).
pub fn check(dir: &Path, id: &str) -> Result<()> {
    let path = dir.join(FILE);
    let rebuild = "mrbp sample MANIFEST --out DIR --per-run --force";
    super::between_runs::check(&path, dir, id)?;
    if let Some(alone) = super::parquet_meta(&path, RUN_IDS)? {
        for pair in alone.split(',').filter(|p| !p.is_empty()) {
            let (run, made) = pair.split_once('=').unwrap_or((pair, ""));
            let record = dir.join(RUNS).join(run).join(super::folder::RECORD);
            let now = super::record::read(&record).map(|r| r.calibration_id).unwrap_or_default();
            if now != made {
                return Err(Error::input(&path, format!("stale: run {run} has been calibrated alone again since (or its folder is incomplete); rebuild it with `{rebuild}`")));
            }
        }
    }
    Ok(())
}

/// The consistency of the runs of calibration `id` in its folder `dir`;
/// one derived from another calibration, or from run-alone calibrations
/// since redone, is refused.
pub fn read(dir: &Path, id: &str) -> Result<Vec<ParameterConsistency>> {
    check(dir, id)?;
    let path = dir.join(FILE);
    let df = read_parquet(&path)?;
    let s = |n: &str| str_column(&df, n, &path);
    let f = |n: &str| f64_column(&df, n, &path);
    let (parameter, kind, label) = (s("parameter")?, s("kind")?, s("label")?);
    let (mean_log, sd_log, q05, q50, q95) =
        (f("mean_log")?, f("sd_log")?, f("q05")?, f("q50")?, f("q95")?);
    let (chi2_nu, p_value, spread_log) = (f("chi2_nu")?, f("p_value")?, f("spread_log")?);
    let mut out: Vec<ParameterConsistency> = Vec::new();
    for i in 0..parameter.len() {
        let estimate = Estimate {
            label: label[i].clone(),
            mean_log: mean_log[i],
            sd_log: sd_log[i],
            q05: q05[i],
            q50: q50[i],
            q95: q95[i],
        };
        if out.last().is_none_or(|p| p.parameter != parameter[i]) {
            out.push(ParameterConsistency {
                parameter: parameter[i].clone(),
                runs: Vec::new(),
                joint: estimate.clone(),
                chi2_nu: chi2_nu[i],
                p_value: p_value[i],
                spread_log: spread_log[i],
                new_test: estimate.clone(),
            });
        }
        let p = out.last_mut().expect("pushed");
        match kind[i].as_str() {
            RUN => p.runs.push(estimate),
            JOINT => p.joint = estimate,
            NEW_TEST => p.new_test = estimate,
            other => {
                return Err(Error::input(&path, format!("unknown kind {other:?} in column kind")))
            }
        }
    }
    Ok(out)
}
