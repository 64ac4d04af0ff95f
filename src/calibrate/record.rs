//! What a calibration did (`calibration.toml`): its campaign and runs, its
//! start (identification, MAP, step study), the sampler's run, timings and
//! warnings, and the id that files derived from it carry.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::sampling::Sampled;
use super::start::Start;
use crate::data::{Campaign, Geometry, RecordPart};
use crate::model::PARAM_NAMES;
use crate::noise::NoiseKind;
use crate::posterior::laplace::IntervalRow;

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StepRow {
    pub substeps: u32,
    pub largest_shift_sd: f64,
    pub parameter: String,
}

/// `calibration.toml`, read back by `predict`, `report` and `compare`.
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
    /// The current the parameters describe (a current law's reference).
    pub current_a: f64,
    pub runs: Vec<String>,
    /// The nominal coil current of each run, in `runs`' order (A); empty
    /// in folders written before it was recorded.
    #[serde(default)]
    pub run_currents: Vec<f64>,
    pub noise: NoiseKind,
    pub part: RecordPart,
    pub substeps: u32,
    #[serde(default)]
    pub seed: u64,
    pub step_study: Vec<StepRow>,
    pub identification: BTreeMap<String, f64>,
    pub map: BTreeMap<String, f64>,
    pub map_log_density: f64,
    pub laplace_sd_log: BTreeMap<String, f64>,
    /// The sd (nats) of ln p/q over the initial walkers, draws of the
    /// Laplace approximation q at the mode: near 0 where q describes the
    /// posterior; above 8 the run walked as for a posterior far from
    /// Gaussian (docs/calibration.md, "The start"). Absent in folders
    /// written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub laplace_spread_nats: Option<f64>,
    pub walkers: usize,
    pub ensembles: usize,
    pub steps: usize,
    /// The step at which R̂ < 1.01, ESS ≥ 400 and chains 10 τ long first
    /// held: a run stopped later waited to confirm them (docs/calibration.md,
    /// "Convergence"). Absent where they never held, or in folders written
    /// before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_converged_step: Option<usize>,
    pub burn_in: usize,
    pub seconds_start: f64,
    pub seconds_sampling: f64,
    /// Bulk ESS per second of the whole calibration's wall time, per
    /// parameter: what the calibration's cost bought.
    #[serde(default)]
    pub ess_bulk_per_second: BTreeMap<String, f64>,
    /// The sampler's warnings (convergence, stuck walkers).
    pub warnings: Vec<String>,
    /// What the start found about the model's fit (residuals with memory).
    #[serde(default)]
    pub model_warnings: Vec<String>,
    /// Where the noise model's own force (a discrepancy, AR(1)) took over
    /// force the law alone carries: its law-path RMS against the law
    /// alone's, all runs together and run by run (empty: within the ratio,
    /// or a noise without a force).
    #[serde(default)]
    pub confounding: Vec<String>,
    /// Where `memory = "auto"` found memory in the MAP residuals: what it
    /// found and the likelihood it chose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub memory_found: Option<String>,
    /// Where the likelihood allows for the residuals' memory: each
    /// coordinate's interval had the residuals been taken as independent
    /// (the Laplace approximation of that posterior at its mode), shown
    /// beside the posterior's own. Empty otherwise.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub independent: Vec<IntervalRow>,
    /// Where the posterior was sampled by sequential Monte Carlo first
    /// (`--sampler smc`): its temperatures and the integral of the
    /// posterior density.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smc: Option<SmcRecord>,
    /// The campaign's geometry (A, h): what turns the bands into forces.
    #[serde(default)]
    pub geometry: Option<Geometry>,
    /// Names this calibration: files derived from it record it, so a later
    /// stage can tell them from those of an earlier calibration.
    #[serde(default)]
    pub calibration_id: String,
}

/// What sequential Monte Carlo did before the ensemble sampler
/// (`[smc]` of calibration.toml).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmcRecord {
    /// The reference it started from.
    pub reference: String,
    /// Each population's temperatures, from the first above 0 to 1.
    pub temperatures: Vec<Vec<f64>>,
    /// Each population's mutation steps at each temperature.
    pub mutation_steps: Vec<Vec<usize>>,
    /// ln ∫ p(x) dx of the posterior density p as mrbp evaluates it, in the
    /// sampler's coordinates: its priors and likelihood without their
    /// normalising constants, so only a difference between two
    /// calibrations with the same priors, noise model and records is a log
    /// Bayes factor.
    pub log_integral: f64,
    /// The log evidence ln p(records | law, priors, noise model):
    /// `log_integral` with the priors' and the likelihood's normalising
    /// constants ([`crate::posterior::Posterior::log_evidence_offset`]); the
    /// same standard errors. Where the likelihood allowed for the
    /// residuals' memory (tempered or adjusted), of that likelihood:
    /// `evidence_of` says which.
    pub log_evidence: f64,
    pub evidence_of: String,
    /// Whether it is a pseudo-evidence (of a tempered or adjusted
    /// likelihood).
    pub pseudo_evidence: bool,
    /// Its standard error from the incremental weights and from the spread
    /// of the populations' estimates.
    pub se_weights: f64,
    pub se_spread: f64,
    /// Each population's estimate.
    pub per_population: Vec<f64>,
    /// The rank-normalised split-R̂ of each coordinate over the final
    /// particles, each population a chain (largest).
    pub max_rhat: f64,
    /// Posterior evaluations and wall time (s).
    pub evaluations: usize,
    pub seconds: f64,
}

impl SmcRecord {
    /// Its larger standard error (the weights', the populations' spread).
    pub fn se(&self) -> f64 {
        self.se_weights.max(self.se_spread)
    }

    /// One sentence for the printed summary and the report: the ladder it
    /// climbed, the log evidence with its standard error, what that is of.
    pub fn summary(&self) -> String {
        let rungs: Vec<usize> = self.temperatures.iter().map(Vec::len).collect();
        let (lo, hi) =
            (rungs.iter().copied().min().unwrap_or(0), rungs.iter().copied().max().unwrap_or(0));
        let ladder = if lo == hi { format!("{lo}") } else { format!("{lo}–{hi}") };
        let steps: usize = self.mutation_steps.iter().flatten().sum();
        format!(
            "sequential Monte Carlo from {}: {} population(s), {ladder} temperature(s) each, {steps} mutation steps in all, {} log-densities, {:.1} s; log evidence {:.2} ± {:.2} (standard error: weights {:.2}, populations' spread {:.2}), of {}",
            self.reference,
            self.per_population.len(),
            self.evaluations,
            self.seconds,
            self.log_evidence,
            self.se(),
            self.se_weights,
            self.se_spread,
            self.evidence_of
        )
    }
}

/// A name for a new calibration: when and by which process it was made.
fn new_calibration_id() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{nanos:x}-{:x}", std::process::id())
}

/// The command line of this process, for the records.
pub fn command_line() -> String {
    let mut args = std::env::args();
    let program = args.next().map(|p| {
        std::path::Path::new(&p).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or(p)
    });
    program.into_iter().chain(args).collect::<Vec<_>>().join(" ")
}

impl CalibrationRecord {
    /// How many runs the residual-memory warning names (its remedy line
    /// aside).
    pub fn runs_with_memory(&self) -> usize {
        // the remedy line names no run: known by its lead, the same in
        // every version's wording
        let lead = super::MEMORY_REMEDY.split(" (").next().unwrap_or(super::MEMORY_REMEDY);
        let remedy = |w: &str| w.starts_with(lead);
        self.model_warnings.iter().filter(|w| !remedy(w)).count()
    }

    /// The record of a calibration of `campaign` that started at `start`,
    /// took `walkers_start` seconds more to place its walkers (the Laplace
    /// approximation at the mode and the initial positions, over which
    /// ln p/q spread by `laplace_spread` nats) and sampled `sampled`.
    pub fn of(
        campaign: &Campaign,
        start: &Start,
        walkers_start: f64,
        laplace_spread: f64,
        sampled: &Sampled,
    ) -> CalibrationRecord {
        let seconds_start = start.seconds + walkers_start;
        let names = &start.posterior.layout.names;
        let coordinates = start.posterior.layout.coordinate_names();
        let named = |v: &[f64]| names.iter().zip(v).map(|(n, v)| (n.clone(), *v)).collect();
        let manifest = std::fs::canonicalize(&campaign.manifest_path)
            .unwrap_or(campaign.manifest_path.clone());
        CalibrationRecord {
            mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
            command: command_line(),
            campaign: campaign.name.clone(),
            currents: campaign.currents(),
            manifest: manifest.display().to_string(),
            current_a: start.posterior.model.describes_current(start.current_a),
            runs: campaign.runs.iter().map(|r| r.id().to_string()).collect(),
            run_currents: campaign.runs.iter().map(|r| r.spec.current_a).collect(),
            noise: start.settings.likelihood.noise,
            part: start.settings.likelihood.part,
            substeps: start.settings.integrator.substeps,
            seed: start.settings.sampler.seed,
            step_study: start
                .step_study
                .iter()
                .map(|s| {
                    let (i, v) = s.worst();
                    StepRow {
                        substeps: s.substeps,
                        largest_shift_sd: v,
                        parameter: coordinates[i].clone(),
                    }
                })
                .collect(),
            identification: start
                .identification
                .iter()
                .flat_map(|id| PARAM_NAMES.iter().zip(id.params.to_array()))
                .map(|(n, v)| (n.to_string(), v))
                .collect(),
            map: named(&start.posterior.layout.to_si(&start.map.x)),
            map_log_density: start.map.log_density,
            laplace_sd_log: named(&start.map.log_theta_sd(&start.posterior.layout)),
            laplace_spread_nats: laplace_spread.is_finite().then_some(laplace_spread),
            walkers: start.settings.sampler.walkers,
            ensembles: start.settings.sampler.ensembles,
            steps: sampled.diagnostics.steps,
            first_converged_step: sampled.first_held,
            burn_in: sampled.diagnostics.burn_in,
            seconds_start,
            seconds_sampling: sampled.seconds,
            ess_bulk_per_second: names
                .iter()
                .zip(&sampled.diagnostics.coordinates)
                .map(|(n, d)| (n.clone(), d.ess_bulk / (seconds_start + sampled.seconds)))
                .collect(),
            warnings: sampled.diagnostics.warnings.clone(),
            model_warnings: start.warnings.clone(),
            confounding: Vec::new(),
            memory_found: start.memory_found.clone(),
            smc: None,
            independent: start.independent.clone(),
            geometry: Some(campaign.geometry),
            calibration_id: new_calibration_id(),
        }
    }
}
