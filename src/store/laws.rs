//! `laws.parquet`: damper laws side by side (`mrbp run --law A,B,…`), one
//! row per law, current, record and kind (in sample, held out), written
//! and read here; the calibrations it compares are named in its metadata
//! (`mrbp.calibration_ids`, `law/current=id,…`).

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::{Error, Result};
use crate::laws::LawKind;
use crate::validate::laws::{Kind, LawEvidence, LawRow, Measures, BRIDGE, SMC};

/// The study's table in its folder.
pub const FILE: &str = "laws.parquet";

/// The metadata key naming the calibrations compared.
pub const CALIBRATIONS: &str = "mrbp.calibration_ids";

/// The table of `rows`, naming the calibrations compared (`ids`).
pub fn table(rows: &[LawRow], ids: &[(String, String)]) -> Table {
    let named: Vec<String> = ids.iter().map(|(label, id)| format!("{label}={id}")).collect();
    Table::new()
        .str("law", rows.iter().map(|r| r.law.name()).collect())
        .f64("current_a", rows.iter().map(|r| r.current_a).collect())
        .str("run", rows.iter().map(|r| r.run.clone()).collect())
        .str("kind", rows.iter().map(|r| r.kind.name().to_string()).collect())
        .i64("samples", rows.iter().map(|r| r.measures.samples as i64).collect())
        .f64("nrmse", rows.iter().map(|r| r.measures.nrmse).collect())
        .f64("e_t", rows.iter().map(|r| r.measures.e_t).collect())
        .f64("e_x", rows.iter().map(|r| r.measures.e_x).collect())
        .f64("e_v", rows.iter().map(|r| r.measures.e_v).collect())
        .f64("inside_p95", rows.iter().map(|r| r.measures.inside_p95).collect())
        .f64("band_width", rows.iter().map(|r| r.measures.band_width).collect())
        .f64("lppd", rows.iter().map(|r| r.lppd).collect())
        .f64("seconds", rows.iter().map(|r| r.seconds).collect())
        .f64("log_evidence", evidence(rows, |e| e.log_evidence))
        .f64("log_evidence_se", evidence(rows, |e| e.se))
        .str("evidence_by", rows.iter().map(|r| r.evidence.map_or("", |e| e.by).into()).collect())
        .bool(
            "pseudo_evidence",
            rows.iter().map(|r| r.evidence.is_some_and(|e| e.pseudo)).collect(),
        )
        .f64("held_out_rhat", rows.iter().map(|r| r.held_out_rhat).collect())
        .str(
            "held_out_unconverged",
            rows.iter().map(|r| r.held_out_unconverged.clone().unwrap_or_default()).collect(),
        )
        .meta(CALIBRATIONS, &named.join(","))
}

/// `value` of each row's evidence; NaN where it has none.
fn evidence(rows: &[LawRow], value: impl Fn(&LawEvidence) -> f64) -> Vec<f64> {
    rows.iter().map(|r| r.evidence.as_ref().map_or(f64::NAN, &value)).collect()
}

pub fn write(path: &Path, rows: &[LawRow], ids: &[(String, String)]) -> Result<()> {
    write_parquet(path, table(rows, ids))
}

pub fn read(path: &Path) -> Result<Vec<LawRow>> {
    let df = read_parquet(path)?;
    let law = str_column(&df, "law", path)?;
    let run = str_column(&df, "run", path)?;
    let kind = str_column(&df, "kind", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (current, samples, nrmse, e_t, e_x, e_v, inside, width, lppd, seconds) = (
        col("current_a")?,
        col("samples")?,
        col("nrmse")?,
        col("e_t")?,
        col("e_x")?,
        col("e_v")?,
        col("inside_p95")?,
        col("band_width")?,
        col("lppd")?,
        col("seconds")?,
    );
    // the evidence columns (absent in files written before 2026-11-30)
    let names = super::parquet::column_names(&df);
    let has = |n: &str| names.iter().any(|c| c == n);
    let evidence = if has("log_evidence") {
        let by = str_column(&df, "evidence_by", path)?;
        let pseudo = col("pseudo_evidence")?;
        let (value, se) = (col("log_evidence")?, col("log_evidence_se")?);
        (0..law.len())
            .map(|i| {
                let by = [SMC, BRIDGE].into_iter().find(|b| *b == by[i])?;
                Some(LawEvidence {
                    log_evidence: value[i],
                    se: se[i],
                    pseudo: pseudo[i] != 0.0,
                    by,
                })
            })
            .collect()
    } else {
        vec![None; law.len()]
    };
    // the held-out refits' R̂ (absent in files written before 2026-11-30)
    let held_out_rhat =
        if has("held_out_rhat") { col("held_out_rhat")? } else { vec![f64::NAN; law.len()] };
    // what an unconverged refit waited for (absent before 2026-12-04,
    // when a refit was judged by its R̂ alone)
    let unconverged: Vec<String> = if has("held_out_unconverged") {
        str_column(&df, "held_out_unconverged", path)?
    } else {
        held_out_rhat
            .iter()
            .map(|&r| crate::validate::waited_for_rhat(r).unwrap_or_default())
            .collect()
    };
    (0..law.len())
        .map(|i| {
            let bad = |what: &str| Error::input(path, format!("row {}: {what}", i + 1));
            Ok(LawRow {
                law: LawKind::ALL
                    .iter()
                    .copied()
                    .find(|k| k.name() == law[i])
                    .ok_or_else(|| bad(&format!("unknown law '{}'", law[i])))?,
                current_a: current[i],
                run: run[i].clone(),
                kind: Kind::parse(&kind[i])
                    .ok_or_else(|| bad(&format!("unknown kind '{}'", kind[i])))?,
                measures: Measures {
                    samples: samples[i] as usize,
                    nrmse: nrmse[i],
                    e_t: e_t[i],
                    e_x: e_x[i],
                    e_v: e_v[i],
                    inside_p95: inside[i],
                    band_width: width[i],
                },
                lppd: lppd[i],
                seconds: seconds[i],
                evidence: evidence[i],
                held_out_rhat: held_out_rhat[i],
                held_out_unconverged: Some(unconverged[i].clone()).filter(|u| !u.is_empty()),
            })
        })
        .collect()
}
