//! `adequacy.parquet`: one row per run, where the calibrated law misses the
//! record (see [`crate::predict::adequacy`]), written by `predict` and read back by
//! the reports.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::Result;
use crate::predict::adequacy::{AdequacyRow, Excitation};

/// Writes the adequacy of a prediction from calibration `id`.
pub fn write(path: &Path, rows: &[AdequacyRow], id: &str) -> Result<()> {
    write_parquet(path, table(rows, id))
}

/// The table of `adequacy.parquet`.
pub fn table(rows: &[AdequacyRow], id: &str) -> Table {
    let f = |get: fn(&AdequacyRow) -> f64| rows.iter().map(get).collect::<Vec<f64>>();
    let mut t = Table::new()
        .derived_from(id)
        .str("run", rows.iter().map(|r| r.run.clone()).collect())
        .f64("current_a", f(|r| r.current_a))
        .str("excitation", rows.iter().map(|r| r.excitation.label()).collect())
        .f64("amplitude_m", f(|r| r.excitation.amplitude_m))
        .f64("frequency_hz", f(|r| r.excitation.frequency_hz))
        .f64("peak_velocity_m_s", f(|r| r.excitation.peak_velocity_m_s))
        .f64("peak_force_n", f(|r| r.peak_force_n))
        .f64("residual_rms_n", f(|r| r.residual_rms_n))
        .f64("lag1_autocorrelation", f(|r| r.lag1_autocorrelation))
        .f64("decorrelation_s", f(|r| r.decorrelation_s))
        .f64("interval_inflation", f(|r| r.interval_inflation))
        .f64("trend_offset_n", f(|r| r.trend_offset_n))
        .f64("trend_stiffness_n_per_m", f(|r| r.trend_stiffness_n_per_m))
        .f64("trend_damping_n_s_per_m", f(|r| r.trend_damping_n_s_per_m))
        .f64("trend_share", f(|r| r.trend_share))
        .f64("reversal_rms_n", f(|r| r.reversal_rms_n))
        .f64("stroke_rms_n", f(|r| r.stroke_rms_n))
        .f64("inside_p95", f(|r| r.inside_p95))
        .f64("inside_p95_reversal", f(|r| r.inside_p95_reversal))
        .f64("inside_p95_stroke", f(|r| r.inside_p95_stroke));
    if rows.iter().any(|r| r.innovation_lag1.is_finite()) {
        t = t.f64("innovation_lag1", f(|r| r.innovation_lag1));
    }
    t
}

pub fn read(path: &Path) -> Result<Vec<AdequacyRow>> {
    let df = read_parquet(path)?;
    let runs = str_column(&df, "run", path)?;
    let col = |n: &str| f64_column(&df, n, path);
    let (current, amplitude, frequency, peak_velocity) =
        (col("current_a")?, col("amplitude_m")?, col("frequency_hz")?, col("peak_velocity_m_s")?);
    let (peak, rms, lag1, decorrelation, inflation) = (
        col("peak_force_n")?,
        col("residual_rms_n")?,
        col("lag1_autocorrelation")?,
        col("decorrelation_s")?,
        col("interval_inflation")?,
    );
    let (offset, stiffness, damping, share) = (
        col("trend_offset_n")?,
        col("trend_stiffness_n_per_m")?,
        col("trend_damping_n_s_per_m")?,
        col("trend_share")?,
    );
    let innovation = if super::parquet::column_names(&df).iter().any(|c| c == "innovation_lag1") {
        col("innovation_lag1")?
    } else {
        vec![f64::NAN; runs.len()]
    };
    let (reversal, stroke, inside, inside_reversal, inside_stroke) = (
        col("reversal_rms_n")?,
        col("stroke_rms_n")?,
        col("inside_p95")?,
        col("inside_p95_reversal")?,
        col("inside_p95_stroke")?,
    );
    Ok((0..runs.len())
        .map(|i| AdequacyRow {
            run: runs[i].clone(),
            current_a: current[i],
            excitation: Excitation {
                amplitude_m: amplitude[i],
                frequency_hz: frequency[i],
                peak_velocity_m_s: peak_velocity[i],
            },
            peak_force_n: peak[i],
            residual_rms_n: rms[i],
            lag1_autocorrelation: lag1[i],
            decorrelation_s: decorrelation[i],
            innovation_lag1: innovation[i],
            interval_inflation: inflation[i],
            trend_offset_n: offset[i],
            trend_stiffness_n_per_m: stiffness[i],
            trend_damping_n_s_per_m: damping[i],
            trend_share: share[i],
            reversal_rms_n: reversal[i],
            stroke_rms_n: stroke[i],
            inside_p95: inside[i],
            inside_p95_reversal: inside_reversal[i],
            inside_p95_stroke: inside_stroke[i],
        })
        .collect())
}
