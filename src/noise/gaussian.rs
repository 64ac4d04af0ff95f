//! Independent Gaussian residuals with one unknown scale σ per run, and, by
//! default, errors in variables: the measured strain is noisy too.
//!
//! The strain noise (variance s_γ², read off the record) reaches the stress
//! through the law's tangent stiffness S_k = dτ/dγ along the path (G when
//! elastic, near 0 in flow). Each residual then has variance
//! σ² + S_k² s_γ² (the long-run variance of the smoothed strain's error is
//! the raw one), and the error of the strain at each reversal, which the
//! whole branch after it shares, is one random offset per branch with
//! variance v = s_γ² × (the smoother's centre weight), integrated out
//! exactly: a rank-one term per branch (Sherman-Morrison), two sums per
//! branch. Without strain noise (or with `errors_in_variables = false`)
//! the residuals are N(0, σ²).

use std::sync::Arc;

use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use super::model::{
    log_uniform, log_uniform_normaliser, log_variance_term, normal_ln_pdf, rms, NoiseModel,
    NoiseOptions, NoiseSimulator, NoiseValues, Parameter, Pointwise, Pool, Profile, RunScorer,
    Scales, Transform, Whiten,
};
use crate::data::RunData;
use crate::model::{tangent_stiffness, LANES};

const PARAMETERS: &[Parameter] = &[Parameter {
    name: "sigma",
    unit: "Pa",
    transform: Transform::Log,
    pool: Pool::RootMeanSquare,
}];

#[derive(Clone, Debug)]
pub struct Gaussian {
    sigma_bounds: (f64, f64),
    errors_in_variables: bool,
}

impl Gaussian {
    pub fn new(options: &NoiseOptions) -> Self {
        Gaussian {
            sigma_bounds: options.sigma_bounds,
            errors_in_variables: options.errors_in_variables,
        }
    }

    /// The strain noise variance that reaches this run's stress (0: none).
    fn strain_var(&self, run: &RunData) -> f64 {
        if self.errors_in_variables {
            run.strain_noise_var
        } else {
            0.0
        }
    }
}

impl NoiseModel for Gaussian {
    fn parameters(&self) -> &'static [Parameter] {
        PARAMETERS
    }

    fn log_prior(&self, _run: &RunData, coordinates: &[f64]) -> f64 {
        log_uniform(coordinates[0], self.sigma_bounds)
    }

    fn log_prior_normaliser(&self, _run: &RunData) -> f64 {
        log_uniform_normaliser(self.sigma_bounds)
    }

    fn laplace_sd(&self, run: &RunData, _coordinates: &NoiseValues) -> NoiseValues {
        [1.0 / (2.0 * run.compared().max(1) as f64).sqrt(), 0.0, 0.0, 0.0]
    }

    fn uses_stiffness(&self, run: &RunData) -> bool {
        self.strain_var(run) > 0.0
    }

    fn scorer<'a>(
        &'a self,
        run: &'a RunData,
        coordinates: &[NoiseValues; LANES],
    ) -> Box<dyn RunScorer + 'a> {
        let log_sigma = coordinates.map(|c| c[0]);
        if self.uses_stiffness(run) {
            Box::new(EivScorer::new(run, log_sigma, self.strain_var(run)))
        } else {
            Box::new(Scorer { n: 0.0, log_sigma, sum_sq: [0.0; LANES] })
        }
    }

    fn pointwise(
        &self,
        run: &RunData,
        model: &[f64],
        stiffness: &[f64],
        values: &NoiseValues,
        rng: &mut dyn Rng,
    ) -> Pointwise {
        let n = run.time.len().min(model.len());
        let sigma = values[0];
        let sigma2 = sigma * sigma;
        let strain_var = self.strain_var(run);
        let v = strain_var * run.strain_smoothing_share;
        // the branch's information on its offset so far: Σ c²/d and Σ c r/d
        let (mut info, mut score, mut offset) = (0.0f64, 0.0f64, 0.0f64);
        let mut out = Pointwise {
            log_likelihood: Vec::with_capacity(n.saturating_sub(1)),
            replicate: Vec::with_capacity(n.saturating_sub(1)),
        };
        for k in 1..n {
            let res = run.tau[k] - model[k];
            let z: f64 = rng.sample(StandardNormal);
            let (ll, noise) = if strain_var > 0.0 {
                if k == 1 || run.reverses[k] {
                    // a new branch: nothing known of its offset yet; the
                    // replicate draws its own
                    (info, score) = (0.0, 0.0);
                    offset = v.sqrt() * rng.sample::<f64, _>(StandardNormal);
                }
                let c = stiffness[k];
                let d = sigma2 + c * c * strain_var;
                // the offset given the branch so far: mean vB/(1+vA), variance v/(1+vA)
                let shrink = 1.0 + v * info;
                let mean = c * v * score / shrink;
                let var = d + c * c * v / shrink;
                info += c * c / d;
                score += c * res / d;
                (normal_ln_pdf(res - mean, var.sqrt()), d.sqrt() * z + c * offset)
            } else {
                (normal_ln_pdf(res, sigma), sigma * z)
            };
            out.log_likelihood.push(ll);
            out.replicate.push(model[k] + noise);
        }
        out
    }

    fn simulator(
        &self,
        run: &RunData,
        draws: &[NoiseValues],
        replicates: usize,
    ) -> Box<dyn NoiseSimulator> {
        Box::new(Simulator {
            sigma: draws.iter().map(|v| v[0]).collect(),
            replicates,
            strain_var: self.strain_var(run),
        })
    }

    fn marginal_ln_pdf(&self, run: &RunData, r: f64, stiffness: f64, values: &NoiseValues) -> f64 {
        normal_ln_pdf(r, sd(values[0], stiffness, self.strain_var(run)))
    }

    /// σ = the RMS residual; with errors in variables σ² solving the
    /// likelihood's maximum Σ w_k = Σ r_k² w_k², w_k = 1/(σ² + a_k),
    /// a_k = S_k² s_γ², by the fixed point σ² ← σ² Σ r²w²/Σ w from the
    /// moment estimate (RMS² − mean a_k, at least a twentieth of RMS²).
    fn profile(&self, run: &RunData, residuals: &[f64], g: f64) -> Profile {
        let (lo, hi) = self.sigma_bounds;
        let ms = rms(residuals).max(1e-9).powi(2);
        let var = self.strain_var(run);
        let (sigma, whitening): (f64, Arc<dyn Whiten>) = if var <= 0.0 {
            (ms.sqrt(), Arc::new(Scales(vec![ms.sqrt(); residuals.len()])))
        } else {
            let a = strain_noise_of_residuals(run, residuals, g, var);
            let sigma2 = eiv_sigma2(residuals, &a, ms);
            (sigma2.sqrt(), Arc::new(StrainNoise { run: run.clone(), sigma2, var }))
        };
        // the most likely σ inside the prior's bounds
        let chosen = if self.errors_in_variables { sigma } else { rms(residuals).max(1e-9) };
        Profile { scale: sigma, whitening, coordinates: [chosen.clamp(lo, hi).ln(), 0.0, 0.0, 0.0] }
    }

    /// Under the log-uniform prior on σ the σ-marginal, up to a constant:
    /// −(n/2) ln Σr² (errors in variables left aside).
    fn profile_log_likelihood(&self, _run: &RunData, residuals: &[f64]) -> f64 {
        let n = residuals.len() as f64;
        let sum_sq: f64 = residuals.iter().map(|v| v * v).sum();
        -0.5 * n * (sum_sq / n).ln()
    }
}

/// Residuals of variance σ² + S_k² s_γ², the stiffness S_k along the
/// model stress they imply (errors in variables).
#[derive(Debug)]
struct StrainNoise {
    run: RunData,
    sigma2: f64,
    var: f64,
}

impl Whiten for StrainNoise {
    fn whiten(&self, residuals: &[f64], g: f64, white: &mut Vec<f64>, terms: &mut Vec<f64>) {
        let a = strain_noise_of_residuals(&self.run, residuals, g, self.var);
        white.extend(residuals.iter().zip(&a).map(|(v, a)| v / (self.sigma2 + a).sqrt()));
        terms.extend(a.iter().map(|a| log_variance_term(self.sigma2 + a, self.sigma2)));
    }
}

/// The sd of one residual: σ and the strain noise through the stiffness.
fn sd(sigma: f64, stiffness: f64, strain_var: f64) -> f64 {
    if strain_var > 0.0 {
        (sigma * sigma + stiffness * stiffness * strain_var).sqrt()
    } else {
        sigma
    }
}

/// a_k = S_k² s_γ² along the model stress τ_obs − r (with its terms), its
/// slope along the drive.
fn strain_noise_of_residuals(run: &RunData, residuals: &[f64], g: f64, var: f64) -> Vec<f64> {
    let fitted: Vec<f64> = residuals.iter().enumerate().map(|(i, v)| run.tau[i + 1] - v).collect();
    (0..residuals.len())
        .map(|i| {
            let prev = if i == 0 { run.initial_tau } else { fitted[i - 1] };
            let dg = run.gamma[i + 1] - run.gamma[i];
            let s = tangent_stiffness(fitted[i] - prev, dg, g);
            s * s * var
        })
        .collect()
}

/// The σ² that maximises the errors-in-variables likelihood of `r` with
/// strain noise `a`, by its fixed point from the moment estimate.
fn eiv_sigma2(r: &[f64], a: &[f64], ms: f64) -> f64 {
    let mean_a = a.iter().sum::<f64>() / a.len().max(1) as f64;
    let mut sigma2 = (ms - mean_a).max(0.05 * ms);
    for _ in 0..50 {
        let (mut sw, mut srw) = (0.0, 0.0);
        for (v, ak) in r.iter().zip(a) {
            let w = 1.0 / (sigma2 + ak);
            sw += w;
            srw += v * v * w * w;
        }
        let next = sigma2 * srw / sw;
        let done = (next / sigma2 - 1.0).abs() < 1e-6;
        sigma2 = next.max(1e-6 * ms);
        if done {
            break;
        }
    }
    sigma2
}

/// Σ r² per lane: the log-likelihood up to −n/2 ln 2π.
struct Scorer {
    n: f64,
    log_sigma: [f64; LANES],
    sum_sq: [f64; LANES],
}

impl RunScorer for Scorer {
    #[inline]
    fn push(&mut self, _k: usize, residual: &[f64; LANES], _stiffness: &[f64; LANES]) {
        self.n += 1.0;
        for (s, r) in self.sum_sq.iter_mut().zip(residual) {
            *s += r * r;
        }
    }

    fn finish(&mut self) -> [f64; LANES] {
        std::array::from_fn(|l| {
            let sigma2 = (2.0 * self.log_sigma[l]).exp();
            -self.n * self.log_sigma[l] - 0.5 * self.sum_sq[l] / sigma2
        })
    }
}

/// Errors in variables: Σ ln(1 + a_k/σ²), Σ r_k²/(σ² + a_k) and, per
/// branch, Σ r c/d and Σ c²/d for its shared offset.
///
/// The first sum is kept as a product of the factors 1 + a_k/σ² (each ≥ 1),
/// whose logarithm is taken only when it grows large and at the end: one
/// multiplication per sample and lane in place of a `ln_1p`, which cost as
/// much as the integration itself. (Rounding each factor loses at most
/// 1e-16 of ln(1 + x) per sample, far below what moves a posterior.)
struct EivScorer<'a> {
    run: &'a RunData,
    n: f64,
    log_sigma: [f64; LANES],
    /// 1/σ² per lane.
    precision: [f64; LANES],
    sigma2: [f64; LANES],
    strain_var: f64,
    /// Variance of the branch offset.
    v: f64,
    log_inflation: [f64; LANES],
    /// Π (1 + a_k/σ²) since the last time it went into `log_inflation`.
    inflation: [f64; LANES],
    weighted: [f64; LANES],
    branch: [(f64, f64); LANES],
}

/// The product of inflation factors is folded into its logarithm once it
/// exceeds this (far from overflow: one factor is at most 1 + G² s²/σ²).
const FOLD_INFLATION: f64 = 1e150;

impl<'a> EivScorer<'a> {
    fn new(run: &'a RunData, log_sigma: [f64; LANES], strain_var: f64) -> Self {
        let sigma2 = log_sigma.map(|l| {
            let s = l.exp();
            s * s
        });
        EivScorer {
            run,
            n: 0.0,
            log_sigma,
            precision: sigma2.map(|s| 1.0 / s),
            sigma2,
            strain_var,
            v: strain_var * run.strain_smoothing_share,
            log_inflation: [0.0; LANES],
            inflation: [1.0; LANES],
            weighted: [0.0; LANES],
            branch: [(0.0, 0.0); LANES],
        }
    }

    /// Integrates the branch's offset out (rank one, Sherman-Morrison).
    fn close(&mut self) {
        for l in 0..LANES {
            let (rc, cc) = self.branch[l];
            self.log_inflation[l] += (self.v * cc).ln_1p();
            self.weighted[l] -= self.v * rc * rc / (1.0 + self.v * cc);
            self.branch[l] = (0.0, 0.0);
        }
        self.fold();
    }

    /// Moves the product of inflation factors into their log-sum.
    fn fold(&mut self) {
        for l in 0..LANES {
            self.log_inflation[l] += self.inflation[l].ln();
            self.inflation[l] = 1.0;
        }
    }
}

impl RunScorer for EivScorer<'_> {
    #[inline]
    fn push(&mut self, k: usize, residual: &[f64; LANES], stiffness: &[f64; LANES]) {
        if self.run.reverses[k] {
            self.close();
        }
        self.n += 1.0;
        let mut largest = 0.0f64;
        for l in 0..LANES {
            let (res, c) = (residual[l], stiffness[l]);
            let a = c * c * self.strain_var;
            let inv_d = 1.0 / (self.sigma2[l] + a);
            self.inflation[l] *= 1.0 + a * self.precision[l];
            largest = largest.max(self.inflation[l]);
            self.weighted[l] += res * res * inv_d;
            self.branch[l].0 += res * c * inv_d;
            self.branch[l].1 += c * c * inv_d;
        }
        if largest > FOLD_INFLATION {
            self.fold();
        }
    }

    fn finish(&mut self) -> [f64; LANES] {
        self.close();
        std::array::from_fn(|l| {
            -self.n * self.log_sigma[l] - 0.5 * self.log_inflation[l] - 0.5 * self.weighted[l]
        })
    }
}

/// New records' noise: N(0, σ² + S_k² s_γ²) at each sample.
struct Simulator {
    /// σ of each draw.
    sigma: Vec<f64>,
    replicates: usize,
    strain_var: f64,
}

impl NoiseSimulator for Simulator {
    fn next(&mut self, stiffness: &[f64], rng: &mut dyn Rng, out: &mut [f64]) {
        for (d, sigma) in self.sigma.iter().enumerate() {
            let sd = sd(*sigma, stiffness[d], self.strain_var);
            for e in &mut out[d * self.replicates..(d + 1) * self.replicates] {
                let z: f64 = rng.sample(StandardNormal);
                *e = sd * z;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::testing::{pointwise_sum, run, scored};
    use super::super::HALF_LN_2PI;
    use super::*;
    use nalgebra::{DMatrix, DVector};

    fn model(eiv: bool) -> Gaussian {
        Gaussian::new(&NoiseOptions { errors_in_variables: eiv, ..NoiseOptions::default() })
    }

    /// Without strain noise: Σ ln N(r_k; 0, σ²) by hand, up to −n/2 ln 2π;
    /// the pointwise terms sum to it with the constant.
    #[test]
    fn independent_residuals_are_a_sum_of_normal_log_densities() {
        let (run, path) = run(0.0);
        let sigma: f64 = 250.0;
        let direct: f64 = (1..run.time.len())
            .map(|k| -sigma.ln() - 0.5 * ((run.tau[k] - path[k]) / sigma).powi(2))
            .sum();
        let m = model(true);
        let ll = scored(&m, &run, &path, [sigma.ln(), 0.0, 0.0, 0.0], 5e6);
        assert!((ll - direct).abs() < 1e-9 * direct.abs(), "{ll} vs {direct}");
        let n = run.compared() as f64;
        let sum = pointwise_sum(&m, &run, &path, [sigma, 0.0, 0.0, 0.0], 5e6);
        assert!((sum - (direct - n * HALF_LN_2PI)).abs() < 1e-9 * direct.abs());
    }

    /// What the MAP search's least squares weigh with errors in variables:
    /// the whitened residuals and log-variance terms give
    /// Σ w² + Σ (u² − 1) + n ln 2πσ² = −2 Σ ln N(r_k; 0, σ² + S_k² s_γ²), by hand with the
    /// stiffness along the path (the surrogate leaves the branch offsets
    /// aside), at two paths whose stiffness differs, to 1e-9 relative.
    #[test]
    fn the_search_weighs_the_likelihood_of_its_variances() {
        let var = 1e-8;
        let (run, path) = run(var);
        let (sigma2, g) = (250.0f64.powi(2), 5e6);
        let w = StrainNoise { run: run.clone(), sigma2, var };
        for p in [path.clone(), path.iter().map(|v| 1.3 * v).collect::<Vec<f64>>()] {
            let stiffness = super::super::stiffness_path(&run, &p, g);
            let r: Vec<f64> = (1..run.time.len()).map(|k| run.tau[k] - p[k]).collect();
            let direct: f64 = r
                .iter()
                .enumerate()
                .map(|(i, r)| normal_ln_pdf(*r, (sigma2 + stiffness[i + 1].powi(2) * var).sqrt()))
                .sum();
            let (mut white, mut terms) = (Vec::new(), Vec::new());
            w.whiten(&r, g, &mut white, &mut terms);
            let n = r.len() as f64;
            let sum: f64 = white.iter().map(|v| v * v).sum::<f64>()
                + terms.iter().map(|u| u * u - 1.0).sum::<f64>();
            let searched = -0.5 * (sum + n * (sigma2.ln() + 2.0 * HALF_LN_2PI));
            assert!(
                (searched - direct).abs() < 1e-9 * direct.abs(),
                "searched {searched} vs {direct}"
            );
        }
    }

    /// Errors in variables: the scorer and the pointwise terms both equal
    /// the multivariate normal density of the residuals with covariance
    /// D + v c cᵀ per branch, by Cholesky (an independent computation).
    #[test]
    fn errors_in_variables_is_the_multivariate_normal_with_branch_offsets() {
        let (run, path) = run(1e-8);
        // σ = 0.02 Pa makes each factor 1 + c² s²/σ² large enough that their
        // product is folded into its logarithm within a branch
        for sigma in [250.0f64, 0.02] {
            let g = 5e6;
            let n = run.compared();
            let (s2, sv, v) = (
                sigma * sigma,
                run.strain_noise_var,
                run.strain_noise_var * run.strain_smoothing_share,
            );
            let mut cov = DMatrix::zeros(n, n);
            let mut c = vec![0.0; n];
            let branch = super::super::testing::branches(&run);
            for k in 1..=n {
                let dg = run.gamma[k] - run.gamma[k - 1];
                c[k - 1] = tangent_stiffness(path[k] - path[k - 1], dg, g);
                cov[(k - 1, k - 1)] = s2 + c[k - 1] * c[k - 1] * sv;
            }
            for i in 0..n {
                for j in 0..n {
                    if branch[i] == branch[j] {
                        cov[(i, j)] += v * c[i] * c[j];
                    }
                }
            }
            let r = DVector::from_fn(n, |i, _| run.tau[i + 1] - path[i + 1]);
            let chol = cov.cholesky().unwrap();
            let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            let direct = -(n as f64) * HALF_LN_2PI - 0.5 * log_det - 0.5 * r.dot(&chol.solve(&r));
            assert!(branch[n - 1] >= 1, "the test run must have two branches");
            // the largest log-product of a branch's factors, past the fold at σ = 0.02 Pa
            let mut per_branch = vec![0.0f64; branch[n - 1] + 1];
            for k in 0..n {
                per_branch[branch[k]] += (c[k] * c[k] * sv / s2).ln_1p();
            }
            let most = per_branch.iter().fold(0.0f64, |m, v| m.max(*v));
            assert!(
                sigma > 100.0 || most > FOLD_INFLATION.ln(),
                "σ = {sigma}: log-product {most} never folds"
            );
            let m = model(true);
            let sum = pointwise_sum(&m, &run, &path, [sigma, 0.0, 0.0, 0.0], g);
            assert!((sum - direct).abs() < 1e-8 * direct.abs(), "pointwise {sum} vs {direct}");
            let scored =
                scored(&m, &run, &path, [sigma.ln(), 0.0, 0.0, 0.0], g) - (n as f64) * HALF_LN_2PI;
            assert!((scored - direct).abs() < 1e-8 * direct.abs(), "scorer {scored} vs {direct}");
            // switched off, the same run scores as independent noise
            let plain = scored_plain(&run, &path, sigma);
            assert!(
                (super::super::testing::scored(
                    &model(false),
                    &run,
                    &path,
                    [sigma.ln(), 0.0, 0.0, 0.0],
                    g
                ) - plain)
                    .abs()
                    < 1e-9 * plain.abs()
            );
        }
    }

    fn scored_plain(run: &RunData, path: &[f64], sigma: f64) -> f64 {
        (1..run.time.len())
            .map(|k| -sigma.ln() - 0.5 * ((run.tau[k] - path[k]) / sigma).powi(2))
            .sum()
    }

    /// The replicate of a noise-free draw is the path itself.
    #[test]
    fn replicates_centre_on_the_path() {
        let (run, path) = run(0.0);
        let stiffness = super::super::stiffness_path(&run, &path, 5e6);
        let p = model(false).pointwise(
            &run,
            &path,
            &stiffness,
            &[1e-9, 0.0, 0.0, 0.0],
            &mut crate::rng::stream(2, &[]),
        );
        for (rep, m) in p.replicate.iter().zip(&path[1..]) {
            assert!((rep - m).abs() < 1e-6);
        }
    }

    /// The profiled σ maximises the likelihood: the scorer's value there is
    /// above its value at σ × 1.05 and σ / 1.05.
    #[test]
    fn the_profiled_sigma_maximises_the_likelihood() {
        let (run, path) = run(1e-8);
        let residuals: Vec<f64> = (1..run.time.len()).map(|k| run.tau[k] - path[k]).collect();
        let m = model(true);
        let p = m.profile(&run, &residuals, 5e6);
        let at = |f: f64| scored(&m, &run, &path, [p.coordinates[0] + f.ln(), 0.0, 0.0, 0.0], 5e6);
        assert!(
            at(1.0) > at(1.05) && at(1.0) > at(1.0 / 1.05),
            "{} {} {}",
            at(1.0),
            at(1.05),
            at(1.0 / 1.05)
        );
    }
}
