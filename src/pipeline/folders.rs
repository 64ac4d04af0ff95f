//! Output folders: where results may go, and what a new calibration makes
//! stale. Every stage that writes a folder asks [`prepare`] first, so a bad
//! `--out` is one clear line (exit 2) before any work, never a raw OS error
//! after minutes of sampling, and holds the folder ([`crate::lock`]) until
//! the command ends.

use std::path::{Path, PathBuf};

use crate::data::Campaign;
use crate::error::{Error, Result};
use crate::lock::Writing;
use crate::store;

/// A folder made ready by [`prepare`] and held for writing. Released at
/// its end; the folders [`prepare`] created for it are removed again if
/// nothing but the lock file was written into them (a command refused
/// before any work leaves no folder behind).
#[derive(Debug)]
pub struct Held {
    lock: Option<Writing>,
    /// The folders that did not exist before, deepest first.
    created: Vec<PathBuf>,
}

impl Drop for Held {
    fn drop(&mut self) {
        drop(self.lock.take());
        for dir in &self.created {
            let Ok(entries) = std::fs::read_dir(dir) else { continue };
            let names: Vec<_> = entries.flatten().map(|e| e.file_name()).collect();
            if names.iter().all(|n| n == crate::lock::FILE) {
                let _ = std::fs::remove_file(dir.join(crate::lock::FILE));
                let _ = std::fs::remove_dir(dir);
            }
        }
    }
}

/// The folders a command holds, released newest first: a folder made
/// inside one made before (a current's inside `--out`) goes before the
/// folder that holds it, so a command refused before any work removes
/// both, not only the inner one.
#[derive(Debug, Default)]
pub struct HeldAll(pub Vec<Held>);

impl Drop for HeldAll {
    fn drop(&mut self) {
        while let Some(held) = self.0.pop() {
            drop(held);
        }
    }
}

/// The files of a calibration folder derived from its chains: a new
/// calibration removes them, since they would describe the old one.
pub const DERIVED: [&str; 13] = [
    store::prediction::BANDS,
    store::inference::FILE,
    store::prediction::COVERAGE,
    store::prediction::ADEQUACY,
    store::prediction::RECORD,
    store::coverage::LOO,
    store::coverage::LOO_BANDS,
    crate::report::html::REPORT,
    store::consistency::FILE,
    store::between_runs::FILE,
    store::between_runs::LOO,
    store::between_runs::TYPICAL,
    RUNS,
];

/// The sub-folder of the run-alone calibrations (`--per-run`).
pub const RUNS: &str = store::consistency::RUNS;

/// The sub-folder of the records of a calibration made from records in
/// memory (the Python package's frames): a manifest and one CSV per run.
pub const RECORDS: &str = "records";

/// The report's figures (SVG and PNG) start so; the identification's
/// (`fig1…fig5`), which the calibration itself writes, do not.
const FIGURES: [&str; 8] = [
    "bands_", "adequacy_", "residuals", "corner", "marginals", "traces", "diagnostics",
    "consistency",
];

/// The results of `mrbp sample` in a calibration folder.
pub const CALIBRATION: [&str; 5] = [
    store::folder::CHAINS,
    store::folder::SUMMARY,
    store::folder::RECORD,
    store::folder::CONFIG,
    store::identification::FILE,
];

/// The results of `mrbp identify`.
pub const IDENTIFICATION: [&str; 1] = [store::identification::FILE];

/// Makes `out` (named by `option` in messages) ready for results: refuses a
/// path that is a file or lies under one, a folder that cannot be written, a
/// campaign's own folder (`inputs`), a folder another process writes, and —
/// unless `force` — a folder that already holds any of `results`, listing
/// them. Holds the folder while the returned value lives, and removes what
/// killed writes left there.
pub fn prepare(
    out: &Path,
    option: &str,
    inputs: &[&Campaign],
    results: &[&str],
    force: bool,
) -> Result<Held> {
    let shown = out.display();
    if out.is_file() {
        return Err(Error::Usage(format!("{option} {shown}: this is a file, not a folder")));
    }
    let canonical = |p: &Path| std::fs::canonicalize(p).ok();
    if let Some(here) = canonical(out) {
        for c in inputs {
            let dir = c
                .manifest_path
                .parent()
                .filter(|d| !d.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            if canonical(dir).as_ref() == Some(&here) {
                return Err(Error::Usage(format!(
                    "{option} {shown}: this is the folder of the campaign {} itself; results go to a folder of their own",
                    c.manifest_path.display()
                )));
            }
        }
    }
    let created: Vec<PathBuf> = out
        .ancestors()
        .take_while(|d| !d.as_os_str().is_empty() && !d.exists())
        .map(Path::to_path_buf)
        .collect();
    std::fs::create_dir_all(out).map_err(|e| {
        Error::Usage(format!("{option} {shown}: cannot create this folder ({})", reason(&e)))
    })?;
    // from here on, a refusal removes what this call created
    let mut held = Held { lock: None, created };
    tempfile::NamedTempFile::new_in(out).map_err(|e| {
        Error::Usage(format!("{option} {shown}: cannot write in this folder ({})", reason(&e)))
    })?;
    held.lock = Some(crate::lock::write(out)?);
    crate::atomic::clean_leftovers(out)?;
    let present: Vec<&str> = results.iter().copied().filter(|f| out.join(f).exists()).collect();
    if !present.is_empty() && !force {
        return Err(Error::Usage(format!(
            "{option} {shown} already holds results ({}): pass --force to replace them, or choose another folder",
            present.join(", ")
        )));
    }
    Ok(held)
}

/// Removes the files derived from an earlier calibration in `dir`.
pub fn clear_derived(dir: &Path) -> Result<()> {
    let figure = |name: &str| {
        FIGURES.iter().any(|p| name.starts_with(p))
            && (name.ends_with(".png") || name.ends_with(".svg"))
    };
    let listed = std::fs::read_dir(dir).map_err(|e| Error::output(dir, e))?;
    for entry in listed.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if DERIVED.contains(&name.as_str()) || figure(&name) {
            crate::atomic::remove(&entry.path())?;
        }
    }
    crate::atomic::remove(&dir.join("loo"))
}

fn reason(e: &std::io::Error) -> String {
    match e.kind() {
        std::io::ErrorKind::PermissionDenied => "permission denied".into(),
        std::io::ErrorKind::NotADirectory => "a part of the path is a file".into(),
        std::io::ErrorKind::AlreadyExists => "a part of the path is a file".into(),
        std::io::ErrorKind::ReadOnlyFilesystem => "read-only file system".into(),
        _ => e.to_string(),
    }
}
