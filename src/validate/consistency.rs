//! Consistency across runs: every run calibrated alone, beside the joint
//! calibration of them all — the first question of a validation study:
//! does one parameter set describe every test?
//!
//! Per parameter of the damper law, in ln θ (the sampler's coordinate, where posteriors
//! are near normal):
//!
//! - **χ²/ν** of the run-wise posterior means y_i about their
//!   precision-weighted mean, each with its own sd s_i (ν = runs − 1). With
//!   one θ behind every run and honest intervals it is about 1; its p-value
//!   is the χ²_ν tail.
//! - **The between-run layer**'s interval for **a new test of this damper**
//!   ([`super::between_runs`]: the runs as draws from a population of
//!   tests), what a user should quote when the runs disagree.

use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::between_runs::BetweenRuns;
use crate::calibrate::Calibration;
use crate::sampler::quantile_sorted;

/// The p-value below which the runs are said to disagree.
pub const DISAGREE_P: f64 = 0.01;

/// Draws of each calibration summarised.
const DRAWS: usize = 4000;

/// One posterior of one parameter: of a run alone, of the joint calibration,
/// or the between-run layer's prediction for a new test.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    /// The run's id, `joint`, or `new test`.
    pub label: String,
    /// Mean and sd of ln θ.
    pub mean_log: f64,
    pub sd_log: f64,
    /// Quantiles of θ (SI).
    pub q05: f64,
    pub q50: f64,
    pub q95: f64,
}

pub const JOINT: &str = "joint";
pub const NEW_TEST: &str = "new test";

impl Estimate {
    /// Of `parameter` in `calibration` at its draws `positions`, labelled
    /// `label`.
    fn of(
        calibration: &Calibration,
        positions: &[(usize, usize)],
        parameter: &str,
        label: &str,
    ) -> Option<Estimate> {
        let mut values = calibration.sample.values(parameter, positions)?;
        values.retain(|v| *v > 0.0 && v.is_finite());
        values.sort_by(f64::total_cmp);
        Estimate::of_sorted(&values, label)
    }

    /// Of sorted positive values, labelled `label`.
    fn of_sorted(values: &[f64], label: &str) -> Option<Estimate> {
        if values.len() < 2 {
            return None;
        }
        let logs: Vec<f64> = values.iter().map(|v| v.ln()).collect();
        let n = logs.len() as f64;
        let mean_log = logs.iter().sum::<f64>() / n;
        let sd_log = (logs.iter().map(|v| (v - mean_log).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        Some(Estimate {
            label: label.to_string(),
            mean_log,
            sd_log,
            q05: quantile_sorted(values, 0.05),
            q50: quantile_sorted(values, 0.5),
            q95: quantile_sorted(values, 0.95),
        })
    }

    /// Whether `value` (SI) lies within the 90 % interval.
    pub fn holds(&self, value: f64) -> bool {
        self.q05 <= value && value <= self.q95
    }
}

/// One parameter's consistency across runs.
#[derive(Clone, Debug, PartialEq)]
pub struct ParameterConsistency {
    pub parameter: String,
    /// Each run calibrated alone.
    pub runs: Vec<Estimate>,
    /// The calibration of every run together.
    pub joint: Estimate,
    pub chi2_nu: f64,
    pub p_value: f64,
    /// The between-test sd of ln θ ([`BetweenRuns::spread_of`]).
    pub spread_log: f64,
    /// The between-run layer's predictive for a new test.
    pub new_test: Estimate,
}

impl ParameterConsistency {
    /// Whether the runs disagree beyond their own intervals.
    pub fn disagrees(&self) -> bool {
        self.p_value < DISAGREE_P
    }

    /// How many run-wise medians the new-test interval holds.
    pub fn runs_held(&self) -> usize {
        self.runs.iter().filter(|r| self.new_test.holds(r.q50)).count()
    }

    /// The between-test spread as a factor: ×1.37, say; beyond a
    /// thousandfold in three significant digits (×1.70e47, where four
    /// runs of Spencer's model lie modes apart: the layer does not bound
    /// the spread, while its new-test interval keeps to the physical
    /// range).
    pub fn spread_shown(&self) -> String {
        let factor = self.spread_log.exp();
        match factor < 1e3 {
            true => format!("×{factor:.2}"),
            false => format!("×{}", short(factor)),
        }
    }

    /// One line in plain words.
    pub fn verdict(&self) -> String {
        let p = &self.parameter;
        let values: Vec<String> =
            self.runs.iter().map(|r| format!("{} {}", r.label, short(r.q50))).collect();
        let interval = |e: &Estimate| format!("[{}, {}]", short(e.q05), short(e.q95));
        if self.disagrees() {
            format!(
                "{p}: the runs disagree (χ²/ν = {:.1}; {}): one {p} does not describe these tests. The joint 90 % interval {} is too narrow for a new test; the between-run layer gives {} (spread {} between tests)",
                self.chi2_nu,
                values.join(", "),
                interval(&self.joint),
                interval(&self.new_test),
                self.spread_shown()
            )
        } else {
            format!(
                "{p}: the runs agree (χ²/ν = {:.2}); joint 90 % interval {}",
                self.chi2_nu,
                interval(&self.joint)
            )
        }
    }
}

/// Three significant digits.
fn short(v: f64) -> String {
    format!("{v:.3e}")
}

/// The consistency of every law parameter of `joint` across the
/// calibrations of its runs one by one (`runs`, labelled by run id), with
/// the new test of `layer` at `joint`'s current.
pub fn consistency(
    joint: &Calibration,
    runs: &[(String, Calibration)],
    layer: &BetweenRuns,
) -> Vec<ParameterConsistency> {
    let joint_draws = joint.draw_positions(DRAWS);
    let run_draws: Vec<Vec<(usize, usize)>> =
        runs.iter().map(|(_, c)| c.draw_positions(DRAWS)).collect();
    let Some(group) = layer.group(joint.record.current_a) else {
        return Vec::new();
    };
    layer
        .names()
        .iter()
        .enumerate()
        .filter_map(|(k, name)| {
            let joint = Estimate::of(joint, &joint_draws, name, JOINT)?;
            let runs: Vec<Estimate> = runs
                .iter()
                .zip(&run_draws)
                .map(|((id, c), at)| Estimate::of(c, at, name, id))
                .collect::<Option<_>>()?;
            let new_test = Estimate::of_sorted(&layer.new_test_sorted(group, k), NEW_TEST)?;
            let y: Vec<f64> = runs.iter().map(|r| r.mean_log).collect();
            let s: Vec<f64> = runs.iter().map(|r| r.sd_log.max(1e-12)).collect();
            let (chi2_nu, p_value) = chi2_per_dof(&y, &s);
            Some(ParameterConsistency {
                parameter: name.to_string(),
                runs,
                joint,
                chi2_nu,
                p_value,
                spread_log: layer.spread_of(group, k),
                new_test,
            })
        })
        .collect()
}

/// χ²/ν of `y` about its precision-weighted mean with sds `s`, and the
/// χ²_ν tail probability (NaN for fewer than two values).
pub fn chi2_per_dof(y: &[f64], s: &[f64]) -> (f64, f64) {
    if y.len() < 2 {
        return (f64::NAN, f64::NAN);
    }
    let w: Vec<f64> = s.iter().map(|s| 1.0 / (s * s)).collect();
    let mean = y.iter().zip(&w).map(|(y, w)| y * w).sum::<f64>() / w.iter().sum::<f64>();
    let chi2: f64 = y.iter().zip(&w).map(|(y, w)| (y - mean).powi(2) * w).sum();
    let nu = (y.len() - 1) as f64;
    let p = ChiSquared::new(nu).map(|d| d.sf(chi2)).unwrap_or(f64::NAN);
    (chi2 / nu, p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_of_agreeing_and_disagreeing_runs() {
        // one value each, sds 1: about the weighted mean 0, χ² = 2 + 0 + 2
        let (c, p) = chi2_per_dof(&[-1.0, 0.0, 1.0], &[1.0, 1.0, 1.0]);
        assert!((c - 1.0).abs() < 1e-12);
        // χ²_2 tail at 2: e^{-1}
        assert!((p - (-1.0f64).exp()).abs() < 1e-9, "{p}");
        let (c, p) = chi2_per_dof(&[-10.0, 0.0, 10.0], &[1.0, 1.0, 1.0]);
        assert!((c - 100.0).abs() < 1e-9 && p < 1e-40);
    }

    #[test]
    fn a_spread_beyond_a_thousandfold_is_shown_in_powers_of_ten() {
        let e = |label: &str| Estimate {
            label: label.into(),
            mean_log: 0.0,
            sd_log: 1.0,
            q05: 0.5,
            q50: 1.0,
            q95: 2.0,
        };
        let mut p = ParameterConsistency {
            parameter: "c1".into(),
            runs: vec![e("a"), e("b")],
            joint: e(JOINT),
            chi2_nu: 50.0,
            p_value: 1e-20,
            spread_log: 2.0f64.ln(),
            new_test: e(NEW_TEST),
        };
        assert_eq!(p.spread_shown(), "×2.00");
        p.spread_log = 109.0;
        assert_eq!(p.spread_shown(), "×2.178e47");
        assert!(p.verdict().contains("(spread ×2.178e47 between tests)"), "{}", p.verdict());
    }
}
