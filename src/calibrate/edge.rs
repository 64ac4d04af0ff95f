//! The adjusted likelihood's blind spot, seen in the walkers' own draws.
//!
//! The adjusted likelihood scores a point θ by the fit at θ* = θ̂ + C (θ −
//! θ̂) (docs/calibration.md, "The adjusted likelihood"). Along a parameter
//! the records leave free about the MAP and rule out further on, its
//! widening can carry the posterior past that edge, where draws whose own
//! paths miss the records get the MAP's score: Spencer's internal spring
//! k0 on the measured 1 A records, whose posterior came out as its prior
//! (9 N/m to 9e5 N/m between its 5th and 95th percentiles), 24–36 % of the
//! draws far, the bands 230–540 % of the peak force wide, while the
//! tempered likelihood fixes k0 at 1–300 N/m (docs/real-data.md, "Spencer
//! at 1 A"). The start's check ([`super::start`]) reaches only as far as
//! the Laplace approximation does, which there found 2 of 64 draws far.
//!
//! So where `memory = "auto"` took the adjusted likelihood, [`EdgeWatch`]
//! integrates the walkers along their own paths at steps 10, 20, 40, … and
//! stops the run where more than a tenth miss some run by more than
//! [`crate::predict::FAR`] times the best fit's residual RMS (the measure of the
//! bands' `far_draws`), [`far_from_records`] does the same with the
//! finished chains' draws, and [`sample_watched`] then starts again under
//! the tempered likelihood, saying why.

use std::path::PathBuf;

use super::start::{far_paths, start_refusing_adjusted, Start, BLIND_SPOT_SHARE};
use super::{sample, Calibrated, CalibrationSettings};
use crate::data::Campaign;
use crate::error::{Error, Result};
use crate::posterior::{map, Draws, Memory, Posterior};
use crate::predict::FAR;
use crate::sampler::{Chains, Observer, RunState};

/// Draws each check integrates along their own paths.
const CHECKED_DRAWS: usize = 200;

/// The first step at which [`EdgeWatch`] looks; then at twice each.
const FIRST_LOOK: usize = 10;

/// Watches a run under the adjusted likelihood `auto` took for walkers
/// past the records' edge (the module's doc); an error stops the run where it
/// finds them, and [`Self::found`] says what it found.
pub struct EdgeWatch {
    plain: Posterior,
    at_map: Vec<(f64, usize)>,
    next: usize,
    found: Option<String>,
}

impl EdgeWatch {
    /// A watch for the run from `start`: `None` unless `auto` took the
    /// adjusted likelihood there.
    pub fn of(start: &Start) -> Option<EdgeWatch> {
        if start.memory_found.is_none() || start.settings.likelihood.memory != Memory::Adjusted {
            return None;
        }
        // the independent likelihood's MAP: the best fit the records allow
        // (the adjusted posterior's own may lie past their edge already)
        let plain = start.posterior.without_adjustment();
        let at_map = map::residual_rms(&plain, &start.searched.x)?;
        Some(EdgeWatch { plain, at_map, next: FIRST_LOOK, found: None })
    }

    /// What the watch found, in a sentence.
    pub fn found(&self) -> Option<&str> {
        self.found.as_deref()
    }

    /// The sentence for `points` where more than a tenth are far (a path
    /// that cannot be integrated counts as far).
    fn far(&self, points: &[Vec<f64>], what: &str) -> Option<String> {
        let (far, integrated) = far_paths(&self.plain, points, &self.at_map);
        let far = far + (points.len() - integrated);
        (far as f64 > BLIND_SPOT_SHARE * points.len().max(1) as f64).then(|| {
            format!(
                "{far} of {} {what} have paths that miss a record by more than {FAR}× the residual RMS of the best fit, the independent likelihood's MAP (a parameter the records leave free about the MAP and rule out further on: the adjustment scored them by the fit at points nearer the MAP)",
                points.len()
            )
        })
    }
}

impl Observer for EdgeWatch {
    fn stepped(&mut self, state: &RunState) -> Result<()> {
        if state.step < self.next {
            return Ok(());
        }
        self.next = 2 * state.step;
        let chains = state.chains;
        let last = chains.steps() - 1;
        let every = chains.chains().div_ceil(CHECKED_DRAWS).max(1);
        let points: Vec<Vec<f64>> =
            (0..chains.chains()).step_by(every).map(|c| chains.point(last, c).to_vec()).collect();
        match self.far(&points, &format!("walkers at step {}", state.step)) {
            Some(why) => {
                self.found = Some(why.clone());
                Err(Error::Compute(why))
            }
            None => Ok(()),
        }
    }
}

/// The caller's observers, told first, and the watch beside them.
struct Beside<'a, 'b> {
    others: &'a mut [&'b mut dyn Observer],
    watch: &'a mut EdgeWatch,
}

impl Observer for Beside<'_, '_> {
    fn started(&mut self, state: &RunState) -> Result<()> {
        self.others.iter_mut().try_for_each(|o| o.started(state))
    }
    fn stepped(&mut self, state: &RunState) -> Result<()> {
        self.others.iter_mut().try_for_each(|o| o.stepped(state))?;
        self.watch.stepped(state)
    }
    fn checked(
        &mut self,
        state: &RunState,
        diagnostics: &crate::sampler::Diagnostics,
        waiting: Option<&crate::sampler::stopping::Waiting>,
    ) {
        self.others.iter_mut().for_each(|o| o.checked(state, diagnostics, waiting));
    }
    fn finished(&mut self, state: &RunState) -> Result<()> {
        self.others.iter_mut().try_for_each(|o| o.finished(state))
    }
    fn tempered(&mut self, population: usize, stage: &crate::sampler::smc::Stage) {
        self.others.iter_mut().for_each(|o| o.tempered(population, stage));
    }
    fn populated(
        &mut self,
        done: usize,
        write: &dyn Fn(&std::path::Path) -> Result<()>,
    ) -> Result<()> {
        self.others.iter_mut().try_for_each(|o| o.populated(done, write))
    }
}

/// [`CHECKED_DRAWS`] of the finished `chains`' draws (after `burn_in`,
/// thinned by `tau`) checked as [`EdgeWatch`] checks the walkers.
fn far_in(watch: &EdgeWatch, chains: &Chains, burn_in: usize, tau: f64) -> Option<String> {
    let points: Vec<Vec<f64>> = Draws::after(burn_in, tau)
        .positions(chains, CHECKED_DRAWS)
        .into_iter()
        .map(|(step, chain)| chains.point(step, chain).to_vec())
        .collect();
    watch.far(&points, "of its posterior's draws")
}

/// Where `auto` took the adjusted likelihood for `made`, more than a tenth
/// of [`CHECKED_DRAWS`] of its posterior's draws far from a record: what
/// was found, in a sentence.
pub fn far_from_records(made: &Calibrated) -> Option<String> {
    let watch = EdgeWatch::of(&made.start)?;
    let d = &made.diagnostics;
    far_in(&watch, &made.chains, d.burn_in, d.tau_max)
}

/// [`sample`] from `start` (or the checkpoint at `resume_from`) with
/// `observers`, an [`EdgeWatch`] beside them where `auto` took the
/// adjusted likelihood; where the watch or the finished draws find the
/// blind spot, the start again from `settings` refusing the adjusted
/// likelihood (`log` told each line) and the sampling afresh.
pub fn sample_watched(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    start: Start,
    resume_from: Option<&PathBuf>,
    observers: &mut [&mut dyn Observer],
    log: &mut dyn FnMut(&str),
) -> Result<Calibrated> {
    let Some(mut watch) = EdgeWatch::of(&start) else {
        return sample(campaign, start, resume_from, observers);
    };
    let searched = start.searched.clone();
    let made = {
        let mut beside = Beside { others: observers, watch: &mut watch };
        sample(campaign, start, resume_from, &mut [&mut beside])
    };
    let why = match made {
        Err(e) => match watch.found() {
            Some(why) => why.to_string(),
            None => return Err(e),
        },
        Ok(made) => {
            let d = &made.diagnostics;
            match far_in(&watch, &made.chains, d.burn_in, d.tau_max) {
                Some(why) => why,
                None => return Ok(made),
            }
        }
    };
    log(&format!(
        "  memory: under the adjusted likelihood {why}: calibrating again under the tempered likelihood"
    ));
    let start = start_refusing_adjusted(campaign, settings, &why, &searched, log)?;
    sample(campaign, start, None, observers)
}
