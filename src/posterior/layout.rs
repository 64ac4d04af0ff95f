//! Where each quantity sits in a point of the posterior, and the map
//! between the sampler's unconstrained coordinates and SI units.
//!
//! A point is θ (the parameter model's coordinates), then one noise scale σ
//! per run, then (AR(1) noise only) one lag-one correlation ρ per run. The
//! sampler walks in ln θ, ln σ and atanh ρ; outputs use θ, σ, ρ under the
//! names `G` … (or a law's), `sigma_<run>`, `rho_<run>`.

use std::ops::Range;

use super::likelihood::NoiseModel;
use super::parameters::ParameterModel;

/// The layout of a posterior's points.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    /// Every coordinate's name, in order.
    pub names: Vec<String>,
    /// The run ids, in the order of their σ (and ρ).
    pub runs: Vec<String>,
    pub theta: Range<usize>,
    pub sigma: Range<usize>,
    /// Empty unless the noise is AR(1).
    pub rho: Range<usize>,
}

impl Layout {
    pub fn new(model: &ParameterModel, runs: &[String], noise: NoiseModel) -> Layout {
        let nt = model.names().len();
        let nr = runs.len();
        let rho_len = if noise == NoiseModel::Ar1 { nr } else { 0 };
        let mut names: Vec<String> = model.names().iter().map(|s| s.to_string()).collect();
        names.extend(runs.iter().map(|r| format!("sigma_{r}")));
        names.extend(runs.iter().take(rho_len).map(|r| format!("rho_{r}")));
        Layout {
            names,
            runs: runs.to_vec(),
            theta: 0..nt,
            sigma: nt..nt + nr,
            rho: nt + nr..nt + nr + rho_len,
        }
    }

    pub fn dim(&self) -> usize {
        self.names.len()
    }

    /// The names of θ.
    pub fn theta_names(&self) -> &[String] {
        &self.names[self.theta.clone()]
    }

    /// Whether `name` is a noise coordinate (σ or ρ of a run).
    pub fn is_noise(&self, name: &str) -> bool {
        self.names.iter().position(|n| n == name).is_some_and(|i| !self.theta.contains(&i))
    }

    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The position of run `id` among the runs.
    pub fn run_index(&self, id: &str) -> Option<usize> {
        self.runs.iter().position(|r| r == id)
    }

    /// A point in SI units (θ, σ, ρ) from unconstrained coordinates.
    pub fn to_si(&self, x: &[f64]) -> Vec<f64> {
        x.iter().enumerate().map(|(i, v)| if self.rho.contains(&i) { v.tanh() } else { v.exp() }).collect()
    }

    /// The unconstrained coordinates of a point in SI units (inverse of [`Self::to_si`]).
    pub fn from_si(&self, si: &[f64]) -> Vec<f64> {
        si.iter().enumerate().map(|(i, v)| if self.rho.contains(&i) { v.atanh() } else { v.ln() }).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_ranges_and_maps_agree() {
        let runs = vec!["a".to_string(), "b".to_string()];
        let l = Layout::new(&ParameterModel::PerCurrent, &runs, NoiseModel::Ar1);
        assert_eq!(l.dim(), 11);
        assert_eq!(&l.names[7..], ["sigma_a", "sigma_b", "rho_a", "rho_b"]);
        assert_eq!((l.sigma.clone(), l.rho.clone()), (7..9, 9..11));
        assert!(l.is_noise("rho_b") && !l.is_noise("G") && !l.is_noise("nope"));
        let x: Vec<f64> = (0..11).map(|i| 0.1 * i as f64 - 0.5).collect();
        let si = l.to_si(&x);
        assert!((si[0] - (-0.5f64).exp()).abs() < 1e-15 && (si[10] - 0.5f64.tanh()).abs() < 1e-15);
        for (a, b) in l.from_si(&si).iter().zip(&x) {
            assert!((a - b).abs() < 1e-12);
        }
        let g = Layout::new(&ParameterModel::CurrentLaw { reference_a: 1.0 }, &runs, NoiseModel::Gaussian);
        assert_eq!((g.dim(), g.rho.len()), (11, 0));
    }
}
