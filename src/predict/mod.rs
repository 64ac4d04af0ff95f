//! Posterior propagation: posterior draws through the integrator along
//! each run — credible and predictive bands, coverage and log predictive
//! density ([`bands`]) — and where the calibrated law misses the records
//! ([`adequacy`]): together, what a prediction makes.

pub mod adequacy;
pub mod bands;

use serde::{Deserialize, Serialize};

use crate::data::{Run, RunData};
use crate::error::Result;
use crate::posterior::Draw;
pub use adequacy::{AdequacyRow, Excitation};
pub use bands::{
    bands, bands_of, model_paths, Bands, Coverage, CoverageRow, PredictSettings, RunBands, FAR,
    FAR_DRAWS_WARN, MODEL_PROBS, PREDICTIVE_PROBS,
};

/// How posterior draws are propagated into bands (`mrbp predict`, `run`,
/// `report`).
#[derive(clap::Args, Clone, Copy, Debug)]
pub struct PredictOptions {
    /// Posterior draws to propagate (after burn-in, thinned by τ, spread evenly)
    #[arg(long, default_value_t = PredictOptions::default().draws)]
    pub draws: usize,
    /// Noise replicates per draw in the predictive band
    #[arg(long, default_value_t = PredictOptions::default().replicates)]
    pub replicates: usize,
    /// Seed of the noise replicates
    #[arg(id = "predict_seed", long = "predict-seed", default_value_t = PredictOptions::default().seed)]
    pub seed: u64,
}

impl PredictOptions {
    /// Refuses no draws or no replicates.
    pub fn check(&self) -> Result<()> {
        if self.draws == 0 || self.replicates == 0 {
            return Err(crate::error::Error::Usage(
                "--draws and --replicates must be at least 1".into(),
            ));
        }
        Ok(())
    }
}

impl Default for PredictOptions {
    fn default() -> Self {
        PredictOptions { draws: 400, replicates: 10, seed: 1 }
    }
}

/// How a prediction was made (`prediction.toml`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PredictionRecord {
    pub mrbp_version: String,
    pub command: String,
    pub draws: usize,
    pub burn_in: usize,
    pub thin: usize,
    pub noise_replicates: usize,
    pub seed: u64,
    pub substeps: u32,
    pub seconds: f64,
    /// The calibration the bands came from (its `calibration_id`).
    #[serde(default)]
    pub calibration_id: String,
    pub coverage: Vec<CoverageRow>,
}

/// What a prediction of a calibration made: every run's bands, coverage
/// and adequacy, and how they were made.
#[derive(Clone, Debug)]
pub struct Prediction {
    pub bands: Vec<RunBands>,
    pub coverage: Vec<CoverageRow>,
    pub adequacy: Vec<AdequacyRow>,
    pub record: PredictionRecord,
}

/// A run's bands and coverage from posterior draws: the whole of what a
/// prediction says about one run.
pub struct RunPrediction {
    pub bands: RunBands,
    pub coverage: CoverageRow,
}

/// Integrates `draws` along `run` (driven as `data`) and forms its bands
/// and coverage; `run_index` keys the noise stream.
pub fn predict_run(
    run: &Run,
    data: &RunData,
    run_index: usize,
    draws: &[Draw],
    settings: &PredictSettings,
    calibrated: bool,
    tick: &(dyn Fn() + Sync),
) -> Result<RunPrediction> {
    let b = bands(data, run_index, draws, settings, tick)?;
    let coverage = CoverageRow::of(run, &b, &b.coverage(&data.tau), calibrated);
    Ok(RunPrediction { bands: RunBands::of(run, data, b), coverage })
}
