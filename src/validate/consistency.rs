//! Consistency across runs: every run calibrated alone, beside the joint
//! calibration of them all — the first question of a validation study:
//! does one parameter set describe every test?
//!
//! Per B-P parameter, in ln θ (the sampler's coordinate, where posteriors
//! are near normal):
//!
//! - **χ²/ν** of the run-wise posterior means y_i about their
//!   precision-weighted mean, each with its own sd s_i (ν = runs − 1). With
//!   one θ behind every run and honest intervals it is about 1; its p-value
//!   is the χ²_ν tail.
//! - **A between-run layer** (random effects, partial pooling): the
//!   run-wise posteriors as normal likelihoods of run-level values,
//!   y_i ~ N(ln θ_i, s_i²), ln θ_i ~ N(μ, τ²), μ flat, the spread τ
//!   half-Cauchy(0, 1) (one e-fold between tests at one prior sd). μ is
//!   integrated exactly and τ on a grid. Its predictive interval for
//!   ln θ of **a new test of this damper**, N(μ, τ²) mixed over the
//!   posterior of (μ, τ), is what a user should quote when the runs
//!   disagree.

use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};

use crate::calibrate::Calibration;
use crate::model::PARAM_NAMES;
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
    fn of(calibration: &Calibration, positions: &[(usize, usize)], parameter: &str, label: &str) -> Option<Estimate> {
        let mut values = calibration.sample.values(parameter, positions)?;
        values.retain(|v| *v > 0.0 && v.is_finite());
        if values.len() < 2 {
            return None;
        }
        values.sort_by(f64::total_cmp);
        let logs: Vec<f64> = values.iter().map(|v| v.ln()).collect();
        let n = logs.len() as f64;
        let mean_log = logs.iter().sum::<f64>() / n;
        let sd_log = (logs.iter().map(|v| (v - mean_log).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        Some(Estimate {
            label: label.to_string(),
            mean_log,
            sd_log,
            q05: quantile_sorted(&values, 0.05),
            q50: quantile_sorted(&values, 0.5),
            q95: quantile_sorted(&values, 0.95),
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
    /// Posterior median of the between-run spread τ of ln θ.
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

    /// One line in plain words.
    pub fn verdict(&self) -> String {
        let p = &self.parameter;
        let values: Vec<String> = self.runs.iter().map(|r| format!("{} {}", r.label, short(r.q50))).collect();
        let interval = |e: &Estimate| format!("[{}, {}]", short(e.q05), short(e.q95));
        if self.disagrees() {
            format!(
                "{p}: the runs disagree (χ²/ν = {:.1}; {}): one {p} does not describe these tests. The joint 90 % interval {} is too narrow for a new test; the between-run layer gives {} (spread ×{:.2} between tests)",
                self.chi2_nu,
                values.join(", "),
                interval(&self.joint),
                interval(&self.new_test),
                self.spread_log.exp()
            )
        } else {
            format!("{p}: the runs agree (χ²/ν = {:.2}); joint 90 % interval {}", self.chi2_nu, interval(&self.joint))
        }
    }
}

/// Three significant digits.
fn short(v: f64) -> String {
    format!("{v:.3e}")
}

/// The consistency of every B-P parameter of `joint` across the
/// calibrations of its runs one by one (`runs`, labelled by run id).
pub fn consistency(joint: &Calibration, runs: &[(String, Calibration)]) -> Vec<ParameterConsistency> {
    let joint_draws = joint.draw_positions(DRAWS);
    let run_draws: Vec<Vec<(usize, usize)>> = runs.iter().map(|(_, c)| c.draw_positions(DRAWS)).collect();
    PARAM_NAMES
        .iter()
        .filter_map(|name| {
            let joint = Estimate::of(joint, &joint_draws, name, JOINT)?;
            let runs: Vec<Estimate> = runs.iter().zip(&run_draws).map(|((id, c), at)| Estimate::of(c, at, name, id)).collect::<Option<_>>()?;
            Some(of_estimates(name, runs, joint))
        })
        .collect()
}

/// χ²/ν and the between-run layer of run-wise estimates.
pub fn of_estimates(parameter: &str, runs: Vec<Estimate>, joint: Estimate) -> ParameterConsistency {
    let y: Vec<f64> = runs.iter().map(|r| r.mean_log).collect();
    let s: Vec<f64> = runs.iter().map(|r| r.sd_log.max(1e-12)).collect();
    let (chi2_nu, p_value) = chi2_per_dof(&y, &s);
    let layer = RandomEffects::fit(&y, &s);
    let new_test = Estimate {
        label: NEW_TEST.to_string(),
        mean_log: layer.mean(),
        sd_log: layer.sd(),
        q05: layer.quantile(0.05).exp(),
        q50: layer.quantile(0.5).exp(),
        q95: layer.quantile(0.95).exp(),
    };
    ParameterConsistency { parameter: parameter.to_string(), runs, joint, chi2_nu, p_value, spread_log: layer.spread_median(), new_test }
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

/// The normal-normal random-effects model on a grid of the spread τ: at
/// each τ the weight p(τ | y) and the new test's normal predictive
/// N(μ̂(τ), V(τ) + τ²).
pub struct RandomEffects {
    /// (τ, weight, predictive mean, predictive variance).
    grid: Vec<(f64, f64, f64, f64)>,
}

/// Points of the τ grid.
const GRID: usize = 4001;

impl RandomEffects {
    pub fn fit(y: &[f64], s: &[f64]) -> RandomEffects {
        let spread = y.iter().fold(f64::NEG_INFINITY, |a, b| a.max(*b)) - y.iter().fold(f64::INFINITY, |a, b| a.min(*b));
        let top = 20.0 * (spread + s.iter().fold(0.0f64, |a, b| a.max(*b))).max(1e-6);
        let mut grid: Vec<(f64, f64, f64, f64)> = (0..GRID)
            .map(|i| {
                let tau = top * i as f64 / (GRID - 1) as f64;
                let w: Vec<f64> = s.iter().map(|s| 1.0 / (s * s + tau * tau)).collect();
                let sw: f64 = w.iter().sum();
                let mu = y.iter().zip(&w).map(|(y, w)| y * w).sum::<f64>() / sw;
                // ln p(y | τ) with μ integrated over a flat prior, and the half-Cauchy prior
                let log_marginal = 0.5 * w.iter().map(|w| w.ln()).sum::<f64>() - 0.5 * sw.ln() - 0.5 * y.iter().zip(&w).map(|(y, w)| (y - mu).powi(2) * w).sum::<f64>();
                let log_prior = -(1.0 + tau * tau).ln();
                (tau, log_marginal + log_prior, mu, 1.0 / sw + tau * tau)
            })
            .collect();
        let top_log = grid.iter().map(|g| g.1).fold(f64::NEG_INFINITY, f64::max);
        let total: f64 = grid.iter().map(|g| (g.1 - top_log).exp()).sum();
        for g in &mut grid {
            g.1 = (g.1 - top_log).exp() / total;
        }
        RandomEffects { grid }
    }

    pub fn mean(&self) -> f64 {
        self.grid.iter().map(|(_, w, m, _)| w * m).sum()
    }

    pub fn sd(&self) -> f64 {
        let mean = self.mean();
        self.grid.iter().map(|(_, w, m, v)| w * (v + (m - mean).powi(2))).sum::<f64>().sqrt()
    }

    /// The posterior median of τ.
    pub fn spread_median(&self) -> f64 {
        let mut acc = 0.0;
        for (tau, w, _, _) in &self.grid {
            acc += w;
            if acc >= 0.5 {
                return *tau;
            }
        }
        self.grid.last().map(|g| g.0).unwrap_or(0.0)
    }

    fn cdf(&self, x: f64) -> f64 {
        self.grid.iter().map(|(_, w, m, v)| w * Normal::new(*m, v.sqrt()).map(|d| d.cdf(x)).unwrap_or(0.5)).sum()
    }

    /// The `p` quantile of the new test's ln θ, by bisection.
    pub fn quantile(&self, p: f64) -> f64 {
        let (mean, sd) = (self.mean(), self.sd());
        let (mut lo, mut hi) = (mean - 20.0 * sd, mean + 20.0 * sd);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if self.cdf(mid) < p {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }
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
    fn the_spread_vanishes_for_identical_runs_and_the_predictive_is_the_pooled_mean() {
        let layer = RandomEffects::fit(&[0.3, 0.3, 0.3, 0.3], &[0.1, 0.1, 0.1, 0.1]);
        // τ's posterior is the prior times a marginal falling in τ: its median is well below the runs' sd
        assert!(layer.spread_median() < 0.1, "{}", layer.spread_median());
        assert!((layer.mean() - 0.3).abs() < 1e-9);
        // the 90 % interval of a new test is at least the pooled mean's (sd 0.05) and below the run sds' scale ×3
        let half = layer.quantile(0.95) - layer.quantile(0.5);
        assert!(half > 1.645 * 0.05 && half < 3.0 * 1.645 * 0.1, "{half}");
    }

    /// With precise runs far apart, the new test's 90 % interval against an
    /// independent computation: 2·10⁶ Monte Carlo draws of (τ, μ, θ_new)
    /// from the same model (τ on a fine log grid, numpy) gave quantiles
    /// ±1.3049 about the mean (Monte Carlo se about 0.002; the classical
    /// flat-prior t interval, 1.234, is a little narrower since its prior
    /// on the spread is 1/τ). Tolerance 1 %: five Monte Carlo se and the grid.
    #[test]
    fn the_new_test_interval_of_spread_runs_matches_monte_carlo() {
        let y = [-0.6, -0.1, 0.2, 0.5];
        let s = [0.001; 4];
        let layer = RandomEffects::fit(&y, &s);
        let mean = y.iter().sum::<f64>() / 4.0;
        let half = 0.5 * (layer.quantile(0.95) - layer.quantile(0.05));
        assert!((half / 1.3049 - 1.0).abs() < 0.01, "{half}");
        assert!((layer.quantile(0.5) - mean).abs() < 1e-3, "{}", layer.quantile(0.5));
        // the predictive's weights sum to 1: its distribution function runs from 0 to 1
        let (below, above) = (layer.cdf(mean - 1e4), layer.cdf(mean + 1e4));
        assert!(below < 1e-9 && (above - 1.0).abs() < 1e-9, "{below} {above}");
    }
}
