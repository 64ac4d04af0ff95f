//! `summary.parquet`: one row per coordinate, its posterior statistics and
//! diagnostics (SI units), and the steps and walkers they came from.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::calibrate::SmcRecord;
use crate::error::Result;
use crate::posterior::laplace::IntervalRow;
use crate::posterior::SummaryRow;
use crate::sampler::ParameterDiagnostics;

/// The rows of a calibration whose draws run from `burn_in` to `steps`, of
/// `walkers` chains in all, of calibration `id`; `holds_for` says what
/// their intervals hold for, and where the likelihood allowed for the
/// residuals' memory, `independent` holds the same records' intervals
/// had the residuals been taken as independent (`independent_sd`, `…_q05`,
/// `…_q50`, `…_q95`; NaN for a coordinate it lacks); where the calibration
/// was sampled by sequential Monte Carlo, `evidence` puts its log
/// evidence in the file's metadata ([`LOG_EVIDENCE`]).
pub fn write(
    path: &Path,
    rows: &[SummaryRow],
    (burn_in, steps, walkers): (usize, usize, usize),
    holds_for: &str,
    independent: &[IntervalRow],
    evidence: Option<&SmcRecord>,
    id: &str,
) -> Result<()> {
    let n = rows.len();
    let mut t = Table::new().derived_from(id);
    if let Some(e) = evidence {
        t = t
            .meta(LOG_EVIDENCE, &e.log_evidence.to_string())
            .meta(LOG_EVIDENCE_SE, &e.se().to_string())
            .meta(EVIDENCE_OF, &e.evidence_of);
    }
    let mut t = t.str("parameter", rows.iter().map(|r| r.parameter.clone()).collect());
    for (name, values) in statistics(rows) {
        t = t.f64(name, values);
    }
    let mut t = t
        .i64("first_draw", vec![burn_in as i64; n])
        .i64("last_draw", vec![steps as i64; n])
        .i64("walkers", vec![walkers as i64; n])
        .str("holds_for", vec![holds_for.to_string(); n]);
    if !independent.is_empty() {
        let of = |r: &SummaryRow| independent.iter().find(|i| i.parameter == r.parameter);
        let columns: [(&str, Interval); 4] = [
            ("independent_sd", |i| i.sd),
            ("independent_q05", |i| i.q05),
            ("independent_q50", |i| i.q50),
            ("independent_q95", |i| i.q95),
        ];
        for (name, f) in columns {
            t = t.f64(name, rows.iter().map(|r| of(r).map_or(f64::NAN, f)).collect());
        }
    }
    write_parquet(path, t)
}

/// The metadata keys of the log evidence where the calibration was sampled
/// by sequential Monte Carlo (`calibration.toml`'s `[smc]`): its value,
/// its standard error (the larger of the two) and what it is of.
pub const LOG_EVIDENCE: &str = "mrbp.log_evidence";
pub const LOG_EVIDENCE_SE: &str = "mrbp.log_evidence_se";
pub const EVIDENCE_OF: &str = "mrbp.evidence_of";

/// How an `independent_*` column reads an approximation's interval row.
type Interval = fn(&IntervalRow) -> f64;

/// A summary column: its name and how it reads a coordinate's statistics.
type Statistic = (&'static str, fn(&ParameterDiagnostics) -> f64);

/// The statistics columns of the summary (after `parameter`), in order:
/// what the file and the Python package's frame hold.
pub fn statistics(rows: &[SummaryRow]) -> Vec<(&'static str, Vec<f64>)> {
    let fields: [Statistic; 10] = [
        ("mean", |p| p.mean),
        ("sd", |p| p.sd),
        ("q05", |p| p.q05),
        ("q50", |p| p.q50),
        ("q95", |p| p.q95),
        ("ess_bulk", |p| p.ess_bulk),
        ("ess_tail", |p| p.ess_tail),
        ("r_hat", |p| p.r_hat),
        ("tau_int", |p| p.tau_int),
        ("mcse_mean", |p| p.mcse_mean),
    ];
    fields.into_iter().map(|(name, f)| (name, rows.iter().map(|r| f(&r.stats)).collect())).collect()
}

pub fn read(path: &Path) -> Result<Vec<SummaryRow>> {
    let df = read_parquet(path)?;
    let names = str_column(&df, "parameter", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (mean, sd, q05, q50, q95) =
        (col("mean")?, col("sd")?, col("q05")?, col("q50")?, col("q95")?);
    let (eb, et, rh, tau, mcse) =
        (col("ess_bulk")?, col("ess_tail")?, col("r_hat")?, col("tau_int")?, col("mcse_mean")?);
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
