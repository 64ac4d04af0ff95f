//! Sequential Monte Carlo before the ensemble sampler (`--sampler smc`):
//! from a Student-t about the Laplace approximation at the mode to the
//! posterior ([`crate::sampler::smc`]), each of the sampler's ensembles a
//! population of its walkers; the ensemble sampler then continues from the
//! final particles, whose basins hold walkers in proportion to their mass.

use std::path::Path;
use std::time::Instant;

use super::evidence::{evidence_of, RECORDS_OWN};
use super::record::SmcRecord;
use super::settings::SMC_REFERENCE_DF;
use crate::error::Result;
use crate::posterior::Posterior;
use crate::sampler::smc::{self, Reference, SmcSettings};
use crate::sampler::{Elliptical, LogDensity, Observer, Sampler, SamplerSettings};

/// Forwards what sequential Monte Carlo tells to the sampler's observers.
struct Told<'a, 'b>(&'a mut [&'b mut dyn Observer]);

impl smc::SmcObserver for Told<'_, '_> {
    fn tempered(&mut self, population: usize, stage: &smc::Stage) {
        for o in self.0.iter_mut() {
            o.tempered(population, stage);
        }
    }
    fn populated(&mut self, key: &smc::checkpoint::Key, done: &[smc::Population]) -> Result<()> {
        let write = |path: &Path| smc::checkpoint::save(path, key, done);
        self.0.iter_mut().try_for_each(|o| o.populated(done.len(), &write))
    }
}

/// The sampler that continues from sequential Monte Carlo's particles on
/// `posterior`, started from `laplace` with the walkers, ensembles, moves
/// and seed of `settings`; and what it did. The populations saved at
/// `saved` (a checkpoint of the same run, [`smc::checkpoint`]) are taken
/// as they are and the run goes on from the first one missing.
pub(crate) fn from_laplace<'t>(
    posterior: &'t Posterior,
    laplace: &Elliptical,
    settings: &SamplerSettings,
    saved: Option<&Path>,
    observers: &mut [&mut dyn Observer],
) -> Result<(Sampler<'t, Posterior>, SmcRecord)> {
    let clock = Instant::now();
    let reference = Reference { dist: laplace.clone(), df: Some(SMC_REFERENCE_DF) };
    let smc_settings = SmcSettings {
        particles: settings.walkers,
        populations: settings.ensembles,
        moves: settings.moves.clone(),
        seed: settings.seed,
        ..SmcSettings::default()
    };
    let key = smc::checkpoint::Key::of(posterior.dim(), &reference, &smc_settings);
    let done = match saved {
        Some(path) => smc::checkpoint::load(path, &key)?,
        None => Vec::new(),
    };
    let run = smc::run(
        posterior,
        &reference,
        &smc_settings,
        done,
        &mut Told(observers),
        &crate::interrupt::requested,
    )?;
    let chains = run.chains();
    let max_rhat = (0..run.dim).map(|i| run.rhat(|x| x[i])).fold(0.0, f64::max);
    let evaluations = run
        .populations
        .iter()
        .map(|p| settings.walkers * (1 + p.stages.iter().map(|s| s.steps).sum::<usize>()))
        .sum();
    let of = evidence_of(posterior);
    let record = SmcRecord {
        reference: format!(
            "Student-t ({SMC_REFERENCE_DF} degrees of freedom) about the Laplace approximation at the mode"
        ),
        temperatures: run.populations.iter().map(|p| p.stages.iter().map(|s| s.beta).collect()).collect(),
        mutation_steps: run
            .populations
            .iter()
            .map(|p| p.stages.iter().map(|s| s.steps).collect())
            .collect(),
        log_integral: run.evidence.log_z,
        log_evidence: run.evidence.log_z + posterior.log_evidence_offset(),
        evidence_of: of.to_string(),
        pseudo_evidence: of != RECORDS_OWN,
        se_weights: run.evidence.se_weights,
        se_spread: run.evidence.se_spread,
        per_population: run.evidence.per_population.clone(),
        max_rhat,
        evaluations,
        seconds: clock.elapsed().as_secs_f64(),
    };
    let sampler =
        Sampler::from_state(posterior, settings.clone(), chains.positions, chains.log_prob)?
            .with_reference(laplace.clone());
    Ok((sampler, record))
}
