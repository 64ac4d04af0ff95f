//! A calibration's log evidence: what it is of, and, for a calibration the
//! ensemble sampler made, its estimate by bridge sampling from the chains
//! ([`crate::sampler::bridge`]; sequential Monte Carlo gives its own,
//! [`super::SmcRecord`]).

use super::Calibration;
use crate::data::Campaign;
use crate::error::{Error, Result};
use crate::posterior::Posterior;
use crate::sampler::bridge;

/// What an evidence of the records' own likelihood is of.
pub const RECORDS_OWN: &str = "the records given the law, its priors and the noise model";

/// What the log evidence of `posterior` is of: the records' own
/// likelihood, or the tempered or adjusted one that allowed for their
/// memory (a pseudo-evidence).
pub fn evidence_of(posterior: &Posterior) -> &'static str {
    if posterior.likelihood.adjustment().is_some() {
        "the adjusted likelihood (the residuals' memory allowed for): a pseudo-evidence, comparable only between calibrations adjusted alike"
    } else if (0..posterior.runs.len()).any(|j| posterior.weight(j) != 1.0) {
        "the tempered likelihood (each run's log-likelihood weighted by its residuals' memory): a pseudo-evidence, comparable only between calibrations tempered alike"
    } else {
        RECORDS_OWN
    }
}

/// [`Estimate::by`] of a calibration sampled by sequential Monte Carlo.
pub const SMC: &str = "sequential Monte Carlo";
/// [`Estimate::by`] of one the ensemble sampler made: bridge sampling
/// from its chains ([`by_bridge`]).
pub const BRIDGE: &str = "bridge sampling";

/// A calibration's log evidence, however it was estimated.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    pub log_evidence: f64,
    pub se: f64,
    /// What it is of ([`evidence_of`]).
    pub of: String,
    pub pseudo: bool,
    /// [`SMC`] or [`BRIDGE`].
    pub by: &'static str,
    /// The posterior draws bridged with ([`BRIDGE`] only).
    pub draws: Option<usize>,
}

/// The log evidence of `cal` (made of runs of `campaign`): sequential
/// Monte Carlo's where it was sampled so, else by bridge sampling from
/// its chains.
pub fn estimate(cal: &Calibration, campaign: &Campaign) -> Result<Estimate> {
    match by_smc(cal) {
        Some(recorded) => Ok(recorded),
        None => by_bridge(cal, campaign),
    }
}

/// The log evidence sequential Monte Carlo recorded, where it sampled `cal`.
pub fn by_smc(cal: &Calibration) -> Option<Estimate> {
    let smc = cal.record.smc.as_ref()?;
    Some(Estimate {
        log_evidence: smc.log_evidence,
        se: smc.se(),
        of: smc.evidence_of.clone(),
        pseudo: smc.pseudo_evidence,
        by: SMC,
        draws: None,
    })
}

/// Posterior draws at most on each side of the bridge (the proposal's fit,
/// the bridge): the cost is twice this many log-densities.
pub const BRIDGE_DRAWS: usize = 2000;

/// The random stream of the proposal's draws (beside the sampler's).
const BRIDGE_STREAM: u64 = 0xb71d6e;

/// The log evidence of `cal` (made of runs of `campaign`) by bridge
/// sampling from its chains: the draws after the burn-in, thinned by τ,
/// alternately to fit a Gaussian proposal and to bridge with, their
/// effective size at most half the smallest bulk ESS.
pub fn by_bridge(cal: &Calibration, campaign: &Campaign) -> Result<Estimate> {
    let runs = cal.used_runs(campaign);
    let integrator = cal.predict_settings(0, 0).integrator;
    let posterior = cal.settings.posterior(&runs, integrator);
    let layout = &posterior.layout;
    let sample = &cal.sample;
    let positions = cal.draws().positions(&sample.chains, 2 * BRIDGE_DRAWS);
    // alternately to fit the proposal and to bridge with (an odd last one
    // left out: the two sets the same size)
    let (mut fit, mut bridged) = (Vec::new(), Vec::new());
    for (i, &(step, chain)) in positions.iter().enumerate().take(positions.len() / 2 * 2) {
        let at = sample.chains.point(step, chain);
        let si: Vec<f64> = layout
            .names
            .iter()
            .map(|n| {
                sample.layout.index(n).map(|k| at[k]).ok_or_else(|| {
                    Error::Compute(format!(
                        "{}: the chains have no coordinate {n}: the folder's calibration is not its settings'",
                        cal.dir.display()
                    ))
                })
            })
            .collect::<Result<_>>()?;
        let into = if i % 2 == 0 { &mut fit } else { &mut bridged };
        into.extend(layout.from_si(&si));
    }
    let draws = bridged.len() / layout.names.len().max(1);
    let smallest_ess = cal
        .summary
        .iter()
        .map(|r| r.ess_bulk)
        .filter(|e| e.is_finite())
        .fold(f64::INFINITY, f64::min);
    let effective = (smallest_ess / 2.0).min(draws as f64);
    let mut rng = crate::rng::stream(cal.settings.sampler.seed, &[BRIDGE_STREAM]);
    let b = bridge::log_evidence(&posterior, &fit, &bridged, effective, &mut rng)?;
    let of = evidence_of(&posterior);
    Ok(Estimate {
        log_evidence: b.log_z + posterior.log_evidence_offset(),
        se: b.se,
        of: of.to_string(),
        pseudo: of != RECORDS_OWN,
        by: BRIDGE,
        draws: Some(draws),
    })
}
