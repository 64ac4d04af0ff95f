//! Leave-one-out validation of a calibration: for each run, the posterior
//! from the other runs alone predicts the run it did not see.
//!
//! Each held-out posterior is sampled afresh (no importance reweighting:
//! leaving out a whole record of thousands of samples moves the posterior
//! too far for that), warm-started from the last positions of the full
//! calibration's walkers, which lie close to it, for a fixed number of steps.
//! The held-out run's noise level is not known to that posterior; the
//! prediction uses the root-mean-square σ of the runs it did see.

use crate::calibrate::CalibrationSettings;
use crate::data::{Campaign, Run};
use crate::error::{Error, Result};
use crate::posterior::{PosteriorSample, RecordPart, RunData};
use crate::predict::{predict_run, PredictSettings, RunPrediction};
use crate::sampler::{Diagnostics, Observer, RunControl, Sampler};

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

/// One held-out run: its prediction and the sampler's convergence.
pub struct HeldOut {
    pub prediction: RunPrediction,
    pub max_rhat: f64,
    pub burn_in: usize,
}

/// Leaves out each run of `campaign` in turn. `settings` are the full
/// calibration's (walkers and sub-steps filled in), `sample` its posterior
/// sample, whose last positions start each held-out sampler. `observe`
/// makes the observers of each held-out run, told its id.
pub fn leave_one_out(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    sample: &PosteriorSample,
    loo: &LooSettings,
    observe: &mut dyn FnMut(&str) -> Vec<Box<dyn Observer>>,
) -> Result<Vec<HeldOut>> {
    if campaign.runs.len() < 2 {
        return Err(Error::Usage("leave-one-out needs a calibration of at least two runs".into()));
    }
    campaign
        .runs
        .iter()
        .enumerate()
        .map(|(j, left_out)| {
            let mut observers = observe(left_out.id());
            let mut refs: Vec<&mut dyn Observer> = observers.iter_mut().map(|o| o.as_mut() as &mut dyn Observer).collect();
            hold_out(campaign, settings, sample, j, left_out, loo, &mut refs)
        })
        .collect()
}

fn hold_out(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    sample: &PosteriorSample,
    j: usize,
    left_out: &Run,
    loo: &LooSettings,
    observers: &mut [&mut dyn Observer],
) -> Result<HeldOut> {
    let kept = campaign.filtered(|r| r.id() != left_out.id());
    let integrator = settings.integrator.integrator(settings.integrator.substeps);
    let posterior = settings.posterior(&kept, integrator);
    let layout = &posterior.layout;
    // the full calibration's last walkers, in this posterior's coordinates
    let ch = &sample.chains;
    let last = ch.steps() - 1;
    let columns: Vec<usize> = layout
        .names
        .iter()
        .map(|n| sample.layout.index(n).ok_or_else(|| Error::Compute(format!("the calibration's sample has no '{n}'"))))
        .collect::<Result<_>>()?;
    let init: Vec<Vec<f64>> =
        (0..ch.chains()).map(|c| layout.from_si(&columns.iter().map(|&i| ch.at(last, c, i)).collect::<Vec<f64>>())).collect();
    let s = &settings.sampler;
    // a stream of its own for each held-out run
    let mut sampler = Sampler::new(&posterior, s.sampler(s.walkers, s.seed ^ (0x100 + j as u64)), &init)?;
    sampler.run(&RunControl::fixed(loo.steps), observers)?;
    let held = PosteriorSample::from_coordinates(layout, posterior.model, &sampler.chains);
    let burn_in = Diagnostics::burn_in_rule(&sampler.chains);
    let diagnostics = held.diagnostics(burn_in);
    // short chains: every step after burn-in, not thinned
    let positions = held.positions(burn_in, 1, loo.draws);
    let draws = held.draws(&positions, left_out.id(), left_out.spec.current_a);
    let data = RunData::from_run(left_out, RecordPart::WholeRecord, settings.likelihood.smooth_strain_ms);
    let predict = PredictSettings::new(integrator, &settings.likelihood, loo.replicates, loo.seed);
    let prediction = predict_run(left_out, &data, j, &draws, &predict, false, &|| {})?;
    Ok(HeldOut { prediction, max_rhat: diagnostics.max_rhat(), burn_in })
}
