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

pub fn write(dir: &Path, parameters: &[ParameterConsistency]) -> Result<()> {
    let rows: Vec<(&ParameterConsistency, &str, &Estimate)> = parameters
        .iter()
        .flat_map(|p| p.runs.iter().map(move |r| (p, RUN, r)).chain([(p, JOINT, &p.joint), (p, NEW_TEST, &p.new_test)]))
        .collect();
    let f = |g: &dyn Fn(&(&ParameterConsistency, &str, &Estimate)) -> f64| rows.iter().map(g).collect::<Vec<f64>>();
    write_parquet(
        &dir.join(FILE),
        Table::new()
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

pub fn read(dir: &Path) -> Result<Vec<ParameterConsistency>> {
    let path = dir.join(FILE);
    let df = read_parquet(&path)?;
    let s = |n: &str| str_column(&df, n, &path);
    let f = |n: &str| f64_column(&df, n, &path);
    let (parameter, kind, label) = (s("parameter")?, s("kind")?, s("label")?);
    let (mean_log, sd_log, q05, q50, q95) = (f("mean_log")?, f("sd_log")?, f("q05")?, f("q50")?, f("q95")?);
    let (chi2_nu, p_value, spread_log) = (f("chi2_nu")?, f("p_value")?, f("spread_log")?);
    let mut out: Vec<ParameterConsistency> = Vec::new();
    for i in 0..parameter.len() {
        let estimate = Estimate { label: label[i].clone(), mean_log: mean_log[i], sd_log: sd_log[i], q05: q05[i], q50: q50[i], q95: q95[i] };
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
            other => return Err(Error::input(&path, format!("unknown kind {other:?} in column kind"))),
        }
    }
    Ok(out)
}
