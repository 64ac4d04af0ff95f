//! `identification.parquet`: one row per run (or "all", the combined
//! estimate) and quantity of the paper's identification.

use std::path::Path;

use super::parquet::{f64_column, read_parquet, str_column, write_parquet, Table};
use crate::error::Result;

/// The file's name in a calibration or identification folder.
pub const FILE: &str = "identification.parquet";

/// One row of the file: a quantity of one run (or "all") at one current,
/// as identified and before the combined estimate was pulled into the
/// physical range (`raw_value`).
#[derive(Clone, Debug, PartialEq)]
pub struct IdentificationRow {
    pub run: String,
    pub current_a: f64,
    pub parameter: String,
    pub value: f64,
    pub raw_value: f64,
}

pub fn read(path: &Path) -> Result<Vec<IdentificationRow>> {
    let df = read_parquet(path)?;
    let (run, parameter) = (str_column(&df, "run", path)?, str_column(&df, "parameter", path)?);
    let (current, value, raw) = (
        f64_column(&df, "current_a", path)?,
        f64_column(&df, "value", path)?,
        f64_column(&df, "raw_value", path)?,
    );
    Ok((0..run.len())
        .map(|i| IdentificationRow {
            run: run[i].clone(),
            current_a: current[i],
            parameter: parameter[i].clone(),
            value: value[i],
            raw_value: raw[i],
        })
        .collect())
}
use crate::identify::CurrentIdentification;
use crate::model::PARAM_NAMES;

/// Writes `identification.parquet` with one row per run and quantity plus
/// the combined estimate (`run` = "all") per current; `id` names the
/// calibration it started, if any.
pub fn write(path: &Path, results: &[CurrentIdentification], id: Option<&str>) -> Result<()> {
    let (mut run, mut current, mut parameter, mut value, mut raw) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut push = |r: &str, c: f64, p: &str, v: f64, rv: f64| {
        run.push(r.to_string());
        current.push(c);
        parameter.push(p.to_string());
        value.push(v);
        raw.push(rv);
    };
    for res in results {
        let c = res.current_a;
        for (i, r) in res.runs.iter().enumerate() {
            let (tau02, rate02) = r.yield_point.unwrap_or((f64::NAN, f64::NAN));
            for (name, v) in [("G", r.g), ("R1", r.r1), ("D1", r.d1), ("m1", r.m1), ("m2", r.m2)] {
                push(&r.run, c, name, v, v);
            }
            push(&r.run, c, "tau02_pa", tau02, tau02);
            push(&r.run, c, "gamma_i_rate_at_tau02", rate02, rate02);
            push(&r.run, c, "elastic_samples", r.elastic_points as f64, r.elastic_points as f64);
            if let Some(f) = &r.curve {
                for (name, v) in [
                    ("eq7_a", f.eq7.a),
                    ("eq7_b", f.eq7.b),
                    ("eq7_c", f.eq7.c),
                    ("eq7_d", f.eq7.d),
                    ("eq7_rms_pa", f.rms),
                ] {
                    push(&r.run, c, name, v, v);
                }
                push(
                    &r.run, c, "eq7_converged", f.converged as u8 as f64, f.converged as u8 as f64,
                );
            }
            if let Some(f) = &r.steady {
                for (name, v) in [
                    ("flow_curve_saturated_stress_pa", f.z),
                    ("flow_curve_n", f.n),
                    ("flow_curve_samples", f.flow_samples as f64),
                    ("flow_curve_rms_log", f.rms_log),
                ] {
                    push(&r.run, c, name, v, v);
                }
            }
            push(&r.run, c, "euler_rms_pa", res.euler_rms[i], res.euler_rms[i]);
        }
        for (k, name) in PARAM_NAMES.iter().enumerate() {
            push("all", c, name, res.params.to_array()[k], res.raw[k]);
        }
        push("all", c, "eq6_rms_log", res.yield_fit.rms_log, res.yield_fit.rms_log);
    }
    let table = match id {
        Some(id) => Table::new().derived_from(id),
        None => Table::new(),
    };
    write_parquet(
        path,
        table
            .str("run", run)
            .f64("current_a", current)
            .str("parameter", parameter)
            .f64("value", value)
            .f64("raw_value", raw),
    )
}
