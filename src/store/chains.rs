//! `chains.parquet`: every walker at every step, burn-in included, in SI
//! units: `ensemble`, `chain`, `draw`, one column per coordinate,
//! `log_prob`, `accepted`; rows chain by chain, steps in order.

use std::path::Path;

use super::parquet::{column_names, f64_column, read_parquet, write_parquet, Table};
use crate::error::{Error, Result};
use crate::posterior::{Layout, ParameterModel, PosteriorSample};
use crate::sampler::Chains;

const BOOKKEEPING: [&str; 5] = ["ensemble", "chain", "draw", "log_prob", "accepted"];

/// The columns of `chains.parquet`, in order: the integer bookkeeping
/// (`ensemble`, `chain`, `draw`), the coordinates and `log_prob`, and
/// `accepted`; rows chain by chain, steps in order. What the file and the
/// Python package's frame hold.
pub struct Columns {
    pub bookkeeping: Vec<(&'static str, Vec<i64>)>,
    pub values: Vec<(String, Vec<f64>)>,
    pub accepted: Vec<bool>,
}

/// The columns of `sample`'s chains.
pub fn columns(sample: &PosteriorSample) -> Columns {
    let ch = &sample.chains;
    let (nc, steps) = (ch.chains(), ch.steps());
    let order = || (0..nc).flat_map(move |c| (0..steps).map(move |s| (s, c)));
    let bookkeeping = vec![
        ("ensemble", order().map(|(_, c)| (c / ch.walkers) as i64).collect()),
        ("chain", order().map(|(_, c)| c as i64).collect()),
        ("draw", order().map(|(s, _)| s as i64).collect()),
    ];
    let mut values: Vec<(String, Vec<f64>)> = sample
        .layout
        .names
        .iter()
        .enumerate()
        .map(|(i, name)| (name.clone(), order().map(|(s, c)| ch.at(s, c, i)).collect()))
        .collect();
    values.push(("log_prob".into(), order().map(|(s, c)| ch.log_prob[s * nc + c]).collect()));
    Columns {
        bookkeeping,
        values,
        accepted: order().map(|(s, c)| ch.accepted[s * nc + c]).collect(),
    }
}

/// Writes the chains of calibration `id`.
pub fn write(path: &Path, sample: &PosteriorSample, id: &str) -> Result<()> {
    let columns = columns(sample);
    let mut t = Table::new().derived_from(id);
    for (name, values) in columns.bookkeeping {
        t = t.i64(name, values);
    }
    for (name, values) in columns.values {
        t = t.f64(&name, values);
    }
    write_parquet(path, t.bool("accepted", columns.accepted))
}

/// Reads the chains back; their coordinates must be those of `layout`,
/// their runs' currents `run_currents` (the record's; may be empty).
pub fn read(
    path: &Path,
    layout: &Layout,
    model: ParameterModel,
    run_currents: &[f64],
) -> Result<PosteriorSample> {
    let df = read_parquet(path)?;
    let chain = f64_column(&df, "chain", path)?;
    let draw = f64_column(&df, "draw", path)?;
    let ensemble = f64_column(&df, "ensemble", path)?;
    let log_prob = f64_column(&df, "log_prob", path)?;
    let accepted = f64_column(&df, "accepted", path)?;
    let rows = chain.len();
    let chains = chain.iter().fold(0.0f64, |m, c| m.max(*c)) as usize + 1;
    let steps = rows / chains.max(1);
    // the layout that `write` makes: chain-major, steps in order
    let ordered = rows > 0
        && steps * chains == rows
        && (0..rows).all(|r| chain[r] as usize == r / steps && draw[r] as usize == r % steps);
    if !ordered {
        return Err(Error::input(
            path,
            "rows are not ordered by chain and draw as `mrbp sample` writes them",
        ));
    }
    let names: Vec<String> =
        column_names(&df).into_iter().filter(|n| !BOOKKEEPING.contains(&n.as_str())).collect();
    if names != layout.names {
        return Err(Error::input(
            path,
            format!("columns {names:?} are not the calibration's {:?}", layout.names),
        ));
    }
    let ensembles = ensemble.iter().fold(0.0f64, |m, e| m.max(*e)) as usize + 1;
    let columns = names.iter().map(|n| f64_column(&df, n, path)).collect::<Result<Vec<_>>>()?;
    // file rows are chain-major, the sample is step-major
    let row = |s: usize, c: usize| c * steps + s;
    let order = || (0..steps).flat_map(move |s| (0..chains).map(move |c| (s, c)));
    let positions =
        order().flat_map(|(s, c)| columns.iter().map(move |col| col[row(s, c)])).collect();
    Ok(PosteriorSample {
        layout: layout.clone(),
        model,
        chains: Chains {
            dim: names.len(),
            ensembles,
            walkers: chains / ensembles.max(1),
            positions,
            log_prob: order().map(|(s, c)| log_prob[row(s, c)]).collect(),
            accepted: order().map(|(s, c)| accepted[row(s, c)] != 0.0).collect(),
        },
        run_currents: run_currents.to_vec(),
    })
}
