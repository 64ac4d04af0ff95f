//! AR(1) residuals: r_1 ~ N(0, σ²/(1 − ρ²)), r_k − ρ r_{k−1} ~ N(0, σ²),
//! with one innovation sd σ and one lag-one correlation ρ per run (uniform
//! on (−1, 1), |ρ| < 0.999 keeping the process stationary). The measured
//! strain is taken as exact.

use std::sync::Arc;

use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use super::model::{
    log_uniform, log_uniform_normaliser, normal_ln_pdf, rms, NoiseModel, NoiseOptions,
    NoiseSimulator, NoiseValues, Parameter, Pointwise, Pool, Profile, RunScorer, Scales, Transform,
};
use crate::data::RunData;
use crate::model::LANES;

const PARAMETERS: &[Parameter] = &[
    Parameter { name: "sigma", unit: "Pa", transform: Transform::Log, pool: Pool::RootMeanSquare },
    Parameter { name: "rho", unit: "1", transform: Transform::Atanh, pool: Pool::Mean },
];

#[derive(Clone, Debug)]
pub struct Ar1 {
    sigma_bounds: (f64, f64),
}

impl Ar1 {
    pub fn new(options: &NoiseOptions) -> Self {
        Ar1 { sigma_bounds: options.sigma_bounds }
    }
}

/// The stationary sd σ/√(1 − ρ²).
fn stationary_sd(sigma: f64, rho: f64) -> f64 {
    sigma / (1.0 - rho * rho).max(1e-12).sqrt()
}

impl NoiseModel for Ar1 {
    fn parameters(&self) -> &'static [Parameter] {
        PARAMETERS
    }

    fn log_prior(&self, _run: &RunData, coordinates: &[f64]) -> f64 {
        if log_uniform(coordinates[0], self.sigma_bounds) == f64::NEG_INFINITY {
            return f64::NEG_INFINITY;
        }
        let rho = coordinates[1].tanh();
        if !(rho.abs() < 0.999) {
            return f64::NEG_INFINITY;
        }
        // uniform ρ: the Jacobian of ρ = tanh z
        (1.0 - rho * rho).ln()
    }

    /// σ log-uniform, ρ uniform on (−0.999, 0.999).
    fn log_prior_normaliser(&self, _run: &RunData) -> f64 {
        log_uniform_normaliser(self.sigma_bounds) + 1.998f64.ln()
    }

    fn laplace_sd(&self, run: &RunData, _coordinates: &NoiseValues) -> NoiseValues {
        let n = run.compared().max(1) as f64;
        [1.0 / (2.0 * n).sqrt(), 1.0 / n.sqrt(), 0.0, 0.0]
    }

    fn models_memory(&self) -> bool {
        true
    }

    fn scorer<'a>(
        &'a self,
        _run: &'a RunData,
        coordinates: &[NoiseValues; LANES],
    ) -> Box<dyn RunScorer + 'a> {
        Box::new(Scorer {
            n: 0.0,
            log_sigma: coordinates.map(|c| c[0]),
            rho: coordinates.map(|c| c[1].tanh()),
            sum_sq: [0.0; LANES],
            first: [0.0; LANES],
            lag_cross: [0.0; LANES],
            lag_sq: [0.0; LANES],
            prev: [0.0; LANES],
        })
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
        let (sigma, rho) = (values[0], values[1]);
        let (mut prev_res, mut prev_noise) = (0.0f64, 0.0f64);
        let mut out = Pointwise::default();
        for k in 1..n {
            let res = run.tau[k] - model[k];
            let z: f64 = rng.sample(StandardNormal);
            let (ll, noise) = if k == 1 {
                let s = stationary_sd(sigma, rho);
                (normal_ln_pdf(res, s), s * z)
            } else {
                (normal_ln_pdf(res - rho * prev_res, sigma), rho * prev_noise + sigma * z)
            };
            prev_res = res;
            prev_noise = noise;
            out.log_likelihood.push(ll);
            out.replicate.push(model[k] + noise);
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
            draws: draws.iter().map(|v| (v[0], v[1])).collect(),
            replicates,
            state: Vec::new(),
        })
    }

    fn marginal_ln_pdf(
        &self,
        _run: &RunData,
        r: f64,
        _stiffness: f64,
        values: &NoiseValues,
    ) -> f64 {
        normal_ln_pdf(r, stationary_sd(values[0], values[1]))
    }

    /// ρ the residuals' lag-one correlation (within ±0.98), σ the innovation
    /// sd that gives their RMS; residuals weighed by their RMS.
    fn profile(&self, _run: &RunData, residuals: &[f64], _g: f64) -> Profile {
        let ms = rms(residuals).max(1e-9).powi(2);
        let s = rms(residuals).max(1e-9);
        let num: f64 = residuals.windows(2).map(|w| w[0] * w[1]).sum();
        let den: f64 = residuals.iter().map(|v| v * v).sum();
        let rho = (num / den).clamp(-0.98, 0.98);
        let (lo, hi) = self.sigma_bounds;
        Profile {
            scale: ms.sqrt(),
            whitening: Arc::new(Scales(vec![ms.sqrt(); residuals.len()])),
            coordinates: [(s * (1.0 - rho * rho).sqrt()).clamp(lo, hi).ln(), rho.atanh(), 0.0, 0.0],
        }
    }

    /// At the lag-one ρ and the innovation variance that maximise it.
    fn profile_log_likelihood(&self, _run: &RunData, r: &[f64]) -> f64 {
        let n = r.len() as f64;
        let sum_sq: f64 = r.iter().map(|v| v * v).sum();
        let cross: f64 = r.windows(2).map(|w| w[0] * w[1]).sum();
        let lag_sq: f64 = r[..r.len().saturating_sub(1)].iter().map(|v| v * v).sum();
        let rho = (cross / lag_sq).clamp(-0.99, 0.99);
        let innov = (sum_sq - r[0] * r[0]) - 2.0 * rho * cross
            + rho * rho * lag_sq
            + (1.0 - rho * rho) * r[0] * r[0];
        -0.5 * n * (innov / n).ln() + 0.5 * (1.0 - rho * rho).ln()
    }
}

/// Σ r², r_1, Σ r_k r_{k−1} and Σ r_{k−1}² per lane: the log-likelihood up
/// to −n/2 ln 2π.
struct Scorer {
    n: f64,
    log_sigma: [f64; LANES],
    rho: [f64; LANES],
    sum_sq: [f64; LANES],
    first: [f64; LANES],
    lag_cross: [f64; LANES],
    lag_sq: [f64; LANES],
    prev: [f64; LANES],
}

impl RunScorer for Scorer {
    #[inline]
    fn push(&mut self, k: usize, residual: &[f64; LANES], _stiffness: &[f64; LANES]) {
        self.n += 1.0;
        for l in 0..LANES {
            let r = residual[l];
            self.sum_sq[l] += r * r;
            if k == 1 {
                self.first[l] = r;
            } else {
                self.lag_cross[l] += r * self.prev[l];
                self.lag_sq[l] += self.prev[l] * self.prev[l];
            }
            self.prev[l] = r;
        }
    }

    fn finish(&mut self) -> [f64; LANES] {
        std::array::from_fn(|l| {
            let (log_sigma, rho, first) = (self.log_sigma[l], self.rho[l], self.first[l]);
            let sigma2 = (2.0 * log_sigma).exp();
            let tail_sq = self.sum_sq[l] - first * first;
            let innov = tail_sq - 2.0 * rho * self.lag_cross[l] + rho * rho * self.lag_sq[l];
            let one = 1.0 - rho * rho;
            -self.n * log_sigma + 0.5 * one.ln() - 0.5 * (one * first * first + innov) / sigma2
        })
    }
}

/// The chains from their stationary start.
struct Simulator {
    /// (σ, ρ) of each draw.
    draws: Vec<(f64, f64)>,
    replicates: usize,
    /// The last noise of every path (empty before the first sample).
    state: Vec<f64>,
}

impl NoiseSimulator for Simulator {
    fn next(&mut self, _stiffness: &[f64], rng: &mut dyn Rng, out: &mut [f64]) {
        for (d, &(sigma, rho)) in self.draws.iter().enumerate() {
            for p in d * self.replicates..(d + 1) * self.replicates {
                let z: f64 = rng.sample(StandardNormal);
                out[p] = match self.state.get(p) {
                    None => sigma * z / (1.0 - rho * rho).max(1e-12).sqrt(),
                    Some(e) => rho * e + sigma * z,
                };
            }
        }
        self.state.clear();
        self.state.extend_from_slice(out);
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{pointwise_sum, run, scored};
    use super::super::HALF_LN_2PI;
    use super::*;
    use nalgebra::{DMatrix, DVector};

    /// The scorer and the pointwise terms: the multivariate normal density
    /// of the whole residual vector with the stationary covariance
    /// σ² ρ^|i−j| / (1 − ρ²), by a Cholesky factorisation.
    #[test]
    fn matches_the_multivariate_normal() {
        let (run, path) = run(0.0);
        let r: Vec<f64> = (1..run.time.len()).map(|k| run.tau[k] - path[k]).collect();
        let n = r.len();
        let (sigma, rho): (f64, f64) = (220.0, 0.6);
        let cov = DMatrix::from_fn(n, n, |i, j| {
            sigma * sigma * rho.powi((i as i32 - j as i32).abs()) / (1.0 - rho * rho)
        });
        let chol = cov.cholesky().unwrap();
        let x = DVector::from_column_slice(&r);
        let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
        let direct = -0.5 * log_det - 0.5 * x.dot(&chol.solve(&x));
        let m = Ar1::new(&NoiseOptions::default());
        let ll = scored(&m, &run, &path, [sigma.ln(), rho.atanh(), 0.0, 0.0], 5e6);
        assert!((ll - direct).abs() < 1e-9 * direct.abs(), "{ll} vs {direct}");
        let sum =
            pointwise_sum(&m, &run, &path, [sigma, rho, 0.0, 0.0], 5e6) + n as f64 * HALF_LN_2PI;
        assert!((sum - direct).abs() < 1e-9 * direct.abs(), "{sum} vs {direct}");
    }

    /// A new record's noise keeps the stationary variance σ²/(1 − ρ²):
    /// over 20 000 chains the variance at sample 300 is within 4 % (its
    /// relative standard error is 1 %).
    #[test]
    fn simulated_noise_is_stationary() {
        let (run, _) = run(0.0);
        let m = Ar1::new(&NoiseOptions::default());
        let (sigma, rho) = (300.0f64, 0.8f64);
        let mut rng = crate::rng::stream(9, &[]);
        let chains = 20_000;
        let mut sim = m.simulator(&run, &[[sigma, rho, 0.0, 0.0]], chains);
        let mut e = vec![0.0; chains];
        for _ in 0..300 {
            sim.next(&[0.0], &mut rng, &mut e);
        }
        let var = e.iter().map(|v| v * v).sum::<f64>() / chains as f64;
        let expected = sigma * sigma / (1.0 - rho * rho);
        assert!((var / expected - 1.0).abs() < 0.04, "{var} vs {expected}");
    }
}
