//! `coverage.parquet` and `loo.parquet`: one row per run, how well its
//! bands hold the record; `loo.parquet` adds the Pareto k̂ of the held-out
//! run's importance weights and whether it was calibrated afresh.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::{Error, Result};
use crate::predict::CoverageRow;
use crate::validate::{HeldOutBy, LeaveOneOut, LooRow};

/// The files of a leave-one-out study in a calibration folder.
pub const LOO: &str = "loo.parquet";
pub const LOO_BANDS: &str = "loo_bands.parquet";

/// The command that makes a leave-one-out study afresh, for messages.
pub const REBUILD_LOO: &str = "mrbp report DIR --leave-one-out";

/// Writes a leave-one-out study of calibration `id` into its folder `dir`:
/// `loo.parquet`, which says the study is complete, goes first and comes
/// back last.
/// The metadata key of `loo.parquet` that holds the settings the study
/// was made with ([`crate::validate::LooSettings::described`]).
pub const LOO_SETTINGS: &str = "mrbp.loo_settings";

/// Writes the leave-one-out study of calibration `id`, made with the
/// settings `described`, into `dir` (`loo.parquet` last: its presence
/// means the study is whole).
pub fn write_leave_one_out(
    dir: &Path,
    study: &LeaveOneOut,
    id: &str,
    described: &str,
) -> Result<()> {
    crate::atomic::remove(&dir.join(LOO))?;
    super::bands::write(&dir.join(LOO_BANDS), &study.bands, id)?;
    write_loo(&dir.join(LOO), &study.rows, id, described)
}

/// The settings the leave-one-out study in `dir` was made with; `None`
/// without a study, or for one written before they were recorded.
pub fn leave_one_out_settings(dir: &Path) -> Result<Option<String>> {
    let path = dir.join(LOO);
    if !path.exists() {
        return Ok(None);
    }
    super::parquet::parquet_meta(&path, LOO_SETTINGS)
}

/// The leave-one-out study of calibration `id` in `dir`, if it has a
/// complete one; one derived from another calibration is refused.
pub fn read_leave_one_out(dir: &Path, id: &str) -> Result<Option<LeaveOneOut>> {
    if !(dir.join(LOO).exists() && dir.join(LOO_BANDS).exists()) {
        return Ok(None);
    }
    for file in [LOO, LOO_BANDS] {
        super::check_derived(&dir.join(file), id, REBUILD_LOO)?;
    }
    Ok(Some(LeaveOneOut {
        rows: read_loo(&dir.join(LOO))?,
        bands: super::bands::read(&dir.join(LOO_BANDS))?,
    }))
}

/// Writes the coverage of a prediction from calibration `id`.
pub fn write(path: &Path, rows: &[CoverageRow], id: &str) -> Result<()> {
    write_parquet(path, table(rows).derived_from(id))
}

/// The table of `coverage.parquet` (without its calibration's id).
pub fn table(rows: &[CoverageRow]) -> Table {
    Table::new()
        .str("run", rows.iter().map(|r| r.run.clone()).collect())
        .f64("current_a", rows.iter().map(|r| r.current_a).collect())
        .i64("samples", rows.iter().map(|r| r.samples as i64).collect())
        .f64("inside_p95", rows.iter().map(|r| r.inside_p95).collect())
        .f64("inside_q95", rows.iter().map(|r| r.inside_q95).collect())
        .f64("rmse_q50_pa", rows.iter().map(|r| r.rmse_q50_pa).collect())
        .i64("draws", rows.iter().map(|r| r.draws as i64).collect())
        .i64("failed_draws", rows.iter().map(|r| r.failed_draws as i64).collect())
        .bool("calibrated", rows.iter().map(|r| r.calibrated).collect())
        .f64("lppd", rows.iter().map(|r| r.lppd).collect())
        .f64("far_draws", rows.iter().map(|r| r.far_draws).collect())
        .f64("band_width", rows.iter().map(|r| r.band_width).collect())
}

fn write_loo(path: &Path, rows: &[LooRow], id: &str, described: &str) -> Result<()> {
    let coverage: Vec<CoverageRow> = rows.iter().map(|r| r.coverage.clone()).collect();
    let t = table(&coverage)
        .derived_from(id)
        .f64("pareto_k", rows.iter().map(|r| r.pareto_k).collect())
        .f64("pareto_k_laplace", rows.iter().map(|r| r.pareto_k_laplace).collect())
        .str("held_out_by", rows.iter().map(|r| r.by.label().to_string()).collect())
        .f64("max_r_hat", rows.iter().map(|r| r.max_rhat).collect())
        .str(
            "unconverged",
            rows.iter().map(|r| r.unconverged.clone().unwrap_or_default()).collect(),
        )
        .str("failure", rows.iter().map(|r| r.failure.clone().unwrap_or_default()).collect())
        .str(
            "tempered_instead",
            rows.iter().map(|r| r.tempered_instead.clone().unwrap_or_default()).collect(),
        )
        .meta(LOO_SETTINGS, described);
    write_parquet(path, t)
}

fn read_loo(path: &Path) -> Result<Vec<LooRow>> {
    let df = read_parquet(path)?;
    let coverage = read(path)?;
    let k = f64_column(&df, "pareto_k", path)?;
    let k_laplace = f64_column(&df, "pareto_k_laplace", path)?;
    let by = str_column(&df, "held_out_by", path)?;
    let rhat = f64_column(&df, "max_r_hat", path)?;
    // files written before a held-out run could fail (or take the tempered
    // likelihood in the adjusted one's place) have no column
    let failure = str_column(&df, "failure", path).unwrap_or_else(|_| vec![String::new(); k.len()]);
    let tempered =
        str_column(&df, "tempered_instead", path).unwrap_or_else(|_| vec![String::new(); k.len()]);
    // files written before it judged a refit by its R̂ alone
    let unconverged = str_column(&df, "unconverged", path).unwrap_or_else(|_| {
        rhat.iter().map(|&r| crate::validate::waited_for_rhat(r).unwrap_or_default()).collect()
    });
    coverage
        .into_iter()
        .enumerate()
        .map(|(i, c)| {
            let by = HeldOutBy::from_label(&by[i]).ok_or_else(|| {
                Error::input(path, format!("row {}: unknown held_out_by '{}'", i + 1, by[i]))
            })?;
            Ok(LooRow {
                coverage: c,
                pareto_k: k[i],
                pareto_k_laplace: k_laplace[i],
                by,
                max_rhat: rhat[i],
                unconverged: Some(unconverged[i].clone()).filter(|u| !u.is_empty()),
                failure: Some(failure[i].clone()).filter(|f| !f.is_empty()),
                tempered_instead: Some(tempered[i].clone()).filter(|f| !f.is_empty()),
            })
        })
        .collect()
}

pub fn read(path: &Path) -> Result<Vec<CoverageRow>> {
    let df = read_parquet(path)?;
    let run = str_column(&df, "run", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let calibrated = f64_column(&df, "calibrated", path).unwrap_or_else(|_| vec![1.0; run.len()]);
    let lppd = f64_column(&df, "lppd", path).unwrap_or_else(|_| vec![f64::NAN; run.len()]);
    let far = f64_column(&df, "far_draws", path).unwrap_or_else(|_| vec![f64::NAN; run.len()]);
    let width = f64_column(&df, "band_width", path).unwrap_or_else(|_| vec![f64::NAN; run.len()]);
    let (cur, samples, p, q, rmse, draws, failed) = (
        col("current_a")?,
        col("samples")?,
        col("inside_p95")?,
        col("inside_q95")?,
        col("rmse_q50_pa")?,
        col("draws")?,
        col("failed_draws")?,
    );
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
            lppd: lppd[i],
            far_draws: far[i],
            band_width: width[i],
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A held-out run that failed reads back as written: its route, its
    /// reason and its missing numbers; a run held out beside it keeps its
    /// own (an empty `failure`); a refit that stopped unconverged keeps
    /// what it waited for.
    #[test]
    fn a_failed_held_out_run_reads_back_with_its_reason() {
        let dir = std::env::temp_dir().join(format!("mrbp-loo-failed-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(LOO);
        let mut ok = LooRow::failed("t1", 1.0, String::new());
        (ok.by, ok.failure, ok.pareto_k) = (HeldOutBy::Reweighting, None, 0.4);
        (ok.coverage.samples, ok.coverage.inside_p95, ok.coverage.lppd) = (99, 0.96, -120.5);
        let failed = LooRow::failed("t2", 1.0, "the MAP search failed".into());
        // a refit stopped short of its ESS with every R̂ below 1.01
        let mut short = ok.clone();
        (short.coverage.run, short.by, short.max_rhat) = ("t3".into(), HeldOutBy::Sampling, 1.008);
        short.unconverged = Some("ESS of m1 is 363 (target ≥ 400)".into());
        write_loo(&path, &[ok.clone(), failed.clone(), short], "cal-id", "steps=1").unwrap();
        let back = read_loo(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!((back[0].unconverged.as_deref(), back[1].unconverged.as_deref()), (None, None));
        assert_eq!(back[2].unconverged.as_deref(), Some("ESS of m1 is 363 (target ≥ 400)"));
        assert_eq!(back[0].by, HeldOutBy::Reweighting);
        assert_eq!((back[0].failure.as_deref(), back[0].coverage.lppd), (None, -120.5));
        assert_eq!(back[1].by, HeldOutBy::Failed);
        assert_eq!(back[1].failure.as_deref(), Some("the MAP search failed"));
        assert!(back[1].coverage.lppd.is_nan() && back[1].pareto_k.is_nan());
    }
}
