//! The between-run layer's files in a calibration folder (`--per-run`):
//!
//! - `between_runs.parquet`: draws of the layer at the folder's current —
//!   a new test's parameters (the damper law's, terms, noise; SI) and the
//!   centre's law parameters (`centre_<p>`, the typical test there), one
//!   row per draw.
//!   The draws of every current's folder from one fit share their `draw`
//!   index, so centres at two currents can be compared draw by draw;
//! - `loo_new_test.parquet`: each run predicted as a new test by the layer
//!   fitted without it (`left_out` = `run`), and without every run at its
//!   current (`current`): the columns of `coverage.parquet`, `left_out` and
//!   `max_r_hat` (of the layer's chains fitted without it).
//!
//! - `typical_test.parquet` (runs at two currents or more): each law
//!   parameter of the typical test (the centre) and of a new test against
//!   the coil current, from 0 A to 1.2× the highest calibrated current, the
//!   same rows in every current's folder of one fit.
//!
//! All name the joint calibration (`mrbp.calibration_id`) and every
//! calibration alone the layer was fitted to (`mrbp.layer_runs`: each run's
//! folder relative to this one, `=` its calibration id); a reader refuses
//! them when any of those has been calibrated again since.

use std::path::{Component, Path, PathBuf};

use super::parquet::{
    check_derived, f64_column, parquet_meta, read_parquet, str_column, write_parquet, Table,
};
use crate::compare::CurrentKind;
use crate::error::{Error, Result};
use crate::predict::CoverageRow;
use crate::validate::between_runs::{BetweenRuns, LeftOut, NewTestRow, TypicalRow};

pub const FILE: &str = "between_runs.parquet";
pub const LOO: &str = "loo_new_test.parquet";
pub const TYPICAL: &str = "typical_test.parquet";

/// The metadata key naming the calibrations alone the layer was fitted to.
pub const LAYER_RUNS: &str = "mrbp.layer_runs";

/// Rows of `between_runs.parquet`: draws spread evenly over the layer's.
pub const ROWS: usize = 4000;

const REBUILD: &str = "mrbp sample MANIFEST --out DIR --per-run --force (or mrbp run … --per-run)";

/// The calibrations alone a layer was fitted to, as metadata: each folder
/// relative to `dir`, `=` its calibration id.
pub fn layer_runs(dir: &Path, folders: &[(&Path, &str)]) -> String {
    folders
        .iter()
        .map(|(folder, id)| format!("{}={id}", relative(dir, folder).display()))
        .collect::<Vec<_>>()
        .join(",")
}

/// Writes the layer's draws at the current of the joint calibration `id`
/// in `dir` (group `group` of `layer`).
pub fn write(dir: &Path, layer: &BetweenRuns, group: usize, id: &str, runs: &str) -> Result<()> {
    let picks = crate::posterior::evenly_spaced(layer.draws.len(), ROWS);
    let mut table = Table::new()
        .derived_from(id)
        .meta(LAYER_RUNS, runs)
        .meta(
            "mrbp.layer_currents_a",
            &layer.currents.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(","),
        )
        .meta("mrbp.layer_max_r_hat", &layer.max_rhat.to_string())
        .meta("mrbp.layer_min_ess", &layer.min_ess.to_string())
        .i64("draw", picks.iter().map(|&i| i as i64).collect());
    let theta = |z: &[f64]| {
        layer
            .theta(z)
            .filter(|t| layer.in_support(t))
            .unwrap_or([f64::NAN; crate::laws::MAX_LAW_PARAMETERS])
    };
    let names = layer.names();
    for (k, name) in names.iter().enumerate() {
        table = table
            .f64(name, picks.iter().map(|&i| theta(&layer.draws[i].new_tests[group])[k]).collect());
    }
    for (k, c) in layer.coordinates.iter().enumerate().skip(names.len()) {
        table = table.f64(
            &c.name,
            picks.iter().map(|&i| c.scale.to_si(layer.draws[i].new_tests[group][k])).collect(),
        );
    }
    for (k, name) in names.iter().enumerate() {
        table = table.f64(
            &format!("centre_{name}"),
            picks.iter().map(|&i| theta(&layer.draws[i].means[group])[k]).collect(),
        );
    }
    write_parquet(&dir.join(FILE), table)
}

/// A new test's law parameters and the centre's, read back: per
/// parameter, its values over the draws; and which fit they came from
/// (the calibration ids of the runs it took, sorted: the same in every
/// current's folder of one fit).
pub struct LayerTable {
    pub draw: Vec<f64>,
    pub new_test: Vec<Vec<f64>>,
    pub centre: Vec<Vec<f64>>,
    pub fit: String,
}

/// The layer's draws in `dir`, derived from calibration `id` of the law
/// whose parameters are `names`; refused if stale.
pub fn read(dir: &Path, id: &str, names: &[String]) -> Result<LayerTable> {
    let path = dir.join(FILE);
    check(&path, dir, id)?;
    let df = read_parquet(&path)?;
    let col = |n: &str| f64_column(&df, n, &path);
    let mut ids: Vec<String> = parquet_meta(&path, LAYER_RUNS)?
        .unwrap_or_default()
        .split(',')
        .filter_map(|p| p.rsplit_once('=').map(|(_, id)| id.to_string()))
        .collect();
    ids.sort();
    Ok(LayerTable {
        draw: col("draw")?,
        new_test: names.iter().map(|n| col(n)).collect::<Result<_>>()?,
        centre: names.iter().map(|n| col(&format!("centre_{n}"))).collect::<Result<_>>()?,
        fit: ids.join(","),
    })
}

/// New tests of the damper from the layer's draws in `dir` (derived from
/// calibration `id` of `law`, whose `layout` names its noise parameters): each a
/// draw of the law's parameters, terms and noise; draws outside the prior's
/// support (NaN) left out. Also the layer's `mrbp.layer_runs`. Refused if
/// missing or stale.
pub fn new_tests(
    dir: &Path,
    id: &str,
    law: crate::laws::LawKind,
    layout: &crate::posterior::Layout,
) -> Result<(Vec<crate::posterior::Draw>, String)> {
    let path = layer_file(dir, id)?;
    let df = read_parquet(&path)?;
    let col = |n: &str| f64_column(&df, n, &path);
    let names = layout.theta_names();
    let theta: Vec<Vec<f64>> = names.iter().map(|n| col(n)).collect::<Result<_>>()?;
    let optional = |n: &str| if df.column(n).is_ok() { col(n).map(Some) } else { Ok(None) };
    let (spring, offset) = (optional("gas_spring_n_per_m")?, optional("force_offset_n")?);
    let noise: Vec<Vec<f64>> =
        layout.noise_parameters.iter().map(|p| col(p.name)).collect::<Result<_>>()?;
    let draws = (0..theta[0].len())
        .filter(|&i| theta.iter().all(|t| t[i].is_finite()))
        .map(|i| {
            let mut values = [0.0; crate::noise::MAX_PARAMETERS];
            for (v, column) in values.iter_mut().zip(&noise) {
                *v = column[i];
            }
            let mut law_values = [0.0; crate::laws::MAX_LAW_PARAMETERS];
            for (v, column) in law_values.iter_mut().zip(&theta) {
                *v = column[i];
            }
            crate::posterior::Draw {
                law,
                values: law_values,
                field: None,
                spring_n_per_m: spring.as_ref().map_or(0.0, |c| c[i]),
                offset_n: offset.as_ref().map_or(0.0, |c| c[i]),
                noise: values,
            }
        })
        .collect();
    Ok((draws, parquet_meta(&path, LAYER_RUNS)?.unwrap_or_default()))
}

/// The folders of the calibrations alone the layer in `dir` (derived from
/// calibration `id`) was fitted to, as its `between_runs.parquet` names
/// them; refused where the file is missing or stale.
pub fn layer_folders(dir: &Path, id: &str) -> Result<Vec<PathBuf>> {
    let runs = parquet_meta(&layer_file(dir, id)?, LAYER_RUNS)?.unwrap_or_default();
    Ok(folder_ids(&runs).map(|(folder, _)| dir.join(folder)).collect())
}

/// `between_runs.parquet` of `dir`, checked ([`check`]); a usage error
/// naming `--per-run` where the folder has none.
fn layer_file(dir: &Path, id: &str) -> Result<PathBuf> {
    let path = dir.join(FILE);
    if !path.exists() {
        return Err(Error::Usage(format!(
            "{} has no between-run layer ({FILE}): calibrate each run alone too, `mrbp run MANIFEST --out DIR --per-run`, which fits it where a current has two runs or more (docs/calibration.md)",
            dir.display()
        )));
    }
    check(&path, dir, id)?;
    Ok(path)
}

/// The (folder, calibration id) pairs of a layer's `mrbp.layer_runs`
/// ([`layer_runs`]).
fn folder_ids(runs: &str) -> impl Iterator<Item = (&str, &str)> {
    runs.split(',')
        .filter(|p| !p.is_empty())
        .map(|pair| pair.rsplit_once('=').unwrap_or((pair, "")))
}

/// Writes the typical test against the current into the folder `dir` of
/// the joint calibration `id`.
pub fn write_typical(dir: &Path, rows: &[TypicalRow], id: &str, runs: &str) -> Result<()> {
    let q = |f: fn(&TypicalRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    write_parquet(
        &dir.join(TYPICAL),
        Table::new()
            .derived_from(id)
            .meta(LAYER_RUNS, runs)
            .str("parameter", rows.iter().map(|r| r.parameter.clone()).collect())
            .f64("current_a", q(|r| r.current_a))
            .str("kind", rows.iter().map(|r| r.kind.name().to_string()).collect())
            .f64("centre_q05", q(|r| r.centre[0]))
            .f64("centre_q50", q(|r| r.centre[1]))
            .f64("centre_q95", q(|r| r.centre[2]))
            .f64("new_test_q05", q(|r| r.new_test[0]))
            .f64("new_test_q50", q(|r| r.new_test[1]))
            .f64("new_test_q95", q(|r| r.new_test[2])),
    )
}

/// The typical test against the current in `dir`, if there is one;
/// refused if stale.
pub fn read_typical(dir: &Path, id: &str) -> Result<Option<Vec<TypicalRow>>> {
    let path = dir.join(TYPICAL);
    if !path.exists() {
        return Ok(None);
    }
    check(&path, dir, id)?;
    let df = read_parquet(&path)?;
    let (parameter, kind) = (str_column(&df, "parameter", &path)?, str_column(&df, "kind", &path)?);
    let col = |n: &str| f64_column(&df, n, &path);
    let current = col("current_a")?;
    let centre = [col("centre_q05")?, col("centre_q50")?, col("centre_q95")?];
    let new_test = [col("new_test_q05")?, col("new_test_q50")?, col("new_test_q95")?];
    (0..parameter.len())
        .map(|i| {
            let kind = CurrentKind::parse(&kind[i]).ok_or_else(|| {
                Error::input_at(
                    &path,
                    Some(i + 1),
                    Some("kind"),
                    format!("'{}' is not calibrated, between or outside", kind[i]),
                )
            })?;
            Ok(TypicalRow {
                parameter: parameter[i].clone(),
                current_a: current[i],
                kind,
                centre: centre.each_ref().map(|c| c[i]),
                new_test: new_test.each_ref().map(|c| c[i]),
            })
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

/// Writes the layer's leave-one-out coverage of the runs of calibration
/// `id` into `dir`.
pub fn write_leave_one_out(dir: &Path, rows: &[NewTestRow], id: &str, runs: &str) -> Result<()> {
    let coverage: Vec<CoverageRow> = rows.iter().map(|r| r.coverage.clone()).collect();
    let table = super::coverage::table(&coverage)
        .str("left_out", rows.iter().map(|r| r.left_out.label().to_string()).collect())
        .f64("max_r_hat", rows.iter().map(|r| r.max_rhat).collect())
        .f64("min_ess", rows.iter().map(|r| r.min_ess).collect());
    write_parquet(&dir.join(LOO), table.derived_from(id).meta(LAYER_RUNS, runs))
}

/// The layer's leave-one-out coverage in `dir`, if there is one; refused if
/// stale.
pub fn read_leave_one_out(dir: &Path, id: &str) -> Result<Option<Vec<NewTestRow>>> {
    let path = dir.join(LOO);
    if !path.exists() {
        return Ok(None);
    }
    check(&path, dir, id)?;
    let coverage = super::coverage::read(&path)?;
    let df = read_parquet(&path)?;
    let left_out = str_column(&df, "left_out", &path)?;
    let rhat = f64_column(&df, "max_r_hat", &path)?;
    // files written before 2026-12-04 kept the R̂ alone
    let ess = f64_column(&df, "min_ess", &path).unwrap_or_else(|_| vec![f64::NAN; rhat.len()]);
    coverage
        .into_iter()
        .zip(left_out)
        .zip(rhat.into_iter().zip(ess))
        .enumerate()
        .map(|(i, ((coverage, l), (max_rhat, min_ess)))| match LeftOut::parse(&l) {
            Some(left_out) => Ok(NewTestRow { coverage, left_out, max_rhat, min_ess }),
            None => Err(Error::input(&path, format!("row {}: unknown left_out '{l}'", i + 1))),
        })
        .collect::<Result<Vec<_>>>()
        .map(Some)
}

/// Refuses `path` (a file of folder `dir`) unless it was derived from
/// calibration `id` and from the calibrations alone now in the folders its
/// metadata names.
pub fn check(path: &Path, dir: &Path, id: &str) -> Result<()> {
    check_derived(path, id, REBUILD)?;
    let Some(runs) = parquet_meta(path, LAYER_RUNS)? else {
        return Ok(());
    };
    for (folder, made) in folder_ids(&runs) {
        let record = dir.join(folder).join(super::folder::RECORD);
        let now = super::record::read(&record).map(|r| r.calibration_id).unwrap_or_default();
        if now != made {
            return Err(Error::input(path, format!("stale: the run in {folder} has been calibrated alone again since (or its folder is incomplete); rebuild it with `{REBUILD}`")));
        }
    }
    Ok(())
}

/// `to` relative to `from` (both folders), through their canonical forms
/// where they exist.
fn relative(from: &Path, to: &Path) -> PathBuf {
    let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let (from, to) = (canonical(from), canonical(to));
    let a: Vec<Component> = from.components().collect();
    let b: Vec<Component> = to.components().collect();
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..a.len() {
        out.push("..");
    }
    for c in &b[common..] {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_climb_and_descend() {
        assert_eq!(
            relative(Path::new("/a/b/I1.0A"), Path::new("/a/b/I1.0A/runs/r1")),
            PathBuf::from("runs/r1")
        );
        assert_eq!(
            relative(Path::new("/a/b/I1.0A"), Path::new("/a/b/I0.5A/runs/r2")),
            PathBuf::from("../I0.5A/runs/r2")
        );
        assert_eq!(relative(Path::new("/a/b"), Path::new("/a/b")), PathBuf::from("."));
    }
}
