//! Where each quantity sits in a point of the posterior, and the map
//! between the sampler's unconstrained coordinates and SI units.
//!
//! A point is θ (the parameter model's coordinates), then the terms of
//! [`ModelTerms`] that are on (the gas-spring stiffness, a force offset per
//! run), then one noise scale σ per run, then (AR(1) noise only) one lag-one
//! correlation ρ per run. The sampler walks in ln θ (or
//! [`Coordinates::SaturationShare`]), the terms as they are, ln σ and
//! atanh ρ; outputs use θ, the terms, σ, ρ under the names `G` … (or a
//! law's), `gas_spring_n_per_m`, `force_offset_n_<run>`, `sigma_<run>`,
//! `rho_<run>`.

use std::ops::Range;

use serde::{Deserialize, Serialize};

use super::likelihood::NoiseModel;
use super::parameters::ParameterModel;
use super::terms::ModelTerms;

/// The coordinates the sampler walks θ in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Coordinates {
    /// ln θ.
    Log,
    /// ln θ, but R1 and D1 as ln(R1 + D1), the saturated stress the records
    /// pin down, and logit of D1's share of it, ln(D1/R1), which they may
    /// not: the ridge R1 + D1 ≈ const, curved in ln R1 and ln D1, becomes
    /// straight. The map from (ln R1, ln D1) has Jacobian 1, so densities of
    /// ln θ carry over unchanged.
    SaturationShare,
}

/// The layout of a posterior's points.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    /// Every coordinate's name, in order.
    pub names: Vec<String>,
    /// The run ids, in the order of their σ (and ρ).
    pub runs: Vec<String>,
    pub theta: Range<usize>,
    /// The gas-spring stiffness (empty unless that term is on).
    pub spring: Range<usize>,
    /// A force offset per run (empty unless that term is on).
    pub offset: Range<usize>,
    /// Everything before the noise: θ and the terms, which the MAP search
    /// fits while it profiles the noise out.
    pub fitted: Range<usize>,
    pub sigma: Range<usize>,
    /// Empty unless the noise is AR(1).
    pub rho: Range<usize>,
    /// Where R1 and D1 sit in θ when they are walked as saturation and share.
    share: Option<(usize, usize)>,
}

/// ln(1 + eᵛ), without overflow.
fn softplus(v: f64) -> f64 {
    v.max(0.0) + (-v.abs()).exp().ln_1p()
}

impl Layout {
    pub fn new(model: &ParameterModel, runs: &[String], noise: NoiseModel, coordinates: Coordinates, terms: &ModelTerms) -> Layout {
        let nt = model.names().len();
        let nr = runs.len();
        let ns = usize::from(terms.gas_spring);
        let no = if terms.force_offset { nr } else { 0 };
        let nf = nt + ns + no;
        let rho_len = if noise == NoiseModel::Ar1 { nr } else { 0 };
        let mut names: Vec<String> = model.names().iter().map(|s| s.to_string()).collect();
        names.extend(std::iter::repeat_n("gas_spring_n_per_m".to_string(), ns));
        names.extend(runs.iter().take(no).map(|r| format!("force_offset_n_{r}")));
        names.extend(runs.iter().map(|r| format!("sigma_{r}")));
        names.extend(runs.iter().take(rho_len).map(|r| format!("rho_{r}")));
        Layout {
            names,
            runs: runs.to_vec(),
            theta: 0..nt,
            spring: nt..nt + ns,
            offset: nt + ns..nf,
            fitted: 0..nf,
            sigma: nf..nf + nr,
            rho: nf + nr..nf + nr + rho_len,
            share: match coordinates {
                Coordinates::Log => None,
                Coordinates::SaturationShare => Some((model.index("R1"), model.index("D1"))),
            },
        }
    }

    /// Names of the sampler's coordinates, for messages.
    pub fn coordinate_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| if self.rho.contains(&i) { format!("atanh {n}") } else if self.linear(i) { n.clone() } else { format!("ln {n}") })
            .collect();
        if let Some((r1, d1)) = self.share {
            names[r1] = "ln (R1 + D1)".into();
            names[d1] = "ln (D1 / R1)".into();
        }
        names
    }

    /// ln θ at the sampler's coordinates `x` (θ first).
    pub fn log_theta(&self, x: &[f64]) -> Vec<f64> {
        let mut log = x[self.theta.clone()].to_vec();
        if let Some((r1, d1)) = self.share {
            let (u, v) = (x[r1], x[d1]);
            log[r1] = u - softplus(v);
            log[d1] = u - softplus(-v);
        }
        log
    }

    /// The sampler's θ coordinates of ln θ (inverse of [`Self::log_theta`]).
    pub fn theta_coordinates(&self, log_theta: &[f64]) -> Vec<f64> {
        let mut x = log_theta.to_vec();
        if let Some((r1, d1)) = self.share {
            let (a, b) = (log_theta[r1], log_theta[d1]);
            x[r1] = a.max(b) + (-(a - b).abs()).exp().ln_1p();
            x[d1] = b - a;
        }
        x
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
        self.names.iter().position(|n| n == name).is_some_and(|i| i >= self.fitted.end)
    }

    /// Whether coordinate `i` is walked as it is (the terms), not through a
    /// logarithm.
    fn linear(&self, i: usize) -> bool {
        self.spring.contains(&i) || self.offset.contains(&i)
    }

    /// The gas-spring stiffness (N/m) and the force offset of run `j` (N) at
    /// `x` (sampler coordinates or SI: the terms are the same in both); 0
    /// for a term that is off.
    pub fn terms(&self, x: &[f64], j: usize) -> (f64, f64) {
        let spring = if self.spring.is_empty() { 0.0 } else { x[self.spring.start] };
        let offset = if self.offset.is_empty() { 0.0 } else { x[self.offset.start + j] };
        (spring, offset)
    }

    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The position of run `id` among the runs.
    pub fn run_index(&self, id: &str) -> Option<usize> {
        self.runs.iter().position(|r| r == id)
    }

    /// A point in SI units (θ, σ, ρ) from the sampler's coordinates.
    pub fn to_si(&self, x: &[f64]) -> Vec<f64> {
        let theta = self.log_theta(x).into_iter().map(f64::exp);
        let rest = x.iter().enumerate().skip(self.theta.end).map(|(i, v)| {
            if self.rho.contains(&i) {
                v.tanh()
            } else if self.linear(i) {
                *v
            } else {
                v.exp()
            }
        });
        theta.chain(rest).collect()
    }

    /// The sampler's coordinates of a point in SI units (inverse of [`Self::to_si`]).
    pub fn from_si(&self, si: &[f64]) -> Vec<f64> {
        let log: Vec<f64> = si[self.theta.clone()].iter().map(|v| v.ln()).collect();
        let rest = si.iter().enumerate().skip(self.theta.end).map(|(i, v)| {
            if self.rho.contains(&i) {
                v.atanh()
            } else if self.linear(i) {
                *v
            } else {
                v.ln()
            }
        });
        self.theta_coordinates(&log).into_iter().chain(rest).collect()
    }
}

/// The unit of a coordinate of the posterior, by its name.
pub fn unit_of(name: &str) -> &'static str {
    if let Some(i) = crate::model::PARAM_NAMES.iter().position(|p| *p == name) {
        return crate::model::PARAM_UNITS[i];
    }
    match name {
        "G_field" | "G_zero" => "Pa",
        "saturation_current_a" => "A",
        "gas_spring_n_per_m" => "N/m",
        _ if name.starts_with("sigma_") => "Pa",
        _ if name.starts_with("force_offset_n_") => "N",
        _ if name.starts_with("rho_") => "1",
        _ => "",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_ranges_and_maps_agree() {
        let runs = vec!["a".to_string(), "b".to_string()];
        let l = Layout::new(&ParameterModel::PerCurrent, &runs, NoiseModel::Ar1, Coordinates::Log, &ModelTerms::default());
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
        let g = Layout::new(&ParameterModel::CurrentLaw { reference_a: 1.0 }, &runs, NoiseModel::Gaussian, Coordinates::Log, &ModelTerms::default());
        assert_eq!((g.dim(), g.rho.len()), (11, 0));
        let terms = ModelTerms { force_offset: true, gas_spring: true, ..ModelTerms::default() };
        let t = Layout::new(&ParameterModel::PerCurrent, &runs, NoiseModel::Gaussian, Coordinates::Log, &terms);
        assert_eq!(&t.names[7..10], ["gas_spring_n_per_m", "force_offset_n_a", "force_offset_n_b"]);
        assert_eq!((t.fitted.clone(), t.sigma.clone()), (0..10, 10..12));
        let x: Vec<f64> = (0..12).map(|i| i as f64 - 3.0).collect();
        assert_eq!(t.terms(&x, 1), (4.0, 6.0));
        assert_eq!((t.to_si(&x)[8], t.from_si(&t.to_si(&x))[9]), (5.0, 6.0));
    }

    /// Saturation-share coordinates: R1 + D1 and ln(D1/R1) at their places,
    /// the map inverts, and its Jacobian determinant is 1 (finite
    /// differences), so densities of ln θ need no correction.
    #[test]
    fn saturation_share_coordinates_invert_with_unit_jacobian() {
        let runs = vec!["a".to_string()];
        let l = Layout::new(&ParameterModel::PerCurrent, &runs, NoiseModel::Gaussian, Coordinates::SaturationShare, &ModelTerms::default());
        let si = [2e5, 1.2e5, 1.6e5, 3e4, 4e-6, 2e-4, 1.2, 300.0];
        let x = l.from_si(&si);
        assert!((x[2] - (1.9e5f64).ln()).abs() < 1e-12 && (x[3] - (3e4f64 / 1.6e5).ln()).abs() < 1e-12);
        for (a, b) in l.to_si(&x).iter().zip(&si) {
            assert!((a / b - 1.0).abs() < 1e-12, "{a} vs {b}");
        }
        let h = 1e-6;
        let at = |du: f64, dv: f64| {
            let mut y = x.clone();
            y[2] += du;
            y[3] += dv;
            let lt = l.log_theta(&y);
            (lt[2], lt[3])
        };
        let (a0, b0) = at(0.0, 0.0);
        let (au, bu) = at(h, 0.0);
        let (av, bv) = at(0.0, h);
        let det = ((au - a0) * (bv - b0) - (av - a0) * (bu - b0)) / (h * h);
        assert!((det - 1.0).abs() < 1e-6, "{det}");
        assert_eq!(l.coordinate_names()[3], "ln (D1 / R1)");
    }
}
