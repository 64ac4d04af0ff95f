//! One writer per folder. A command that writes a folder holds an exclusive
//! advisory lock on its `.mrbp.lock` until it ends (the operating system
//! releases it if the process dies); a second writer is refused, naming the
//! holder's process id, which the holder writes into the lock file. A reader
//! takes a shared lock while it reads, so it never reads a folder that
//! another process is rewriting. Within one process the locks nest: a
//! command may claim a folder it already holds, and read it.

use std::collections::HashMap;
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, PoisonError};

use crate::error::{Error, Result};

/// The lock file inside a locked folder.
pub const FILE: &str = ".mrbp.lock";

/// Folders this process holds for writing: how many claims, and the open
/// lock file whose closing releases the lock.
static HELD: Mutex<Option<HashMap<PathBuf, (usize, File)>>> = Mutex::new(None);

fn with_held<T>(f: impl FnOnce(&mut HashMap<PathBuf, (usize, File)>) -> T) -> T {
    let mut guard = HELD.lock().unwrap_or_else(PoisonError::into_inner);
    f(guard.get_or_insert_with(HashMap::new))
}

/// The folder's name as the registry knows it (the same folder by any path).
fn key(dir: &Path) -> PathBuf {
    std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf())
}

/// A folder claimed for writing; dropping the last claim releases it.
#[derive(Debug)]
pub struct Writing {
    key: PathBuf,
}

impl Drop for Writing {
    fn drop(&mut self) {
        with_held(|held| {
            if let Some((claims, _)) = held.get_mut(&self.key) {
                *claims -= 1;
                if *claims == 0 {
                    held.remove(&self.key);
                }
            }
        });
    }
}

/// A folder being read under a shared lock (nothing when this process
/// writes it itself, or the folder cannot hold a lock file).
#[derive(Debug)]
pub struct Reading {
    _file: Option<File>,
}

/// Claims the existing folder `dir` for writing, or refuses (exit 2) if
/// another process writes it.
pub fn write(dir: &Path) -> Result<Writing> {
    claim(dir, false)
}

/// As [`write`], but waits for another writer to end instead of refusing
/// (a study's tasks, which several workers may be handed).
pub fn write_waiting(dir: &Path) -> Result<Writing> {
    claim(dir, true)
}

fn claim(dir: &Path, wait: bool) -> Result<Writing> {
    let key = key(dir);
    if with_held(|held| held.get_mut(&key).map(|(claims, _)| *claims += 1)).is_some() {
        return Ok(Writing { key });
    }
    let path = dir.join(FILE);
    let mut file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .read(true)
        .write(true)
        .open(&path)
        .map_err(|e| Error::output(&path, e))?;
    if wait {
        file.lock().map_err(|e| Error::output(&path, e))?;
    } else {
        // a reader holds the folder for moments, a writer for minutes
        let tried = patiently(|| file.try_lock());
        match tried {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                return Err(busy(dir, "wait until it ends, or write to another folder"))
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(Error::output(&path, e)),
        }
    }
    // tell a refused writer who holds the folder
    let pid = std::process::id().to_string();
    let told =
        file.set_len(0).and_then(|_| file.rewind()).and_then(|_| file.write_all(pid.as_bytes()));
    told.map_err(|e| Error::output(&path, e))?;
    with_held(|held| held.insert(key.clone(), (1, file)));
    Ok(Writing { key })
}

/// Reads of `dir` may begin: refuses (exit 2) while another process writes
/// it. Keep the returned value while reading.
pub fn read(dir: &Path) -> Result<Reading> {
    if with_held(|held| held.contains_key(&key(dir))) {
        return Ok(Reading { _file: None });
    }
    let path = dir.join(FILE);
    // a folder never written under a lock, or not ours to write: nothing to wait for
    let Ok(file) = OpenOptions::new().read(true).open(&path) else {
        return Ok(Reading { _file: None });
    };
    let tried = patiently(|| file.try_lock_shared());
    match tried {
        Ok(()) => Ok(Reading { _file: Some(file) }),
        Err(std::fs::TryLockError::WouldBlock) => Err(busy(dir, "read it when that has ended")),
        Err(std::fs::TryLockError::Error(_)) => Ok(Reading { _file: None }),
    }
}

/// Tries to lock for up to a second: a folder read or released at this
/// very moment is not a folder being written.
fn patiently(
    mut attempt: impl FnMut() -> std::result::Result<(), std::fs::TryLockError>,
) -> std::result::Result<(), std::fs::TryLockError> {
    let start = std::time::Instant::now();
    loop {
        match attempt() {
            Err(std::fs::TryLockError::WouldBlock)
                if start.elapsed() < std::time::Duration::from_secs(1) =>
            {
                std::thread::sleep(std::time::Duration::from_millis(25))
            }
            other => return other,
        }
    }
}

/// Whether another process is writing `dir` now (for `mrbp status`): its
/// process id if it wrote one.
pub fn writer(dir: &Path) -> Option<String> {
    match read(dir) {
        Err(Error::Busy(_)) => Some(holder(&dir.join(FILE)).unwrap_or_else(|| "?".into())),
        _ => None,
    }
}

fn holder(path: &Path) -> Option<String> {
    let mut text = String::new();
    File::open(path).ok()?.read_to_string(&mut text).ok()?;
    let pid = text.trim();
    (!pid.is_empty() && pid.chars().all(|c| c.is_ascii_digit())).then(|| pid.to_string())
}

fn busy(dir: &Path, advice: &str) -> Error {
    let who = match holder(&dir.join(FILE)) {
        Some(pid) => format!("another mrbp (process {pid})"),
        None => "another mrbp".to_string(),
    };
    Error::Busy(format!("{} is being written by {who}: {advice}", dir.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn claims_nest_and_release() {
        let dir = tempfile::tempdir().unwrap();
        let a = write(dir.path()).unwrap();
        let b = write(dir.path()).unwrap();
        assert!(read(dir.path()).is_ok(), "this process may read what it writes");
        drop(a);
        assert!(with_held(|h| h.contains_key(&key(dir.path()))));
        drop(b);
        assert!(!with_held(|h| h.contains_key(&key(dir.path()))));
        let pid: String = std::fs::read_to_string(dir.path().join(FILE)).unwrap();
        assert_eq!(pid, std::process::id().to_string());
    }
}
