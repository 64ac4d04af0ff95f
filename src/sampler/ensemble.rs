//! Several independent ensembles stepped together with the parallel
//! red-blue update (Foreman-Mackey et al. 2013, after Goodman & Weare 2010).

use std::path::Path;

use rand::RngExt;
use rayon::prelude::*;

use super::chains::Chains;
use super::checkpoint;
use super::density::{free_coordinates, log_densities_memo, LogDensity, BATCH};
use super::diagnostics::Diagnostics;
use super::elliptical::Elliptical;
use super::moves::mixture::last_fit_step;
use super::moves::{Fit, Learned, Move};
use super::observer::{Observer, RunState};
use super::settings::SamplerSettings;
use super::stopping::{RunControl, Stopping};
use super::stranded;
use crate::error::{Error, Result};

/// Index of the stream that picks the move of an ensemble's step.
const MOVE_STREAM: u64 = u64::MAX;

/// Index of the stream that seeds an ensemble's mixture fits.
const FIT_STREAM: u64 = u64::MAX - 2;

/// Index of the stream of a walker's block updates at a step.
const BLOCK_STREAM: u64 = u64::MAX - 4;

/// Sweeps over the target's blocks ([`LogDensity::blocks`]) after every
/// step: each block of each walker is proposed this many times. A block's
/// conditional costs a small share of a full evaluation (the discrepancy
/// model's Kalman filter over one run, about 1/35 of integrating the
/// measured damper's four runs at 1 A and scoring them).
const BLOCK_SWEEPS: usize = 4;

/// The stretch move's scale within a block.
const BLOCK_STRETCH: f64 = 2.0;

/// The most memory the walkers' memos may take (bytes); beyond it the
/// blocks are not updated on their own (the ensemble moves still move
/// them with the rest).
const MEMO_BUDGET_BYTES: usize = 3 << 30;

/// The sampler: settings, the state, and the history of every step.
pub struct Sampler<'t, T: LogDensity> {
    target: &'t T,
    pub settings: SamplerSettings,
    pub chains: Chains,
    /// What each ensemble learned from its history, and the step of the
    /// fit (0: none yet), for [`Move::History`] and [`Move::Curved`].
    history: (usize, Vec<Learned>),
    /// A fixed distribution close to the target (the Laplace approximation
    /// at the mode), for [`Move::Anchored`].
    reference: Option<Elliptical>,
    /// Whether observers were told that this run started.
    announced: bool,
    /// The stopping rule's memory of this run.
    stopping: Stopping,
    /// The target's blocks ([`LogDensity::blocks`]); empty where it has
    /// none or their memos would not fit in [`MEMO_BUDGET_BYTES`].
    blocks: Vec<Vec<usize>>,
    /// Each walker's memo at its current position (empty until made: a
    /// resumed run remakes them at its first step).
    memos: Vec<Vec<f64>>,
    /// The coordinates the ensemble moves propose: those in no block (all
    /// of them where there are none). The blocks' coordinates are moved
    /// by the block updates alone, so that a block pressed against its
    /// prior's bound (a time scale at its longest) does not make every
    /// joint proposal fall outside it.
    free: Vec<usize>,
}

/// A batch of walkers' proposals: positions, log-densities, whether each
/// is accepted, and the memos made with them (none without blocks).
struct Proposed {
    positions: Vec<f64>,
    log_prob: Vec<f64>,
    accept: Vec<bool>,
    memos: Vec<Vec<f64>>,
}

/// A batch of walkers after their block updates: positions, log-densities
/// and each block's terms (`[block][walker]`).
struct Moved {
    positions: Vec<f64>,
    log_prob: Vec<f64>,
    block_terms: Vec<Vec<f64>>,
}

/// `blocks`, or none where `walkers` memos of `memo_len` numbers (and
/// half as many again for the proposals in flight) would take more than
/// [`MEMO_BUDGET_BYTES`].
fn within_budget(blocks: Vec<Vec<usize>>, memo_len: usize, walkers: usize) -> Vec<Vec<usize>> {
    if memos_fit(memo_len, walkers) {
        blocks
    } else {
        Vec::new()
    }
}

/// Whether `walkers` memos of `memo_len` numbers (and half as many again
/// for the proposals in flight) fit in [`MEMO_BUDGET_BYTES`]: whether a
/// target's blocks ([`LogDensity::blocks`]) are updated on their own, and
/// the ensemble moves propose only the other coordinates.
pub fn memos_fit(memo_len: usize, walkers: usize) -> bool {
    memo_len * walkers * std::mem::size_of::<f64>() * 3 / 2 <= MEMO_BUDGET_BYTES
}

/// The coordinates `free` of each of `points` (`d` coordinates each).
fn project(points: &[f64], d: usize, free: &[usize]) -> Vec<f64> {
    points.chunks_exact(d.max(1)).flat_map(|p| free.iter().map(move |&i| p[i])).collect()
}

impl<'t, T: LogDensity> Sampler<'t, T> {
    /// A sampler whose step 0 is `initial`: one position per chain, ensemble
    /// by ensemble. Refuses to start if any walker has log-density −∞ or a
    /// non-finite coordinate, naming the first such walker.
    pub fn new(target: &'t T, settings: SamplerSettings, initial: &[Vec<f64>]) -> Result<Self> {
        let d = target.dim();
        settings.check(d)?;
        let nc = settings.walkers * settings.ensembles;
        if initial.len() != nc {
            return Err(Error::Usage(format!(
                "{} initial positions for {nc} walkers",
                initial.len()
            )));
        }
        let mut positions = Vec::with_capacity(nc * d);
        for (c, x) in initial.iter().enumerate() {
            if x.len() != d || x.iter().any(|v| !v.is_finite()) {
                return Err(Error::Compute(format!(
                    "walker {c} starts at a non-finite or wrong-sized position"
                )));
            }
            positions.extend_from_slice(x);
        }
        let mut log_prob = vec![0.0; nc];
        let blocks = target.blocks();
        let mut memos = vec![Vec::new(); if blocks.is_empty() { 0 } else { nc }];
        log_densities_memo(target, &positions, &mut log_prob, &mut memos);
        let blocks = within_budget(blocks, memos.first().map_or(0, Vec::len), nc);
        if blocks.is_empty() {
            memos.clear();
        }
        if let Some(c) = log_prob.iter().position(|lp| *lp == f64::NEG_INFINITY) {
            return Err(Error::Compute(format!(
                "walker {c} (ensemble {}, walker {}) starts where the log-density is −∞: {:?}",
                c / settings.walkers,
                c % settings.walkers,
                initial[c]
            )));
        }
        Ok(Sampler::assemble(target, settings, positions, log_prob, blocks, memos))
    }

    /// A sampler whose step 0 is `positions` (one after another, ensemble
    /// by ensemble) with their log-densities `log_prob` already known (a
    /// population handed on by [`super::smc`]): nothing is evaluated again
    /// unless the target has blocks, whose memos only an evaluation makes.
    pub fn from_state(
        target: &'t T,
        settings: SamplerSettings,
        positions: Vec<f64>,
        log_prob: Vec<f64>,
    ) -> Result<Self> {
        let d = target.dim();
        if !target.blocks().is_empty() {
            let initial: Vec<Vec<f64>> = positions.chunks_exact(d).map(<[f64]>::to_vec).collect();
            return Sampler::new(target, settings, &initial);
        }
        settings.check(d)?;
        let nc = settings.walkers * settings.ensembles;
        if positions.len() != nc * d || log_prob.len() != nc {
            return Err(Error::Usage(format!(
                "{} positions and {} log-densities for {nc} walkers",
                positions.len() / d.max(1),
                log_prob.len()
            )));
        }
        Ok(Sampler::assemble(target, settings, positions, log_prob, Vec::new(), Vec::new()))
    }

    /// A fresh run whose step 0 is `positions` with their log-densities,
    /// the target's `blocks` updated on their own (none: every coordinate
    /// free) from the walkers' `memos`.
    fn assemble(
        target: &'t T,
        settings: SamplerSettings,
        positions: Vec<f64>,
        log_prob: Vec<f64>,
        blocks: Vec<Vec<usize>>,
        memos: Vec<Vec<f64>>,
    ) -> Self {
        let (d, nc) = (target.dim(), settings.walkers * settings.ensembles);
        Sampler {
            target,
            chains: Chains {
                dim: d,
                ensembles: settings.ensembles,
                walkers: settings.walkers,
                positions,
                log_prob,
                accepted: vec![false; nc],
            },
            history: (0, vec![Learned::default(); settings.ensembles]),
            reference: None,
            settings,
            announced: false,
            stopping: Stopping::default(),
            free: free_coordinates(d, &blocks),
            blocks,
            memos,
        }
    }

    /// A sampler restored from a checkpoint (see [`super::observer::Checkpointer`]).
    pub fn resume(target: &'t T, path: &Path) -> Result<Self> {
        let (settings, chains) = checkpoint::load(path, target.dim())?;
        settings.check(target.dim())?;
        let history = (0, vec![Learned::default(); settings.ensembles]);
        let mut blocks = target.blocks();
        if !blocks.is_empty() {
            // the budget as the run that saved it measured it
            let (d, mut memo) = (target.dim(), vec![Vec::new()]);
            log_densities_memo(target, &chains.last_positions()[..d], &mut [0.0], &mut memo);
            blocks = within_budget(blocks, memo[0].len(), chains.chains());
        }
        let free = free_coordinates(target.dim(), &blocks);
        Ok(Sampler {
            target,
            settings,
            chains,
            history,
            reference: None,
            announced: false,
            stopping: Stopping::default(),
            blocks,
            memos: Vec::new(),
            free,
        })
    }

    /// The sampler with a fixed reference distribution for
    /// [`Move::Anchored`] (in the sampler's coordinates); a reference of
    /// another dimension is ignored.
    pub fn with_reference(mut self, reference: Elliptical) -> Self {
        self.reference = (reference.dim() == self.chains.dim).then_some(reference);
        self
    }

    /// Steps until `control` says stop, telling `observers` what happens;
    /// convergence is judged on the chains as they are.
    pub fn run(&mut self, control: &RunControl, observers: &mut [&mut dyn Observer]) -> Result<()> {
        let adaptive = self.adaptive();
        self.run_until(control, observers, &|chains| {
            Diagnostics::compute(chains, Diagnostics::burn_in_rule(chains, adaptive))
        })
    }

    /// [`Sampler::run`], with convergence judged on `diagnose(chains)`: the
    /// diagnostics of the quantities of interest (SI units, say), which may
    /// not be the sampler's coordinates.
    pub fn run_until(
        &mut self,
        control: &RunControl,
        observers: &mut [&mut dyn Observer],
        diagnose: &dyn Fn(&Chains) -> Diagnostics,
    ) -> Result<()> {
        let mut accepted = 0;
        self.announce(control, observers)?;
        self.replay_checks(control, diagnose);
        // steps taken before this run (a probe of the start, a resumed
        // run's) are checked where an uninterrupted run would have checked
        let mut converged =
            self.chains.steps() > 1 && self.converged_now(control, accepted, observers, diagnose);
        while !converged && self.chains.steps() < control.max_steps + 1 {
            accepted = self.step_observed(control, observers)?;
            converged = self.converged_now(control, accepted, observers, diagnose);
        }
        for o in observers.iter_mut() {
            o.finished(&self.state(control, accepted))?;
        }
        Ok(())
    }

    /// Whether the run has converged, where `control` checks at the current
    /// step (telling `observers` what the check found and what the rule
    /// waits for).
    fn converged_now(
        &mut self,
        control: &RunControl,
        accepted: usize,
        observers: &mut [&mut dyn Observer],
        diagnose: &dyn Fn(&Chains) -> Diagnostics,
    ) -> bool {
        let step = self.chains.steps().saturating_sub(1);
        if !(control.until_converged && control.checks_at(step)) {
            return false;
        }
        let diag = diagnose(&self.chains);
        let waiting = self.stopping.check(control, step, &diag);
        let state = self.state(control, accepted);
        for o in observers.iter_mut() {
            o.checked(&state, &diag, waiting.as_ref());
        }
        waiting.is_none()
    }

    /// The step at which the stopping rule's R̂, ESS and length first held.
    pub fn first_held(&self) -> Option<usize> {
        self.stopping.first_held()
    }

    /// A run that confirms counts from the step at which the rule first
    /// held: where chains were taken before this run (a resumed run's),
    /// the checks an uninterrupted run made at those steps are made again
    /// on the chains as they were, so both stop at the same step.
    fn replay_checks(&mut self, control: &RunControl, diagnose: &dyn Fn(&Chains) -> Diagnostics) {
        if !(control.until_converged && control.confirm) || self.stopping.first_held().is_some() {
            return;
        }
        let now = self.chains.steps().saturating_sub(1);
        for step in (1..now).filter(|s| control.checks_at(*s)) {
            let diag = diagnose(&self.chains.first_steps(step + 1));
            self.stopping.check(control, step, &diag);
            if self.stopping.first_held().is_some() {
                break;
            }
        }
    }

    /// Tells `observers` that the run started, once: a run continued by
    /// [`Sampler::run_until`] after steps taken with [`Sampler::step_observed`]
    /// is the same run.
    pub fn announce(
        &mut self,
        control: &RunControl,
        observers: &mut [&mut dyn Observer],
    ) -> Result<()> {
        if !self.announced {
            let state = self.state(control, 0);
            for o in observers.iter_mut() {
                o.started(&state)?;
            }
            self.announced = true;
        }
        Ok(())
    }

    /// One [`Sampler::step`], told to `observers` (which may stop the run:
    /// a checkpoint at Ctrl-C); the number of accepted proposals.
    pub fn step_observed(
        &mut self,
        control: &RunControl,
        observers: &mut [&mut dyn Observer],
    ) -> Result<usize> {
        self.announce(control, observers)?;
        let accepted = self.step();
        let state = self.state(control, accepted);
        for o in observers.iter_mut() {
            o.stepped(&state)?;
        }
        Ok(accepted)
    }

    fn state(&self, control: &RunControl, accepted: usize) -> RunState<'_> {
        RunState {
            settings: &self.settings,
            chains: &self.chains,
            step: self.chains.steps().saturating_sub(1),
            max_steps: control.max_steps,
            min_ess: control.until_converged.then_some(control.min_ess),
            accepted,
        }
    }

    /// Diagnostics of the chains so far, with the burn-in rule of
    /// [`Sampler::burn_in`].
    pub fn diagnostics(&self) -> Diagnostics {
        Diagnostics::compute(&self.chains, self.burn_in())
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
        self.fit_history(step as usize);
        let mut pos = self.chains.last_positions().to_vec();
        let mut lp = self.chains.last_log_prob().to_vec();
        if !self.blocks.is_empty() && self.memos.len() != nc {
            // a resumed run: the memos at the stored positions (their
            // log-densities are those stored)
            self.memos = vec![Vec::new(); nc];
            log_densities_memo(self.target, &pos, &mut vec![0.0; nc], &mut self.memos);
        }
        for redraw in stranded::due(&self.chains, step as usize) {
            self.redraw(&redraw, &mut pos, &mut lp);
        }
        let history = &self.history.1;
        // the moves work in the free coordinates ([`Sampler::free`])
        let (free, df) = (&self.free, self.free.len());
        let marginal =
            if df < d { self.reference.as_ref().and_then(|r| r.marginal(free)) } else { None };
        let reference = if df < d { marginal.as_ref() } else { self.reference.as_ref() };
        let mut acc = vec![false; nc];
        let half = nw / 2;
        for h in 0..2 {
            // chain index of every walker that moves now
            let movers: Vec<usize> =
                (0..ne).flat_map(|e| (0..half).map(move |w| e * nw + h * half + w)).collect();
            let snapshot = &pos;
            let free_snapshot = project(snapshot, d, free);
            let target = self.target;
            // each ensemble's move fitted once to its other half
            let fits: Vec<Fit> = (0..ne)
                .map(|e| {
                    let other_start = e * nw + (1 - h) * half;
                    moves[e].fit(
                        &free_snapshot[other_start * df..(other_start + half) * df],
                        df,
                        &history[e],
                        reference,
                    )
                })
                .collect();
            let with_memos = !self.blocks.is_empty();
            let results: Vec<Proposed> = movers
                .par_chunks(BATCH)
                .map(|chunk| {
                    let mut proposals = vec![0.0; chunk.len() * d];
                    let mut factors = vec![0.0; chunk.len()];
                    let mut log_u = vec![0.0; chunk.len()];
                    let mut y = vec![0.0; df];
                    for (k, &c) in chunk.iter().enumerate() {
                        let (e, w) = (c / nw, c % nw);
                        let other_start = e * nw + (1 - h) * half;
                        let others = &free_snapshot[other_start * df..(other_start + half) * df];
                        let mut rng = crate::rng::stream(seed, &[e as u64, step, w as u64]);
                        factors[k] = moves[e].propose(
                            &fits[e],
                            &free_snapshot[c * df..(c + 1) * df],
                            others,
                            &mut rng,
                            &mut y,
                        );
                        let proposal = &mut proposals[k * d..(k + 1) * d];
                        proposal.copy_from_slice(&snapshot[c * d..(c + 1) * d]);
                        for (v, &i) in y.iter().zip(free) {
                            proposal[i] = *v;
                        }
                        log_u[k] = rng.random::<f64>().ln();
                    }
                    let mut new_lp = vec![0.0; chunk.len()];
                    let mut memos = vec![Vec::new(); if with_memos { chunk.len() } else { 0 }];
                    log_densities_memo(target, &proposals, &mut new_lp, &mut memos);
                    let accept = chunk
                        .iter()
                        .enumerate()
                        .map(|(k, &c)| {
                            let ratio = factors[k] + new_lp[k] - lp[c];
                            new_lp[k] > f64::NEG_INFINITY && log_u[k] < ratio
                        })
                        .collect();
                    Proposed { positions: proposals, log_prob: new_lp, accept, memos }
                })
                .collect();
            for (chunk, Proposed { positions: proposals, log_prob: new_lp, accept, mut memos }) in
                movers.chunks(BATCH).zip(results)
            {
                for (k, &c) in chunk.iter().enumerate() {
                    if accept[k] {
                        pos[c * d..(c + 1) * d].copy_from_slice(&proposals[k * d..(k + 1) * d]);
                        lp[c] = new_lp[k];
                        acc[c] = true;
                        if with_memos {
                            self.memos[c] = std::mem::take(&mut memos[k]);
                        }
                    }
                }
            }
        }
        self.update_blocks(step, &mut pos, &mut lp);
        let n_acc = acc.iter().filter(|a| **a).count();
        self.chains.positions.extend_from_slice(&pos);
        self.chains.log_prob.extend_from_slice(&lp);
        self.chains.accepted.extend_from_slice(&acc);
        n_acc
    }

    /// Draws the walkers of a stranded ensemble afresh ([`stranded`]); a
    /// draw where the log-density is −∞ takes the position of the same
    /// walker of the ensemble drawn from.
    fn redraw(&mut self, redraw: &stranded::Redraw, pos: &mut [f64], lp: &mut [f64]) {
        let (d, nw) = (self.chains.dim, self.settings.walkers);
        let fresh = stranded::positions(&self.chains, redraw, self.settings.seed);
        if fresh.is_empty() {
            return;
        }
        let mut fresh_lp = vec![0.0; nw];
        let mut fresh_memos = vec![Vec::new(); if self.blocks.is_empty() { 0 } else { nw }];
        log_densities_memo(self.target, &fresh, &mut fresh_lp, &mut fresh_memos);
        for w in 0..nw {
            let (c, source) = (redraw.ensemble * nw + w, redraw.from * nw + w);
            if fresh_lp[w] > f64::NEG_INFINITY {
                pos[c * d..(c + 1) * d].copy_from_slice(&fresh[w * d..(w + 1) * d]);
                lp[c] = fresh_lp[w];
                if let Some(m) = fresh_memos.get_mut(w) {
                    self.memos[c] = std::mem::take(m);
                }
            } else {
                pos.copy_within(source * d..(source + 1) * d, c * d);
                lp[c] = lp[source];
                if !self.blocks.is_empty() {
                    self.memos[c] = self.memos[source].clone();
                }
            }
        }
    }

    /// Each walker's blocks ([`LogDensity::blocks`]) updated on their own,
    /// the rest of its position held: [`BLOCK_SWEEPS`] sweeps of a stretch
    /// move within each block against the complementary half of its
    /// ensemble (the red-blue update again, which keeps it exact), each
    /// proposal weighed by the block's conditional density from the
    /// walker's memo. A composition of moves that each leave the target
    /// invariant; the draws of walker w of ensemble e at this step come
    /// from its own stream.
    fn update_blocks(&mut self, step: u64, pos: &mut [f64], lp: &mut [f64]) {
        if self.blocks.is_empty() {
            return;
        }
        let (d, nw, ne, seed) =
            (self.chains.dim, self.settings.walkers, self.settings.ensembles, self.settings.seed);
        let half = nw / 2;
        let (target, blocks) = (self.target, &self.blocks);
        for h in 0..2 {
            let movers: Vec<usize> =
                (0..ne).flat_map(|e| (0..half).map(move |w| e * nw + h * half + w)).collect();
            let snapshot = &*pos;
            let lp_now = &*lp;
            let memos = &self.memos;
            let results: Vec<Moved> = movers
                .par_chunks(BATCH)
                .map(|chunk| {
                    let n = chunk.len();
                    let mut x: Vec<f64> = chunk
                        .iter()
                        .flat_map(|&c| snapshot[c * d..(c + 1) * d].iter().copied())
                        .collect();
                    let mut l: Vec<f64> = chunk.iter().map(|&c| lp_now[c]).collect();
                    let chunk_memos: Vec<&[f64]> =
                        chunk.iter().map(|&c| memos[c].as_slice()).collect();
                    let mut rngs: Vec<_> = chunk
                        .iter()
                        .map(|&c| {
                            crate::rng::stream(
                                seed,
                                &[(c / nw) as u64, step, (c % nw) as u64, BLOCK_STREAM],
                            )
                        })
                        .collect();
                    // each block's terms at the walker, as its memo holds them
                    let mut current: Vec<Vec<f64>> = (0..blocks.len())
                        .map(|b| chunk_memos.iter().map(|m| m[b]).collect())
                        .collect();
                    let (mut y, mut proposed) = (x.clone(), vec![0.0; n]);
                    let (mut factor, mut log_u) = (vec![0.0; n], vec![0.0; n]);
                    for _ in 0..BLOCK_SWEEPS {
                        for (b, block) in blocks.iter().enumerate() {
                            y.copy_from_slice(&x);
                            for (k, &c) in chunk.iter().enumerate() {
                                let rng = &mut rngs[k];
                                let u: f64 = rng.random();
                                let z = ((BLOCK_STRETCH - 1.0) * u + 1.0).powi(2) / BLOCK_STRETCH;
                                let j = (c / nw) * nw + (1 - h) * half + rng.random_range(0..half);
                                for &i in block {
                                    let xj = snapshot[j * d + i];
                                    y[k * d + i] = xj + z * (x[k * d + i] - xj);
                                }
                                factor[k] = (block.len() as f64 - 1.0) * z.ln();
                                log_u[k] = rng.random::<f64>().ln();
                            }
                            target.block_log_density_batch(b, &y, &chunk_memos, &mut proposed);
                            for k in 0..n {
                                let gain = proposed[k] - current[b][k];
                                if proposed[k].is_finite() && log_u[k] < factor[k] + gain {
                                    for &i in block {
                                        x[k * d + i] = y[k * d + i];
                                    }
                                    l[k] += gain;
                                    current[b][k] = proposed[k];
                                }
                            }
                        }
                    }
                    Moved { positions: x, log_prob: l, block_terms: current }
                })
                .collect();
            for (chunk, Moved { positions: x, log_prob: l, block_terms: current }) in
                movers.chunks(BATCH).zip(results)
            {
                for (k, &c) in chunk.iter().enumerate() {
                    pos[c * d..(c + 1) * d].copy_from_slice(&x[k * d..(k + 1) * d]);
                    lp[c] = l[k];
                    for (b, v) in current.iter().enumerate() {
                        self.memos[c][b] = v[k];
                    }
                }
            }
        }
    }

    /// Whether a move adapts to the ensembles' history.
    pub fn adaptive(&self) -> bool {
        self.settings.moves.iter().any(|(m, _)| m.uses_history())
    }

    /// The burn-in rule of [`Diagnostics::burn_in_rule`] for these chains
    /// and moves.
    pub fn burn_in(&self) -> usize {
        Diagnostics::burn_in_rule(&self.chains, self.adaptive())
    }

    /// Makes each ensemble's fits to its history ([`Learned`]) at the last fit step
    /// before `step` (see [`super::moves::mixture`]), if a move uses it and
    /// it is not fitted yet: to the walkers' positions over the steps from
    /// half that step on. A function of the chains and the seed only, so a
    /// resumed run refits what an uninterrupted one fitted.
    fn fit_history(&mut self, step: usize) {
        let at = last_fit_step(step);
        if at == 0 || at == self.history.0 || !self.adaptive() {
            return;
        }
        let (nw, seed) = (self.settings.walkers, self.settings.seed);
        let (chains, moves, free) = (&self.chains, &self.settings.moves, &self.free);
        self.history.1 = (0..self.settings.ensembles)
            .into_par_iter()
            .map(|e| {
                let walkers: Vec<Vec<f64>> = (e * nw..(e + 1) * nw)
                    .map(|c| {
                        (at / 2..at)
                            .flat_map(|s| free.iter().map(move |&i| chains.at(s, c, i)))
                            .collect()
                    })
                    .collect();
                Learned::fit(
                    moves,
                    &walkers,
                    free.len(),
                    &mut crate::rng::stream(seed, &[e as u64, at as u64, FIT_STREAM]),
                )
            })
            .collect();
        self.history.0 = at;
    }

    fn pick_move(&self, ensemble: u64, step: u64) -> Move {
        let moves = &self.settings.moves;
        if moves.len() == 1 {
            return moves[0].0;
        }
        let total: f64 = moves.iter().map(|(_, w)| w).sum();
        let mut u = crate::rng::stream(self.settings.seed, &[ensemble, step, MOVE_STREAM])
            .random::<f64>()
            * total;
        for (m, w) in moves {
            if u < *w {
                return *m;
            }
            u -= w;
        }
        moves[moves.len() - 1].0
    }
}
