//! `comparison.parquet` (every calibration's summary, one row per
//! parameter) and `differences.parquet` (every pair and parameter).

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::compare::{Comparison, ComparisonRow, Difference, DifferenceRow};
use crate::error::Result;

/// The files of a comparison folder.
pub const SUMMARIES: &str = "comparison.parquet";
pub const DIFFERENCES: &str = "differences.parquet";

pub fn write(dir: &Path, c: &Comparison) -> Result<()> {
    let rows = &c.rows;
    let col = |f: &dyn Fn(&crate::compare::ComparisonRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    write_parquet(
        &dir.join(SUMMARIES),
        Table::new()
            .str("calibration", rows.iter().map(|r| r.calibration.clone()).collect())
            .f64("current_a", col(&|r| r.current_a))
            .str("parameter", rows.iter().map(|r| r.parameter.clone()).collect())
            .f64("mean", col(&|r| r.mean))
            .f64("sd", col(&|r| r.sd))
            .f64("q05", col(&|r| r.q05))
            .f64("q50", col(&|r| r.q50))
            .f64("q95", col(&|r| r.q95)),
    )?;
    let d = &c.differences;
    let col = |f: &dyn Fn(&Difference) -> f64| d.iter().map(|r| f(&r.difference)).collect::<Vec<f64>>();
    write_parquet(
        &dir.join(DIFFERENCES),
        Table::new()
            .str("calibration_a", d.iter().map(|r| r.a.clone()).collect())
            .str("calibration_b", d.iter().map(|r| r.b.clone()).collect())
            .str("parameter", d.iter().map(|r| r.parameter.clone()).collect())
            .f64("diff_q05", col(&|d| d.diff_q05))
            .f64("diff_q50", col(&|d| d.diff_q50))
            .f64("diff_q95", col(&|d| d.diff_q95))
            .f64("ratio_q05", col(&|d| d.ratio_q05))
            .f64("ratio_q50", col(&|d| d.ratio_q50))
            .f64("ratio_q95", col(&|d| d.ratio_q95))
            .f64("p_greater", col(&|d| d.p_greater)),
    )
}

pub fn read(dir: &Path) -> Result<Comparison> {
    let path = dir.join(SUMMARIES);
    let df = read_parquet(&path)?;
    let (cal, parameter) = (str_column(&df, "calibration", &path)?, str_column(&df, "parameter", &path)?);
    let col = |n: &str| f64_column(&df, n, &path);
    let (current, mean, sd, q05, q50, q95) = (col("current_a")?, col("mean")?, col("sd")?, col("q05")?, col("q50")?, col("q95")?);
    let rows = (0..cal.len())
        .map(|i| ComparisonRow { calibration: cal[i].clone(), current_a: current[i], parameter: parameter[i].clone(), mean: mean[i], sd: sd[i], q05: q05[i], q50: q50[i], q95: q95[i] })
        .collect();
    let path = dir.join(DIFFERENCES);
    let df = read_parquet(&path)?;
    let (a, b, parameter) = (str_column(&df, "calibration_a", &path)?, str_column(&df, "calibration_b", &path)?, str_column(&df, "parameter", &path)?);
    let col = |n: &str| f64_column(&df, n, &path);
    let (d05, d50, d95) = (col("diff_q05")?, col("diff_q50")?, col("diff_q95")?);
    let (r05, r50, r95, p) = (col("ratio_q05")?, col("ratio_q50")?, col("ratio_q95")?, col("p_greater")?);
    let differences = (0..a.len())
        .map(|i| DifferenceRow {
            a: a[i].clone(),
            b: b[i].clone(),
            parameter: parameter[i].clone(),
            difference: Difference { diff_q05: d05[i], diff_q50: d50[i], diff_q95: d95[i], ratio_q05: r05[i], ratio_q50: r50[i], ratio_q95: r95[i], p_greater: p[i] },
        })
        .collect();
    Ok(Comparison { rows, differences })
}
