//! Tempered sequential Monte Carlo (Del Moral, Doucet & Jasra 2006; the
//! TMCMC of Ching & Chen 2007): a population of particles drawn from a
//! reference density r is carried to the target p through the tempered
//! densities π_β ∝ r^(1−β) p^β, 0 = β₀ < β₁ < … < 1. At each temperature
//! the particles are reweighted by (p/r)^(β' − β) — β' chosen so that
//! the weights keep a set effective sample size ([`tempering`]) —,
//! resampled ([`resample`]) and then moved by the ensemble sampler's moves
//! on π_β' ([`super::Sampler`] on a [`Tempered`] target) until nearly every
//! particle has moved. The product of the mean weights estimates the
//! target's normalising constant, the evidence where the target is a
//! prior times a likelihood ([`evidence`]).
//!
//! Several independent populations are run, one after another: their
//! spread measures the evidence's error and their final particles' R̂ how
//! well they agree. A basin of the target holds particles in proportion to
//! its mass (the reweighting sets it; the moves need not cross between
//! basins). Every random number comes from a stream keyed by (seed,
//! population, temperature, …): the same seed gives the same particles
//! whatever the number of threads.

pub mod checkpoint;
pub mod evidence;
pub mod resample;
pub mod tempering;

pub use super::observer::Stage;
pub use evidence::Evidence;
pub use tempering::{Reference, Tempered};

use rand::Rng;
use serde::{Deserialize, Serialize};

use super::chains::Chains;
use super::density::{log_densities, LogDensity};
use super::diagnostics::split_rhat;
use super::moves::Move;
use super::settings::SamplerSettings;
use super::Sampler;
use crate::error::{Error, Result};

/// Stream of a population's draws from the reference.
const DRAW_STREAM: u64 = u64::MAX - 10;
/// Stream of a temperature's resampling.
const RESAMPLE_STREAM: u64 = u64::MAX - 11;
/// Stream that seeds a temperature's mutation.
const MUTATE_STREAM: u64 = u64::MAX - 12;

/// The smallest temperature at which ln p is recovered from ln π_β and
/// ln r ([`Tempered::target_part`]) rather than evaluated again: dividing
/// by β magnifies the rounding of ln π_β (about 1e-16 of its size) by
/// 1/β, 4e-8 nats for a log-density of 2e5 at this β, while a first step
/// forced tiny by particles whose density is astronomically small (as
/// extreme parameters of a law make it) would turn it into nonsense.
const RECOVER_FROM: f64 = 1e-3;

/// What a sequential Monte Carlo run is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmcSettings {
    /// Particles per population (even, at least 2 × dim: the moves' red-blue
    /// halves).
    pub particles: usize,
    /// Independent populations.
    pub populations: usize,
    /// The ensemble moves that mutate a population, with their weights.
    pub moves: Vec<(Move, f64)>,
    /// The effective sample size each reweighting keeps, as a share of the
    /// particles.
    pub ess_fraction: f64,
    /// A temperature's mutation stops once the chance that a particle has
    /// not moved (the product over steps of one minus the acceptance rate)
    /// is below `unmoved` and the correlation across the particles between
    /// their positions before and after (root mean square over the
    /// coordinates, less its value by chance) is below `correlation` …
    pub unmoved: f64,
    pub correlation: f64,
    /// … or after this many steps.
    pub max_steps: usize,
    pub seed: u64,
}

impl Default for SmcSettings {
    fn default() -> Self {
        SmcSettings {
            particles: 256,
            populations: 4,
            moves: vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
            ess_fraction: 0.9,
            unmoved: 0.01,
            correlation: 0.03,
            max_steps: 50,
            seed: 1,
        }
    }
}

impl SmcSettings {
    /// Checks the settings against a target of `dim` coordinates.
    pub fn check(&self, dim: usize) -> Result<()> {
        if !self.particles.is_multiple_of(2) || self.particles < 2 * dim.max(2) {
            return Err(Error::Usage(format!(
                "particles per population must be even and at least 2 × dimension = {}; got {}",
                2 * dim.max(2),
                self.particles
            )));
        }
        // the moves, against a population that passed the test above
        self.mutation(0).check(dim)?;
        if self.populations == 0 {
            return Err(Error::Usage("at least one population is needed".into()));
        }
        if !(self.ess_fraction > 0.0 && self.ess_fraction < 1.0) {
            return Err(Error::Usage(format!(
                "the ESS kept at each temperature is a share in (0, 1); got {}",
                self.ess_fraction
            )));
        }
        let share = |v: f64| v > 0.0 && v < 1.0;
        if !share(self.unmoved) || !share(self.correlation) || self.max_steps == 0 {
            return Err(Error::Usage(format!(
                "a mutation needs a chance and a correlation in (0, 1) and at least one step; got {}, {} and {}",
                self.unmoved, self.correlation, self.max_steps
            )));
        }
        Ok(())
    }

    /// The ensemble sampler that mutates a population, seeded `seed`.
    fn mutation(&self, seed: u64) -> SamplerSettings {
        SamplerSettings { walkers: self.particles, ensembles: 1, moves: self.moves.clone(), seed }
    }
}

/// A population carried to β = 1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Population {
    /// The particles, one after another (equal weights).
    pub positions: Vec<f64>,
    /// ln p at each.
    pub log_prob: Vec<f64>,
    pub stages: Vec<Stage>,
    /// ln Ẑ and its delta-method variance ([`evidence`]).
    pub log_z: f64,
    pub variance: f64,
}

/// A run: its populations and the evidence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SmcRun {
    pub dim: usize,
    pub populations: Vec<Population>,
    pub evidence: Evidence,
}

impl SmcRun {
    /// The final particles as a one-step history, each population an
    /// ensemble (the ensemble sampler continues from it, and the
    /// diagnostics read it).
    pub fn chains(&self) -> Chains {
        let walkers = self.populations.first().map_or(0, |p| p.log_prob.len());
        Chains {
            dim: self.dim,
            ensembles: self.populations.len(),
            walkers,
            positions: self.populations.iter().flat_map(|p| p.positions.iter().copied()).collect(),
            log_prob: self.populations.iter().flat_map(|p| p.log_prob.iter().copied()).collect(),
            accepted: vec![false; walkers * self.populations.len()],
        }
    }

    /// The rank-normalised split-R̂ of `f` over the populations' final
    /// particles (each population a chain; its particles are exchangeable,
    /// so their order does not matter).
    pub fn rhat(&self, f: impl Fn(&[f64]) -> f64) -> f64 {
        let d = self.dim.max(1);
        let chains: Vec<Vec<f64>> = self
            .populations
            .iter()
            .map(|p| p.positions.chunks_exact(d).map(&f).collect())
            .collect();
        split_rhat(&chains)
    }
}

/// What a run tells its observer: each temperature of a population, and
/// the populations finished so far after each one (with what they were
/// made from, for a checkpoint).
pub trait SmcObserver {
    fn tempered(&mut self, _population: usize, _stage: &Stage) {}
    fn populated(&mut self, _key: &checkpoint::Key, _done: &[Population]) -> Result<()> {
        Ok(())
    }
}

/// An observer that is told nothing.
impl SmcObserver for () {}

/// Runs every population of `settings` from `reference` to `target`,
/// after the populations `saved` (of a checkpoint of the same run: the
/// first ones, as the run makes them), telling `observer` each
/// temperature and each finished population. `stop` is asked between
/// temperatures: where it says so, the run ends with
/// [`Error::Interrupted`].
pub fn run<T: LogDensity>(
    target: &T,
    reference: &Reference,
    settings: &SmcSettings,
    saved: Vec<Population>,
    observer: &mut dyn SmcObserver,
    stop: &dyn Fn() -> bool,
) -> Result<SmcRun> {
    let d = target.dim();
    settings.check(d)?;
    if reference.dist.dim() != d {
        return Err(Error::Usage(format!(
            "a reference of {} coordinates for a target of {d}",
            reference.dist.dim()
        )));
    }
    let key = checkpoint::Key::of(d, reference, settings);
    let mut populations = saved;
    populations.truncate(settings.populations);
    for p in populations.len()..settings.populations {
        let mut told = |population: usize, stage: &Stage| observer.tempered(population, stage);
        let made = population(target, reference, settings, p as u64, &mut told, stop)?;
        populations.push(made);
        observer.populated(&key, &populations)?;
    }
    let log_z: Vec<f64> = populations.iter().map(|p| p.log_z).collect();
    let variances: Vec<f64> = populations.iter().map(|p| p.variance).collect();
    Ok(SmcRun { dim: d, evidence: Evidence::combine(&log_z, &variances), populations })
}

/// How much of where the particles were is left in where they are: the
/// root mean square over coordinates of corr(xᵢ, yᵢ) across the particles,
/// less what N independent pairs would show by chance (E r² = 1/(N − 1)),
/// so that the rule can be met by any number of particles (a coordinate
/// that does not vary counts 0).
fn remaining_correlation(x: &[f64], y: &[f64], d: usize) -> f64 {
    let n = (x.len() / d.max(1)) as f64;
    let mean_square = (0..d)
        .map(|i| {
            let column = |v: &[f64]| -> Vec<f64> { v.chunks_exact(d).map(|p| p[i]).collect() };
            let (a, b) = (column(x), column(y));
            let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
            let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
            for (u, v) in a.iter().zip(&b) {
                sab += (u - ma) * (v - mb);
                saa += (u - ma) * (u - ma);
                sbb += (v - mb) * (v - mb);
            }
            if saa > 0.0 && sbb > 0.0 {
                sab * sab / (saa * sbb)
            } else {
                0.0
            }
        })
        .sum::<f64>()
        / d.max(1) as f64;
    (mean_square - 1.0 / (n - 1.0)).max(0.0).sqrt()
}

/// One population, from the reference to β = 1.
fn population<T: LogDensity>(
    target: &T,
    reference: &Reference,
    settings: &SmcSettings,
    p: u64,
    observer: &mut dyn FnMut(usize, &Stage),
    stop: &dyn Fn() -> bool,
) -> Result<Population> {
    let (d, n, seed) = (target.dim(), settings.particles, settings.seed);
    let mut x = vec![0.0; n * d];
    for (i, xi) in x.chunks_exact_mut(d).enumerate() {
        reference.draw(&mut crate::rng::stream(seed, &[p, i as u64, DRAW_STREAM]), xi);
    }
    let mut log_p = log_densities(target, &x);
    let mut log_r: Vec<f64> = x.chunks_exact(d).map(|xi| reference.log_density(xi)).collect();
    let (mut beta, mut stages, mut log_z, mut variance) = (0.0, Vec::new(), 0.0, 0.0);
    while beta < 1.0 {
        if stop() {
            return Err(Error::Interrupted(format!(
                "sequential Monte Carlo stopped in population {} at β = {beta:.3e}",
                p + 1
            )));
        }
        let delta: Vec<f64> = log_p
            .iter()
            .zip(&log_r)
            .map(|(lp, lr)| if *lp > f64::NEG_INFINITY { lp - lr } else { f64::NEG_INFINITY })
            .collect();
        if delta.iter().all(|v| *v == f64::NEG_INFINITY) {
            return Err(Error::Compute(format!(
                "population {p}: no particle lies where the target's density is finite (β = {beta:.3e})"
            )));
        }
        let next = tempering::next_beta(beta, &delta, settings.ess_fraction * n as f64);
        let log_w = tempering::log_weights(beta, next, &delta);
        let ess = tempering::ess(&log_w);
        let log_increment = crate::numeric::log_mean_exp(&log_w);
        log_z += log_increment;
        variance += (1.0 / ess - 1.0 / n as f64).max(0.0);
        let stage = stages.len() as u64;
        let picks = resample::systematic(
            &log_w,
            n,
            &mut crate::rng::stream(seed, &[p, stage, RESAMPLE_STREAM]),
        );
        x = picks.iter().flat_map(|&i| x[i * d..(i + 1) * d].iter().copied()).collect();
        log_p = picks.iter().map(|&i| log_p[i]).collect();
        log_r = picks.iter().map(|&i| log_r[i]).collect();
        beta = next;
        let tempered = Tempered { target, reference, beta };
        let log_t: Vec<f64> =
            log_p.iter().zip(&log_r).map(|(a, b)| tempered.combine(*a, *b)).collect();
        let mutation_seed = crate::rng::stream(seed, &[p, stage, MUTATE_STREAM]).next_u64();
        let mut sampler =
            Sampler::from_state(&tempered, settings.mutation(mutation_seed), x, log_t)?
                .with_reference(reference.dist.clone());
        let before = sampler.chains.last_positions().to_vec();
        let (mut steps, mut unmoved, mut accepted) = (0, 1.0, 0);
        while steps < settings.max_steps {
            let a = sampler.step();
            accepted += a;
            unmoved *= 1.0 - a as f64 / n as f64;
            steps += 1;
            if steps >= 2
                && unmoved <= settings.unmoved
                && remaining_correlation(&before, sampler.chains.last_positions(), d)
                    <= settings.correlation
            {
                break;
            }
        }
        x = sampler.chains.last_positions().to_vec();
        log_r = x.chunks_exact(d).map(|xi| reference.log_density(xi)).collect();
        log_p = if beta >= RECOVER_FROM {
            sampler
                .chains
                .last_log_prob()
                .iter()
                .zip(&log_r)
                .map(|(lt, lr)| tempered.target_part(*lt, *lr))
                .collect()
        } else {
            log_densities(target, &x)
        };
        let stage = Stage {
            beta,
            ess,
            log_increment,
            steps,
            acceptance: accepted as f64 / (steps * n) as f64,
        };
        observer(p as usize, &stage);
        stages.push(stage);
    }
    Ok(Population { positions: x, log_prob: log_p, stages, log_z, variance })
}
