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

/// γᴵ = γ − τ/G and γ̇ᴵ = γ̇ − τ̇/G (eq. 2 with dτ/dγ · γ̇ = τ̇), from smoothed
/// derivatives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Inelastic {
    pub strain: Vec<f64>,
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

    /// γᴵ and γ̇ᴵ for shear modulus `g`, with derivatives smoothed over
    /// `half_window` samples on each side (see [`smoothed_derivative`]).
    pub fn inelastic(&self, g: f64, half_window: usize) -> Inelastic {
        let gamma_rate = smoothed_derivative(&self.time, &self.gamma, half_window);
        let tau_rate = smoothed_derivative(&self.time, &self.tau, half_window);
        Inelastic {
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

/// dy/dt at every sample as the slope of a straight line fitted by least
/// squares to the samples within `half_window` on each side (fewer at the
/// ends). Unlike a plain difference it does not amplify sensor noise by
/// 1/Δt; it is exact for linear data and works on uneven time grids.
pub fn smoothed_derivative(t: &[f64], y: &[f64], half_window: usize) -> Vec<f64> {
    let n = t.len();
    let h = half_window.max(1);
    (0..n)
        .map(|k| {
            let lo = k.saturating_sub(h);
            let hi = (k + h + 1).min(n);
            let m = (hi - lo) as f64;
            let tm = t[lo..hi].iter().sum::<f64>() / m;
            let ym = y[lo..hi].iter().sum::<f64>() / m;
            let (mut sty, mut stt) = (0.0, 0.0);
            for i in lo..hi {
                let dt = t[i] - tm;
                sty += dt * (y[i] - ym);
                stt += dt * dt;
            }
            if stt > 0.0 {
                sty / stt
            } else {
                0.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_is_exact_on_lines_and_close_on_smooth_curves() {
        let t: Vec<f64> = (0..200).map(|k| 0.001 * k as f64 + 0.3 * (k as f64).sqrt() * 1e-4).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * t - 1.0).collect();
        for d in smoothed_derivative(&t, &y, 5) {
            assert!((d - 3.0).abs() < 1e-9);
        }
        // sin: the symmetric window's bias is O(h²); h = 5 ms, ω = 2π
        let y: Vec<f64> = t.iter().map(|t| (std::f64::consts::TAU * t).sin()).collect();
        let d = smoothed_derivative(&t, &y, 5);
        for k in 5..195 {
            let exact = std::f64::consts::TAU * (std::f64::consts::TAU * t[k]).cos();
            assert!((d[k] - exact).abs() < 2e-3 * std::f64::consts::TAU, "{k}");
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
        let ie = s.inelastic(1.0e6, 1);
        assert!((ie.strain[2] - (3.0 - 2000.0 / 1.0e6)).abs() < 1e-12);
    }
}
