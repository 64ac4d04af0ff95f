//! The sampler's state on disk: enough to continue a run exactly where it
//! stopped, so that a resumed run equals an uninterrupted one.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use super::chains::Chains;
use super::settings::SamplerSettings;
use crate::atomic;
use crate::error::{Error, Result};

/// 2: the parameters of a law other than B-P are walked above their
/// floors (`posterior::Layout`), so the walkers of format 1 sit elsewhere.
const FORMAT: &str = "mrbp-sampler-checkpoint-2";

/// The file of sequential Monte Carlo's finished populations
/// ([`super::smc::checkpoint`]), beside the sampler's in a calibration
/// folder.
pub const SMC_FILE: &str = "smc.checkpoint";

/// The populations' checkpoint beside the sampler's at `sampler_checkpoint`.
pub fn smc_beside(sampler_checkpoint: &Path) -> PathBuf {
    sampler_checkpoint.with_file_name(SMC_FILE)
}

/// A checkpoint file as written: the name of its format, then its body,
/// in postcard (the fields one after another, so the sampler's files of
/// before this frame read back as they were).
#[derive(Serialize)]
struct Written<'a, T> {
    format: &'a str,
    body: &'a T,
}

/// A checkpoint file as read.
#[derive(Deserialize)]
struct Read<T> {
    format: String,
    body: T,
}

/// Writes `body` at `path` after the name of its `format`, atomically.
pub(super) fn write_framed<T: Serialize>(path: &Path, format: &str, body: &T) -> Result<()> {
    let bytes =
        postcard::to_allocvec(&Written { format, body }).map_err(|e| Error::output(path, e))?;
    atomic::write(path, &bytes)
}

/// The body of the checkpoint at `path` written by [`write_framed`] in
/// `format`; an error naming `what` where the file is not one, or of
/// another format.
pub(super) fn read_framed<T: DeserializeOwned>(path: &Path, format: &str, what: &str) -> Result<T> {
    let bytes = std::fs::read(path)
        .map_err(|e| Error::input(path, format!("cannot read checkpoint: {e}")))?;
    let read: Read<T> = postcard::from_bytes(&bytes).map_err(|_| {
        Error::input(
            path,
            format!("not a {what} (damaged, or another file): remove it to start afresh"),
        )
    })?;
    if read.format != format {
        return Err(Error::input(
            path,
            format!("checkpoint format '{}', this mrbp reads '{format}'", read.format),
        ));
    }
    Ok(read.body)
}

/// Saves the settings and chains at `path`, atomically.
pub fn save(path: &Path, settings: &SamplerSettings, chains: &Chains) -> Result<()> {
    write_framed(path, FORMAT, &(settings, chains))
}

/// Reads a checkpoint written by [`save`] for a target of `dim` coordinates.
pub fn load(path: &Path, dim: usize) -> Result<(SamplerSettings, Chains)> {
    let (settings, chains) = read(path)?;
    if chains.dim != dim {
        return Err(Error::input(
            path,
            format!(
                "checkpoint of a target with {} coordinates, not {dim}: another calibration's?",
                chains.dim
            ),
        ));
    }
    Ok((settings, chains))
}

/// Reads a checkpoint written by [`save`], whatever its target: to check
/// it against the options before any work.
pub fn read(path: &Path) -> Result<(SamplerSettings, Chains)> {
    read_framed(path, FORMAT, "sampler checkpoint")
}
