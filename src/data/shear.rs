//! Shear stress and strain from a stand record (paper eq. 1) and the
//! inelastic strain and its rate (eqs. 1–2).

use serde::{Deserialize, Serialize};

use super::smooth::local_polynomial;
use super::table::Record;

/// Damper geometry that turns force and displacement into stress and strain.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    /// Working interface area A (m²).
    pub area_m2: f64,
    /// Gap size h (m).
    pub gap_m: f64,
}

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
            gamma: rec.displacement.iter().map(|x| (x - x0) / geometry.gap_m).collect(),
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
            strain: self.gamma.iter().zip(&self.tau).map(|(gm, t)| gm - t / g).collect(),
            rate: gamma_rate.iter().zip(&tau_rate).map(|(gd, td)| gd - td / g).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shear_from_record_uses_geometry() {
        let rec = Record {
            time: vec![0.0, 0.1, 0.2],
            displacement: vec![0.01, 0.011, 0.013],
            force: vec![0.0, 50.0, 100.0],
            current: None,
        };
        let g = Geometry { area_m2: 0.05, gap_m: 1e-3 };
        let s = Shear::from_record(&rec, &g, None);
        assert_eq!(s.tau, vec![0.0, 1000.0, 2000.0]);
        assert!((s.gamma[2] - 3.0).abs() < 1e-12);
        assert_eq!(s.gamma[0], 0.0);
        let ie = s.inelastic(1.0e6, 2);
        assert!((ie.strain[2] - (3.0 - 2000.0 / 1.0e6)).abs() < 1e-12);
    }
}
