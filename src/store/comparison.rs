//! `comparison.parquet` (every calibration's summary, one row per
//! parameter) and `differences.parquet` (every pair and parameter), and
//! `comparison.toml`, the record of what was compared: which folders, and
//! which calibration each held. The record is removed first and written
//! last, so a comparison folder with it is complete.

use std::path::{Component, Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::compare::{Comparison, ComparisonRow, Difference, DifferenceRow};
use crate::error::{Error, Result};

/// The record of a comparison.
pub const RECORD: &str = "comparison.toml";

/// What a comparison compared.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ComparisonRecord {
    pub mrbp_version: String,
    pub command: String,
    pub compared: Vec<Compared>,
}

/// One calibration compared: its label in the tables, its folder (relative
/// to the comparison's folder where they share a root) and its calibration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Compared {
    pub label: String,
    pub folder: String,
    pub calibration_id: String,
}

impl Compared {
    /// A calibration in `folder`, as seen from the comparison in `out`.
    pub fn new(label: &str, folder: &Path, calibration_id: &str, out: &Path) -> Compared {
        Compared {
            label: label.to_string(),
            folder: relative(folder, out).display().to_string(),
            calibration_id: calibration_id.to_string(),
        }
    }

    /// Its folder, from the comparison's folder `out` (`out/../x` as `x`).
    pub fn folder_from(&self, out: &Path) -> PathBuf {
        let mut path = PathBuf::new();
        for part in out.join(&self.folder).components() {
            match part {
                Component::ParentDir
                    if matches!(path.components().next_back(), Some(Component::Normal(_))) =>
                {
                    path.pop();
                }
                other => path.push(other),
            }
        }
        path
    }
}

/// `target` as a path from `base` (both made absolute); `target` itself
/// when they share no root.
fn relative(target: &Path, base: &Path) -> PathBuf {
    let (Ok(t), Ok(b)) = (std::fs::canonicalize(target), std::fs::canonicalize(base)) else {
        return std::path::absolute(target).unwrap_or_else(|_| target.to_path_buf());
    };
    let (t, b): (Vec<Component>, Vec<Component>) =
        (t.components().collect(), b.components().collect());
    let common = t.iter().zip(&b).take_while(|(x, y)| x == y).count();
    if common <= 1 {
        return t.iter().collect();
    }
    let mut path: PathBuf = b[common..].iter().map(|_| Component::ParentDir).collect();
    path.extend(&t[common..]);
    path
}

/// Makes the comparison in `dir` incomplete, before its files are replaced.
pub fn retire(dir: &Path) -> Result<()> {
    crate::atomic::remove(&dir.join(RECORD))
}

/// Writes the record, last: the comparison in `dir` is complete.
pub fn write_record(dir: &Path, record: &ComparisonRecord) -> Result<()> {
    let text =
        toml::to_string(record).map_err(|e| Error::Compute(format!("writing {RECORD}: {e}")))?;
    crate::atomic::write(
        &dir.join(RECORD),
        format!("# What this comparison compared (mrbp compare).\n{text}").as_bytes(),
    )
}

/// The record of the comparison in `dir`.
pub fn read_record(dir: &Path) -> Result<ComparisonRecord> {
    let path = dir.join(RECORD);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| Error::input(&path, format!("cannot read: {e}")))?;
    toml::from_str(&text)
        .map_err(|e| Error::input(&path, format!("not a comparison record: {}", e.message())))
}

/// The calibrations of `record` as the tables' metadata names them.
pub fn ids_text(record: &ComparisonRecord) -> String {
    record
        .compared
        .iter()
        .map(|c| format!("{}={}", c.label, c.calibration_id))
        .collect::<Vec<_>>()
        .join(",")
}

/// The files of a comparison folder.
pub const SUMMARIES: &str = "comparison.parquet";
pub const DIFFERENCES: &str = "differences.parquet";
/// The metadata key naming the calibrations compared.
pub const CALIBRATION_IDS: &str = "mrbp.calibration_ids";

/// Writes the comparison's tables into `dir`; `ids` (`label=calibration
/// id`, …) names the calibrations compared, in each file's metadata.
pub fn write(dir: &Path, c: &Comparison, ids: &str) -> Result<()> {
    let rows = &c.rows;
    let col = |f: &dyn Fn(&crate::compare::ComparisonRow) -> f64| {
        rows.iter().map(f).collect::<Vec<f64>>()
    };
    write_parquet(
        &dir.join(SUMMARIES),
        Table::new()
            .meta(CALIBRATION_IDS, ids)
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
    let col =
        |f: &dyn Fn(&Difference) -> f64| d.iter().map(|r| f(&r.difference)).collect::<Vec<f64>>();
    write_parquet(
        &dir.join(DIFFERENCES),
        Table::new()
            .meta(CALIBRATION_IDS, ids)
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
    let (cal, parameter) =
        (str_column(&df, "calibration", &path)?, str_column(&df, "parameter", &path)?);
    let col = |n: &str| f64_column(&df, n, &path);
    let (current, mean, sd, q05, q50, q95) =
        (col("current_a")?, col("mean")?, col("sd")?, col("q05")?, col("q50")?, col("q95")?);
    let rows = (0..cal.len())
        .map(|i| ComparisonRow {
            calibration: cal[i].clone(),
            current_a: current[i],
            parameter: parameter[i].clone(),
            mean: mean[i],
            sd: sd[i],
            q05: q05[i],
            q50: q50[i],
            q95: q95[i],
        })
        .collect();
    let path = dir.join(DIFFERENCES);
    let df = read_parquet(&path)?;
    let (a, b, parameter) = (
        str_column(&df, "calibration_a", &path)?,
        str_column(&df, "calibration_b", &path)?,
        str_column(&df, "parameter", &path)?,
    );
    let col = |n: &str| f64_column(&df, n, &path);
    let (d05, d50, d95) = (col("diff_q05")?, col("diff_q50")?, col("diff_q95")?);
    let (r05, r50, r95, p) =
        (col("ratio_q05")?, col("ratio_q50")?, col("ratio_q95")?, col("p_greater")?);
    let differences = (0..a.len())
        .map(|i| DifferenceRow {
            a: a[i].clone(),
            b: b[i].clone(),
            parameter: parameter[i].clone(),
            difference: Difference {
                diff_q05: d05[i],
                diff_q50: d50[i],
                diff_q95: d95[i],
                ratio_q05: r05[i],
                ratio_q50: r50[i],
                ratio_q95: r95[i],
                p_greater: p[i],
            },
        })
        .collect();
    Ok(Comparison { rows, differences })
}
