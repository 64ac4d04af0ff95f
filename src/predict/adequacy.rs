//! Model adequacy: where the calibrated law misses a record, in the terms a
//! damper engineer uses — force in newtons, the excitation as amplitude and
//! frequency, the residual against displacement and velocity.
//!
//! Everything here is computed from a run's bands (the posterior-median
//! model and the predictive band) and the record: the residual force
//! r = (τ_obs − q50)·A, the velocity of the smoothed displacement that drove
//! the model, and a few numbers that say what kind of misfit it is:
//!
//! * its size (RMS, and as a share of the peak force);
//! * its memory: the lag-1 autocorrelation ρ and the decorrelation time. A
//!   likelihood with independent noise reads n correlated residuals as n
//!   independent ones, so parameter intervals are too narrow by about
//!   √((1 + ρ)/(1 − ρ)) (the AR(1) variance inflation of a mean);
//! * its shape: the least-squares trend r ≈ a + k·x + c·v, i.e. the force
//!   offset, spring and viscous damping the law lacks, and the share of the
//!   residual variance they explain;
//! * where it sits: RMS and predictive coverage at the reversals (|v| below
//!   a fifth of the peak velocity, where yield is timed) against mid-stroke.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::bands::RunBands;
use crate::sampler::quantile;

/// A sample is "at a reversal" when its speed is below this share of the
/// peak speed (for a sinusoid: the 13 % of the cycle around each reversal).
pub const REVERSAL_SPEED_SHARE: f64 = 0.2;

/// The excitation of a record, as a test engineer names it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// Half the peak-to-peak displacement (0.5 % and 99.5 % quantiles, so a
    /// spike does not set it), m.
    pub amplitude_m: f64,
    /// Cycles per second from the up-crossings of the mid-stroke (NaN when
    /// the record holds fewer than two), Hz.
    pub frequency_hz: f64,
    /// The 99th percentile of the speed, m/s.
    pub peak_velocity_m_s: f64,
}

impl Excitation {
    /// The excitation of displacement `x` (m) sampled at `time` (s), with
    /// velocity `v` (m/s).
    pub fn of(time: &[f64], x: &[f64], v: &[f64]) -> Excitation {
        let (lo, hi) = (quantile(x, 0.005), quantile(x, 0.995));
        let amplitude_m = 0.5 * (hi - lo);
        let mid = 0.5 * (hi + lo);
        // Up-crossings with a hysteresis of a tenth of the amplitude, so
        // quantisation steps near mid-stroke do not count as cycles.
        let band = 0.1 * amplitude_m;
        let mut below = false;
        let mut crossings = Vec::new();
        for (k, &xk) in x.iter().enumerate() {
            if xk < mid - band {
                below = true;
            } else if below && xk > mid + band {
                below = false;
                crossings.push(time[k]);
            }
        }
        let frequency_hz = match crossings.as_slice() {
            [first, .., last] if last > first => (crossings.len() - 1) as f64 / (last - first),
            _ => f64::NAN,
        };
        let speed: Vec<f64> = v.iter().map(|v| v.abs()).collect();
        Excitation { amplitude_m, frequency_hz, peak_velocity_m_s: quantile(&speed, 0.99) }
    }

    /// "±25 mm, 0.25 Hz".
    pub fn label(&self) -> String {
        let mm = self.amplitude_m * 1e3;
        let amp = if mm >= 10.0 { format!("±{mm:.0} mm") } else { format!("±{mm:.1} mm") };
        if self.frequency_hz.is_finite() {
            format!(
                "{amp}, {} Hz",
                crate::plot::tick(crate::plot::significant(self.frequency_hz, 2))
            )
        } else {
            amp
        }
    }
}

/// How well the calibrated law describes one run: one row of
/// `adequacy.parquet`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdequacyRow {
    pub run: String,
    pub current_a: f64,
    pub excitation: Excitation,
    /// The 99th percentile of |F|, N.
    pub peak_force_n: f64,
    /// RMS of the residual force F_obs − F_median, N.
    pub residual_rms_n: f64,
    /// Lag-1 autocorrelation of the residual.
    pub lag1_autocorrelation: f64,
    /// First lag at which the residual's autocorrelation falls below 1/e, s.
    pub decorrelation_s: f64,
    /// Lag-1 autocorrelation of the noise model's standardised one-step-
    /// ahead innovations, where it models a force of its own (the
    /// discrepancy model; NaN otherwise): the memory it leaves.
    pub innovation_lag1: f64,
    /// √((1 + ρ)/(1 − ρ)) with ρ the lag-1 autocorrelation (floored at 0)
    /// of the residual, or of the innovations where the noise model has
    /// them: how much too narrow the parameter intervals are.
    pub interval_inflation: f64,
    /// Least-squares r ≈ a + k·(x − x̄) + c·v: a (N), k (N/m), c (N·s/m).
    pub trend_offset_n: f64,
    pub trend_stiffness_n_per_m: f64,
    pub trend_damping_n_s_per_m: f64,
    /// Share of the residual variance the trend explains (R²).
    pub trend_share: f64,
    /// RMS of the residual at reversals and mid-stroke, N.
    pub reversal_rms_n: f64,
    pub stroke_rms_n: f64,
    /// Share of the record inside the 95 % predictive band: overall, at
    /// reversals, mid-stroke.
    pub inside_p95: f64,
    pub inside_p95_reversal: f64,
    pub inside_p95_stroke: f64,
}

/// The displacement that drove the model: the smoothed strain times the
/// gap, from the record's first position (m).
pub fn model_displacement(b: &RunBands, gap_m: f64) -> Vec<f64> {
    let x0 = b.displacement.first().copied().unwrap_or(0.0);
    b.gamma_model.iter().map(|g| x0 + g * gap_m).collect()
}

/// [`model_displacement`] and its velocity by central differences, m and
/// m/s.
pub fn kinematics(b: &RunBands, gap_m: f64) -> (Vec<f64>, Vec<f64>) {
    let x = model_displacement(b, gap_m);
    let n = x.len();
    let v = (0..n)
        .map(|k| {
            let (a, c) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let dt = b.time[c] - b.time[a];
            if dt > 0.0 {
                (x[c] - x[a]) / dt
            } else {
                0.0
            }
        })
        .collect();
    (x, v)
}

/// The residual force F_obs − F_median, N.
pub fn residual_force(b: &RunBands, area_m2: f64) -> Vec<f64> {
    b.tau_obs.iter().zip(&b.model[2]).map(|(o, m)| (o - m) * area_m2).collect()
}

/// Autocorrelation of `r` at lags 0..=max_lag (the sampler's FFT
/// estimator: mean removed, biased, so it stays within [−1, 1]).
pub fn autocorrelation(r: &[f64], max_lag: usize) -> Vec<f64> {
    let mut acf = crate::sampler::diagnostics::autocorrelation(r);
    acf.truncate(max_lag + 1);
    acf
}

/// The number of samples in one cycle of `e` along `time` (the whole record
/// when the frequency is unknown).
pub fn samples_per_cycle(time: &[f64], e: &Excitation) -> usize {
    let n = time.len();
    if n < 2 || !e.frequency_hz.is_finite() {
        return n.saturating_sub(1);
    }
    let dt = (time[n - 1] - time[0]) / (n - 1) as f64;
    ((1.0 / (e.frequency_hz * dt)).round() as usize).clamp(1, n - 1)
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    }
}

fn share(v: impl Iterator<Item = bool>) -> f64 {
    let (k, n) = v.fold((0usize, 0usize), |(k, n), x| (k + x as usize, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        k as f64 / n as f64
    }
}

/// Least squares r ≈ a + k·(x − x̄) + c·v: (a, k, c, R²). Columns are scaled
/// to unit spread first, so strokes of millimetres and speeds of metres per
/// second make a well-conditioned system.
fn trend(r: &[f64], x: &[f64], v: &[f64]) -> (f64, f64, f64, f64) {
    let n = r.len();
    let mean = |a: &[f64]| a.iter().sum::<f64>() / n as f64;
    let spread = |a: &[f64], m: f64| {
        (a.iter().map(|y| (y - m).powi(2)).sum::<f64>() / n as f64).sqrt().max(f64::MIN_POSITIVE)
    };
    let (xm, vm) = (mean(x), mean(v));
    let (sx, sv) = (spread(x, xm), spread(v, vm));
    let design = DMatrix::from_fn(n, 3, |i, j| match j {
        0 => 1.0,
        1 => (x[i] - xm) / sx,
        _ => v[i] / sv,
    });
    let y = DVector::from_column_slice(r);
    let Ok(beta) = design.clone().svd(true, true).solve(&y, 1e-12) else {
        return (f64::NAN, f64::NAN, f64::NAN, f64::NAN);
    };
    let fitted = &design * &beta;
    let rm = mean(r);
    let total: f64 = r.iter().map(|y| (y - rm).powi(2)).sum();
    let left: f64 = r.iter().zip(fitted.iter()).map(|(y, f)| (y - f).powi(2)).sum();
    let r2 = if total > 0.0 { 1.0 - left / total } else { f64::NAN };
    (beta[0], beta[1] / sx, beta[2] / sv, r2)
}

/// The adequacy of the calibrated law on run `b` (geometry: area A and gap h).
pub fn assess(b: &RunBands, area_m2: f64, gap_m: f64) -> AdequacyRow {
    let (x, v) = kinematics(b, gap_m);
    let excitation = Excitation::of(&b.time, &x, &v);
    let r = residual_force(b, area_m2);
    // Samples where the record and the band are finite.
    let ok: Vec<usize> = (0..r.len())
        .filter(|&k| {
            r[k].is_finite() && b.predictive[0][k].is_finite() && b.predictive[1][k].is_finite()
        })
        .collect();
    let pick = |a: &[f64]| ok.iter().map(|&k| a[k]).collect::<Vec<f64>>();
    let (r, x, v) = (pick(&r), pick(&x), pick(&v));
    let time = pick(&b.time);
    let inside: Vec<bool> = ok
        .iter()
        .map(|&k| b.predictive[0][k] <= b.tau_obs[k] && b.tau_obs[k] <= b.predictive[1][k])
        .collect();
    let at_reversal: Vec<bool> =
        v.iter().map(|v| v.abs() < REVERSAL_SPEED_SHARE * excitation.peak_velocity_m_s).collect();

    let acf = autocorrelation(&r, samples_per_cycle(&time, &excitation));
    let rho = acf.get(1).copied().unwrap_or(f64::NAN);
    let dt = if time.len() > 1 {
        (time[time.len() - 1] - time[0]) / (time.len() - 1) as f64
    } else {
        f64::NAN
    };
    let decorrelation_s =
        acf.iter().position(|c| *c < (-1.0f64).exp()).map_or(f64::NAN, |lag| lag as f64 * dt);
    let innovation_lag1 = b.discrepancy.as_ref().map_or(f64::NAN, |d| {
        let w: Vec<f64> = d[2].iter().copied().filter(|v| v.is_finite()).collect();
        autocorrelation(&w, 2).get(1).copied().unwrap_or(f64::NAN)
    });
    let rho_pos = if innovation_lag1.is_finite() { innovation_lag1 } else { rho }.clamp(0.0, 0.999);
    let (a, k, c, r2) =
        if r.len() >= 4 { trend(&r, &x, &v) } else { (f64::NAN, f64::NAN, f64::NAN, f64::NAN) };
    let force: Vec<f64> = b.force.iter().map(|f| f.abs()).filter(|f| f.is_finite()).collect();
    let part = |want: bool| {
        rms(r.iter().zip(&at_reversal).filter(|(_, &rev)| rev == want).map(|(r, _)| *r))
    };
    let cover = |want: bool| {
        share(inside.iter().zip(&at_reversal).filter(|(_, &rev)| rev == want).map(|(i, _)| *i))
    };
    AdequacyRow {
        run: b.run.clone(),
        current_a: b.current_a,
        excitation,
        peak_force_n: if force.is_empty() { f64::NAN } else { quantile(&force, 0.99) },
        residual_rms_n: rms(r.iter().copied()),
        lag1_autocorrelation: rho,
        decorrelation_s,
        innovation_lag1,
        interval_inflation: ((1.0 + rho_pos) / (1.0 - rho_pos)).sqrt(),
        trend_offset_n: a,
        trend_stiffness_n_per_m: k,
        trend_damping_n_s_per_m: c,
        trend_share: r2,
        reversal_rms_n: part(true),
        stroke_rms_n: part(false),
        inside_p95: share(inside.iter().copied()),
        inside_p95_reversal: cover(true),
        inside_p95_stroke: cover(false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;
    use rand_distr::StandardNormal;
    use std::f64::consts::PI;

    /// A sinusoid of ±20 mm at 0.5 Hz sampled at 200 Hz for four cycles,
    /// with a model stress of zero and an observed stress built from `r`.
    fn bands_with(
        residual_n: impl Fn(f64, f64, f64) -> f64,
        area: f64,
        gap: f64,
        half_band_n: f64,
    ) -> RunBands {
        let n = 1600;
        let time: Vec<f64> = (0..n).map(|k| k as f64 / 200.0).collect();
        let x: Vec<f64> = time.iter().map(|t| 0.02 * (2.0 * PI * 0.5 * t).sin()).collect();
        let v: Vec<f64> = time.iter().map(|t| 0.02 * PI * (2.0 * PI * 0.5 * t).cos()).collect();
        let tau: Vec<f64> = (0..n).map(|k| residual_n(time[k], x[k], v[k]) / area).collect();
        let zero = vec![0.0; n];
        RunBands {
            run: "r".into(),
            current_a: 1.0,
            gamma: x.iter().map(|x| x / gap).collect(),
            gamma_model: x.iter().map(|x| x / gap).collect(),
            tau_obs: tau,
            model: [(); 5].map(|_| zero.clone()),
            predictive: [vec![-half_band_n / area; n], vec![half_band_n / area; n]],
            displacement: x,
            force: vec![100.0; n],
            discrepancy: None,
            coil_current_a: None,
            time,
        }
    }

    /// A residual made of a known offset, spring and damper is recovered by
    /// the trend to the precision of the central differences (the velocity
    /// of a 200 Hz sinusoid at 0.5 Hz is off by (ωΔt)²/6 ≈ 1e-4 relative).
    #[test]
    fn trend_recovers_offset_spring_and_damper() {
        let b = bands_with(|_, x, v| 12.0 + 2000.0 * x + 300.0 * v, 0.01, 1e-3, 1e3);
        let a = assess(&b, 0.01, 1e-3);
        assert!((a.trend_offset_n - 12.0).abs() < 0.05, "{}", a.trend_offset_n);
        assert!(
            (a.trend_stiffness_n_per_m / 2000.0 - 1.0).abs() < 1e-3,
            "{}",
            a.trend_stiffness_n_per_m
        );
        assert!(
            (a.trend_damping_n_s_per_m / 300.0 - 1.0).abs() < 1e-3,
            "{}",
            a.trend_damping_n_s_per_m
        );
        assert!(a.trend_share > 0.999999);
    }

    /// The excitation of the stand: amplitude from the quantiles (within
    /// 0.1 % of 20 mm: the 0.5 % quantile of a sinusoid sits at cos(0.1π)),
    /// frequency from the up-crossings (exact to the sampling, 1/200 s over
    /// 3 cycles), peak speed 2π·0.5·0.02.
    #[test]
    fn excitation_of_a_sinusoid() {
        let b = bands_with(|_, _, _| 0.0, 0.01, 1e-3, 1.0);
        let a = assess(&b, 0.01, 1e-3);
        let e = a.excitation;
        assert!((e.amplitude_m / 0.02 - 1.0).abs() < 2e-3, "{}", e.amplitude_m);
        assert!((e.frequency_hz - 0.5).abs() < 0.5 * 0.01 / 3.0, "{}", e.frequency_hz);
        assert!((e.peak_velocity_m_s / (0.02 * PI) - 1.0).abs() < 1e-3, "{}", e.peak_velocity_m_s);
        assert_eq!(e.label(), "±20 mm, 0.5 Hz");
    }

    /// AR(1) residuals with ρ = 0.9: the lag-1 estimate from 1600 samples
    /// has sd √((1 − ρ²)/n) ≈ 0.011; 0.05 is four and a half of them. White
    /// residuals give ρ near 0 (sd 1/√n = 0.025; 0.1 is four of them) and an
    /// inflation near 1.
    #[test]
    fn autocorrelation_of_ar1_and_white_residuals() {
        let mut rng = crate::rng::stream(5, &[]);
        let e: Vec<f64> = (0..1600).map(|_| rng.sample::<f64, _>(StandardNormal)).collect();
        let mut ar = vec![0.0; 1600];
        for k in 1..1600 {
            ar[k] = 0.9 * ar[k - 1] + e[k];
        }
        let white = bands_with(|t, _, _| e[(t * 200.0).round() as usize], 0.01, 1e-3, 1.96);
        let corr = bands_with(|t, _, _| ar[(t * 200.0).round() as usize], 0.01, 1e-3, 1.96);
        let (w, c) = (assess(&white, 0.01, 1e-3), assess(&corr, 0.01, 1e-3));
        assert!(w.lag1_autocorrelation.abs() < 0.1, "{}", w.lag1_autocorrelation);
        assert!(w.interval_inflation < 1.11);
        assert!((c.lag1_autocorrelation - 0.9).abs() < 0.05, "{}", c.lag1_autocorrelation);
        assert!((c.interval_inflation - (1.9f64 / 0.1).sqrt()).abs() < 1.5);
        // Decorrelation of an AR(1): ρ^lag = 1/e at lag −1/ln ρ ≈ 9.5 samples.
        assert!((c.decorrelation_s * 200.0 - 9.5).abs() < 4.0, "{}", c.decorrelation_s);
        // White noise of unit sd inside ±1.96: 95 % ± 4 sd of a binomial share.
        assert!(
            (w.inside_p95 - 0.95).abs() < 4.0 * (0.95f64 * 0.05 / 1600.0).sqrt(),
            "{}",
            w.inside_p95
        );
    }

    /// Spikes at the reversals only: the reversal RMS carries them, the
    /// mid-stroke RMS is zero, and the coverage splits the same way.
    #[test]
    fn reversal_spikes_are_located() {
        let b = bands_with(
            |_, _, v| if v.abs() < 0.1 * 0.02 * PI { 50.0 } else { 0.0 },
            0.01,
            1e-3,
            10.0,
        );
        let a = assess(&b, 0.01, 1e-3);
        assert!(a.reversal_rms_n > 30.0, "{}", a.reversal_rms_n);
        assert_eq!(a.stroke_rms_n, 0.0);
        assert_eq!(a.inside_p95_stroke, 1.0);
        assert!(a.inside_p95_reversal < 0.7, "{}", a.inside_p95_reversal);
    }
}
