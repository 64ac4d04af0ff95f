//! The sampler's state on disk: enough to continue a run exactly where it
//! stopped, so that a resumed run equals an uninterrupted one.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::chains::Chains;
use super::settings::SamplerSettings;
use crate::atomic;
use crate::error::{Error, Result};

const FORMAT: &str = "mrbp-sampler-checkpoint-1";

/// The file of sequential Monte Carlo's finished populations
/// ([`super::smc::checkpoint`]), beside the sampler's in a calibration
/// folder.
pub const SMC_FILE: &str = "smc.checkpoint";

/// The populations' checkpoint beside the sampler's at `sampler_checkpoint`.
pub fn smc_beside(sampler_checkpoint: &Path) -> PathBuf {
    sampler_checkpoint.with_file_name(SMC_FILE)
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    format: String,
    settings: SamplerSettings,
    chains: Chains,
}

/// Saves the settings and chains at `path`, atomically.
pub fn save(path: &Path, settings: &SamplerSettings, chains: &Chains) -> Result<()> {
    let cp =
        Checkpoint { format: FORMAT.into(), settings: settings.clone(), chains: chains.clone() };
    let bytes = postcard::to_allocvec(&cp).map_err(|e| Error::output(path, e))?;
    atomic::write(path, &bytes)
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
    let bytes = std::fs::read(path)
        .map_err(|e| Error::input(path, format!("cannot read checkpoint: {e}")))?;
    let cp: Checkpoint = postcard::from_bytes(&bytes).map_err(|_| {
        Error::input(
            path,
            "not a sampler checkpoint (damaged, or another file): remove it to start afresh",
        )
    })?;
    if cp.format != FORMAT {
        return Err(Error::input(
            path,
            format!("checkpoint format '{}', this mrbp reads '{FORMAT}'", cp.format),
        ));
    }
    Ok((cp.settings, cp.chains))
}
