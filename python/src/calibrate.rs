//! `calibrate`: sampling from Python, with its progress shown or told and
//! Ctrl-C (a checkpoint kept where asked).

use std::path::PathBuf;
use std::sync::Arc;

use clap::ValueEnum;
use pyo3::exceptions::{PyKeyboardInterrupt, PyValueError};
use pyo3::prelude::*;

use mrbp::calibrate::settings::{Overrides, SamplerMethod};
use mrbp::data::same_current;
use mrbp::error::Error;
use mrbp::posterior::ModelKind;
use mrbp::sampler::{Checkpointer, Observer, RunState};

use crate::calibration::Calibration;
use crate::campaign::Campaign;
use crate::raise;

/// Whether Python has a signal pending that raises (Ctrl-C in a terminal,
/// a notebook's interrupt button); its handler runs here.
fn python_interrupted() -> bool {
    Python::attach(|py| py.check_signals().is_err())
}

/// Stops a calibration at Python's Ctrl-C (saving the sampler's state
/// first where a checkpoint is kept), and reports its progress to a Python
/// callable where asked: `progress(stage, step, max_steps, ess,
/// ess_target, r_hat, acceptance)`, stage "started", "step" or
/// "finished", the diagnostics None until the first convergence check.
struct Python_ {
    progress: Option<Py<PyAny>>,
    checkpoint: Option<PathBuf>,
    checked: Option<(f64, f64)>,
    accepted: usize,
}

impl Python_ {
    fn report(&self, stage: &str, state: &RunState) -> mrbp::Result<()> {
        let Some(callback) = &self.progress else { return Ok(()) };
        let (ess, r_hat) = self.checked.map_or((None, None), |(e, r)| (Some(e), Some(r)));
        let rate = self.accepted as f64 / state.chains.chains().max(1) as f64;
        let called = Python::attach(|py| {
            callback
                .call1(py, (stage, state.step, state.max_steps, ess, state.min_ess, r_hat, rate))
                .map(|_| ())
                .map_err(|e| {
                    e.is_instance_of::<PyKeyboardInterrupt>(py).then_some(()).ok_or(e.to_string())
                })
        });
        match called {
            Ok(()) => Ok(()),
            // Ctrl-C while the callback ran
            Err(Ok(())) => Err(self.interrupted(state)),
            Err(Err(e)) => Err(Error::Compute(format!("the progress callback raised: {e}"))),
        }
    }

    /// The error that stops the run at Ctrl-C, the state saved first where
    /// a checkpoint is kept.
    fn interrupted(&self, state: &RunState) -> Error {
        let Some(path) = &self.checkpoint else {
            return Error::Interrupted(format!("interrupted after step {} (no checkpoint kept: calibrate(..., checkpoint='a file') keeps one to resume from)", state.step));
        };
        if let Err(e) = mrbp::sampler::checkpoint::save(path, state.settings, state.chains) {
            return e;
        }
        Error::Interrupted(format!(
            "interrupted after step {}: the chains so far are in {}; calibrate(..., checkpoint=<that file>, resume=True) with the same options continues them",
            state.step,
            path.display()
        ))
    }
}

impl Observer for Python_ {
    fn started(&mut self, state: &RunState) -> mrbp::Result<()> {
        self.report("started", state)
    }

    fn stepped(&mut self, state: &RunState) -> mrbp::Result<()> {
        self.accepted = state.accepted;
        self.report("step", state)?;
        match python_interrupted() {
            true => Err(self.interrupted(state)),
            false => Ok(()),
        }
    }

    fn checked(
        &mut self,
        _state: &RunState,
        diagnostics: &mrbp::sampler::Diagnostics,
        _waiting: Option<&mrbp::sampler::Waiting>,
    ) {
        let ess = diagnostics.min_ess();
        if ess.is_finite() {
            self.checked = Some((ess, diagnostics.max_rhat()));
        }
    }

    fn finished(&mut self, state: &RunState) -> mrbp::Result<()> {
        self.report("finished", state)
    }
}

/// Calibrates the runs of `campaign` at `current` (per-current model; any
/// current the campaign has, or its only one) or all runs with the current
/// law (`model="current-law"`), as `mrbp sample` does with the same
/// options: the same seed gives the same chains. The GIL is released while
/// it samples; Ctrl-C raises KeyboardInterrupt, after saving the sampler's
/// state to `checkpoint` if given (every 100 steps too), which `resume`
/// continues exactly. `progress` is a callable told of every step.
#[pyfunction]
#[pyo3(signature = (campaign, current = None, model = None, noise = None, seed = None, steps = None, walkers = None, ensembles = None, substeps = None, config = None, exact_input = false, progress = None, checkpoint = None, resume = false, memory = None, law = None, sampler = None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn calibrate(
    py: Python<'_>,
    campaign: &Campaign,
    current: Option<f64>,
    model: Option<String>,
    noise: Option<String>,
    seed: Option<u64>,
    steps: Option<usize>,
    walkers: Option<usize>,
    ensembles: Option<usize>,
    substeps: Option<u32>,
    config: Option<PathBuf>,
    exact_input: bool,
    progress: Option<Py<PyAny>>,
    checkpoint: Option<PathBuf>,
    resume: bool,
    memory: Option<String>,
    law: Option<String>,
    sampler: Option<String>,
) -> PyResult<Calibration> {
    let value = |v: Option<String>| v.map(|s| s.trim().to_string()).filter(|s| !s.is_empty());
    let model = match value(model) {
        Some(m) => Some(ModelKind::from_str(&m, true).map_err(|_| {
            PyValueError::new_err(format!(
                "model {m:?}: one of 'per-current', 'current-law', 'current-curves'"
            ))
        })?),
        None => None,
    };
    let noise = match value(noise) {
        Some(n) => Some(mrbp::noise::NoiseKind::from_str(&n, true).map_err(|_| {
            let names: Vec<String> = mrbp::noise::NoiseKind::value_variants()
                .iter()
                .filter_map(|v| v.to_possible_value().map(|p| p.get_name().to_string()))
                .collect();
            PyValueError::new_err(format!("noise {n:?}: one of {}", names.join(", ")))
        })?),
        None => None,
    };
    let memory = match value(memory) {
        Some(m) => Some(mrbp::posterior::Memory::from_str(&m, true).map_err(|_| {
            PyValueError::new_err(format!(
                "memory {m:?}: one of 'auto', 'independent', 'tempered', 'adjusted'"
            ))
        })?),
        None => None,
    };
    let law = match value(law) {
        Some(l) => vec![mrbp::laws::LawKind::from_str(&l, true).map_err(|_| {
            let names: Vec<String> = mrbp::laws::LawKind::ALL.iter().map(|k| k.name()).collect();
            PyValueError::new_err(format!("law {l:?}: one of {}", names.join(", ")))
        })?],
        None => Vec::new(),
    };
    let sampler = match value(sampler) {
        Some(m) => Some(SamplerMethod::from_str(&m, true).map_err(|_| {
            PyValueError::new_err(format!("sampler {m:?}: one of 'ensemble', 'smc'"))
        })?),
        None => None,
    };
    let overrides = Overrides {
        config,
        law,
        sampler,
        model,
        walkers,
        ensembles,
        steps,
        seed,
        noise,
        memory,
        exact_input,
        substeps,
        ..Default::default()
    };
    let settings = overrides.settings().map_err(raise)?;
    let all = campaign.inner.clone();
    let group = if settings.parameter_model().is_current_law() {
        if current.is_some() {
            return Err(PyValueError::new_err("current: a current law calibrates every current of the campaign; leave current out"));
        }
        (*all).clone()
    } else {
        let currents = all.currents();
        let c = match (current, currents.as_slice()) {
            (Some(c), _) if !currents.iter().any(|h| same_current(*h, c)) => {
                return Err(PyValueError::new_err(format!(
                    "current {c}: the campaign has runs at {currents:?} A"
                )))
            }
            (Some(c), _) => c,
            (None, [only]) => *only,
            (None, _) => {
                return Err(PyValueError::new_err(format!(
                    "current: the campaign has runs at {currents:?} A; say which to calibrate"
                )))
            }
        };
        all.at_current(c)
    };
    group.require_usable("the calibration").map_err(raise)?;
    let resume_from = match (&checkpoint, resume) {
        (None, true) => {
            return Err(PyValueError::new_err(
                "resume: say which checkpoint to continue (checkpoint='the file')",
            ))
        }
        (Some(path), true)
            if !path.exists() && !mrbp::sampler::checkpoint::smc_beside(path).exists() =>
        {
            return Err(PyValueError::new_err(format!(
                "resume: no checkpoint at {}",
                path.display()
            )))
        }
        (Some(path), true) => {
            mrbp::pipeline::check_resumable(path, &settings).map_err(raise)?;
            Some(path.clone())
        }
        _ => None,
    };
    let made = py
        .detach(move || {
            let start = mrbp::calibrate::start(&group, &settings, &mut |_| {})?;
            let mut observer =
                Python_ { progress, checkpoint: checkpoint.clone(), checked: None, accepted: 0 };
            // the state every 100 steps, beside the one saved at Ctrl-C
            let mut checkpointer = checkpoint.as_ref().map(|path| Checkpointer {
                path: path.clone(),
                every: mrbp::pipeline::CHECKPOINT_EVERY,
                stop: || false,
            });
            let mut observers: Vec<&mut dyn Observer> = vec![&mut observer];
            if let Some(c) = checkpointer.as_mut() {
                observers.push(c);
            }
            // as the command line: the tempered likelihood where the
            // adjusted one `auto` took reaches past the records
            let made = mrbp::calibrate::sample_watched(
                &group,
                &settings,
                start,
                resume_from.as_ref(),
                &mut observers,
                &mut |_| {},
            )?;
            if let Some(path) = &checkpoint {
                // the chains are whole in the calibration returned: the
                // checkpoints (the sampler's, and the populations' of
                // sequential Monte Carlo beside it) have done their job
                let _ = std::fs::remove_file(path);
                let _ = std::fs::remove_file(mrbp::sampler::checkpoint::smc_beside(path));
            }
            Ok::<_, Error>((made, Arc::new(group)))
        })
        .map_err(raise)?;
    let (made, group) = made;
    Ok(Calibration { inner: made.calibration, made: Some((group, made.start.identification)) })
}
