//! What a sampler is: ensembles, walkers, moves and seed.

use serde::{Deserialize, Serialize};

use super::moves::Move;
use crate::error::{Error, Result};

/// What the sampler is: ensembles, walkers, moves and seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplerSettings {
    /// Walkers per ensemble (even, at least 2 × dim).
    pub walkers: usize,
    /// Independent ensembles (R̂ compares them).
    pub ensembles: usize,
    /// Moves with their weights; one is picked per ensemble and step.
    pub moves: Vec<(Move, f64)>,
    pub seed: u64,
}

impl Default for SamplerSettings {
    fn default() -> Self {
        SamplerSettings { walkers: 32, ensembles: 4, moves: vec![(Move::default(), 1.0)], seed: 1 }
    }
}

impl SamplerSettings {
    /// Checks the settings against a target of `dim` coordinates.
    pub fn check(&self, dim: usize) -> Result<()> {
        if !self.walkers.is_multiple_of(2) || self.walkers < 2 * dim.max(2) {
            return Err(Error::Usage(format!(
                "--walkers: walkers per ensemble must be even and at least 2 × dimension = {}; got {}",
                2 * dim.max(2),
                self.walkers
            )));
        }
        if self.ensembles == 0 {
            return Err(Error::Usage("--ensembles: at least one ensemble is needed".into()));
        }
        if self.moves.is_empty() || self.moves.iter().any(|(_, w)| !(*w > 0.0) || !w.is_finite()) {
            return Err(Error::Usage("moves need positive, finite weights".into()));
        }
        for (m, _) in &self.moves {
            m.check().map_err(Error::Usage)?;
            if m.min_complement() > self.walkers / 2 {
                return Err(Error::Usage(format!("{m:?} needs more walkers")));
            }
        }
        Ok(())
    }
}
