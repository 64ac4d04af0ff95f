//! Several independent ensembles stepped together with the parallel
//! red-blue update (Foreman-Mackey et al. 2013, after Goodman & Weare 2010).

use std::path::{Path, PathBuf};

use rand::RngExt;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::diagnostics::Diagnostics;
use super::moves::Move;
use super::LogDensity;
use crate::error::{Error, Result};

/// Walkers proposed and evaluated together in one batch. Fixed, so that the
/// batching never depends on the number of threads.
const BATCH: usize = 8;

/// Relative change of τ_max between convergence checks counted as stable.
const TAU_STABLE: f64 = 0.05;

/// Index of the stream that picks the move of an ensemble's step.
const MOVE_STREAM: u64 = u64::MAX;

/// What the sampler is: ensembles, walkers, moves and seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplerSettings {
    /// Walkers per ensemble (even, at least 2 × dim).
    pub walkers: usize,
    /// Independent ensembles (R̂ compares them).
    pub ensembles: usize,
    /// Moves with their weights; one is picked per ensemble and step.
    pub moves: Vec<(Move, f64)>,
    pub seed: u64,
}

impl Default for SamplerSettings {
    fn default() -> Self {
        SamplerSettings {
            walkers: 32,
            ensembles: 4,
            moves: vec![(Move::default(), 1.0)],
            seed: 1,
        }
    }
}

impl SamplerSettings {
    fn check(&self, dim: usize) -> Result<()> {
        if self.walkers % 2 != 0 || self.walkers < 2 * dim.max(2) {
            return Err(Error::Usage(format!(
                "walkers per ensemble must be even and at least 2 × dimension = {}; got {}",
                2 * dim.max(2),
                self.walkers
            )));
        }
        if self.ensembles == 0 {
            return Err(Error::Usage("at least one ensemble is needed".into()));
        }
        if self.moves.is_empty() || self.moves.iter().any(|(_, w)| !(*w > 0.0) || !w.is_finite()) {
            return Err(Error::Usage("moves need positive, finite weights".into()));
        }
        for (m, _) in &self.moves {
            m.check().map_err(Error::Usage)?;
            if m.min_complement() > self.walkers / 2 {
                return Err(Error::Usage(format!("{m:?} needs more walkers")));
            }
        }
        Ok(())
    }
}

/// How long to run and what to do meanwhile.
#[derive(Clone, Debug)]
pub struct RunControl {
    /// Run until this many steps in total (including steps already taken).
    pub max_steps: usize,
    /// Stop earlier once converged (see [`Diagnostics::converged`]), checking
    /// every `check_every` steps. `false`: exactly `max_steps`.
    pub until_converged: bool,
    pub check_every: usize,
    /// Convergence also needs this bulk and tail ESS for every coordinate.
    pub min_ess: f64,
    /// Save the state here every `checkpoint_every` steps.
    pub checkpoint: Option<(PathBuf, usize)>,
    /// Show a progress bar on a terminal.
    pub progress: bool,
}

impl RunControl {
    pub fn fixed(steps: usize) -> Self {
        RunControl {
            max_steps: steps,
            until_converged: false,
            check_every: 500,
            min_ess: 0.0,
            checkpoint: None,
            progress: false,
        }
    }
}

/// Every step of every walker: positions, log-densities and whether the
/// step's proposal was accepted. Walker index `w` of ensemble `e` is chain
/// `e * walkers + w`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chains {
    pub dim: usize,
    pub ensembles: usize,
    pub walkers: usize,
    /// Step-major: `[step][chain][coordinate]`.
    pub positions: Vec<f64>,
    /// `[step][chain]`.
    pub log_prob: Vec<f64>,
    /// `[step][chain]`.
    pub accepted: Vec<bool>,
}

impl Chains {
    pub fn chains(&self) -> usize {
        self.ensembles * self.walkers
    }

    pub fn steps(&self) -> usize {
        self.log_prob.len() / self.chains().max(1)
    }

    /// Coordinate `i` of chain `c` at `step`.
    pub fn at(&self, step: usize, chain: usize, i: usize) -> f64 {
        self.positions[(step * self.chains() + chain) * self.dim + i]
    }

    /// The trace of coordinate `i` of every chain from step `from` on:
    /// `[chain][step]`.
    pub fn traces(&self, i: usize, from: usize) -> Vec<Vec<f64>> {
        (0..self.chains())
            .map(|c| (from..self.steps()).map(|s| self.at(s, c, i)).collect())
            .collect()
    }

    /// The traces of an arbitrary function of the position.
    pub fn traces_of(&self, from: usize, f: impl Fn(&[f64]) -> f64) -> Vec<Vec<f64>> {
        let (d, nc) = (self.dim, self.chains());
        (0..nc)
            .map(|c| {
                (from..self.steps())
                    .map(|s| f(&self.positions[(s * nc + c) * d..(s * nc + c + 1) * d]))
                    .collect()
            })
            .collect()
    }

    /// Acceptance fraction of each chain over steps `from..`.
    pub fn acceptance(&self, from: usize) -> Vec<f64> {
        let nc = self.chains();
        let steps = self.steps().saturating_sub(from).max(1);
        (0..nc)
            .map(|c| (from..self.steps()).filter(|&s| self.accepted[s * nc + c]).count() as f64 / steps as f64)
            .collect()
    }

    /// The last position of every chain, `[chain][coordinate]` flattened.
    fn last_positions(&self) -> &[f64] {
        let n = self.chains() * self.dim;
        &self.positions[self.positions.len() - n..]
    }

    fn last_log_prob(&self) -> &[f64] {
        let n = self.chains();
        &self.log_prob[self.log_prob.len() - n..]
    }
}

/// The sampler: settings, the state, and the history of every step.
pub struct Sampler<'t, T: LogDensity> {
    target: &'t T,
    pub settings: SamplerSettings,
    pub chains: Chains,
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    format: String,
    settings: SamplerSettings,
    chains: Chains,
}

const CHECKPOINT_FORMAT: &str = "mrbp-sampler-checkpoint-1";

impl<'t, T: LogDensity> Sampler<'t, T> {
    /// A sampler whose step 0 is `initial`: one position per chain, ensemble
    /// by ensemble. Refuses to start if any walker has log-density −∞ or a
    /// non-finite coordinate, naming the first such walker.
    pub fn new(target: &'t T, settings: SamplerSettings, initial: &[Vec<f64>]) -> Result<Self> {
        let d = target.dim();
        settings.check(d)?;
        let nc = settings.walkers * settings.ensembles;
        if initial.len() != nc {
            return Err(Error::Usage(format!("{} initial positions for {nc} walkers", initial.len())));
        }
        let mut positions = Vec::with_capacity(nc * d);
        for (c, x) in initial.iter().enumerate() {
            if x.len() != d || x.iter().any(|v| !v.is_finite()) {
                return Err(Error::Compute(format!("walker {c} starts at a non-finite or wrong-sized position")));
            }
            positions.extend_from_slice(x);
        }
        let mut log_prob = vec![0.0; nc];
        evaluate(target, &positions, &mut log_prob);
        if let Some(c) = log_prob.iter().position(|lp| *lp == f64::NEG_INFINITY) {
            return Err(Error::Compute(format!(
                "walker {c} (ensemble {}, walker {}) starts where the log-density is −∞: {:?}",
                c / settings.walkers,
                c % settings.walkers,
                initial[c]
            )));
        }
        Ok(Sampler {
            target,
            chains: Chains {
                dim: d,
                ensembles: settings.ensembles,
                walkers: settings.walkers,
                positions,
                log_prob,
                accepted: vec![false; nc],
                },
            settings,
        })
    }

    /// A sampler restored from a checkpoint written by [`Sampler::run`].
    pub fn resume(target: &'t T, path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read checkpoint: {e}")))?;
        let cp: Checkpoint = postcard::from_bytes(&bytes)
            .map_err(|e| Error::input(path, format!("not a sampler checkpoint: {e}")))?;
        if cp.format != CHECKPOINT_FORMAT || cp.chains.dim != target.dim() {
            return Err(Error::input(path, "checkpoint of another format or another target"));
        }
        cp.settings.check(target.dim())?;
        Ok(Sampler {
            target,
            settings: cp.settings,
            chains: cp.chains,
        })
    }

    /// Saves the full state atomically; resuming from it continues exactly.
    pub fn save_checkpoint(&self, path: &Path) -> Result<()> {
        let cp = Checkpoint {
            format: CHECKPOINT_FORMAT.into(),
            settings: self.settings.clone(),
            chains: self.chains.clone(),
        };
        let bytes = postcard::to_allocvec(&cp).map_err(|e| Error::output(path, e))?;
        crate::output::atomic_write(path, &bytes)
    }

    /// Steps until `control` says stop.
    pub fn run(&mut self, control: &RunControl) -> Result<()> {
        let start = self.chains.steps();
        let bar = progress_bar(control, start);
        let mut accepted_recent = 0usize;
        let mut last_tau = f64::NAN;
        while self.chains.steps() < control.max_steps + 1 {
            let acc = self.step();
            accepted_recent += acc;
            let done = self.chains.steps() - 1; // steps taken after the initial state
            if let Some(bar) = &bar {
                bar.set_position(done as u64);
                if done % 20 == 0 {
                    let rate = accepted_recent as f64 / (20 * self.chains.chains()) as f64;
                    bar.set_message(format!("acceptance {rate:.2}"));
                    accepted_recent = 0;
                }
            }
            if let Some((path, every)) = &control.checkpoint {
                if done % every.max(&1) == 0 {
                    self.save_checkpoint(path)?;
                }
            }
            if control.until_converged && done % control.check_every.max(1) == 0 {
                // converged: long enough, R̂ fine, enough ESS, and τ stable
                // within 5 % since the last check (τ estimates of short chains
                // drift upwards; emcee's 1 % rarely settles with a few checks)
                let diag = self.diagnostics();
                let stable = (diag.tau_max - last_tau).abs() < TAU_STABLE * diag.tau_max;
                last_tau = diag.tau_max;
                if let Some(bar) = &bar {
                    let line = format!(
                        "  step {done}: τ_max {:.1}, largest R̂ {:.4}, smallest ESS {:.0}",
                        diag.tau_max,
                        diag.max_rhat(),
                        diag.min_ess()
                    );
                    if bar.is_hidden() {
                        eprintln!("{line}");
                    } else {
                        bar.println(line);
                    }
                }
                if stable && diag.converged() && diag.min_ess() >= control.min_ess {
                    break;
                }
            }
        }
        if let Some(bar) = bar {
            bar.finish_and_clear();
        }
        if let Some((path, _)) = &control.checkpoint {
            self.save_checkpoint(path)?;
        }
        Ok(())
    }

    /// Diagnostics of the chains so far, with the burn-in rule of
    /// [`Diagnostics::compute`].
    pub fn diagnostics(&self) -> Diagnostics {
        Diagnostics::compute(&self.chains, None)
    }

    /// One step of every ensemble: the first half of each ensemble moves
    /// against the second, then the second against the updated first.
    /// Returns the number of accepted proposals.
    pub fn step(&mut self) -> usize {
        let (d, nw, ne) = (self.chains.dim, self.settings.walkers, self.settings.ensembles);
        let nc = nw * ne;
        let step = self.chains.steps() as u64; // the step being made
        let seed = self.settings.seed;
        let moves: Vec<Move> = (0..ne).map(|e| self.pick_move(e as u64, step)).collect();
        let mut pos = self.chains.last_positions().to_vec();
        let mut lp = self.chains.last_log_prob().to_vec();
        let mut acc = vec![false; nc];
        let half = nw / 2;
        for h in 0..2 {
            // chain index of every walker that moves now
            let movers: Vec<usize> = (0..ne).flat_map(|e| (0..half).map(move |w| e * nw + h * half + w)).collect();
            let snapshot = &pos;
            let target = self.target;
            let results: Vec<(Vec<f64>, Vec<f64>, Vec<bool>)> = movers
                .par_chunks(BATCH)
                .map(|chunk| {
                    let mut proposals = vec![0.0; chunk.len() * d];
                    let mut factors = vec![0.0; chunk.len()];
                    let mut log_u = vec![0.0; chunk.len()];
                    for (k, &c) in chunk.iter().enumerate() {
                        let (e, w) = (c / nw, c % nw);
                        let other_start = e * nw + (1 - h) * half;
                        let others = &snapshot[other_start * d..(other_start + half) * d];
                        let mut rng = crate::rng::stream(seed, &[e as u64, step, w as u64]);
                        factors[k] = moves[e].propose(
                            &snapshot[c * d..(c + 1) * d],
                            others,
                            &mut rng,
                            &mut proposals[k * d..(k + 1) * d],
                        );
                        log_u[k] = rng.random::<f64>().ln();
                    }
                    let mut new_lp = vec![0.0; chunk.len()];
                    evaluate(target, &proposals, &mut new_lp);
                    let accept = chunk
                        .iter()
                        .enumerate()
                        .map(|(k, &c)| {
                            let ratio = factors[k] + new_lp[k] - lp[c];
                            new_lp[k] > f64::NEG_INFINITY && log_u[k] < ratio
                        })
                        .collect();
                    (proposals, new_lp, accept)
                })
                .collect();
            for (chunk, (proposals, new_lp, accept)) in movers.chunks(BATCH).zip(results) {
                for (k, &c) in chunk.iter().enumerate() {
                    if accept[k] {
                        pos[c * d..(c + 1) * d].copy_from_slice(&proposals[k * d..(k + 1) * d]);
                        lp[c] = new_lp[k];
                        acc[c] = true;
                    }
                }
            }
        }
        let n_acc = acc.iter().filter(|a| **a).count();
        self.chains.positions.extend_from_slice(&pos);
        self.chains.log_prob.extend_from_slice(&lp);
        self.chains.accepted.extend_from_slice(&acc);
        n_acc
    }

    fn pick_move(&self, ensemble: u64, step: u64) -> Move {
        let moves = &self.settings.moves;
        if moves.len() == 1 {
            return moves[0].0;
        }
        let total: f64 = moves.iter().map(|(_, w)| w).sum();
        let mut u = crate::rng::stream(self.settings.seed, &[ensemble, step, MOVE_STREAM]).random::<f64>() * total;
        for (m, w) in moves {
            if u < *w {
                return *m;
            }
            u -= w;
        }
        moves[moves.len() - 1].0
    }
}

/// Log-densities of consecutive points, in parallel batches; NaN becomes −∞.
fn evaluate<T: LogDensity>(target: &T, xs: &[f64], out: &mut [f64]) {
    let d = target.dim();
    xs.par_chunks(BATCH * d)
        .zip(out.par_chunks_mut(BATCH))
        .for_each(|(x, o)| target.log_density_batch(x, o));
    for v in out.iter_mut() {
        if v.is_nan() {
            *v = f64::NEG_INFINITY;
        }
    }
}

fn progress_bar(control: &RunControl, start: usize) -> Option<indicatif::ProgressBar> {
    if !control.progress {
        return None;
    }
    let bar = indicatif::ProgressBar::new(control.max_steps as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("sampling {bar:30} {pos}/{len} steps  {msg}  ETA {eta}")
            .expect("valid template"),
    );
    bar.set_position(start.saturating_sub(1) as u64);
    Some(bar)
}
