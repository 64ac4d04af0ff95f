//! The Python package (python/): its pytest suite against this build's
//! command line, and its example notebook run end to end. CI installs the package (`pip install ./python`) into
//! MRBP_PYTHON's environment and sets MRBP_PYTHON_PACKAGE_CHECK=1, which
//! makes a missing package a failure; elsewhere the suite runs where that
//! Python can import `mrbp` and `pytest`, and is skipped with a line if not.

use std::path::Path;
use std::process::Command;

use crate::common::{python_with, said};

const REQUIRED: &str = "MRBP_PYTHON_PACKAGE_CHECK";

/// Runs `command` to success, showing what it said.
fn succeeds(command: &mut Command, what: &str) {
    let o = command.output().unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(o.status.success(), "{what} failed:\n{}", said(&o));
    eprintln!("{}", said(&o));
}

#[test]
#[ignore = "slow tier: the Python package's pytest suite"]
fn python_package_agrees_with_the_command_line() {
    let Some(python) =
        python_with("mrbp, pytest, pandas, pyarrow", "python package tests", REQUIRED)
    else {
        return;
    };
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("python").join("tests");
    let mut pytest = Command::new(&python);
    pytest
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .arg(&tests)
        .env("MRBP_BIN", env!("CARGO_BIN_EXE_mrbp"));
    succeeds(&mut pytest, "pytest python/tests");
}

/// The example notebook (examples/python/calibrate.ipynb) executed end to
/// end in a Jupyter kernel: calibrate the bundled 1 A records, ArviZ's
/// summary and trace, the bands, a simulated excitation; its last cell
/// asserts convergence and coverage. Mandatory where the package check is.
#[test]
#[ignore = "slow tier: the example notebook in a Jupyter kernel"]
fn example_notebook_runs_end_to_end() {
    let Some(python) = python_with(
        "mrbp, nbclient, nbformat, ipykernel, arviz, matplotlib",
        "the example notebook",
        REQUIRED,
    ) else {
        return;
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut notebook = Command::new(&python);
    notebook
        .arg(root.join("scripts").join("run_notebook.py"))
        .arg(root.join("examples").join("python").join("calibrate.ipynb"));
    succeeds(&mut notebook, "examples/python/calibrate.ipynb");
}
