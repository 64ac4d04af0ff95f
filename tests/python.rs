//! The Python package (python/): its pytest suite against this build's
//! command line, and its example notebook run end to end. CI installs the package (`pip install ./python`) into
//! MRBP_PYTHON's environment and sets MRBP_PYTHON_PACKAGE_CHECK=1, which
//! makes a missing package a failure; elsewhere the suite runs where that
//! Python can import `mrbp` and `pytest`, and is skipped with a line if not.

use std::path::Path;
use std::process::Command;

#[test]
fn python_package_agrees_with_the_command_line() {
    let must = std::env::var("MRBP_PYTHON_PACKAGE_CHECK").is_ok_and(|v| v == "1");
    let python = std::env::var("MRBP_PYTHON").unwrap_or_else(|_| "python3".into());
    let ready = Command::new(&python).args(["-c", "import mrbp, pytest, pandas, pyarrow"]).output().is_ok_and(|o| o.status.success());
    if !ready {
        assert!(!must, "MRBP_PYTHON_PACKAGE_CHECK=1 but {python} cannot import mrbp (pip install ./python) or pytest");
        eprintln!("python package tests skipped: {python} cannot import mrbp and pytest (pip install ./python pytest)");
        return;
    }
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("python").join("tests");
    let o = Command::new(&python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .arg(&tests)
        .env("MRBP_BIN", env!("CARGO_BIN_EXE_mrbp"))
        .output()
        .expect("run pytest");
    let said = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "pytest python/tests failed:\n{said}");
    eprintln!("{said}");
}

/// The example notebook (examples/python/calibrate.ipynb) executed end to
/// end in a Jupyter kernel: calibrate the bundled 1 A records, ArviZ's
/// summary and trace, the bands, a simulated excitation; its last cell
/// asserts convergence and coverage. Mandatory where the package check is.
#[test]
fn example_notebook_runs_end_to_end() {
    let must = std::env::var("MRBP_PYTHON_PACKAGE_CHECK").is_ok_and(|v| v == "1");
    let python = std::env::var("MRBP_PYTHON").unwrap_or_else(|_| "python3".into());
    let ready = Command::new(&python).args(["-c", "import mrbp, nbclient, nbformat, ipykernel, arviz, matplotlib"]).output().is_ok_and(|o| o.status.success());
    if !ready {
        assert!(!must, "MRBP_PYTHON_PACKAGE_CHECK=1 but {python} cannot import mrbp, nbclient, nbformat, ipykernel, arviz and matplotlib (scripts/requirements-checks.txt)");
        eprintln!("example notebook skipped: {python} cannot import mrbp, nbclient, ipykernel, arviz and matplotlib");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let o = Command::new(&python)
        .arg(root.join("scripts").join("run_notebook.py"))
        .arg(root.join("examples").join("python").join("calibrate.ipynb"))
        .output()
        .expect("run the notebook");
    let said = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "examples/python/calibrate.ipynb failed:\n{said}");
    eprintln!("{said}");
}
