//! Each run predicted as a new test by the between-run layer fitted
//! without it, or without every run at its current.

use rayon::prelude::*;

use super::{BetweenRuns, GibbsSettings, LayerRun};
use crate::calibrate::Calibration;
use crate::data::{same_current, Campaign, RecordPart};
use crate::error::Result;
use crate::predict::{predict_run, CoverageRow};

/// What a run was predicted without: itself, or every run at its current.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeftOut {
    Run,
    Current,
}

impl LeftOut {
    pub fn label(self) -> &'static str {
        match self {
            LeftOut::Run => "run",
            LeftOut::Current => "current",
        }
    }

    pub fn parse(text: &str) -> Option<LeftOut> {
        [LeftOut::Run, LeftOut::Current].into_iter().find(|l| l.label() == text)
    }
}

/// One row of `loo_new_test.parquet`: a run predicted as a new test, and
/// what the layer was fitted without.
#[derive(Clone, Debug, PartialEq)]
pub struct NewTestRow {
    pub coverage: CoverageRow,
    pub left_out: LeftOut,
    /// The largest R̂ of the layer's Gibbs chains fitted without it.
    pub max_rhat: f64,
    /// Their smallest ESS (NaN in files written before 2026-12-04).
    pub min_ess: f64,
}

impl NewTestRow {
    /// Whether the layer fitted without the run did not converge
    /// ([`super::settled`]); a file without the ESS is judged by its R̂.
    pub fn unsettled(&self) -> bool {
        match self.min_ess.is_nan() {
            true => crate::validate::unsettled(self.max_rhat),
            false => !super::settled(self.max_rhat, self.min_ess),
        }
    }
}

/// Each run of `campaign` (the runs at one current, calibrated together in
/// `joint`, whose integrator and noise model make the bands) predicted as a
/// new test by the layer fitted without it: runs of this damper calibrated
/// alone at any current, by id, with their records as the noise model sees
/// them (`alone`). `left_out` says without what: the run alone (needs
/// another run at its current: the layer knows no centre there otherwise),
/// or every run at its current (needs runs at two other currents: the
/// centre there comes from the curve in the current); either way the runs
/// left need two at one current at least, as the layer does. Runs that
/// cannot be so predicted are left out of the answer.
pub fn leave_out(
    joint: &Calibration,
    campaign: &Campaign,
    alone: &[LayerRun],
    left_out: LeftOut,
    draws: usize,
    replicates: usize,
    seed: u64,
) -> Result<Vec<NewTestRow>> {
    let settings = joint.predict_settings(replicates, seed);
    let likelihood = &joint.settings.likelihood;
    let current = joint.record.current_a;
    let without = |run: &crate::data::Run, r: &LayerRun| match left_out {
        LeftOut::Run => r.id != run.id(),
        LeftOut::Current => !same_current(r.current_a, current),
    };
    let held: Vec<(usize, &std::sync::Arc<crate::data::Run>, &LayerRun)> = campaign
        .runs
        .iter()
        .enumerate()
        .filter_map(|(j, run)| {
            let own = alone.iter().find(|r| r.id == run.id())?;
            let others: Vec<&LayerRun> = alone.iter().filter(|r| without(run, r)).collect();
            let here = others.iter().filter(|r| same_current(r.current_a, current)).count();
            let mut elsewhere: Vec<f64> = others
                .iter()
                .filter(|r| !same_current(r.current_a, current))
                .map(|r| r.current_a)
                .collect();
            elsewhere.dedup_by(|a, b| same_current(*a, *b));
            let currents: Vec<f64> = others.iter().map(|r| r.current_a).collect();
            let possible = super::can_fit(&currents)
                && match left_out {
                    LeftOut::Run => here >= 1,
                    LeftOut::Current => elsewhere.len() >= 2,
                };
            possible.then_some((j, run, own))
        })
        .collect();
    // without its current, every run there is predicted by one layer
    let shared = match (left_out, held.first()) {
        (LeftOut::Current, Some(&(_, run, _))) => {
            let others: Vec<LayerRun> = alone.iter().filter(|r| without(run, r)).copied().collect();
            Some(BetweenRuns::fit(&others, &[current], GibbsSettings::default(), seed ^ 0x3_0000)?)
        }
        _ => None,
    };
    held.par_iter()
        .map(|&(j, run, own)| {
            let fitted;
            let layer = match &shared {
                Some(layer) => layer,
                None => {
                    let others: Vec<LayerRun> =
                        alone.iter().filter(|r| without(run, r)).copied().collect();
                    fitted = BetweenRuns::fit(
                        &others,
                        &[current],
                        GibbsSettings::default(),
                        seed ^ (0x1_0000 + j as u64),
                    )?;
                    &fitted
                }
            };
            let group = layer.group(current).expect("a current the layer was asked for");
            let data = likelihood.run_data(run, RecordPart::WholeRecord);
            let (new, outside) =
                layer.new_tests(group, own.cal, &data, draws, seed ^ (0x2_0000 + j as u64));
            let mut prediction = predict_run(run, &data, j, &new, &settings, false, &|| {})?;
            prediction.coverage.failed_draws += outside;
            Ok(NewTestRow {
                coverage: prediction.coverage,
                left_out,
                max_rhat: layer.max_rhat,
                min_ess: layer.min_ess,
            })
        })
        .collect()
}
