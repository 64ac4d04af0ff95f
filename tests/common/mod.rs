//! What several test files share.

use std::path::Path;
use std::process::Command;

/// Runs `scripts/<script>` with `args` under the Python of `MRBP_PYTHON`
/// (default `python3`) when it can import `imports`; panics with the
/// script's output if it fails. Without those packages the check is
/// skipped with a line on stderr, unless the environment variable
/// `required` is 1 (CI sets it), which makes their absence a failure.
pub fn python_check(script: &str, args: &[&Path], imports: &str, required: &str) {
    let must = std::env::var(required).is_ok_and(|v| v == "1");
    let python = std::env::var("MRBP_PYTHON").unwrap_or_else(|_| "python3".into());
    let ready = Command::new(&python)
        .args(["-c", &format!("import {imports}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ready {
        assert!(!must, "{required}=1 but {python} cannot import {imports}");
        eprintln!("{script} skipped: {python} cannot import {imports}");
        return;
    }
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts").join(script);
    let o = Command::new(&python).arg(&path).args(args).output().expect("run python");
    let said =
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "{script} failed:\n{said}");
    eprintln!("{said}");
}
