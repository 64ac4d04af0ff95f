//! The sampler's state on disk: enough to continue a run exactly where it
//! stopped, so that a resumed run equals an uninterrupted one.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::chains::Chains;
use super::settings::SamplerSettings;
use crate::atomic;
use crate::error::{Error, Result};

const FORMAT: &str = "mrbp-sampler-checkpoint-1";

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    format: String,
    settings: SamplerSettings,
    chains: Chains,
}

/// Saves the settings and chains at `path`, atomically.
pub fn save(path: &Path, settings: &SamplerSettings, chains: &Chains) -> Result<()> {
    let cp = Checkpoint { format: FORMAT.into(), settings: settings.clone(), chains: chains.clone() };
    let bytes = postcard::to_allocvec(&cp).map_err(|e| Error::output(path, e))?;
    atomic::write(path, &bytes)
}

/// Reads a checkpoint written by [`save`] for a target of `dim` coordinates.
pub fn load(path: &Path, dim: usize) -> Result<(SamplerSettings, Chains)> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read checkpoint: {e}")))?;
    let cp: Checkpoint = postcard::from_bytes(&bytes).map_err(|e| Error::input(path, format!("not a sampler checkpoint: {e}")))?;
    if cp.format != FORMAT || cp.chains.dim != dim {
        return Err(Error::input(path, "checkpoint of another format or another target"));
    }
    Ok((cp.settings, cp.chains))
}
