//! `coverage.parquet` (and `loo.parquet`): one row per run, how well its
//! bands hold the record.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::Result;
use crate::predict::CoverageRow;

pub fn write(path: &Path, rows: &[CoverageRow]) -> Result<()> {
    write_parquet(
        path,
        Table::new()
            .str("run", rows.iter().map(|r| r.run.clone()).collect())
            .f64("current_a", rows.iter().map(|r| r.current_a).collect())
            .i64("samples", rows.iter().map(|r| r.samples as i64).collect())
            .f64("inside_p95", rows.iter().map(|r| r.inside_p95).collect())
            .f64("inside_q95", rows.iter().map(|r| r.inside_q95).collect())
            .f64("rmse_q50_pa", rows.iter().map(|r| r.rmse_q50_pa).collect())
            .i64("draws", rows.iter().map(|r| r.draws as i64).collect())
            .i64("failed_draws", rows.iter().map(|r| r.failed_draws as i64).collect())
            .bool("calibrated", rows.iter().map(|r| r.calibrated).collect()),
    )
}

pub fn read(path: &Path) -> Result<Vec<CoverageRow>> {
    let df = read_parquet(path)?;
    let run = str_column(&df, "run", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let calibrated = f64_column(&df, "calibrated", path).unwrap_or_else(|_| vec![1.0; run.len()]);
    let (cur, samples, p, q, rmse, draws, failed) =
        (col("current_a")?, col("samples")?, col("inside_p95")?, col("inside_q95")?, col("rmse_q50_pa")?, col("draws")?, col("failed_draws")?);
    Ok((0..run.len())
        .map(|i| CoverageRow {
            run: run[i].clone(),
            current_a: cur[i],
            samples: samples[i] as usize,
            inside_p95: p[i],
            inside_q95: q[i],
            rmse_q50_pa: rmse[i],
            draws: draws[i] as usize,
            failed_draws: failed[i] as usize,
            calibrated: calibrated[i] != 0.0,
        })
        .collect())
}
