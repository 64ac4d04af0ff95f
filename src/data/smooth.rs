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
pub fn local_polynomial(t: &[f64], y: &[f64], half_window: usize, degree: usize) -> (Vec<f64>, Vec<f64>) {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_is_exact_on_lines_and_close_on_smooth_curves() {
        let t: Vec<f64> = (0..200).map(|k| 0.001 * k as f64 + 0.3 * (k as f64).sqrt() * 1e-4).collect();
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
