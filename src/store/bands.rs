//! `bands.parquet` (and `loo_bands.parquet`): one row per run and sample,
//! the model and predictive bands with the record they describe.

use std::path::Path;

use super::parquet::{column_names, f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::Result;
use crate::predict::RunBands;

/// Writes the bands of every run, derived from calibration `id`.
pub fn write(path: &Path, runs: &[RunBands], id: &str) -> Result<()> {
    write_parquet(path, table(runs, id))
}

/// The table of `bands.parquet`.
pub fn table(runs: &[RunBands], id: &str) -> Table {
    let col = |f: &dyn Fn(&RunBands) -> &[f64]| {
        runs.iter().flat_map(|b| f(b).iter().copied()).collect::<Vec<f64>>()
    };
    let per_sample = |f: &dyn Fn(&RunBands) -> f64| {
        runs.iter().flat_map(|b| std::iter::repeat_n(f(b), b.time.len())).collect::<Vec<f64>>()
    };
    let names =
        runs.iter().flat_map(|b| std::iter::repeat_n(b.run.clone(), b.time.len())).collect();
    let mut table = Table::new()
        .derived_from(id)
        .str("run", names)
        .f64("current_a", per_sample(&|b| b.current_a))
        .f64("time_s", col(&|b| &b.time))
        .f64("gamma", col(&|b| &b.gamma))
        .f64("gamma_model", col(&|b| &b.gamma_model))
        .f64("tau_obs", col(&|b| &b.tau_obs))
        .f64("q025", col(&|b| &b.model[0]))
        .f64("q25", col(&|b| &b.model[1]))
        .f64("q50", col(&|b| &b.model[2]))
        .f64("q75", col(&|b| &b.model[3]))
        .f64("q975", col(&|b| &b.model[4]))
        .f64("p025", col(&|b| &b.predictive[0]))
        .f64("p975", col(&|b| &b.predictive[1]))
        .f64("displacement_m", col(&|b| &b.displacement))
        .f64("force_n", col(&|b| &b.force));
    if runs.iter().any(|b| b.discrepancy.is_some()) {
        let part = |i: usize| {
            runs.iter()
                .flat_map(|b| {
                    b.discrepancy
                        .as_ref()
                        .map_or_else(|| vec![f64::NAN; b.time.len()], |d| d[i].clone())
                })
                .collect::<Vec<f64>>()
        };
        table = table
            .f64("discrepancy_pa", part(0))
            .f64("discrepancy_sd_pa", part(1))
            .f64("innovation", part(2));
    }
    if runs.iter().any(|b| b.coil_current_a.is_some()) {
        let current = runs
            .iter()
            .flat_map(|b| b.coil_current_a.clone().unwrap_or_else(|| vec![f64::NAN; b.time.len()]))
            .collect::<Vec<f64>>();
        table = table.f64("coil_current_a", current);
    }
    table
}

/// Reads the bands of every run back, in file order.
pub fn read(path: &Path) -> Result<Vec<RunBands>> {
    let df = read_parquet(path)?;
    let run = str_column(&df, "run", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (cur, time, gamma, tau) =
        (col("current_a")?, col("time_s")?, col("gamma")?, col("tau_obs")?);
    let gamma_model = col("gamma_model")?;
    let q = [col("q025")?, col("q25")?, col("q50")?, col("q75")?, col("q975")?];
    let p = [col("p025")?, col("p975")?];
    let (disp, force) = (col("displacement_m")?, col("force_n")?);
    let discrepancy = match column_names(&df).iter().any(|c| c == "discrepancy_pa") {
        true => Some([col("discrepancy_pa")?, col("discrepancy_sd_pa")?, col("innovation")?]),
        false => None,
    };
    let coil_current = match column_names(&df).iter().any(|c| c == "coil_current_a") {
        true => Some(col("coil_current_a")?),
        false => None,
    };
    let mut out: Vec<RunBands> = Vec::new();
    let mut start = 0;
    for i in 1..=run.len() {
        if i == run.len() || run[i] != run[start] {
            let r = start..i;
            out.push(RunBands {
                run: run[start].clone(),
                current_a: cur[start],
                time: time[r.clone()].to_vec(),
                gamma: gamma[r.clone()].to_vec(),
                gamma_model: gamma_model[r.clone()].to_vec(),
                tau_obs: tau[r.clone()].to_vec(),
                model: q.clone().map(|c| c[r.clone()].to_vec()),
                predictive: p.clone().map(|c| c[r.clone()].to_vec()),
                displacement: disp[r.clone()].to_vec(),
                force: force[r.clone()].to_vec(),
                discrepancy: discrepancy.as_ref().map(|d| d.clone().map(|c| c[r.clone()].to_vec())),
                // a run whose current does not vary has NaN there
                coil_current_a: coil_current
                    .as_ref()
                    .map(|c| c[r.clone()].to_vec())
                    .filter(|c| c.iter().all(|v| v.is_finite())),
            });
            start = i;
        }
    }
    Ok(out)
}
