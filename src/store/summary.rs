//! `summary.parquet`: one row per coordinate, its posterior statistics and
//! diagnostics (SI units), and the steps and walkers they came from.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::Result;
use crate::posterior::SummaryRow;
use crate::sampler::ParameterDiagnostics;

/// The rows of a calibration whose draws run from `burn_in` to `steps`, of
/// `walkers` chains in all, of calibration `id`.
pub fn write(path: &Path, rows: &[SummaryRow], burn_in: usize, steps: usize, walkers: usize, id: &str) -> Result<()> {
    let col = |f: &dyn Fn(&ParameterDiagnostics) -> f64| rows.iter().map(|r| f(&r.stats)).collect::<Vec<f64>>();
    let n = rows.len();
    write_parquet(
        path,
        Table::new()
            .derived_from(id)
            .str("parameter", rows.iter().map(|r| r.parameter.clone()).collect())
            .f64("mean", col(&|p| p.mean))
            .f64("sd", col(&|p| p.sd))
            .f64("q05", col(&|p| p.q05))
            .f64("q50", col(&|p| p.q50))
            .f64("q95", col(&|p| p.q95))
            .f64("ess_bulk", col(&|p| p.ess_bulk))
            .f64("ess_tail", col(&|p| p.ess_tail))
            .f64("r_hat", col(&|p| p.r_hat))
            .f64("tau_int", col(&|p| p.tau_int))
            .f64("mcse_mean", col(&|p| p.mcse_mean))
            .i64("first_draw", vec![burn_in as i64; n])
            .i64("last_draw", vec![steps as i64; n])
            .i64("walkers", vec![walkers as i64; n]),
    )
}

pub fn read(path: &Path) -> Result<Vec<SummaryRow>> {
    let df = read_parquet(path)?;
    let names = str_column(&df, "parameter", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (mean, sd, q05, q50, q95) = (col("mean")?, col("sd")?, col("q05")?, col("q50")?, col("q95")?);
    let (eb, et, rh, tau, mcse) = (col("ess_bulk")?, col("ess_tail")?, col("r_hat")?, col("tau_int")?, col("mcse_mean")?);
    Ok((0..names.len())
        .map(|i| SummaryRow {
            parameter: names[i].clone(),
            stats: ParameterDiagnostics {
                mean: mean[i],
                sd: sd[i],
                q05: q05[i],
                q50: q50[i],
                q95: q95[i],
                ess_bulk: eb[i],
                ess_tail: et[i],
                r_hat: rh[i],
                tau_int: tau[i],
                mcse_mean: mcse[i],
            },
        })
        .collect())
}
