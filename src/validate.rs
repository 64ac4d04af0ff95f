//! Leave-one-out validation of a calibration: for each run, the posterior
//! from the other runs alone predicts the run it did not see.
//!
//! Each held-out posterior is sampled afresh (no importance reweighting:
//! leaving out a whole record of thousands of samples moves the posterior
//! too far for that), warm-started from the last positions of the full
//! calibration's walkers, which lie close to it, for a fixed number of steps.
//! The held-out run's noise level is not known to that posterior; the
//! prediction uses the root-mean-square σ of the runs it did see.

use crate::calibrate::si_diagnostics;
use crate::data::{Campaign, Run};
use crate::error::{Error, Result};
use crate::posterior::{Posterior, RunData};
use crate::predict::{self, Bands, Draw};
use crate::sampler::{LogDensity, RunControl, Sampler, SamplerSettings};
use crate::stored::StoredCalibration;

/// How each held-out posterior is sampled and propagated.
#[derive(Clone, Copy, Debug)]
pub struct LooSettings {
    /// Steps of each warm-started sampler run.
    pub steps: usize,
    pub draws: usize,
    pub replicates: usize,
    pub seed: u64,
}

impl Default for LooSettings {
    fn default() -> Self {
        LooSettings { steps: 600, draws: 400, replicates: 10, seed: 1 }
    }
}

/// One held-out run: its bands and the sampler's convergence.
pub struct HeldOut {
    pub run: String,
    pub data: RunData,
    pub bands: Bands,
    pub max_rhat: f64,
    pub burn_in: usize,
}

/// Leaves out each run of the calibration in `stored` in turn.
pub fn leave_one_out(stored: &StoredCalibration, campaign: &Campaign, settings: &LooSettings, progress: bool) -> Result<Vec<HeldOut>> {
    if campaign.runs.len() < 2 {
        return Err(Error::Usage("leave-one-out needs a calibration of at least two runs".into()));
    }
    let mut out = Vec::new();
    for (j, left_out) in campaign.runs.iter().enumerate() {
        if progress {
            eprintln!("  leave-one-out: calibrating without {} ({} steps)", left_out.id(), settings.steps);
        }
        out.push(hold_out(stored, campaign, j, left_out, settings, progress)?);
    }
    Ok(out)
}

fn hold_out(stored: &StoredCalibration, campaign: &Campaign, j: usize, left_out: &Run, settings: &LooSettings, progress: bool) -> Result<HeldOut> {
    let kept = campaign.filtered(|r| r.id() != left_out.id());
    let posterior = Posterior::new(&kept, &stored.settings, stored.integrator());
    let names = posterior.names();
    let ch = &stored.chains;
    let last = ch.steps - 1;
    // the full calibration's walkers, in this posterior's coordinates
    let columns: Vec<usize> = names
        .iter()
        .map(|n| ch.index(n).ok_or_else(|| Error::input(stored.dir.join("chains.parquet"), format!("no column '{n}'"))))
        .collect::<Result<_>>()?;
    let init: Vec<Vec<f64>> = (0..ch.chains)
        .map(|c| posterior.from_si(&columns.iter().map(|&i| ch.at(i, last, c)).collect::<Vec<f64>>()))
        .collect();
    let s = &stored.settings.sampler;
    let sampler_settings = SamplerSettings {
        walkers: stored.record.walkers,
        ensembles: stored.record.ensembles,
        moves: s.moves.clone(),
        // a stream of its own for each held-out run
        seed: s.seed ^ (0x100 + j as u64),
    };
    let mut sampler = Sampler::new(&posterior, sampler_settings, &init)?;
    sampler.run(&RunControl { max_steps: settings.steps, until_converged: false, check_every: 100, min_ess: 0.0, checkpoint: None, progress })?;
    let chains = &sampler.chains;
    let diagnostics = si_diagnostics(&posterior, chains, None);
    let burn = diagnostics.burn_in;
    let pairs: Vec<(usize, usize)> = (burn..chains.steps()).flat_map(|st| (0..chains.chains()).map(move |c| (st, c))).collect();
    let (d, nt, nr) = (posterior.dim(), posterior.theta_len(), kept.runs.len());
    let draws: Vec<Draw> = predict::evenly_spaced(pairs.len(), settings.draws)
        .into_iter()
        .map(|i| {
            let (st, c) = pairs[i];
            let x: Vec<f64> = (0..d).map(|k| chains.at(st, c, k)).collect();
            let si = posterior.to_si(&x);
            Draw::for_unseen_run(posterior.params_at_current(&x, left_out.spec.current_a), &si[nt..nt + nr], &si[nt + nr..])
        })
        .collect();
    let data = stored.prediction_data(left_out);
    let predict_settings = stored.predict_settings(settings.replicates, settings.seed);
    let bands = predict::bands(&data, j, &draws, &stored.integrator(), &predict_settings, &|| {})?;
    Ok(HeldOut { run: left_out.id().to_string(), data, bands, max_rhat: diagnostics.max_rhat(), burn_in: burn })
}
