//! `mrbp._mrbp`: the Rust library seen from Python. The package `mrbp`
//! (python/mrbp/__init__.py) wraps these in pandas frames; nothing here
//! computes anything the command line does not compute the same way.

use std::path::PathBuf;
use std::sync::Arc;

use clap::ValueEnum;
use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use mrbp::calibrate::settings::Overrides;
use mrbp::data::{same_current, Geometry, Manifest, Record, RunSpec};
use mrbp::error::Error;
use mrbp::identify::CurrentIdentification;
use mrbp::posterior::ModelKind;
use mrbp::sampler::{Observer, RunState};

/// A Python exception for an mrbp error: bad input is a ValueError (its
/// message names the run, row and column), an interruption a
/// KeyboardInterrupt, a file that cannot be written an OSError.
fn raise(e: Error) -> PyErr {
    let text = e.to_string();
    match e {
        Error::Input { .. } | Error::Usage(_) => PyValueError::new_err(text),
        Error::Interrupted(_) => PyKeyboardInterrupt::new_err(text),
        Error::Output { .. } => PyOSError::new_err(text),
        Error::Compute(_) | Error::Busy(_) => PyRuntimeError::new_err(text),
    }
}

/// A test campaign: runs of one damper, each a record and a coil current.
#[pyclass(frozen, module = "mrbp._mrbp")]
struct Campaign {
    inner: Arc<mrbp::data::Campaign>,
}

#[pymethods]
impl Campaign {
    /// Reads a campaign manifest and its data files, as `mrbp check` does.
    #[staticmethod]
    fn load(manifest: PathBuf) -> PyResult<Campaign> {
        mrbp::data::Campaign::load(&manifest).map(|c| Campaign { inner: Arc::new(c) }).map_err(raise)
    }

    /// A campaign from arrays in SI units: `runs` holds, per run, its id,
    /// coil current (A), time (s), displacement (m), force (N) and
    /// optionally a current column (A).
    #[staticmethod]
    #[allow(clippy::type_complexity)]
    fn from_arrays(name: String, area_m2: f64, gap_m: f64, runs: Vec<(String, f64, Vec<f64>, Vec<f64>, Vec<f64>, Option<Vec<f64>>)>) -> PyResult<Campaign> {
        let mut specs = Vec::new();
        let mut records = Vec::new();
        for (id, current_a, time, displacement, force, current) in runs {
            specs.push(RunSpec { file: PathBuf::from(format!("{id}.csv")), id, current_a, shear_rate: None, initial_stress_pa: None });
            records.push(Record { time, displacement, force, current });
        }
        let manifest = Manifest { name, geometry: Geometry { area_m2, gap_m }, columns: Default::default(), limits: Default::default(), runs: specs };
        mrbp::data::Campaign::from_records(manifest, records).map(|c| Campaign { inner: Arc::new(c) }).map_err(raise)
    }

    #[getter]
    fn name(&self) -> String {
        self.inner.name.clone()
    }

    /// The runs' ids, in the campaign's order.
    #[getter]
    fn runs(&self) -> Vec<String> {
        self.inner.runs.iter().map(|r| r.id().to_string()).collect()
    }

    /// The coil currents of the runs, each once, rising.
    #[getter]
    fn currents(&self) -> Vec<f64> {
        self.inner.currents()
    }

    /// What loading noticed but did not refuse.
    #[getter]
    fn notes(&self) -> Vec<String> {
        self.inner.notes.clone()
    }

    fn __repr__(&self) -> String {
        format!("Campaign({:?}: {} runs at {:?} A)", self.inner.name, self.inner.runs.len(), self.inner.currents())
    }
}

/// Stops a calibration when Python has a signal pending (Ctrl-C in a
/// notebook), and shows its progress where asked.
struct Python_ {
    progress: Option<mrbp::sampler::Progress>,
}

impl Observer for Python_ {
    fn started(&mut self, state: &RunState) -> mrbp::Result<()> {
        self.progress.as_mut().map_or(Ok(()), |p| p.started(state))
    }

    fn stepped(&mut self, state: &RunState) -> mrbp::Result<()> {
        if let Some(p) = self.progress.as_mut() {
            p.stepped(state)?;
        }
        Python::attach(|py| py.check_signals()).map_err(|_| Error::Interrupted("interrupted from Python (KeyboardInterrupt)".into()))
    }

    fn checked(&mut self, state: &RunState, diagnostics: &mrbp::sampler::Diagnostics) {
        if let Some(p) = self.progress.as_mut() {
            p.checked(state, diagnostics)
        }
    }

    fn finished(&mut self, state: &RunState) -> mrbp::Result<()> {
        self.progress.as_mut().map_or(Ok(()), |p| p.finished(state))
    }
}

/// Named float columns, in order (a frame's).
type Columns = Vec<(String, Vec<f64>)>;

/// The columns of `chains.parquet`: integer bookkeeping, the coordinates
/// with log_prob, and `accepted`.
type ChainColumns = (Vec<(&'static str, Vec<i64>)>, Columns, Vec<bool>);

/// A calibration: its settings, record, summary and posterior sample.
#[pyclass(module = "mrbp._mrbp")]
struct Calibration {
    inner: mrbp::calibrate::Calibration,
    /// How it was made in memory (for `save`); none when read from a folder.
    made: Option<(Arc<mrbp::data::Campaign>, CurrentIdentification)>,
}

#[pymethods]
impl Calibration {
    /// Reads the calibration folder of `mrbp sample` or `mrbp run`.
    #[staticmethod]
    fn load(folder: PathBuf) -> PyResult<Calibration> {
        mrbp::store::folder::read(&folder).map(|inner| Calibration { inner, made: None }).map_err(raise)
    }

    /// The summary's columns, as `summary.parquet` holds them.
    fn summary_columns(&self) -> Vec<(&'static str, Vec<f64>)> {
        mrbp::store::summary::statistics(&self.inner.summary)
    }

    /// The summary's parameter names, in its row order.
    fn summary_parameters(&self) -> Vec<String> {
        self.inner.summary.iter().map(|r| r.parameter.clone()).collect()
    }

    /// Every walker's every step, as `chains.parquet` holds them: the
    /// bookkeeping columns (ensemble, chain, draw, accepted) and the
    /// coordinates with log_prob.
    fn chain_columns(&self) -> ChainColumns {
        let c = mrbp::store::chains::columns(&self.inner.sample);
        (c.bookkeeping, c.values, c.accepted)
    }

    /// The first step after the burn-in (the summary's draws start there).
    #[getter]
    fn burn_in(&self) -> usize {
        self.inner.burn_in()
    }

    #[getter]
    fn calibration_id(&self) -> String {
        self.inner.record.calibration_id.clone()
    }

    /// The largest R̂ of the summary.
    #[getter]
    fn max_r_hat(&self) -> f64 {
        self.inner.max_rhat()
    }

    /// Warnings of the sampler and of the model's fit.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner.record.warnings.iter().chain(&self.inner.record.model_warnings).cloned().collect()
    }

    /// The folder it was read from or saved to, if any.
    #[getter]
    fn folder(&self) -> Option<PathBuf> {
        (!self.inner.dir.as_os_str().is_empty()).then(|| self.inner.dir.clone())
    }

    /// Writes the calibration into `folder` as `mrbp sample` would (the
    /// command line reads it back); an earlier calibration there is
    /// replaced only if `force`.
    #[pyo3(signature = (folder, force = false))]
    fn save(&mut self, py: Python<'_>, folder: PathBuf, force: bool) -> PyResult<()> {
        let Some((campaign, identification)) = &self.made else {
            return Err(PyValueError::new_err(format!("this calibration was read from {}: it is saved there already", self.inner.dir.display())));
        };
        let cal = self.inner.clone();
        let (campaign, identification) = (campaign.clone(), identification.clone());
        let saved = py
            .detach(move || {
                let mut quiet = |_: mrbp::pipeline::Event<'_>| {};
                mrbp::pipeline::Pipeline::new(&mut quiet, false).save(&campaign, &folder, cal, &identification, force)
            })
            .map_err(raise)?;
        self.inner = saved;
        Ok(())
    }

    /// The force of the calibrated damper along an excitation of your own
    /// (`mrbp simulate`): columns of `simulation.parquet`, and the notes
    /// (extrapolation, draws that failed).
    #[pyo3(signature = (time, displacement, current = None, current_column = None, draws = 400, replicates = 10, seed = 1))]
    #[allow(clippy::too_many_arguments)]
    fn simulate(
        &self,
        py: Python<'_>,
        time: Vec<f64>,
        displacement: Vec<f64>,
        current: Option<f64>,
        current_column: Option<Vec<f64>>,
        draws: usize,
        replicates: usize,
        seed: u64,
    ) -> PyResult<(Columns, Vec<String>)> {
        let cal = self.inner.clone();
        let n = time.len();
        let record = Record { time, displacement, force: vec![f64::NAN; n], current: current_column };
        let options = mrbp::pipeline::PredictOptions { draws, replicates, seed };
        let (made, notes) = py
            .detach(move || {
                let mut notes = Vec::new();
                let mut listen = |e: mrbp::pipeline::Event<'_>| {
                    if let mrbp::pipeline::Event::Note(line) = e {
                        notes.push(line.to_string());
                    }
                };
                let made = mrbp::pipeline::Pipeline::new(&mut listen, false).simulation(&cal, std::path::Path::new("excitation"), record, current, &options, None);
                made.map(|m| (m, notes))
            })
            .map_err(raise)?;
        Ok((mrbp::store::simulation::columns(&made), notes))
    }

    fn __repr__(&self) -> String {
        let label = if self.inner.dir.as_os_str().is_empty() { "in memory".to_string() } else { self.inner.label() };
        format!("Calibration({label}, max R̂ {:.4})", self.inner.max_rhat())
    }
}

/// Calibrates the runs of `campaign` at `current` (per-current model; any
/// current the campaign has, or its only one) or all runs with the current
/// law (`model="current-law"`), as `mrbp sample` does with the same
/// options: the same seed gives the same chains. The GIL is released while
/// it samples; Ctrl-C raises KeyboardInterrupt.
#[pyfunction]
#[pyo3(signature = (campaign, current = None, model = None, noise = None, seed = None, steps = None, walkers = None, ensembles = None, substeps = None, config = None, exact_input = false, progress = false))]
#[allow(clippy::too_many_arguments)]
fn calibrate(
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
    progress: bool,
) -> PyResult<Calibration> {
    let value = |v: Option<String>| v.map(|s| s.trim().to_string()).filter(|s| !s.is_empty());
    let model = match value(model) {
        Some(m) => Some(ModelKind::from_str(&m, true).map_err(|_| PyValueError::new_err(format!("model {m:?}: one of 'per-current', 'current-law'")))?),
        None => None,
    };
    let noise = match value(noise) {
        Some(n) => Some(mrbp::noise::NoiseKind::from_str(&n, true).map_err(|_| {
            let names: Vec<String> = mrbp::noise::NoiseKind::value_variants().iter().filter_map(|v| v.to_possible_value().map(|p| p.get_name().to_string())).collect();
            PyValueError::new_err(format!("noise {n:?}: one of {}", names.join(", ")))
        })?),
        None => None,
    };
    let overrides = Overrides { config, model, walkers, ensembles, steps, seed, noise, exact_input, substeps, ..Default::default() };
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
            (Some(c), _) if !currents.iter().any(|h| same_current(*h, c)) => return Err(PyValueError::new_err(format!("current {c}: the campaign has runs at {currents:?} A"))),
            (Some(c), _) => c,
            (None, [only]) => *only,
            (None, _) => return Err(PyValueError::new_err(format!("current: the campaign has runs at {currents:?} A; say which to calibrate"))),
        };
        all.at_current(c)
    };
    group.require_usable("the calibration").map_err(raise)?;
    let made = py
        .detach(move || {
            let start = mrbp::calibrate::start(&group, &settings, &mut |_| {})?;
            let mut observer = Python_ { progress: progress.then(mrbp::sampler::Progress::default) };
            let mut observers: [&mut dyn Observer; 1] = [&mut observer];
            let made = mrbp::calibrate::sample(&group, start, None, &mut observers)?;
            Ok::<_, Error>((made, Arc::new(group)))
        })
        .map_err(raise)?;
    let (made, group) = made;
    Ok(Calibration { inner: made.calibration, made: Some((group, made.start.identification)) })
}

/// The version of the mrbp library inside.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _mrbp(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Campaign>()?;
    m.add_class::<Calibration>()?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    Ok(())
}
