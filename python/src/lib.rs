//! `mrbp._mrbp`: the Rust library seen from Python. The package `mrbp`
//! (python/mrbp/__init__.py) wraps these in pandas frames; nothing here
//! computes anything the command line does not compute the same way.
//!
//! One home each: [`campaign`] (records in), [`calibration`] (a result and
//! what is made from it), [`calibrate`] (sampling, its progress and Ctrl-C).

mod calibrate;
mod calibration;
mod campaign;

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use mrbp::error::Error;

/// A Python exception for an mrbp error: bad input is a ValueError (its
/// message names the run, row and column), an interruption a
/// KeyboardInterrupt, a file that cannot be written an OSError.
pub(crate) fn raise(e: Error) -> PyErr {
    let text = e.to_string();
    match e {
        Error::Input { .. } | Error::Usage(_) => PyValueError::new_err(text),
        Error::Interrupted(_) => PyKeyboardInterrupt::new_err(text),
        Error::Output { .. } => PyOSError::new_err(text),
        Error::Compute(_) | Error::Busy(_) => PyRuntimeError::new_err(text),
    }
}

/// A contiguous float64 NumPy array's values, read in place (one copy into
/// the record Rust owns).
pub(crate) fn values(a: &PyReadonlyArray1<'_, f64>) -> PyResult<Vec<f64>> {
    a.as_slice().map(<[f64]>::to_vec).map_err(|_| {
        PyValueError::new_err("an array must be contiguous float64 (numpy.ascontiguousarray)")
    })
}

/// Named NumPy arrays, handed over without a copy.
pub(crate) fn arrays<'py, N: Into<String>>(
    py: Python<'py>,
    columns: Vec<(N, Vec<f64>)>,
) -> Vec<(String, Bound<'py, PyArray1<f64>>)> {
    columns.into_iter().map(|(name, v)| (name.into(), PyArray1::from_vec(py, v))).collect()
}

/// Named NumPy columns, in order (a frame's).
pub(crate) type Arrays<'py> = Vec<(String, Bound<'py, PyArray1<f64>>)>;

/// The columns of `chains.parquet`: integer bookkeeping, the coordinates
/// with log_prob, and `accepted`.
pub(crate) type ChainColumns<'py> =
    (Vec<(&'static str, Bound<'py, PyArray1<i64>>)>, Arrays<'py>, Bound<'py, PyArray1<bool>>);

/// One array of an InferenceData group: name, dimensions, values, and
/// attributes as JSON.
pub(crate) type DataNode<'py> = (String, Vec<(&'static str, usize)>, Bound<'py, PyAny>, String);

/// Runs `work` on a quiet pipeline whose notes it keeps.
pub(crate) fn noted<T>(
    work: impl FnOnce(&mut mrbp::pipeline::Pipeline<'_>) -> mrbp::Result<T>,
) -> mrbp::Result<(T, Vec<String>)> {
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

/// The version of the mrbp library inside.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _mrbp(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<campaign::Campaign>()?;
    m.add_class::<calibration::Calibration>()?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    Ok(())
}
