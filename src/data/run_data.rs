//! One run as the model and the noise models see it: the samples a
//! calibration compares, the smoothed strain that drives the model, and
//! what the record says about its own strain noise.

use serde::{Deserialize, Serialize};

use super::campaign::Run;
use super::smooth::{centre_weight, noise_variance, smoothed_strain};

/// Which samples of each record enter the likelihood.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum RecordPart {
    /// The first loading branch (the paper's choice).
    #[serde(alias = "FirstBranch")]
    FirstBranch,
    /// From the start to the last reversal: every complete branch.
    #[serde(alias = "AllBranches")]
    AllBranches,
    /// Every sample.
    #[serde(alias = "WholeRecord")]
    WholeRecord,
}

/// One run as the likelihood sees it.
#[derive(Clone, Debug)]
pub struct RunData {
    pub id: String,
    pub time: Vec<f64>,
    /// The strain that drives the model (smoothed).
    pub gamma: Vec<f64>,
    pub tau: Vec<f64>,
    pub initial_tau: f64,
    pub current_a: f64,
    /// The damper's area and gap, which turn force terms into stress.
    pub area_m2: f64,
    pub gap_m: f64,
    /// Variance of the measured strain's noise (displacement noise and
    /// quantisation over h²), estimated from the record: what the
    /// errors-in-variables likelihood propagates into stress.
    pub strain_noise_var: f64,
    /// The share of that variance left in the smoothed strain at one sample
    /// (the smoother's centre weight).
    pub strain_smoothing_share: f64,
    /// `reverses[k]`: the strain turns back at sample k (its increment
    /// changes sign against the last nonzero one), so a new loading branch
    /// starts there.
    pub reverses: Vec<bool>,
}

impl RunData {
    /// The samples of `run` that `part` selects (always from the first
    /// sample: the state at any point depends on the whole history before it).
    pub fn from_run(run: &Run, part: RecordPart, smooth_strain_ms: f64) -> RunData {
        let end = match part {
            RecordPart::WholeRecord => run.shear.len(),
            RecordPart::FirstBranch => run.branches[0].end,
            RecordPart::AllBranches => {
                // the end of the last branch that ends at a reversal
                let complete = run.branches.len().saturating_sub(1).max(1);
                run.branches[complete - 1].end
            }
        };
        let sh = &run.shear;
        let gamma = smoothed_strain(&sh.time, &sh.gamma, smooth_strain_ms);
        let strain_smoothing_share = centre_weight(&sh.time, smooth_strain_ms);
        let strain_noise_var = noise_variance(&sh.gamma, &gamma, strain_smoothing_share);
        RunData::new(
            run.id().to_string(),
            sh.time[..end].to_vec(),
            gamma[..end].to_vec(),
            run.shear.tau[..end].to_vec(),
            run.shear.initial_tau,
            run.spec.current_a,
            (run.geometry.area_m2, run.geometry.gap_m),
            (strain_noise_var, strain_smoothing_share),
        )
    }

    /// A run from its series: time (s), the strain that drives the model,
    /// the measured stress (Pa), the initial stress and current, the
    /// damper's (area, gap) and the strain noise (variance, share left after
    /// smoothing).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        id: String,
        time: Vec<f64>,
        gamma: Vec<f64>,
        tau: Vec<f64>,
        initial_tau: f64,
        current_a: f64,
        (area_m2, gap_m): (f64, f64),
        (strain_noise_var, strain_smoothing_share): (f64, f64),
    ) -> RunData {
        let reverses = reversals(&gamma);
        RunData { id, time, gamma, tau, initial_tau, current_a, area_m2, gap_m, strain_noise_var, strain_smoothing_share, reverses }
    }

    /// Residuals compared: every sample after the first.
    pub fn compared(&self) -> usize {
        self.time.len() - 1
    }

    /// The stress that a force offset `offset_n` (N) and a gas spring of
    /// `spring_n_per_m` (N/m) add at sample `k` (Pa): (F₀ + k x)/A with
    /// x = γ h, the piston's displacement from the record's start.
    #[inline(always)]
    pub fn terms_stress(&self, k: usize, spring_n_per_m: f64, offset_n: f64) -> f64 {
        (offset_n + spring_n_per_m * self.gamma[k] * self.gap_m) / self.area_m2
    }
}

/// Where a strain history turns back: the increment at k has the opposite
/// sign of the last nonzero increment before it.
fn reversals(gamma: &[f64]) -> Vec<bool> {
    let mut direction = 0.0f64;
    let mut out = vec![false; gamma.len()];
    for k in 1..gamma.len() {
        let dg = gamma[k] - gamma[k - 1];
        out[k] = dg != 0.0 && direction != 0.0 && dg.signum() != direction;
        if dg != 0.0 {
            direction = dg.signum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reversals_are_where_the_direction_changes() {
        // up, flat, up, down, flat, down, up
        let g = [0.0, 1.0, 1.0, 2.0, 1.0, 1.0, 0.5, 0.7];
        let r = reversals(&g);
        assert_eq!(r, vec![false, false, false, false, true, false, false, true]);
    }
}
