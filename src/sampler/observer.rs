//! Observers of a sampler run: what happens beside the stepping (a progress
//! bar, diagnostics lines, checkpoints), kept out of the sampler's loop.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::chains::Chains;
use super::checkpoint;
use super::diagnostics::Diagnostics;
use super::settings::SamplerSettings;
use super::stopping::Waiting;
use crate::error::{Error, Result};

/// The state of a run as observers see it.
pub struct RunState<'a> {
    pub settings: &'a SamplerSettings,
    pub chains: &'a Chains,
    /// Steps taken after the initial state.
    pub step: usize,
    /// The step at which the run stops at the latest.
    pub max_steps: usize,
    /// The ESS the stopping rule asks for, if the run stops when converged.
    pub min_ess: Option<f64>,
    /// Proposals accepted in the last step.
    pub accepted: usize,
}

/// One temperature of a population of sequential Monte Carlo
/// ([`super::smc`]), as observers are told it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stage {
    /// The temperature reached.
    pub beta: f64,
    /// The effective sample size of the weights that reached it.
    pub ess: f64,
    /// ln of their mean: this temperature's factor of the evidence.
    pub log_increment: f64,
    /// The mutation's steps and its mean acceptance rate.
    pub steps: usize,
    pub acceptance: f64,
}

/// Something that watches a sampler run. Every method has a default that
/// does nothing; an error stops the run.
pub trait Observer {
    /// Before the first step of this run.
    fn started(&mut self, _state: &RunState) -> Result<()> {
        Ok(())
    }
    /// After every step.
    fn stepped(&mut self, _state: &RunState) -> Result<()> {
        Ok(())
    }
    /// After every convergence check, with what the stopping rule waits
    /// for (`None`: the run stops here).
    fn checked(
        &mut self,
        _state: &RunState,
        _diagnostics: &Diagnostics,
        _waiting: Option<&Waiting>,
    ) {
    }
    /// After the last step.
    fn finished(&mut self, _state: &RunState) -> Result<()> {
        Ok(())
    }
    /// After each temperature of sequential Monte Carlo before the run
    /// (population `population`, from 0).
    fn tempered(&mut self, _population: usize, _stage: &Stage) {}
    /// After each population of sequential Monte Carlo: how many are
    /// finished, and `write`, which saves them (with what they were made
    /// from) at the path it is given.
    fn populated(&mut self, _done: usize, _write: &dyn Fn(&Path) -> Result<()>) -> Result<()> {
        Ok(())
    }
}

/// Saves the sampler's state every `every` steps and at the end; when
/// `stop` says so, saves it at once and stops the run with
/// [`Error::Interrupted`].
pub struct Checkpointer {
    pub path: PathBuf,
    pub every: usize,
    pub stop: fn() -> bool,
}

impl Observer for Checkpointer {
    fn stepped(&mut self, state: &RunState) -> Result<()> {
        let stop = (self.stop)();
        if stop || state.step.is_multiple_of(self.every.max(1)) {
            checkpoint::save(&self.path, state.settings, state.chains)?;
        }
        if stop {
            return Err(Error::Interrupted(format!(
                "interrupted after step {}: the chains so far are in {}; the same command with --resume continues them",
                state.step,
                self.path.display()
            )));
        }
        Ok(())
    }
    fn finished(&mut self, state: &RunState) -> Result<()> {
        checkpoint::save(&self.path, state.settings, state.chains)
    }
    /// Sequential Monte Carlo's populations, beside the sampler's
    /// checkpoint ([`checkpoint::smc_beside`]).
    fn populated(&mut self, _done: usize, write: &dyn Fn(&Path) -> Result<()>) -> Result<()> {
        write(&checkpoint::smc_beside(&self.path))
    }
}

/// A progress bar on the terminal, with the acceptance rate and, at every
/// convergence check, where the diagnostics stand against the stopping rule
/// and how many steps it will take at this pace.
#[derive(Default)]
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    accepted: usize,
    status: String,
}

/// Steps over which the shown acceptance rate is averaged.
const ACCEPTANCE_WINDOW: usize = 10;

impl Observer for Progress {
    fn started(&mut self, state: &RunState) -> Result<()> {
        let bar = indicatif::ProgressBar::new(state.max_steps as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "sampling {bar:30} step {pos}/{len}  {msg}  ETA {eta}",
            )
            .expect("valid template"),
        );
        if state.min_ess.is_some() {
            // the length is an estimate until the first convergence check
            bar.set_style(
                indicatif::ProgressStyle::with_template("sampling {bar:30} step {pos}  {msg}")
                    .expect("valid template"),
            );
        }
        bar.set_position(state.step as u64);
        self.bar = Some(bar);
        Ok(())
    }
    fn stepped(&mut self, state: &RunState) -> Result<()> {
        let Some(bar) = &self.bar else { return Ok(()) };
        self.accepted += state.accepted;
        bar.set_position(state.step as u64);
        // the step just made started from a stranded ensemble drawn afresh
        for redraw in super::stranded::due(state.chains, state.step) {
            let line = format!("  step {}: {}", state.step, redraw.message());
            if bar.is_hidden() {
                eprintln!("{line}");
            } else {
                bar.println(line);
            }
        }
        if state.step.is_multiple_of(ACCEPTANCE_WINDOW) {
            let rate = self.accepted as f64 / (ACCEPTANCE_WINDOW * state.chains.chains()) as f64;
            bar.set_message(format!("acceptance {rate:.2}{}", self.status));
            self.accepted = 0;
        }
        Ok(())
    }
    fn checked(&mut self, state: &RunState, diag: &Diagnostics, waiting: Option<&Waiting>) {
        let Some(min_ess) = state.min_ess else { return };
        let (ess, rhat) = (diag.min_ess(), diag.max_rhat());
        let verdict = match waiting {
            Some(w) => format!("waiting: {w}"),
            None => "converged".to_string(),
        };
        if ess.is_nan() {
            // too few steps after burn-in to estimate an ESS yet
            print_line(&self.bar, &format!("  step {}: {verdict}", state.step));
            return;
        }
        self.status = format!(
            ", smallest ESS {ess:.0}/{min_ess:.0}, largest R̂ {rhat:.4}/{}",
            super::diagnostics::RHAT_THRESHOLD
        );
        let line = format!(
            "  step {}: smallest ESS {ess:.0} (target {min_ess:.0}), largest R̂ {rhat:.4}, τ_max {:.1}; {verdict}",
            state.step, diag.tau_max
        );
        let until = match waiting {
            Some(Waiting::Confirmation { until, .. }) => *until as f64,
            _ => 0.0,
        };
        match &self.bar {
            Some(bar) if !bar.is_hidden() => {
                // ESS grows with the steps kept after burn-in: the steps still
                // needed at this pace give the bar its length and its ETA
                let kept = state.step.saturating_sub(diag.burn_in).max(1) as f64;
                let needed =
                    (diag.burn_in as f64 + kept * (min_ess / ess.max(1.0)).max(1.0)).max(until);
                bar.set_length(
                    (needed.ceil() as u64).clamp(state.step as u64 + 1, state.max_steps as u64),
                );
                bar.set_style(
                    indicatif::ProgressStyle::with_template(
                        "sampling {bar:30} step {pos}/~{len}  {msg}  ETA {eta}",
                    )
                    .expect("valid template"),
                );
                bar.println(line);
            }
            _ => eprintln!("{line}"),
        }
    }
    fn tempered(&mut self, population: usize, stage: &Stage) {
        print_line(
            &self.bar,
            &format!(
                "  sequential Monte Carlo, population {}: β = {:.4} (ESS {:.0} kept), {} mutation steps, acceptance {:.2}",
                population + 1,
                stage.beta,
                stage.ess,
                stage.steps,
                stage.acceptance
            ),
        );
    }

    fn finished(&mut self, _state: &RunState) -> Result<()> {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        Ok(())
    }
}

/// A line above the progress bar, or on standard error where it is hidden.
fn print_line(bar: &Option<indicatif::ProgressBar>, line: &str) {
    match bar {
        Some(bar) if !bar.is_hidden() => bar.println(line),
        _ => eprintln!("{line}"),
    }
}
