//! Terms a real damper adds to the B-P fluid's force, as options with
//! priors: a force offset per run (the load cell's zero, a gas preload) and
//! the stiffness of the gas accumulator, a force k·x proportional to the
//! piston's displacement from the record's start. In shear units they add
//! (F₀ + k x)/A to the model stress, x = γ h.

use serde::{Deserialize, Serialize};

/// Which terms the model has, and their priors (zero-mean normals).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelTerms {
    /// A force offset F₀ per run (N), `force_offset_n_<run>`.
    pub force_offset: bool,
    /// Prior sd of each force offset (N).
    pub force_offset_sd_n: f64,
    /// A gas-spring stiffness k shared by every run (N/m), `gas_spring_n_per_m`.
    pub gas_spring: bool,
    /// Prior sd of the stiffness (N/m).
    pub gas_spring_sd_n_per_m: f64,
}

impl Default for ModelTerms {
    fn default() -> Self {
        ModelTerms {
            force_offset: false,
            force_offset_sd_n: 100.0,
            gas_spring: false,
            gas_spring_sd_n_per_m: 1.0e4,
        }
    }
}

impl ModelTerms {
    pub fn check(&self) -> Result<(), String> {
        if !(self.force_offset_sd_n > 0.0 && self.gas_spring_sd_n_per_m > 0.0) {
            return Err("the priors of the model terms need positive sds".into());
        }
        Ok(())
    }

    /// What a run's force adds at a sample of strain `gamma`, as stress (Pa).
    #[inline(always)]
    pub fn stress(offset_n: f64, spring_n_per_m: f64, gamma: f64, area_m2: f64, gap_m: f64) -> f64 {
        (offset_n + spring_n_per_m * gamma * gap_m) / area_m2
    }
}
