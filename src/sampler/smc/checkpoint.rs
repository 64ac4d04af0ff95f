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
use crate::error::{Error, Result};
use crate::sampler::checkpoint::{read_framed, write_framed};

/// 2: as the sampler's format 2, a law's parameters walk above their floors.
const FORMAT: &str = "mrbp-smc-checkpoint-2";

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

/// Saves the populations finished so far at `path`, atomically.
pub fn save(path: &Path, key: &Key, populations: &[Population]) -> Result<()> {
    write_framed(path, FORMAT, &(key, populations))
}

/// The populations saved at `path` for a run of `key`; an error where the
/// file is not such a checkpoint or was made from something else.
pub fn load(path: &Path, key: &Key) -> Result<Vec<Population>> {
    let (saved, populations): (Key, Vec<Population>) =
        read_framed(path, FORMAT, "sequential Monte Carlo checkpoint")?;
    if saved != *key {
        return Err(Error::input(
            path,
            "--resume: these populations were made from another start or other settings (records, priors, seed, particles or moves): use the same options, or start afresh with --force",
        ));
    }
    if populations.len() > key.settings.populations {
        return Err(Error::input(
            path,
            format!(
                "{} populations saved, the run has {}",
                populations.len(),
                key.settings.populations
            ),
        ));
    }
    Ok(populations)
}
