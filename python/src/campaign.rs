//! `Campaign`: runs of one damper, from a manifest or from arrays.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::PyReadonlyArray1;
use pyo3::prelude::*;

use mrbp::data::{Geometry, Manifest, Record, RunSpec};

use crate::{raise, values};

/// A test campaign: runs of one damper, each a record and a coil current.
#[pyclass(frozen, module = "mrbp._mrbp")]
pub(crate) struct Campaign {
    pub(crate) inner: Arc<mrbp::data::Campaign>,
}

#[pymethods]
impl Campaign {
    /// Reads a campaign manifest and its data files, as `mrbp check` does.
    #[staticmethod]
    fn load(manifest: PathBuf) -> PyResult<Campaign> {
        mrbp::data::Campaign::load(&manifest)
            .map(|c| Campaign { inner: Arc::new(c) })
            .map_err(raise)
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
        runs: Vec<(
            String,
            f64,
            PyReadonlyArray1<'_, f64>,
            PyReadonlyArray1<'_, f64>,
            PyReadonlyArray1<'_, f64>,
            Option<PyReadonlyArray1<'_, f64>>,
        )>,
    ) -> PyResult<Campaign> {
        let mut specs = Vec::new();
        let mut records = Vec::new();
        for (id, current_a, time, displacement, force, current) in runs {
            let current = current.map(|c| values(&c)).transpose()?;
            records.push(Record {
                time: values(&time)?,
                displacement: values(&displacement)?,
                force: values(&force)?,
                current,
            });
            specs.push(RunSpec::new(id.clone(), PathBuf::from(format!("{id}.csv")), current_a));
        }
        let manifest = Manifest {
            name,
            geometry: Geometry { area_m2, gap_m },
            columns: Default::default(),
            limits: Default::default(),
            runs: specs,
        };
        mrbp::data::Campaign::from_records(manifest, records)
            .map(|c| Campaign { inner: Arc::new(c) })
            .map_err(raise)
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
        format!(
            "Campaign({:?}: {} runs at {:?} A)",
            self.inner.name,
            self.inner.runs.len(),
            self.inner.currents()
        )
    }
}
