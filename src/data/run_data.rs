//! One run as the model and the noise models see it: the samples a
//! calibration compares, the smoothed strain that drives the model, and
//! what the record says about its own strain noise.

use serde::{Deserialize, Serialize};

use super::campaign::Run;
use super::smooth::{centre_weight, noise_variance, smoothed_strain};
use super::table::sampling_step;

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
    /// The run's current (A); where it varies, its nominal one.
    pub current_a: f64,
    /// The coil current at every sample (A), where it varies within the
    /// record (the manifest's `current_varies`).
    pub current: Option<Vec<f64>>,
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
    /// The sampling interval (s): the median one, and whether every
    /// interval equals it (to a millionth).
    pub step_s: f64,
    pub uniform: bool,
    /// The resolution of the measured stress (Pa): the step between
    /// neighbouring values of a quantised force channel (see
    /// `resolution`; 0 for one that is not quantised). Quantisation alone
    /// is noise of sd step/√12.
    pub stress_step_pa: f64,
    /// The excitation's period (s): twice the median time between
    /// reversals (of the record's loading branches); with one reversal,
    /// twice the longer stroke; with none, twice the record's duration.
    pub period_s: f64,
}

impl RunData {
    /// This run with its strain at each sample taken `lag_s` later in the
    /// record (linear between samples, and beyond either end along the
    /// first or last interval): the drive of a displacement channel that
    /// lags the force channel by `lag_s`.
    pub fn with_strain_lag(mut self, lag_s: f64) -> RunData {
        let (t, g) = (&self.time, &self.gamma);
        let n = t.len();
        if n < 2 {
            return self;
        }
        let shifted: Vec<f64> = t
            .iter()
            .map(|&at| {
                let at = at + lag_s;
                // the interval [j − 1, j] that holds `at`, or the end one
                let j = t.partition_point(|&s| s <= at).clamp(1, n - 1);
                let w = (at - t[j - 1]) / (t[j] - t[j - 1]);
                g[j - 1] + w * (g[j] - g[j - 1])
            })
            .collect();
        self.gamma = shifted;
        self
    }

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
        // the period from the loading branches, whose hysteresis ignores the
        // noise and quantisation steps near a dead centre
        let turns: Vec<f64> = run.branches.iter().skip(1).map(|b| sh.time[b.start]).collect();
        let mut data = RunData::new(
            run.id().to_string(),
            sh.time[..end].to_vec(),
            gamma[..end].to_vec(),
            run.shear.tau[..end].to_vec(),
            run.shear.initial_tau,
            run.spec.current_a,
            (run.geometry.area_m2, run.geometry.gap_m),
            (strain_noise_var, strain_smoothing_share),
        );
        data.period_s = period_of(&data.time, &turns);
        if run.spec.current_varies {
            data.current = run.record.current.as_ref().map(|c| c[..end].to_vec());
        }
        data
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
        let (step_s, uniform) = sampling_step(&time);
        let turns: Vec<f64> =
            time.iter().zip(&reverses).filter(|(_, r)| **r).map(|(t, _)| *t).collect();
        let period_s = period_of(&time, &turns);
        let stress_step_pa = resolution(&tau);
        RunData {
            id,
            time,
            gamma,
            tau,
            initial_tau,
            current_a,
            current: None,
            area_m2,
            gap_m,
            strain_noise_var,
            strain_smoothing_share,
            reverses,
            step_s,
            uniform,
            stress_step_pa,
            period_s,
        }
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

/// The quantum of a quantised record `v`: the tenth percentile of the gaps
/// between its distinct values, if three gaps in four are whole multiples
/// of it (to 5 %); 0 for a record that is not quantised. (On the measured
/// records 88–98 % of the gaps are; on a smooth record about 10 %, the
/// share of the unit interval the 5 % tolerance covers.)
fn resolution(v: &[f64]) -> f64 {
    let mut sorted: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    sorted.dedup();
    let mut gaps: Vec<f64> = sorted.windows(2).map(|w| w[1] - w[0]).collect();
    if gaps.is_empty() {
        return 0.0;
    }
    gaps.sort_by(f64::total_cmp);
    let quantum = gaps[gaps.len() / 10];
    let whole =
        gaps.iter().filter(|g| ((*g / quantum) - (*g / quantum).round()).abs() < 0.05).count();
    if quantum > 0.0 && whole as f64 >= 0.75 * gaps.len() as f64 {
        quantum
    } else {
        0.0
    }
}

/// Twice the median time between the reversals at `turns`; with one
/// reversal, twice the longer of the strokes before and after it (one
/// cycle from rest: its duration); with none, twice the duration of `time`.
fn period_of(time: &[f64], turns: &[f64]) -> f64 {
    let (start, end) = (time.first().copied().unwrap_or(0.0), time.last().copied().unwrap_or(0.0));
    let mut gaps: Vec<f64> = turns.windows(2).map(|w| w[1] - w[0]).collect();
    match turns {
        [] => return 2.0 * (end - start),
        [turn] => return 2.0 * (turn - start).max(end - turn),
        _ => {}
    }
    gaps.sort_by(f64::total_cmp);
    2.0 * gaps[gaps.len() / 2]
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
    fn step_and_period_of_a_sine() {
        let time: Vec<f64> = (0..2001).map(|k| k as f64 * 1e-3).collect();
        let gamma: Vec<f64> =
            time.iter().map(|t| (2.0 * std::f64::consts::PI * 4.0 * t).sin()).collect();
        let run =
            RunData::new("r".into(), time, gamma.clone(), gamma, 0.0, 1.0, (1.0, 1.0), (0.0, 1.0));
        assert!((run.step_s - 1e-3).abs() < 1e-12 && run.uniform);
        assert!((run.period_s - 0.25).abs() < 2e-3, "{}", run.period_s);
        // one cycle from rest (one reversal): its duration, to two sampling
        // intervals (the reversal is marked a sample after the extreme)
        let one: Vec<f64> =
            (0..301).map(|k| 1.0 - (2.0 * std::f64::consts::PI * k as f64 / 300.0).cos()).collect();
        let time: Vec<f64> = (0..301).map(|k| k as f64 * 1e-3).collect();
        let run =
            RunData::new("r".into(), time, one.clone(), one, 0.0, 1.0, (1.0, 1.0), (0.0, 1.0));
        assert!((run.period_s - 0.3).abs() < 2.5e-3, "{}", run.period_s);
    }

    #[test]
    fn the_resolution_of_a_quantised_record() {
        let v: Vec<f64> =
            (0..2000).map(|k| 3.0 * ((k as f64 * 0.37).sin() * 400.0).round()).collect();
        assert!((resolution(&v) - 3.0).abs() < 1e-9, "{}", resolution(&v));
        let smooth: Vec<f64> = (0..2000).map(|k| 1200.0 * (k as f64 * 0.0037).sin()).collect();
        assert_eq!(resolution(&smooth), 0.0);
    }

    #[test]
    fn reversals_are_where_the_direction_changes() {
        // up, flat, up, down, flat, down, up
        let g = [0.0, 1.0, 1.0, 2.0, 1.0, 1.0, 0.5, 0.7];
        let r = reversals(&g);
        assert_eq!(r, vec![false, false, false, false, true, false, false, true]);
    }
}
