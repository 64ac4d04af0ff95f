//! Observers of a sampler run: what happens beside the stepping (a progress
//! bar, diagnostics lines, checkpoints), kept out of the sampler's loop.

use std::path::PathBuf;

use super::chains::Chains;
use super::checkpoint;
use super::diagnostics::Diagnostics;
use super::settings::SamplerSettings;
use crate::error::Result;

/// The state of a run as observers see it.
pub struct RunState<'a> {
    pub settings: &'a SamplerSettings,
    pub chains: &'a Chains,
    /// Steps taken after the initial state.
    pub step: usize,
    /// The step at which the run stops at the latest.
    pub max_steps: usize,
    /// Proposals accepted in the last step.
    pub accepted: usize,
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
    /// After every convergence check.
    fn checked(&mut self, _state: &RunState, _diagnostics: &Diagnostics) {}
    /// After the last step.
    fn finished(&mut self, _state: &RunState) -> Result<()> {
        Ok(())
    }
}

/// Saves the sampler's state every `every` steps and at the end.
pub struct Checkpointer {
    pub path: PathBuf,
    pub every: usize,
}

impl Observer for Checkpointer {
    fn stepped(&mut self, state: &RunState) -> Result<()> {
        if state.step % self.every.max(1) == 0 {
            checkpoint::save(&self.path, state.settings, state.chains)?;
        }
        Ok(())
    }
    fn finished(&mut self, state: &RunState) -> Result<()> {
        checkpoint::save(&self.path, state.settings, state.chains)
    }
}

/// A progress bar on the terminal, with the acceptance rate and a line of
/// diagnostics at every convergence check.
#[derive(Default)]
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    accepted: usize,
}

/// Steps over which the shown acceptance rate is averaged.
const ACCEPTANCE_WINDOW: usize = 20;

impl Observer for Progress {
    fn started(&mut self, state: &RunState) -> Result<()> {
        let bar = indicatif::ProgressBar::new(state.max_steps as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("sampling {bar:30} {pos}/{len} steps  {msg}  ETA {eta}").expect("valid template"),
        );
        bar.set_position(state.step as u64);
        self.bar = Some(bar);
        Ok(())
    }
    fn stepped(&mut self, state: &RunState) -> Result<()> {
        let Some(bar) = &self.bar else { return Ok(()) };
        self.accepted += state.accepted;
        bar.set_position(state.step as u64);
        if state.step % ACCEPTANCE_WINDOW == 0 {
            let rate = self.accepted as f64 / (ACCEPTANCE_WINDOW * state.chains.chains()) as f64;
            bar.set_message(format!("acceptance {rate:.2}"));
            self.accepted = 0;
        }
        Ok(())
    }
    fn checked(&mut self, state: &RunState, diag: &Diagnostics) {
        let line = format!(
            "  step {}: τ_max {:.1}, largest R̂ {:.4}, smallest ESS {:.0}",
            state.step,
            diag.tau_max,
            diag.max_rhat(),
            diag.min_ess()
        );
        match &self.bar {
            Some(bar) if !bar.is_hidden() => bar.println(line),
            _ => eprintln!("{line}"),
        }
    }
    fn finished(&mut self, _state: &RunState) -> Result<()> {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        Ok(())
    }
}
