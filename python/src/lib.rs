//! `mrbp._mrbp`: the Rust library seen from Python. The package `mrbp`
//! (python/mrbp/__init__.py) wraps these in pandas frames; nothing here
//! computes anything the command line does not compute the same way.

use std::path::PathBuf;
use std::sync::Arc;

use clap::ValueEnum;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use mrbp::calibrate::settings::Overrides;
use mrbp::data::{same_current, Geometry, Manifest, Record, RunSpec};
use mrbp::error::Error;
use mrbp::identify::CurrentIdentification;
use mrbp::posterior::ModelKind;
use mrbp::sampler::{Checkpointer, Observer, RunState};
use mrbp::store::inference::Values;

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
    /// optionally a current column (A), as contiguous float64 NumPy arrays
    /// (read in place).
    #[staticmethod]
    #[allow(clippy::type_complexity)]
    fn from_arrays(
        name: String,
        area_m2: f64,
        gap_m: f64,
        runs: Vec<(String, f64, PyReadonlyArray1<'_, f64>, PyReadonlyArray1<'_, f64>, PyReadonlyArray1<'_, f64>, Option<PyReadonlyArray1<'_, f64>>)>,
    ) -> PyResult<Campaign> {
        let mut specs = Vec::new();
        let mut records = Vec::new();
        for (id, current_a, time, displacement, force, current) in runs {
            let current = current.map(|c| values(&c)).transpose()?;
            records.push(Record { time: values(&time)?, displacement: values(&displacement)?, force: values(&force)?, current });
            specs.push(RunSpec { file: PathBuf::from(format!("{id}.csv")), id, current_a, shear_rate: None, initial_stress_pa: None });
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
            callback.call1(py, (stage, state.step, state.max_steps, ess, state.min_ess, r_hat, rate)).map(|_| ()).map_err(|e| e.is_instance_of::<PyKeyboardInterrupt>(py).then_some(()).ok_or(e.to_string()))
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

    fn checked(&mut self, _state: &RunState, diagnostics: &mrbp::sampler::Diagnostics) {
        let ess = diagnostics.min_ess();
        if ess.is_finite() {
            self.checked = Some((ess, diagnostics.max_rhat()));
        }
    }

    fn finished(&mut self, state: &RunState) -> mrbp::Result<()> {
        self.report("finished", state)
    }
}

/// A contiguous float64 NumPy array's values, read in place (one copy into
/// the record Rust owns).
fn values(a: &PyReadonlyArray1<'_, f64>) -> PyResult<Vec<f64>> {
    a.as_slice().map(<[f64]>::to_vec).map_err(|_| PyValueError::new_err("an array must be contiguous float64 (numpy.ascontiguousarray)"))
}

/// Named NumPy arrays, handed over without a copy.
fn arrays<'py, N: Into<String>>(py: Python<'py>, columns: Vec<(N, Vec<f64>)>) -> Vec<(String, Bound<'py, PyArray1<f64>>)> {
    columns.into_iter().map(|(name, v)| (name.into(), PyArray1::from_vec(py, v))).collect()
}

/// Named NumPy columns, in order (a frame's).
type Arrays<'py> = Vec<(String, Bound<'py, PyArray1<f64>>)>;

/// The columns of `chains.parquet`: integer bookkeeping, the coordinates
/// with log_prob, and `accepted`.
type ChainColumns<'py> = (Vec<(&'static str, Bound<'py, PyArray1<i64>>)>, Arrays<'py>, Bound<'py, PyArray1<bool>>);

/// One array of an InferenceData group: name, dimensions, values, and
/// attributes as JSON.
type DataNode<'py> = (String, Vec<(&'static str, usize)>, Bound<'py, PyAny>, String);

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
    fn summary_columns<'py>(&self, py: Python<'py>) -> Arrays<'py> {
        arrays(py, mrbp::store::summary::statistics(&self.inner.summary))
    }

    /// The summary's parameter names, in its row order.
    fn summary_parameters(&self) -> Vec<String> {
        self.inner.summary.iter().map(|r| r.parameter.clone()).collect()
    }

    /// Every walker's every step, as `chains.parquet` holds them: the
    /// bookkeeping columns (ensemble, chain, draw, accepted) and the
    /// coordinates with log_prob.
    fn chain_columns<'py>(&self, py: Python<'py>) -> ChainColumns<'py> {
        let c = mrbp::store::chains::columns(&self.inner.sample);
        let bookkeeping = c.bookkeeping.into_iter().map(|(n, v)| (n, PyArray1::from_vec(py, v))).collect();
        (bookkeeping, arrays(py, c.values), PyArray1::from_vec(py, c.accepted))
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
    /// (`mrbp simulate`): columns of `simulation.parquet`, the notes
    /// (extrapolation, draws that failed), and the (step, chain) of the
    /// posterior draws it propagated.
    #[pyo3(signature = (time, displacement, current = None, current_column = None, draws = 400, replicates = 10, seed = 1))]
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn simulate<'py>(
        &self,
        py: Python<'py>,
        time: PyReadonlyArray1<'_, f64>,
        displacement: PyReadonlyArray1<'_, f64>,
        current: Option<f64>,
        current_column: Option<PyReadonlyArray1<'_, f64>>,
        draws: usize,
        replicates: usize,
        seed: u64,
    ) -> PyResult<(Arrays<'py>, Vec<String>, Vec<(usize, usize)>)> {
        let cal = self.inner.clone();
        let (time, displacement) = (values(&time)?, values(&displacement)?);
        let n = time.len();
        let record = Record { time, displacement, force: vec![f64::NAN; n], current: current_column.map(|c| values(&c)).transpose()? };
        let options = mrbp::pipeline::PredictOptions { draws, replicates, seed };
        let (made, notes) = py
            .detach(move || noted(|p| p.simulation(&cal, std::path::Path::new("excitation"), record, current, &options, None)))
            .map_err(raise)?;
        let positions = if options.check().is_ok() { self.inner.draw_positions(draws) } else { Vec::new() };
        Ok((arrays(py, mrbp::store::simulation::columns(&made)), notes, positions))
    }

    /// The bands of the calibration's runs (`mrbp predict`): the bytes of
    /// `bands.parquet`, `coverage.parquet` and `adequacy.parquet` by file
    /// name, the runs that could not be predicted (id, why), and the notes.
    #[pyo3(signature = (draws = 400, replicates = 10, seed = 1))]
    #[allow(clippy::type_complexity)]
    fn predict<'py>(&self, py: Python<'py>, draws: usize, replicates: usize, seed: u64) -> PyResult<(Vec<(&'static str, Bound<'py, PyBytes>)>, Vec<(String, String)>, Vec<String>)> {
        let cal = self.inner.clone();
        let campaign = self.campaign()?;
        let options = mrbp::pipeline::PredictOptions { draws, replicates, seed };
        let ((tables, failed), notes) = py
            .detach(move || {
                noted(|pipeline| {
                    let runs = if cal.is_current_law() { (*campaign).clone() } else { cal.used_runs(&campaign) };
                    let (prediction, failed) = pipeline.prediction(&cal, &runs, &|run| cal.record.runs.iter().any(|r| r == run.id()), &options)?;
                    Ok((mrbp::store::prediction::tables(&prediction)?, failed))
                })
            })
            .map_err(raise)?;
        Ok((tables.into_iter().map(|(name, b)| (name, PyBytes::new(py, &b))).collect(), failed, notes))
    }

    /// The calibration as ArviZ's InferenceData, in memory (what
    /// `inference.zarr` holds): the root's attributes (JSON), and per group
    /// its name, attributes (JSON) and arrays (name, dimensions, NumPy
    /// values or a list of strings, attributes as JSON); with the notes.
    #[pyo3(signature = (seed = 1))]
    #[allow(clippy::type_complexity)]
    fn inference_data<'py>(&self, py: Python<'py>, seed: u64) -> PyResult<(String, Vec<(&'static str, String, Vec<DataNode<'py>>)>, Vec<String>)> {
        let cal = self.inner.clone();
        let campaign = self.campaign()?;
        let (data, notes) = py.detach(move || noted(|p| p.inference_data(&cal, &campaign, seed))).map_err(raise)?;
        let json = |m: &serde_json::Map<String, serde_json::Value>| serde_json::Value::Object(m.clone()).to_string();
        let mut groups = Vec::new();
        for g in data.groups {
            let mut nodes = Vec::new();
            for node in g.nodes {
                let attrs = json(&node.attrs);
                let values = match node.values {
                    Values::F64(v) => PyArray1::from_vec(py, v).into_any(),
                    Values::F32(v) => PyArray1::from_vec(py, v).into_any(),
                    Values::I64(v) => PyArray1::from_vec(py, v).into_any(),
                    Values::Bool(v) => PyArray1::from_vec(py, v).into_any(),
                    Values::Str(v) => v.into_pyobject(py)?.into_any(),
                };
                nodes.push((node.name, node.dims, values, attrs));
            }
            groups.push((g.name, json(&g.attrs), nodes));
        }
        Ok((json(&data.attrs), groups, notes))
    }

    fn __repr__(&self) -> String {
        let label = if self.inner.dir.as_os_str().is_empty() { "in memory".to_string() } else { self.inner.label() };
        format!("Calibration({label}, max R̂ {:.4})", self.inner.max_rhat())
    }
}

impl Calibration {
    /// The campaign of the calibration's runs: the one it was made from, or
    /// the manifest its record names.
    fn campaign(&self) -> PyResult<Arc<mrbp::data::Campaign>> {
        match &self.made {
            Some((campaign, _)) => Ok(campaign.clone()),
            None => self.inner.full_campaign().map(Arc::new).map_err(raise),
        }
    }
}

/// Runs `work` on a quiet pipeline whose notes it keeps.
fn noted<T>(work: impl FnOnce(&mut mrbp::pipeline::Pipeline<'_>) -> mrbp::Result<T>) -> mrbp::Result<(T, Vec<String>)> {
    let mut notes = Vec::new();
    let made = {
        let mut listen = |e: mrbp::pipeline::Event<'_>| {
            if let mrbp::pipeline::Event::Note(line) = e {
                notes.push(line.to_string());
            }
        };
        work(&mut mrbp::pipeline::Pipeline::new(&mut listen, false))?
    };
    Ok((made, notes))
}

/// Calibrates the runs of `campaign` at `current` (per-current model; any
/// current the campaign has, or its only one) or all runs with the current
/// law (`model="current-law"`), as `mrbp sample` does with the same
/// options: the same seed gives the same chains. The GIL is released while
/// it samples; Ctrl-C raises KeyboardInterrupt, after saving the sampler's
/// state to `checkpoint` if given (every 100 steps too), which `resume`
/// continues exactly. `progress` is a callable told of every step.
#[pyfunction]
#[pyo3(signature = (campaign, current = None, model = None, noise = None, seed = None, steps = None, walkers = None, ensembles = None, substeps = None, config = None, exact_input = false, progress = None, checkpoint = None, resume = false))]
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
    progress: Option<Py<PyAny>>,
    checkpoint: Option<PathBuf>,
    resume: bool,
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
    let resume_from = match (&checkpoint, resume) {
        (None, true) => return Err(PyValueError::new_err("resume: say which checkpoint to continue (checkpoint='the file')")),
        (Some(path), true) if !path.exists() => return Err(PyValueError::new_err(format!("resume: no checkpoint at {}", path.display()))),
        (Some(path), true) => {
            mrbp::pipeline::check_resumable(path, &settings).map_err(raise)?;
            Some(path.clone())
        }
        _ => None,
    };
    let made = py
        .detach(move || {
            let start = mrbp::calibrate::start(&group, &settings, &mut |_| {})?;
            let mut observer = Python_ { progress, checkpoint: checkpoint.clone(), checked: None, accepted: 0 };
            // the state every 100 steps, beside the one saved at Ctrl-C
            let mut checkpointer = checkpoint.as_ref().map(|path| Checkpointer { path: path.clone(), every: mrbp::pipeline::CHECKPOINT_EVERY, stop: || false });
            let mut observers: Vec<&mut dyn Observer> = vec![&mut observer];
            if let Some(c) = checkpointer.as_mut() {
                observers.push(c);
            }
            let made = mrbp::calibrate::sample(&group, start, resume_from.as_ref(), &mut observers)?;
            if let Some(path) = &checkpoint {
                // the chains are whole in the calibration returned: the checkpoint has done its job
                let _ = std::fs::remove_file(path);
            }
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
