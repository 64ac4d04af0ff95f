//! `adequacy.parquet`: one row per run, where the calibrated law misses the
//! record (see [`crate::adequacy`]). Written by `predict` for pandas and
//! polars users; the report recomputes it from the bands, so nothing reads
//! it back here.

use std::path::Path;

use super::parquet::{write_parquet, Table};
use crate::adequacy::AdequacyRow;
use crate::error::Result;

pub fn write(path: &Path, rows: &[AdequacyRow]) -> Result<()> {
    let f = |get: fn(&AdequacyRow) -> f64| rows.iter().map(get).collect::<Vec<f64>>();
    let t = Table::new()
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
    write_parquet(path, t)
}
