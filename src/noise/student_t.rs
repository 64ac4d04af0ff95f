//! Independent Student-t residuals with ν degrees of freedom (fixed, from
//! the settings) and one unknown scale s per run: robust to outliers. The
//! measured strain is taken as exact.

use std::sync::Arc;

use rand::{Rng, RngExt};
use rand_distr::{StandardNormal, StudentT as StudentTDistribution};

use super::model::{
    log_uniform, log_uniform_normaliser, rms, student_t_log_constant, NoiseModel, NoiseOptions,
    NoiseSimulator, NoiseValues, Parameter, Pointwise, Pool, Profile, RunScorer, Scales, Transform,
};
use crate::data::RunData;
use crate::model::LANES;

const PARAMETERS: &[Parameter] = &[Parameter {
    name: "sigma",
    unit: "Pa",
    transform: Transform::Log,
    pool: Pool::RootMeanSquare,
}];

#[derive(Clone, Debug)]
pub struct StudentT {
    sigma_bounds: (f64, f64),
    nu: f64,
    /// ln Γ((ν+1)/2) − ln Γ(ν/2) − ½ ln(νπ).
    log_constant: f64,
}

impl StudentT {
    pub fn new(options: &NoiseOptions) -> Self {
        let nu = options.student_nu;
        StudentT {
            sigma_bounds: options.sigma_bounds,
            nu,
            log_constant: student_t_log_constant(nu),
        }
    }

    /// ln t_ν(r; 0, s) with ν s² written as `nu_s2`.
    fn ln_pdf(&self, r: f64, sigma: f64, nu_s2: f64) -> f64 {
        self.log_constant - sigma.ln() - 0.5 * (self.nu + 1.0) * (r * r / nu_s2).ln_1p()
    }
}

impl NoiseModel for StudentT {
    fn parameters(&self) -> &'static [Parameter] {
        PARAMETERS
    }

    fn check(&self) -> Result<(), String> {
        if !(self.nu > 0.0) {
            return Err("student_nu must be positive".into());
        }
        Ok(())
    }

    fn log_prior(&self, _run: &RunData, coordinates: &[f64]) -> f64 {
        log_uniform(coordinates[0], self.sigma_bounds)
    }

    fn log_prior_normaliser(&self, _run: &RunData) -> f64 {
        log_uniform_normaliser(self.sigma_bounds)
    }

    /// The scorer's Student-t densities carry their constant.
    fn log_likelihood_constant(&self, _run: &RunData) -> f64 {
        0.0
    }

    fn laplace_sd(&self, run: &RunData, _coordinates: &NoiseValues) -> NoiseValues {
        [1.0 / (2.0 * run.compared().max(1) as f64).sqrt(), 0.0, 0.0, 0.0]
    }

    fn scorer<'a>(
        &'a self,
        _run: &'a RunData,
        coordinates: &[NoiseValues; LANES],
    ) -> Box<dyn RunScorer + 'a> {
        let log_sigma = coordinates.map(|c| c[0]);
        let inv_nu_s2 = log_sigma.map(|l| {
            let s = l.exp();
            1.0 / (self.nu * s * s)
        });
        Box::new(Scorer { model: self, n: 0.0, log_sigma, inv_nu_s2, log_t: [0.0; LANES] })
    }

    fn pointwise(
        &self,
        run: &RunData,
        model: &[f64],
        _stiffness: &[f64],
        values: &NoiseValues,
        rng: &mut dyn Rng,
    ) -> Pointwise {
        let n = run.time.len().min(model.len());
        let sigma = values[0];
        let sigma2 = sigma * sigma;
        let student = StudentTDistribution::new(self.nu).ok();
        let mut out = Pointwise::default();
        for k in 1..n {
            let res = run.tau[k] - model[k];
            let z: f64 = rng.sample(StandardNormal);
            let t = student.as_ref().map_or(z, |t| rng.sample(t));
            out.log_likelihood.push(self.ln_pdf(res, sigma, self.nu * sigma2));
            out.replicate.push(model[k] + sigma * t);
        }
        out
    }

    fn simulator(
        &self,
        _run: &RunData,
        draws: &[NoiseValues],
        replicates: usize,
    ) -> Box<dyn NoiseSimulator> {
        Box::new(Simulator {
            sigma: draws.iter().map(|v| v[0]).collect(),
            replicates,
            student: StudentTDistribution::new(self.nu).ok(),
        })
    }

    fn marginal_ln_pdf(
        &self,
        _run: &RunData,
        r: f64,
        _stiffness: f64,
        values: &NoiseValues,
    ) -> f64 {
        let sigma = values[0];
        self.ln_pdf(r, sigma, self.nu * sigma * sigma)
    }

    /// The scale at the RMS residual: a start, not the t's maximum.
    fn profile(&self, _run: &RunData, residuals: &[f64], _g: f64) -> Profile {
        let ms = rms(residuals).max(1e-9).powi(2);
        let (lo, hi) = self.sigma_bounds;
        let coordinate = rms(residuals).max(1e-9).clamp(lo, hi).ln();
        Profile {
            scale: ms.sqrt(),
            whitening: Arc::new(Scales(vec![ms.sqrt(); residuals.len()])),
            coordinates: [coordinate, 0.0, 0.0, 0.0],
        }
    }

    /// The likelihood at the scale that maximises it, found by
    /// golden-section search on ln s around the RMS residual.
    fn profile_log_likelihood(&self, _run: &RunData, r: &[f64]) -> f64 {
        let n = r.len() as f64;
        let sum_sq: f64 = r.iter().map(|v| v * v).sum();
        let nu = self.nu;
        let ll = |log_s: f64| {
            let s2 = (2.0 * log_s).exp();
            -n * log_s
                - 0.5 * (nu + 1.0) * r.iter().map(|v| (v * v / (nu * s2)).ln_1p()).sum::<f64>()
        };
        let centre = 0.5 * (sum_sq / n).ln();
        ll(crate::fit::golden_section(|log_s| -ll(log_s), centre - 3.0, centre + 1.0, 60))
    }
}

/// Σ ln(1 + r²/(ν s²)) per lane.
struct Scorer<'a> {
    model: &'a StudentT,
    n: f64,
    log_sigma: [f64; LANES],
    inv_nu_s2: [f64; LANES],
    log_t: [f64; LANES],
}

impl RunScorer for Scorer<'_> {
    #[inline]
    fn push(&mut self, _k: usize, residual: &[f64; LANES], _stiffness: &[f64; LANES]) {
        self.n += 1.0;
        for l in 0..LANES {
            let r = residual[l];
            self.log_t[l] += (r * r * self.inv_nu_s2[l]).ln_1p();
        }
    }

    fn finish(&mut self) -> [f64; LANES] {
        let (n, nu) = (self.n, self.model.nu);
        std::array::from_fn(|l| {
            n * self.model.log_constant - n * self.log_sigma[l] - 0.5 * (nu + 1.0) * self.log_t[l]
        })
    }
}

struct Simulator {
    /// The scale of each draw.
    sigma: Vec<f64>,
    replicates: usize,
    student: Option<StudentTDistribution<f64>>,
}

impl NoiseSimulator for Simulator {
    fn next(&mut self, _stiffness: &[f64], rng: &mut dyn Rng, out: &mut [f64]) {
        for (d, sigma) in self.sigma.iter().enumerate() {
            for e in &mut out[d * self.replicates..(d + 1) * self.replicates] {
                let z: f64 = match &self.student {
                    Some(t) => rng.sample(t),
                    None => rng.sample(StandardNormal),
                };
                *e = sigma * z;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{pointwise_sum, run, scored};
    use super::*;
    use statrs::distribution::{Continuous, StudentsT};

    /// The scorer and the pointwise terms: the sum of statrs' Student-t
    /// log-densities with location 0, scale s and ν degrees of freedom.
    #[test]
    fn matches_statrs() {
        let (run, path) = run(1e-8);
        let (s, nu): (f64, f64) = (180.0, 5.0);
        let t = StudentsT::new(0.0, s, nu).unwrap();
        let direct: f64 = (1..run.time.len()).map(|k| t.ln_pdf(run.tau[k] - path[k])).sum();
        let m = StudentT::new(&NoiseOptions { student_nu: nu, ..NoiseOptions::default() });
        let ll = scored(&m, &run, &path, [s.ln(), 0.0, 0.0, 0.0], 5e6);
        assert!((ll - direct).abs() < 1e-9 * direct.abs(), "{ll} vs {direct}");
        let sum = pointwise_sum(&m, &run, &path, [s, 0.0, 0.0, 0.0], 5e6);
        assert!((sum - direct).abs() < 1e-9 * direct.abs(), "{sum} vs {direct}");
    }

    /// ν → ∞: the profile is the Gaussian's at its optimum, −n ln s − n/2.
    #[test]
    fn the_profile_tends_to_the_gaussians() {
        let r: Vec<f64> = (0..200).map(|k| ((k * 7919) % 13) as f64 - 6.0).collect();
        let n = r.len() as f64;
        let g = -0.5 * n * (r.iter().map(|v| v * v).sum::<f64>() / n).ln();
        let (run, _) = super::super::testing::run(0.0);
        let t = StudentT::new(&NoiseOptions { student_nu: 1e6, ..NoiseOptions::default() })
            .profile_log_likelihood(&run, &r);
        assert!((t - (g - 0.5 * n)).abs() < 1e-3 * n, "{t} vs {}", g - 0.5 * n);
    }
}
