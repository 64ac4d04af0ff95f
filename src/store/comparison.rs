//! `comparison.parquet` (every calibration's summary, one row per
//! parameter) and `differences.parquet` (every pair and parameter).

use std::path::Path;

use super::parquet::{write_parquet, Table};
use crate::compare::{Comparison, Difference};
use crate::error::Result;

pub fn write(dir: &Path, c: &Comparison) -> Result<()> {
    let rows = &c.rows;
    let col = |f: &dyn Fn(&crate::compare::ComparisonRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    write_parquet(
        &dir.join("comparison.parquet"),
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
        &dir.join("differences.parquet"),
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
