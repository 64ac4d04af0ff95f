//! Shear stress and strain from a stand record (paper eq. 1) and the
//! inelastic strain and its rate (eqs. 1–2).

use super::campaign::Geometry;
use super::table::Record;

/// τ(t) and γ(t) of one record.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Shear {
    pub time: Vec<f64>,
    /// γ = Δx / h, Δx from the first sample (the fluid starts at rest).
    pub gamma: Vec<f64>,
    /// τ = F / A (Pa).
    pub tau: Vec<f64>,
    /// Stress of the model's initial state (Pa): 0 for a virgin fluid at rest.
    pub initial_tau: f64,
}

/// γᴵ = γ − τ/G and γ̇ᴵ = γ̇ − τ̇/G (eq. 2 with dτ/dγ · γ̇ = τ̇), from locally
/// fitted cubics (smoothed values and derivatives).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Inelastic {
    /// γᴵ from the raw samples.
    pub strain: Vec<f64>,
    /// γᴵ from the smoothed τ and γ.
    pub strain_smooth: Vec<f64>,
    /// Smoothed τ (Pa).
    pub tau_smooth: Vec<f64>,
    /// γ̇ᴵ (1/s).
    pub rate: Vec<f64>,
}

impl Shear {
    pub fn from_record(rec: &Record, geometry: &Geometry, initial_tau: Option<f64>) -> Shear {
        let x0 = rec.displacement.first().copied().unwrap_or(0.0);
        Shear {
            time: rec.time.clone(),
            gamma: rec
                .displacement
                .iter()
                .map(|x| (x - x0) / geometry.gap_m)
                .collect(),
            tau: rec.force.iter().map(|f| f / geometry.area_m2).collect(),
            initial_tau: initial_tau.unwrap_or(0.0),
        }
    }

    pub fn len(&self) -> usize {
        self.time.len()
    }

    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }

    /// γᴵ and γ̇ᴵ for shear modulus `g`, from local cubic fits over
    /// `half_window` samples on each side (see [`local_polynomial`]).
    pub fn inelastic(&self, g: f64, half_window: usize) -> Inelastic {
        let (gamma_s, gamma_rate) = local_polynomial(&self.time, &self.gamma, half_window, 3);
        let (tau_s, tau_rate) = local_polynomial(&self.time, &self.tau, half_window, 3);
        Inelastic {
            strain_smooth: gamma_s.iter().zip(&tau_s).map(|(gm, t)| gm - t / g).collect(),
            tau_smooth: tau_s,
            strain: self
                .gamma
                .iter()
                .zip(&self.tau)
                .map(|(gm, t)| gm - t / g)
                .collect(),
            rate: gamma_rate
                .iter()
                .zip(&tau_rate)
                .map(|(gd, td)| gd - td / g)
                .collect(),
        }
    }
}

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

    #[test]
    fn shear_from_record_uses_geometry() {
        let rec = Record {
            time: vec![0.0, 0.1, 0.2],
            displacement: vec![0.01, 0.011, 0.013],
            force: vec![0.0, 50.0, 100.0],
            current: None,
        };
        let g = Geometry {
            area_m2: 0.05,
            gap_m: 1e-3,
        };
        let s = Shear::from_record(&rec, &g, None);
        assert_eq!(s.tau, vec![0.0, 1000.0, 2000.0]);
        assert!((s.gamma[2] - 3.0).abs() < 1e-12);
        assert_eq!(s.gamma[0], 0.0);
        let ie = s.inelastic(1.0e6, 2);
        assert!((ie.strain[2] - (3.0 - 2000.0 / 1.0e6)).abs() < 1e-12);
    }
}
