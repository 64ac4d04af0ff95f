//! Local least-squares polynomial smoothing: smoothed values and slopes of
//! noisy samples, on even or uneven time grids.

/// Local least-squares polynomials of `degree` (a Savitzky-Golay filter that
/// also works on uneven grids): at every sample, the value and the slope of
/// the polynomial fitted to the samples within `half_window` on each side
/// (fewer at the ends). Unlike a plain difference, the slope does not
/// amplify sensor noise by 1/Δt.
/// A cubic keeps the bias of value and slope at a sharp bend (the yield
/// knee) an order smaller than a straight line over the same window, at the
/// price of more noise.
pub fn local_polynomial(
    t: &[f64],
    y: &[f64],
    half_window: usize,
    degree: usize,
) -> (Vec<f64>, Vec<f64>) {
    use nalgebra::{DMatrix, DVector};
    let n = t.len();
    let h = half_window.max(1);
    let mut values = Vec::with_capacity(n);
    let mut slopes = Vec::with_capacity(n);
    for k in 0..n {
        let lo = k.saturating_sub(h);
        let hi = (k + h + 1).min(n);
        let deg = degree.min(hi - lo - 1);
        // centred and scaled abscissa for a well-conditioned system
        let scale = (t[hi - 1] - t[k]).abs().max((t[k] - t[lo]).abs()).max(f64::MIN_POSITIVE);
        let m = deg + 1;
        let mut ata = DMatrix::<f64>::zeros(m, m);
        let mut aty = DVector::<f64>::zeros(m);
        for i in lo..hi {
            let u = (t[i] - t[k]) / scale;
            let mut powers = [1.0; 8];
            for p in 1..m {
                powers[p] = powers[p - 1] * u;
            }
            for r in 0..m {
                aty[r] += powers[r] * y[i];
                for c in 0..m {
                    ata[(r, c)] += powers[r] * powers[c];
                }
            }
        }
        match ata.lu().solve(&aty) {
            Some(coef) if coef.iter().all(|c| c.is_finite()) => {
                values.push(coef[0]);
                slopes.push(if m > 1 { coef[1] / scale } else { 0.0 });
            }
            _ => {
                values.push(y[k]);
                slopes.push(0.0);
            }
        }
    }
    (values, slopes)
}

/// The fewest samples on each side of the strain's local cubic fit: on a
/// record sampled at a few hundred hertz a few milliseconds are one sample,
/// which smooths nothing.
pub const MIN_SMOOTH_SAMPLES: usize = 5;

/// The strain that drives the model: the measured one smoothed by a local
/// cubic of half-width `smooth_ms` (at least [`MIN_SMOOTH_SAMPLES`] samples;
/// 0 keeps the raw samples), its first sample kept (the record starts at its
/// reference position). Displacement noise and the steps of a quantised
/// displacement channel would otherwise drive the stiff law as stress noise.
pub fn smoothed_strain(time: &[f64], gamma: &[f64], smooth_ms: f64) -> Vec<f64> {
    let n = time.len();
    if n < 2 || smooth_ms <= 0.0 {
        return gamma.to_vec();
    }
    let dt = (time[n - 1] - time[0]) / (n - 1) as f64;
    let half_window = ((smooth_ms * 1e-3 / dt).round() as usize).max(MIN_SMOOTH_SAMPLES);
    let mut g = local_polynomial(time, gamma, half_window, 3).0;
    g[0] = gamma[0];
    g
}

/// The variance of the measurement noise of `raw`, from its difference to
/// `smoothed` (by [`smoothed_strain`], whose [`centre_weight`] is `w0`):
/// the smaller of the mean square and
/// the robust scale (1.4826 × the median absolute difference)² — the first
/// is right for the uniform noise of a quantised channel, the second
/// ignores spikes and sharp bends — corrected for the share 1 − w₀ of the
/// noise that the smoother leaves in the difference (w₀ its weight on the
/// centre sample). White sensor noise and the steps of a quantised channel both
/// show here; so would curvature the window cannot follow, which a stand's
/// displacement does not have on a few milliseconds. 0 without smoothing.
pub fn noise_variance(raw: &[f64], smoothed: &[f64], w0: f64) -> f64 {
    if raw.len() < 2 * MIN_SMOOTH_SAMPLES + 1 || w0 >= 1.0 {
        return 0.0;
    }
    let mut diff: Vec<f64> = raw.iter().zip(smoothed).skip(1).map(|(r, s)| (r - s).abs()).collect();
    let mean_square = diff.iter().map(|d| d * d).sum::<f64>() / diff.len() as f64;
    diff.sort_by(f64::total_cmp);
    let mad = diff[diff.len() / 2];
    (1.4826 * mad).powi(2).min(mean_square) / (1.0 - w0.min(0.95))
}

/// The smoother's weight on the centre sample (its response to an impulse
/// mid-record): the share of white noise variance left in a smoothed value.
/// 1 without smoothing (then [`noise_variance`] reads no noise).
pub fn centre_weight(time: &[f64], smooth_ms: f64) -> f64 {
    let n = time.len();
    if n < 2 * MIN_SMOOTH_SAMPLES + 1 || smooth_ms <= 0.0 {
        return 1.0;
    }
    let mid = n / 2;
    let impulse: Vec<f64> = (0..n).map(|k| if k == mid { 1.0 } else { 0.0 }).collect();
    smoothed_strain(time, &impulse, smooth_ms)[mid].clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    /// White noise of sd 2e-3 on a smooth stroke (2 kHz, 1 Hz): the
    /// estimate is within 10 % of 4e-6. The MAD-based variance of 4000
    /// normals has a relative sd of about 2.7 %; 10 % is more than three
    /// of them. A quantised channel (step q) gives q²/12 within 20 % (the
    /// steps of a slow sinusoid are not quite uniform noise).
    #[test]
    fn noise_variance_is_read_off_the_record() {
        let mut rng = crate::rng::stream(11, &[]);
        let t: Vec<f64> = (0..4000).map(|k| k as f64 / 2000.0).collect();
        let clean: Vec<f64> = t.iter().map(|t| 5.0 * (std::f64::consts::TAU * t).sin()).collect();
        let noisy: Vec<f64> = clean
            .iter()
            .map(|c| c + 2e-3 * rng.sample::<f64, _>(rand_distr::StandardNormal))
            .collect();
        let w0 = centre_weight(&t, 2.0);
        let v = noise_variance(&noisy, &smoothed_strain(&t, &noisy, 2.0), w0);
        assert!((v / 4e-6 - 1.0).abs() < 0.1, "{v}");
        let q = 0.03;
        let steps: Vec<f64> = clean.iter().map(|c| (c / q).round() * q).collect();
        let v = noise_variance(&steps, &smoothed_strain(&t, &steps, 2.0), w0);
        assert!((v / (q * q / 12.0) - 1.0).abs() < 0.2, "{v} against {}", q * q / 12.0);
        assert_eq!(noise_variance(&clean, &clean, centre_weight(&t, 0.0)), 0.0);
    }

    #[test]
    fn derivative_is_exact_on_lines_and_close_on_smooth_curves() {
        let t: Vec<f64> =
            (0..200).map(|k| 0.001 * k as f64 + 0.3 * (k as f64).sqrt() * 1e-4).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * t - 1.0).collect();
        for d in local_polynomial(&t, &y, 5, 1).1 {
            assert!((d - 3.0).abs() < 1e-9);
        }
        // sin: the symmetric window's bias is O(h²); h = 5 ms, ω = 2π
        let y: Vec<f64> = t.iter().map(|t| (std::f64::consts::TAU * t).sin()).collect();
        let d = local_polynomial(&t, &y, 5, 1).1;
        for k in 5..195 {
            let exact = std::f64::consts::TAU * (std::f64::consts::TAU * t[k]).cos();
            assert!((d[k] - exact).abs() < 2e-3 * std::f64::consts::TAU, "{k}");
        }
    }

    #[test]
    fn cubic_fits_are_exact_on_cubics() {
        let t: Vec<f64> = (0..50).map(|k| 0.01 * k as f64 + 1e-4 * ((k * 7) % 3) as f64).collect();
        let y: Vec<f64> = t.iter().map(|t| 2.0 - t + 3.0 * t * t - 5.0 * t * t * t).collect();
        let (v, d) = local_polynomial(&t, &y, 4, 3);
        for k in 0..50 {
            let tk = t[k];
            assert!((v[k] - y[k]).abs() < 1e-9);
            assert!((d[k] - (-1.0 + 6.0 * tk - 15.0 * tk * tk)).abs() < 1e-7, "{k}");
        }
    }
}
