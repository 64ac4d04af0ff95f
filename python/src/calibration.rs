//! `Calibration`: a calibration made here or read from a folder, and what
//! is made from it (summary, draws, bands, InferenceData, a simulation),
//! each by the library's own code.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use mrbp::data::Record;
use mrbp::identify::CurrentIdentification;
use mrbp::store::inference::Values;

use crate::{arrays, noted, raise, values, Arrays, ChainColumns, DataNode};

/// A calibration: its settings, record, summary and posterior sample.
#[pyclass(module = "mrbp._mrbp")]
pub(crate) struct Calibration {
    pub(crate) inner: mrbp::calibrate::Calibration,
    /// How it was made in memory (for `save`); none when read from a folder.
    pub(crate) made: Option<(Arc<mrbp::data::Campaign>, Option<CurrentIdentification>)>,
}

#[pymethods]
impl Calibration {
    /// Reads the calibration folder of `mrbp sample` or `mrbp run`.
    #[staticmethod]
    fn load(folder: PathBuf) -> PyResult<Calibration> {
        mrbp::store::folder::read(&folder)
            .map(|inner| Calibration { inner, made: None })
            .map_err(raise)
    }

    /// The summary's columns, as `summary.parquet` holds them.
    fn summary_columns<'py>(&self, py: Python<'py>) -> Arrays<'py> {
        arrays(py, mrbp::store::summary::statistics(&self.inner.summary))
    }

    /// The summary's parameter names, in its row order.
    fn summary_parameters(&self) -> Vec<String> {
        self.inner.summary.iter().map(|r| r.parameter.clone()).collect()
    }

    /// A law's B-P parameters against the coil current, as
    /// `against_current.parquet` holds them: parameter, kind, and the
    /// current and statistics columns; None for a calibration at one current.
    fn against_current<'py>(
        &self,
        py: Python<'py>,
    ) -> Option<(Vec<String>, Vec<String>, Arrays<'py>)> {
        let cal = &self.inner;
        if !cal.is_current_law() {
            return None;
        }
        let rows = mrbp::compare::against_current(
            &cal.sample,
            &cal.draw_positions(mrbp::store::folder::CURRENT_DRAWS),
            &cal.record.currents,
        );
        let f = |g: fn(&mrbp::compare::CurrentRow) -> f64| rows.iter().map(g).collect::<Vec<f64>>();
        let columns = vec![
            ("current_a", f(|r| r.current_a)),
            ("mean", f(|r| r.mean)),
            ("sd", f(|r| r.sd)),
            ("q05", f(|r| r.q05)),
            ("q50", f(|r| r.q50)),
            ("q95", f(|r| r.q95)),
        ];
        Some((
            rows.iter().map(|r| r.parameter.clone()).collect(),
            rows.iter().map(|r| r.kind.name().to_string()).collect(),
            arrays(py, columns),
        ))
    }

    /// Every walker's every step, as `chains.parquet` holds them: the
    /// bookkeeping columns (ensemble, chain, draw, accepted) and the
    /// coordinates with log_prob.
    fn chain_columns<'py>(&self, py: Python<'py>) -> ChainColumns<'py> {
        let c = mrbp::store::chains::columns(&self.inner.sample);
        let bookkeeping =
            c.bookkeeping.into_iter().map(|(n, v)| (n, PyArray1::from_vec(py, v))).collect();
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

    /// The log evidence, its standard error, what it is of and whether it
    /// is a pseudo-evidence, where sequential Monte Carlo sampled it.
    #[getter]
    fn log_evidence(&self) -> Option<(f64, f64, String, bool)> {
        self.inner
            .record
            .smc
            .as_ref()
            .map(|e| (e.log_evidence, e.se(), e.evidence_of.clone(), e.pseudo_evidence))
    }

    /// The log evidence, its standard error, what it is of, whether it is
    /// a pseudo-evidence and how it was estimated: sequential Monte
    /// Carlo's where it sampled, else by bridge sampling from the chains.
    fn evidence(&self, py: Python<'_>) -> PyResult<(f64, f64, String, bool, String)> {
        let e = match mrbp::calibrate::evidence::by_smc(&self.inner) {
            Some(recorded) => recorded,
            None => {
                let cal = self.inner.clone();
                let campaign = self.campaign()?;
                py.detach(move || mrbp::calibrate::evidence::estimate(&cal, &campaign))
                    .map_err(raise)?
            }
        };
        Ok((e.log_evidence, e.se, e.of, e.pseudo, e.by.to_string()))
    }

    /// The largest R̂ of the summary.
    #[getter]
    fn max_r_hat(&self) -> f64 {
        self.inner.max_rhat()
    }

    /// Warnings of the sampler and of the model's fit.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner
            .record
            .warnings
            .iter()
            .chain(&self.inner.record.model_warnings)
            .cloned()
            .collect()
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
            return Err(PyValueError::new_err(format!(
                "this calibration was read from {}: it is saved there already",
                self.inner.dir.display()
            )));
        };
        let cal = self.inner.clone();
        let (campaign, identification) = (campaign.clone(), identification.clone());
        let saved = py
            .detach(move || {
                let mut quiet = |_: mrbp::pipeline::Event<'_>| {};
                mrbp::pipeline::Pipeline::new(&mut quiet, false).save(
                    &campaign,
                    &folder,
                    cal,
                    identification.as_ref(),
                    force,
                )
            })
            .map_err(raise)?;
        self.inner = saved;
        Ok(())
    }

    /// The force of the calibrated damper along an excitation of your own
    /// (`mrbp simulate`): columns of `simulation.parquet`, the notes
    /// (extrapolation, draws that failed), and the (step, chain) of the
    /// posterior draws it propagated (none for new tests of the between-run
    /// layer, `new_test`: `simulate --new-test`).
    #[pyo3(signature = (time, displacement, current = None, current_column = None, draws = 400, replicates = 10, seed = 1, new_test = false))]
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
        new_test: bool,
    ) -> PyResult<(Arrays<'py>, Vec<String>, Vec<(usize, usize)>)> {
        let cal = self.inner.clone();
        let (time, displacement) = (values(&time)?, values(&displacement)?);
        let n = time.len();
        let record = Record {
            time,
            displacement,
            force: vec![f64::NAN; n],
            current: current_column.map(|c| values(&c)).transpose()?,
        };
        let options = mrbp::pipeline::PredictOptions { draws, replicates, seed };
        let (made, notes) = py
            .detach(move || {
                noted(|p| {
                    p.simulation(
                        &cal,
                        std::path::Path::new("excitation"),
                        record,
                        current,
                        &options,
                        None,
                        new_test,
                    )
                })
            })
            .map_err(raise)?;
        // the posterior draws propagated; new tests are the layer's, not these
        let positions = if new_test { Vec::new() } else { self.inner.draw_positions(draws) };
        Ok((arrays(py, mrbp::store::simulation::columns(&made)), notes, positions))
    }

    /// The bands of the calibration's runs (`mrbp predict`): the bytes of
    /// `bands.parquet`, `coverage.parquet` and `adequacy.parquet` by file
    /// name, the runs that could not be predicted (id, why), and the notes.
    #[pyo3(signature = (draws = 400, replicates = 10, seed = 1))]
    #[allow(clippy::type_complexity)]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        draws: usize,
        replicates: usize,
        seed: u64,
    ) -> PyResult<(Vec<(&'static str, Bound<'py, PyBytes>)>, Vec<(String, String)>, Vec<String>)>
    {
        let cal = self.inner.clone();
        let campaign = self.campaign()?;
        let options = mrbp::pipeline::PredictOptions { draws, replicates, seed };
        let ((tables, failed), notes) = py
            .detach(move || {
                noted(|pipeline| {
                    let (prediction, failed) =
                        pipeline.own_prediction(&cal, &campaign, &options)?;
                    Ok((mrbp::store::prediction::tables(&prediction)?, failed))
                })
            })
            .map_err(raise)?;
        Ok((
            tables.into_iter().map(|(name, b)| (name, PyBytes::new(py, &b))).collect(),
            failed,
            notes,
        ))
    }

    /// The calibration as ArviZ's InferenceData, in memory (what
    /// `inference.zarr` holds): the root's attributes (JSON), and per group
    /// its name, attributes (JSON) and arrays (name, dimensions, NumPy
    /// values or a list of strings, attributes as JSON); with the notes.
    #[pyo3(signature = (seed = 1))]
    #[allow(clippy::type_complexity)]
    fn inference_data<'py>(
        &self,
        py: Python<'py>,
        seed: u64,
    ) -> PyResult<(String, Vec<(&'static str, String, Vec<DataNode<'py>>)>, Vec<String>)> {
        let cal = self.inner.clone();
        let campaign = self.campaign()?;
        let (data, notes) =
            py.detach(move || noted(|p| p.inference_data(&cal, &campaign, seed))).map_err(raise)?;
        let json = |m: &serde_json::Map<String, serde_json::Value>| {
            serde_json::Value::Object(m.clone()).to_string()
        };
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
        let label = if self.inner.dir.as_os_str().is_empty() {
            "in memory".to_string()
        } else {
            self.inner.label()
        };
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
