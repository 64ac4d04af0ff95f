//! Outputs of a calibration: `chains.parquet`, `summary.parquet`,
//! `config.toml` (the settings used) and `calibration.toml` (start, step
//! study, timings), and the summary printed at the end.

use std::path::Path;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::{atomic_write, write_parquet, Table};
use crate::calibrate::Calibration;
use crate::error::{Error, Result};
use crate::model::PARAM_NAMES;

/// `chains.parquet`: one row per walker and step, burn-in included.
pub fn write_chains(path: &Path, cal: &Calibration) -> Result<()> {
    let ch = &cal.chains;
    let (nc, steps, d) = (ch.chains(), ch.steps(), ch.dim);
    let rows = nc * steps;
    let mut ensemble = Vec::with_capacity(rows);
    let mut chain = Vec::with_capacity(rows);
    let mut draw = Vec::with_capacity(rows);
    let mut cols: Vec<Vec<f64>> = vec![Vec::with_capacity(rows); d];
    let mut log_prob = Vec::with_capacity(rows);
    let mut accepted = Vec::with_capacity(rows);
    for c in 0..nc {
        for s in 0..steps {
            ensemble.push((c / ch.walkers) as i64);
            chain.push(c as i64);
            draw.push(s as i64);
            let x = &ch.positions[(s * nc + c) * d..(s * nc + c + 1) * d];
            for (col, v) in cols.iter_mut().zip(cal.posterior.to_si(x)) {
                col.push(v);
            }
            log_prob.push(ch.log_prob[s * nc + c]);
            accepted.push(ch.accepted[s * nc + c]);
        }
    }
    let mut t = Table::new().i64("ensemble", ensemble).i64("chain", chain).i64("draw", draw);
    for (name, col) in cal.names.iter().zip(cols) {
        t = t.f64(name, col);
    }
    write_parquet(path, t.f64("log_prob", log_prob).bool("accepted", accepted))
}

/// `summary.parquet`: one row per parameter (SI units).
pub fn write_summary(path: &Path, cal: &Calibration) -> Result<()> {
    let dg = &cal.diagnostics;
    let c = &dg.coordinates;
    let col = |f: &dyn Fn(&crate::sampler::ParameterDiagnostics) -> f64| c.iter().map(f).collect::<Vec<f64>>();
    let n = c.len();
    write_parquet(
        path,
        Table::new()
            .str("parameter", cal.names.clone())
            .f64("mean", col(&|p| p.mean))
            .f64("sd", col(&|p| p.sd))
            .f64("q05", col(&|p| p.q05))
            .f64("q50", col(&|p| p.q50))
            .f64("q95", col(&|p| p.q95))
            .f64("ess_bulk", col(&|p| p.ess_bulk))
            .f64("ess_tail", col(&|p| p.ess_tail))
            .f64("r_hat", col(&|p| p.r_hat))
            .f64("tau_int", col(&|p| p.tau_int))
            .f64("mcse_mean", col(&|p| p.mcse_mean))
            .i64("first_draw", vec![dg.burn_in as i64; n])
            .i64("last_draw", vec![dg.steps as i64; n])
            .i64("walkers", vec![cal.chains.chains() as i64; n]),
    )
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StepRow {
    pub substeps: u32,
    pub largest_shift_sd: f64,
    pub parameter: String,
}

/// `calibration.toml`: what a calibration did, read back by `predict`,
/// `report` and `compare`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct CalibrationRecord {
    pub mrbp_version: String,
    /// The command line that made it.
    #[serde(default)]
    pub command: String,
    pub campaign: String,
    /// The coil currents of the runs calibrated on.
    #[serde(default)]
    pub currents: Vec<f64>,
    /// The manifest, as an absolute path where it could be resolved.
    pub manifest: String,
    pub current_a: f64,
    pub runs: Vec<String>,
    pub noise: String,
    pub part: String,
    pub substeps: u32,
    #[serde(default)]
    pub seed: u64,
    pub step_study: Vec<StepRow>,
    pub identification: BTreeMap<String, f64>,
    pub map: BTreeMap<String, f64>,
    pub map_log_density: f64,
    pub laplace_sd_log: BTreeMap<String, f64>,
    pub walkers: usize,
    pub ensembles: usize,
    pub steps: usize,
    pub burn_in: usize,
    pub seconds_start: f64,
    pub seconds_sampling: f64,
    pub warnings: Vec<String>,
}

impl CalibrationRecord {
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        toml::from_str(&text).map_err(|e| Error::input(path, format!("not a calibration record: {}", e.message())))
    }
}

/// The command line of this process, for the record.
pub fn command_line() -> String {
    let mut args = std::env::args();
    let program = args.next().map(|p| Path::new(&p).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or(p));
    program.into_iter().chain(args).collect::<Vec<_>>().join(" ")
}

/// `config.toml` and `calibration.toml`.
pub fn write_records(dir: &Path, cal: &Calibration) -> Result<()> {
    let header = "# Settings actually used by this calibration; pass back with --config to repeat it.\n";
    atomic_write(&dir.join("config.toml"), format!("{header}{}", cal.settings.to_toml()?).as_bytes())?;
    let named = |v: &[f64]| cal.names.iter().zip(v).map(|(n, v)| (n.clone(), *v)).collect();
    let identified = PARAM_NAMES.iter().zip(cal.identification.params.to_array()).map(|(n, v)| (n.to_string(), v)).collect();
    let map_si = cal.posterior.to_si(&cal.map.x);
    let manifest = std::fs::canonicalize(&cal.campaign.manifest_path).unwrap_or(cal.campaign.manifest_path.clone());
    let rec = CalibrationRecord {
        mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
        command: command_line(),
        campaign: cal.campaign.name.clone(),
        currents: cal.campaign.currents(),
        manifest: manifest.display().to_string(),
        // a current law's parameters are those of its reference current
        current_a: if cal.posterior.law.is_some() { cal.settings.reference_current_a } else { cal.current_a },
        runs: cal.campaign.runs.iter().map(|r| r.id().to_string()).collect(),
        noise: format!("{:?}", cal.settings.likelihood.noise),
        part: format!("{:?}", cal.settings.likelihood.part),
        substeps: cal.settings.integrator.substeps,
        seed: cal.settings.sampler.seed,
        step_study: cal
            .step_study
            .iter()
            .map(|s| {
                let (i, v) = s.worst();
                StepRow { substeps: s.substeps, largest_shift_sd: v, parameter: cal.names[i].clone() }
            })
            .collect(),
        identification: identified,
        map: cal.names.iter().zip(&map_si).map(|(n, v)| (n.clone(), *v)).collect(),
        map_log_density: cal.map.log_density,
        laplace_sd_log: named(&cal.map.sd()),
        walkers: cal.settings.sampler.walkers,
        ensembles: cal.settings.sampler.ensembles,
        steps: cal.diagnostics.steps,
        burn_in: cal.diagnostics.burn_in,
        seconds_start: cal.seconds.start,
        seconds_sampling: cal.seconds.sampling,
        warnings: cal.diagnostics.warnings.clone(),
    };
    let text = toml::to_string(&rec).map_err(|e| Error::Compute(format!("writing calibration.toml: {e}")))?;
    atomic_write(&dir.join("calibration.toml"), format!("# What this calibration did (mrbp).\n{text}").as_bytes())
}

/// The posterior summary table and the diagnostics' verdict.
pub fn print_summary(cal: &Calibration) {
    let dg = &cal.diagnostics;
    let at = match &cal.posterior.law {
        Some(law) => format!("current law (reference {} A) from {:?} A", law.reference_a, cal.campaign.currents()),
        None => format!("posterior at {} A", cal.current_a),
    };
    println!(
        "\n{at}: {} walkers × {} steps, burn-in {} (τ_max {:.1}), {:?} noise, {} sub-step(s) per sample",
        cal.chains.chains(),
        dg.steps,
        dg.burn_in,
        dg.tau_max,
        cal.settings.likelihood.noise,
        cal.settings.integrator.substeps
    );
    println!(
        "{:<22} {:>11} {:>10} {:>11} {:>11} {:>11} {:>8} {:>8} {:>7} {:>6}",
        "parameter", "mean", "sd", "q05", "q50", "q95", "ess_bulk", "ess_tail", "r_hat", "tau"
    );
    for (name, p) in cal.names.iter().zip(&dg.coordinates) {
        println!(
            "{:<22} {:>11.4e} {:>10.3e} {:>11.4e} {:>11.4e} {:>11.4e} {:>8.0} {:>8.0} {:>7.4} {:>6.1}",
            name, p.mean, p.sd, p.q05, p.q50, p.q95, p.ess_bulk, p.ess_tail, p.r_hat, p.tau_int
        );
    }
    if dg.warnings.is_empty() {
        println!("diagnostics: R̂ < 1.01, chains longer than 50 τ, no stuck walkers");
    }
    for w in &dg.warnings {
        println!("warning: {w}");
    }
    println!(
        "wall time: {:.1} s (identification, MAP and step rule {:.1} s, sampling {:.1} s)",
        cal.seconds.start + cal.seconds.sampling,
        cal.seconds.start,
        cal.seconds.sampling
    );
}
