//! `against_current.parquet`: a law calibration's B-P parameters against
//! the coil current — one row per parameter and current of the grid (the
//! off-state, the calibrated range and a little beyond), with where that
//! current lies for the law.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::compare::{CurrentKind, CurrentRow};
use crate::error::{Error, Result};

pub const FILE: &str = "against_current.parquet";

/// Writes the rows of calibration `id` into its folder `dir`.
pub fn write(dir: &Path, rows: &[CurrentRow], id: &str) -> Result<()> {
    let f = |g: fn(&CurrentRow) -> f64| rows.iter().map(g).collect::<Vec<f64>>();
    write_parquet(
        &dir.join(FILE),
        Table::new()
            .derived_from(id)
            .str("parameter", rows.iter().map(|r| r.parameter.clone()).collect())
            .f64("current_a", f(|r| r.current_a))
            .str("kind", rows.iter().map(|r| r.kind.name().to_string()).collect())
            .f64("mean", f(|r| r.mean))
            .f64("sd", f(|r| r.sd))
            .f64("q05", f(|r| r.q05))
            .f64("q50", f(|r| r.q50))
            .f64("q95", f(|r| r.q95)),
    )
}

/// The rows in `dir` of calibration `id`, if it has the file; a file of
/// another calibration is refused, naming the command that `rebuild`s it.
pub fn read(dir: &Path, id: &str, rebuild: &str) -> Result<Option<Vec<CurrentRow>>> {
    let path = dir.join(FILE);
    if !path.exists() {
        return Ok(None);
    }
    super::check_derived(&path, id, rebuild)?;
    let df = read_parquet(&path)?;
    let (parameter, kind) = (str_column(&df, "parameter", &path)?, str_column(&df, "kind", &path)?);
    let col = |n: &str| f64_column(&df, n, &path);
    let (current, mean, sd, q05, q50, q95) =
        (col("current_a")?, col("mean")?, col("sd")?, col("q05")?, col("q50")?, col("q95")?);
    let mut rows = Vec::with_capacity(parameter.len());
    for i in 0..parameter.len() {
        let kind = CurrentKind::parse(&kind[i]).ok_or_else(|| {
            Error::input_at(
                &path,
                Some(i + 1),
                Some("kind"),
                format!("'{}' is not calibrated, between or outside", kind[i]),
            )
        })?;
        rows.push(CurrentRow {
            parameter: parameter[i].clone(),
            current_a: current[i],
            kind,
            mean: mean[i],
            sd: sd[i],
            q05: q05[i],
            q50: q50[i],
            q95: q95[i],
        });
    }
    Ok(Some(rows))
}
