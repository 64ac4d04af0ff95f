//! Sequential Monte Carlo's finished populations on disk, so that an
//! interrupted run goes on from the first population it had not finished.
//! A population is a function of the target, the reference, the settings
//! and its index alone (its random streams are keyed by them), so the
//! populations read back are those a run without the interruption makes,
//! bit for bit; the file says what they were made from ([`Key`]) and is
//! refused for anything else. Its file lies beside the sampler's
//! checkpoint ([`crate::sampler::checkpoint::smc_beside`]).

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{Population, Reference, SmcSettings};
use crate::atomic;
use crate::error::{Error, Result};

const FORMAT: &str = "mrbp-smc-checkpoint-1";

/// What the populations were made from: the target's dimension, the
/// reference (its mean, scale factor and degrees of freedom: the start's
/// mode and curvature, which the records and settings fix) and the
/// settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Key {
    pub dim: usize,
    pub reference_mean: Vec<f64>,
    pub reference_factor: Vec<f64>,
    pub reference_df: Option<f64>,
    pub settings: SmcSettings,
}

impl Key {
    pub fn of(dim: usize, reference: &Reference, settings: &SmcSettings) -> Key {
        Key {
            dim,
            reference_mean: reference.dist.mean.as_slice().to_vec(),
            reference_factor: reference.dist.factor().as_slice().to_vec(),
            reference_df: reference.df,
            settings: settings.clone(),
        }
    }
}

#[derive(Serialize, Deserialize)]
struct Checkpoint {
    format: String,
    key: Key,
    populations: Vec<Population>,
}

/// Saves the populations finished so far at `path`, atomically.
pub fn save(path: &Path, key: &Key, populations: &[Population]) -> Result<()> {
    let cp =
        Checkpoint { format: FORMAT.into(), key: key.clone(), populations: populations.to_vec() };
    let bytes = postcard::to_allocvec(&cp).map_err(|e| Error::output(path, e))?;
    atomic::write(path, &bytes)
}

/// The populations saved at `path` for a run of `key`; an error where the
/// file is not such a checkpoint or was made from something else.
pub fn load(path: &Path, key: &Key) -> Result<Vec<Population>> {
    let bytes = std::fs::read(path)
        .map_err(|e| Error::input(path, format!("cannot read checkpoint: {e}")))?;
    let cp: Checkpoint = postcard::from_bytes(&bytes).map_err(|_| {
        Error::input(
            path,
            "not a sequential Monte Carlo checkpoint (damaged, or another file): remove it to start afresh",
        )
    })?;
    if cp.format != FORMAT {
        return Err(Error::input(
            path,
            format!("checkpoint format '{}', this mrbp reads '{FORMAT}'", cp.format),
        ));
    }
    if cp.key != *key {
        return Err(Error::input(
            path,
            "--resume: these populations were made from another start or other settings (records, priors, seed, particles or moves): use the same options, or start afresh with --force",
        ));
    }
    if cp.populations.len() > key.settings.populations {
        return Err(Error::input(
            path,
            format!(
                "{} populations saved, the run has {}",
                cp.populations.len(),
                key.settings.populations
            ),
        ));
    }
    Ok(cp.populations)
}
