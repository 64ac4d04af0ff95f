//! One calibration: the runs of one current level, from the identification
//! through the MAP start and the step rule to the posterior sample.

use std::time::Instant;

use crate::data::Campaign;
use crate::error::{Error, Result};
use crate::identify::{identify_current, CurrentIdentification};
use crate::model::Integrator;
use crate::posterior::map::{self, MapEstimate, StepCheck};
use crate::posterior::{CalibrationSettings, ModelKind, Posterior};
use crate::sampler::{Chains, Diagnostics, ParameterDiagnostics, RunControl, Sampler, SamplerSettings};

/// Everything a calibration produced.
pub struct Calibration {
    pub campaign: Campaign,
    pub current_a: f64,
    /// The settings actually used (walkers and sub-steps filled in).
    pub settings: CalibrationSettings,
    pub identification: CurrentIdentification,
    pub map: MapEstimate,
    pub step_study: Vec<StepCheck>,
    pub posterior: Posterior,
    pub names: Vec<String>,
    pub chains: Chains,
    /// Diagnostics in SI units, after burn-in.
    pub diagnostics: Diagnostics,
    pub seconds: CalibrationTimes,
}

#[derive(Clone, Copy, Debug, Default)]
pub struct CalibrationTimes {
    pub start: f64,
    pub sampling: f64,
}

/// Where a calibration keeps its sampler state, and whether to resume it.
#[derive(Clone, Debug, Default)]
pub struct Checkpointing {
    /// Save the sampler state here every `every` steps (atomically).
    pub path: Option<std::path::PathBuf>,
    pub every: usize,
    /// Continue from the state saved at `path` instead of starting anew:
    /// the chains then equal those of an uninterrupted run.
    pub resume: bool,
}

/// Calibrates the runs of `campaign`, which must all have one coil current.
pub fn calibrate(campaign: &Campaign, settings: &CalibrationSettings, progress: bool) -> Result<Calibration> {
    calibrate_with(campaign, settings, progress, &Checkpointing::default())
}

/// [`calibrate`] with a checkpoint of the sampler's state.
pub fn calibrate_with(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    progress: bool,
    checkpointing: &Checkpointing,
) -> Result<Calibration> {
    let currents = campaign.currents();
    let current_a = match settings.model {
        ModelKind::PerCurrent => {
            let [c] = currents[..] else {
                return Err(Error::Usage(format!("a calibration takes runs of one current; got {currents:?} A")));
            };
            c
        }
        ModelKind::CurrentLaw => {
            if currents.len() < 2 {
                return Err(Error::Usage(format!("the current law needs runs at two or more currents; got {currents:?} A")));
            }
            // identify at the current nearest the law's reference
            let r = settings.reference_current_a;
            currents.iter().copied().min_by(|a, b| (a - r).abs().total_cmp(&(b - r).abs())).unwrap_or(r)
        }
    };
    let clock = Instant::now();
    let mut settings = settings.clone();
    let identification = identify_current(campaign, current_a, &settings.identify);

    let integ = &settings.integrator;
    let base = Integrator {
        scheme: integ.scheme,
        extrapolate: integ.extrapolate,
        substeps: integ.substeps.max(1),
        max_substeps: integ.max_substeps,
        ..Integrator::default()
    };
    let posterior = Posterior::new(campaign, &settings, base);
    // the identification may be far off (docs/identification.md): also start
    // from the prior medians and keep the better optimum
    let from_identification: Vec<f64> = match &posterior.law {
        None => identification.params.to_array().to_vec(),
        Some(law) => law.start_from(&identification.params, current_a).to_vec(),
    }
    .iter()
    .map(|v| v.ln())
    .collect();
    let medians: Vec<f64> = posterior
        .priors
        .iter()
        .zip(&from_identification)
        .map(|(p, v)| p.centre().map(|(c, _)| c).unwrap_or(*v))
        .collect();
    let map = map::best_map(&posterior, &[from_identification, medians])
        .ok_or_else(|| Error::Compute("the MAP search failed from every start".into()))?;
    if progress {
        eprintln!("  MAP: log-density {:.1} after {:.1} s; choosing the integrator step", map.log_density, clock.elapsed().as_secs_f64());
    }
    let (substeps, map, step_study) = if integ.substeps == 0 {
        map::choose_substeps(&posterior, &map, base, integ.max_rule_substeps)
    } else {
        (integ.substeps, map, vec![])
    };
    settings.integrator.substeps = substeps;
    if progress {
        for s in &step_study {
            let (i, v) = s.worst();
            eprintln!("  step rule: {} sub-step(s): halving moves {} by {v:.3} sd", s.substeps, posterior.names()[i]);
        }
    }
    let posterior = posterior.with_integrator(Integrator { substeps, ..base });
    let names = posterior.names();
    let dim = names.len();
    if settings.sampler.walkers == 0 {
        settings.sampler.walkers = (2 * dim).max(24).div_ceil(2) * 2;
    }
    let s = &settings.sampler;
    let sampler_settings = SamplerSettings {
        walkers: s.walkers,
        ensembles: s.ensembles,
        moves: s.moves.clone(),
        seed: s.seed,
    };
    let init = map::initial_walkers(&posterior, &map, s.walkers * s.ensembles, s.seed);
    let start_seconds = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let mut sampler = match &checkpointing.path {
        Some(path) if checkpointing.resume => {
            let resumed = Sampler::resume(&posterior, path)?;
            if resumed.settings != sampler_settings {
                return Err(Error::input(path, "checkpoint of a sampler with other settings (walkers, ensembles, moves or seed)"));
            }
            if progress {
                eprintln!("  resuming from {} at step {}", path.display(), resumed.chains.steps() - 1);
            }
            resumed
        }
        _ => Sampler::new(&posterior, sampler_settings, &init)?,
    };
    let control = RunControl {
        max_steps: if s.steps > 0 { s.steps } else { s.max_steps },
        until_converged: s.steps == 0,
        check_every: s.check_every,
        min_ess: s.min_ess,
        checkpoint: checkpointing.path.clone().map(|p| (p, checkpointing.every.max(1))),
        progress,
    };
    sampler.run(&control)?;
    let chains = sampler.chains.clone();
    let sampling_seconds = clock.elapsed().as_secs_f64();

    let diagnostics = si_diagnostics(&posterior, &chains, (s.burn_in > 0).then_some(s.burn_in));
    Ok(Calibration {
        campaign: campaign.clone(),
        current_a,
        settings,
        identification,
        map,
        step_study,
        posterior,
        names,
        chains,
        diagnostics,
        seconds: CalibrationTimes { start: start_seconds, sampling: sampling_seconds },
    })
}

/// Diagnostics of the draws in SI units (θ, σ, ρ rather than their
/// logarithms), with the burn-in of the log-scale diagnostics unless given.
pub fn si_diagnostics(post: &Posterior, chains: &Chains, burn_in: Option<usize>) -> Diagnostics {
    let burn = burn_in.unwrap_or_else(|| Diagnostics::burn_in_rule(chains));
    let coords: Vec<ParameterDiagnostics> = (0..chains.dim)
        .map(|i| {
            let traces = chains.traces_of(burn, |x| post.coordinate_to_si(i, x[i]));
            ParameterDiagnostics::of(&traces, chains.ensembles)
        })
        .collect();
    Diagnostics::assemble(chains, burn, coords)
}
