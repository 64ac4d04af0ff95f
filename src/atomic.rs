//! Atomic file writing: every output goes to a temporary file beside its
//! target and is renamed into place, so a crash or an error never leaves a
//! partial file behind. Removals of results go through here too.
//!
//! Fault injection, for the crash tests: with `MRBP_ABORT_AFTER_WRITE=N`
//! the process aborts (as if killed) right after its N-th write or removal,
//! so every window between two of them can be hit on purpose.

use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

use crate::error::{Error, Result};

/// What temporary files and folders of a write start with; one left behind
/// by a killed process is removed when its folder is next written.
pub const TEMPORARY: &str = ".mrbp-";

/// The environment variable of fault injection.
pub const ABORT_AFTER_WRITE: &str = "MRBP_ABORT_AFTER_WRITE";

static WRITES: AtomicUsize = AtomicUsize::new(0);

/// A write or removal has ended: abort here if fault injection says so.
fn written() {
    static AFTER: OnceLock<Option<usize>> = OnceLock::new();
    let after = AFTER
        .get_or_init(|| std::env::var(ABORT_AFTER_WRITE).ok().and_then(|v| v.trim().parse().ok()));
    let n = WRITES.fetch_add(1, Ordering::SeqCst) + 1;
    if *after == Some(n) {
        eprintln!("mrbp: {ABORT_AFTER_WRITE}={n}: aborting");
        std::process::abort();
    }
}

/// Removes the file or folder at `path`, if there is one; whether it did.
fn remove_quietly(path: &Path) -> Result<bool> {
    let removed = match std::fs::symlink_metadata(path) {
        Err(_) => return Ok(false),
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(path),
        Ok(_) => std::fs::remove_file(path),
    };
    removed.map_err(|e| Error::output(path, e))?;
    Ok(true)
}

/// Removes the file or folder at `path`, if there is one (a write, for
/// fault injection).
pub fn remove(path: &Path) -> Result<()> {
    if remove_quietly(path)? {
        written();
    }
    Ok(())
}

/// Puts the folder `built` (a temporary folder beside it) in place of
/// `path`: the old folder is first renamed aside, so a crash leaves either
/// the old one, none, or the new one — never a half-removed one.
pub fn replace_dir(built: &Path, path: &Path) -> Result<()> {
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if path.exists() {
        let aside = tempfile::Builder::new()
            .prefix(TEMPORARY)
            .suffix(".old.tmp")
            .tempdir_in(parent)
            .map_err(|e| Error::output(parent, e))?
            .keep();
        std::fs::rename(path, &aside).map_err(|e| Error::output(path, e))?;
        written();
        std::fs::rename(built, path).map_err(|e| Error::output(path, e))?;
        written();
        std::fs::remove_dir_all(&aside).map_err(|e| Error::output(&aside, e))?;
    } else {
        std::fs::rename(built, path).map_err(|e| Error::output(path, e))?;
        written();
    }
    Ok(())
}

/// Removes what killed writes left in `dir` (their temporary files and
/// folders); only for a folder this process holds ([`crate::lock`]).
pub fn clean_leftovers(dir: &Path) -> Result<()> {
    let Ok(listed) = std::fs::read_dir(dir) else { return Ok(()) };
    for entry in listed.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with(TEMPORARY) && name.ends_with(".tmp") {
            remove_quietly(&entry.path())?;
        }
    }
    Ok(())
}

/// Writes `bytes` to `path` atomically (temporary file + rename).
pub fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    write_with(path, |w| w.write_all(bytes).map_err(|e| Error::output(path, e)))
}

/// Creates `path` atomically from what `fill` writes into it.
pub fn write_with(path: &Path, fill: impl FnOnce(&mut std::fs::File) -> Result<()>) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    let mut builder = tempfile::Builder::new();
    builder.prefix(TEMPORARY).suffix(".tmp");
    #[cfg(unix)]
    {
        // ordinary file permissions, not the private ones of a temporary file
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    let mut tmp = builder.tempfile_in(dir).map_err(|e| Error::output(dir, e))?;
    fill(tmp.as_file_mut())?;
    tmp.as_file_mut().sync_all().map_err(|e| Error::output(path, e))?;
    tmp.persist(path).map_err(|e| Error::output(path, e.error))?;
    written();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_fill_leaves_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("x.txt");
        let r = write_with(&target, |_| Err(Error::Compute("boom".into())));
        assert!(r.is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        write(&target, b"ok").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"ok");
    }
}
