//! Model discrepancy (Kennedy & O'Hagan 2001): the force record is the law,
//! plus a smooth force the law does not carry, plus measurement noise,
//!
//! r_k = τ_obs,k − τ_model,k = δ(t_k) + e_k,
//!
//! with δ a Gaussian process in time with a Matérn kernel of scale σ_δ and
//! time scale ℓ (smoothness ν = 3/2 by default, or 1/2), and e_k ~ N(0, σ²)
//! white noise — each run with its own (σ, σ_δ, ℓ). A Matérn process is an
//! exact linear state-space model (Hartikainen & Särkkä 2010): (δ, δ′) for
//! ν = 3/2, δ alone for ν = 1/2. The likelihood is a Kalman filter, O(n) per
//! run, and its one-step-ahead predictive densities p(r_k | r_<k) are the
//! pointwise terms, which sum to it exactly.
//!
//! Errors in variables join as in the Gaussian model: the strain noise adds
//! S_k² s_γ² to the white variance, and the branch's shared strain error is
//! one more state, a constant offset c_k b (c_k = S_k) drawn afresh at every
//! reversal — still exact.
//!
//! The priors say what is known (Brynjarsdóttir & O'Hagan 2014): σ and σ_δ
//! log-uniform within the noise scales' bounds, but not below the record's
//! resolution; ℓ log-uniform from a few
//! sampling intervals (shorter is white noise) to a share of the
//! excitation's period (longer would mimic the law's own parameters).

mod filter;
mod process;

use std::sync::Arc;

use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use super::model::{
    log_uniform, log_uniform_normaliser, log_variance_term, normal_ln_pdf, DiscrepancySettings,
    Explained, Kernel, NoiseModel, NoiseOptions, NoiseSimulator, NoiseValues, Parameter, Pointwise,
    Pool, Profile, RunScorer, Transform, Whiten,
};
use crate::data::RunData;
use crate::model::LANES;
use filter::{branch_start, filter_run, smooth_run, Filter};
pub use process::sample_path;
use process::Process;

const PARAMETERS: &[Parameter] = &[
    Parameter { name: "sigma", unit: "Pa", transform: Transform::Log, pool: Pool::RootMeanSquare },
    Parameter {
        name: "discrepancy_sd",
        unit: "Pa",
        transform: Transform::Log,
        pool: Pool::RootMeanSquare,
    },
    Parameter { name: "discrepancy_time", unit: "s", transform: Transform::Log, pool: Pool::Mean },
];

#[derive(Clone, Debug)]
pub struct Discrepancy {
    sigma_bounds: (f64, f64),
    errors_in_variables: bool,
    settings: DiscrepancySettings,
}

impl Discrepancy {
    pub fn new(options: &NoiseOptions) -> Self {
        Discrepancy {
            sigma_bounds: options.sigma_bounds,
            errors_in_variables: options.errors_in_variables,
            settings: options.discrepancy.clone(),
        }
    }

    fn strain_var(&self, run: &RunData) -> f64 {
        if self.errors_in_variables {
            run.strain_noise_var
        } else {
            0.0
        }
    }

    /// The bounds of the scales σ and σ_δ on `run` (Pa): the noise scales'
    /// bounds, the lower one at least the noise of the stress channel's
    /// quantisation (step/√12): white noise or a discrepancy below the
    /// record's resolution means nothing, and its long flat tail would
    /// only slow the sampler.
    pub fn scale_bounds(&self, run: &RunData) -> (f64, f64) {
        self.scale_bounds_at(run.stress_step_pa)
    }

    /// The bounds of σ and σ_δ (Pa) on a record whose stress is quantised
    /// in steps of `stress_step_pa` (0: not quantised).
    pub fn scale_bounds_at(&self, stress_step_pa: f64) -> (f64, f64) {
        let (lo, hi) = self.sigma_bounds;
        (lo.max(stress_step_pa / 12f64.sqrt()).min(0.5 * hi), hi)
    }

    /// The bounds of the time scale ℓ on `run` (s).
    pub fn time_bounds(&self, run: &RunData) -> (f64, f64) {
        self.time_bounds_at(run.step_s, run.period_s)
    }

    /// The bounds of ℓ (s) on a record sampled every `step_s` whose
    /// excitation has the period `period_s`.
    pub fn time_bounds_at(&self, step_s: f64, period_s: f64) -> (f64, f64) {
        let lo = self.settings.time_scale_min_samples * step_s;
        let hi = (self.settings.time_scale_max_period * period_s).max(4.0 * lo);
        (lo, hi)
    }

    /// The process of a run with noise `values` (SI: σ, σ_δ, ℓ).
    fn process(&self, run: &RunData, values: &NoiseValues) -> Process {
        Process::new(self.settings.kernel, values[1], values[2], run.step_s)
    }
}

impl NoiseModel for Discrepancy {
    fn parameters(&self) -> &'static [Parameter] {
        PARAMETERS
    }

    fn check(&self) -> Result<(), String> {
        let s = &self.settings;
        if !(s.time_scale_min_samples > 0.0 && s.time_scale_max_period > 0.0) {
            return Err("[likelihood.discrepancy] time scale bounds must be positive".into());
        }
        Ok(())
    }

    fn log_prior(&self, run: &RunData, c: &[f64]) -> f64 {
        let scales = self.scale_bounds(run);
        log_uniform(c[0], scales)
            + log_uniform(c[1], scales)
            + log_uniform(c[2], self.time_bounds(run))
    }

    fn log_prior_normaliser(&self, run: &RunData) -> f64 {
        2.0 * log_uniform_normaliser(self.scale_bounds(run))
            + log_uniform_normaliser(self.time_bounds(run))
    }

    /// σ from the samples; σ_δ and ℓ from about duration/ℓ independent
    /// stretches of the discrepancy.
    fn laplace_sd(&self, run: &RunData, c: &NoiseValues) -> NoiseValues {
        let n = run.compared().max(1) as f64;
        let duration =
            run.time.last().copied().unwrap_or(0.0) - run.time.first().copied().unwrap_or(0.0);
        let stretches = (duration / c[2].exp()).clamp(1.0, n);
        [1.0 / (2.0 * n).sqrt(), 1.0 / (2.0 * stretches).sqrt(), 1.0 / stretches.sqrt(), 0.0]
    }

    /// The smoothed discrepancy (Rauch–Tung–Striebel) and the filter's
    /// standardised innovations.
    fn explain(
        &self,
        run: &RunData,
        r: &[f64],
        stiffness: &[f64],
        values: &NoiseValues,
    ) -> Option<Explained> {
        let strain_var = self.strain_var(run);
        Some(smooth_run(
            run,
            &self.process(run, values),
            values[0],
            strain_var,
            (strain_var > 0.0).then_some(stiffness),
            r,
        ))
    }

    fn uses_stiffness(&self, run: &RunData) -> bool {
        self.strain_var(run) > 0.0
    }

    fn models_memory(&self) -> bool {
        true
    }

    fn updated_alone(&self) -> bool {
        true
    }

    fn scorer<'a>(
        &'a self,
        run: &'a RunData,
        coordinates: &[NoiseValues; LANES],
    ) -> Box<dyn RunScorer + 'a> {
        let values = coordinates.map(|c| [c[0].exp(), c[1].exp(), c[2].exp(), 0.0]);
        let processes = values.map(|v| self.process(run, &v));
        Box::new(Scorer {
            run,
            strain_var: self.strain_var(run),
            sigma2: values.map(|v| v[0] * v[0]),
            filters: processes.map(|p| Filter::start(&p)),
            processes,
            ll: [0.0; LANES],
        })
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
        let r: Vec<f64> = (1..n).map(|k| run.tau[k] - model[k]).collect();
        let strain_var = self.strain_var(run);
        let process = self.process(run, values);
        let mut out = Pointwise::default();
        filter_run(
            run,
            &process,
            values[0],
            strain_var,
            (strain_var > 0.0).then_some(stiffness),
            &r,
            |_, v, s| out.log_likelihood.push(normal_ln_pdf(v, s.sqrt())),
        );
        let mut sim = self.simulator(run, std::slice::from_ref(values), 1);
        let mut e = [0.0];
        for k in 0..n {
            sim.next(&[stiffness.get(k).copied().unwrap_or(0.0)], rng, &mut e);
            if k > 0 {
                out.replicate.push(model[k] + e[0]);
            }
        }
        out
    }

    fn simulator(
        &self,
        run: &RunData,
        draws: &[NoiseValues],
        replicates: usize,
    ) -> Box<dyn NoiseSimulator> {
        let v_branch = self.strain_var(run) * run.strain_smoothing_share;
        Box::new(Simulator {
            processes: draws.iter().map(|v| self.process(run, v)).collect(),
            sigma: draws.iter().map(|v| v[0]).collect(),
            replicates,
            strain_var: self.strain_var(run),
            v_branch,
            time: run.time.clone(),
            reverses: run.reverses.clone(),
            uniform: run.uniform,
            k: 0,
            state: vec![[0.0; 3]; draws.len() * replicates],
        })
    }

    /// A new test's residual: the discrepancy's and the noise's spread.
    fn marginal_ln_pdf(&self, run: &RunData, r: f64, stiffness: f64, values: &NoiseValues) -> f64 {
        let white = values[0] * values[0] + stiffness * stiffness * self.strain_var(run);
        normal_ln_pdf(r, (values[1] * values[1] + white).sqrt())
    }

    /// (σ, σ_δ, ℓ) that maximise the likelihood of the residuals (the
    /// strain's branch offsets left aside), on a grid of ℓ and σ_δ/σ with σ
    /// in closed form, refined by golden sections; residuals whitened by
    /// the filter at them.
    fn profile(&self, run: &RunData, residuals: &[f64], g: f64) -> Profile {
        let strain_var = self.strain_var(run);
        let stiffness = (strain_var > 0.0).then(|| stiffness_of_residuals(run, residuals, g));
        let noise = Observed { strain_var, stiffness: stiffness.as_deref() };
        let fit = fit(
            run,
            self.settings.kernel,
            residuals,
            self.time_bounds(run),
            self.scale_bounds(run),
            &noise,
        );
        let (sigma, sd) = (fit.sigma, fit.sd);
        let values = [sigma, sd, fit.ell, 0.0];
        Profile {
            scale: (sigma * sigma + sd * sd).sqrt(),
            whitening: Arc::new(Whitening {
                run: run.clone(),
                process: self.process(run, &values),
                sigma,
                strain_var,
            }),
            coordinates: [sigma.ln(), sd.ln(), fit.ell.ln(), 0.0],
        }
    }

    fn profile_log_likelihood(&self, run: &RunData, residuals: &[f64]) -> f64 {
        fit(
            run,
            self.settings.kernel,
            residuals,
            self.time_bounds(run),
            self.scale_bounds(run),
            &Observed { strain_var: 0.0, stiffness: None },
        )
        .log_likelihood
    }
}

/// The law's tangent stiffness along the model stress τ_obs − r, indexed
/// by sample from 0 (G at the first).
fn stiffness_of_residuals(run: &RunData, residuals: &[f64], g: f64) -> Vec<f64> {
    let mut path = vec![run.initial_tau];
    path.extend(residuals.iter().enumerate().map(|(i, v)| run.tau[i + 1] - v));
    super::model::stiffness_path(run, &path, g)
}

/// The maximum-likelihood (σ, σ_δ, ℓ) of residuals and its log-likelihood.
struct Fit {
    sigma: f64,
    sd: f64,
    ell: f64,
    log_likelihood: f64,
}

/// How the strain's noise reaches the residuals (errors in variables): its
/// variance and the law's tangent stiffness at every sample (none: exact
/// strain).
struct Observed<'a> {
    strain_var: f64,
    stiffness: Option<&'a [f64]>,
}

/// Maximises the filter's likelihood of `r` over (σ, σ_δ, ℓ) within
/// `sigma_bounds` and ℓ within `time_bounds`: a grid of ℓ and σ_δ/σ with σ
/// in closed form (without the strain's noise every variance scales with
/// σ²), then golden sections on each coordinate of the exact likelihood,
/// the strain's noise and branch offsets included — the conditional
/// maximum the MAP search alternates with the law's parameters.
fn fit(
    run: &RunData,
    kernel: Kernel,
    r: &[f64],
    time_bounds: (f64, f64),
    sigma_bounds: (f64, f64),
    observed: &Observed,
) -> Fit {
    let n = r.len().max(1) as f64;
    // −2 ln L at unit σ, with σ² profiled: n ln(Σ v²/S / n) + Σ ln S
    let profiled = |log_ratio: f64, log_ell: f64| -> (f64, f64) {
        let process = Process::new(kernel, log_ratio.exp(), log_ell.exp(), run.step_s);
        let (mut q, mut log_s) = (0.0, 0.0);
        filter_run(run, &process, 1.0, 0.0, None, r, |_, v, s| {
            q += v * v / s;
            log_s += s.ln();
        });
        let sigma2 = (q / n).max(1e-300);
        (n * sigma2.ln() + log_s, sigma2)
    };
    let (l_lo, l_hi) = (time_bounds.0.ln(), time_bounds.1.ln());
    let (r_lo, r_hi) = (-4.0, 6.0);
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for i in 0..12 {
        for j in 0..12 {
            let (lr, ll) =
                (r_lo + (r_hi - r_lo) * i as f64 / 11.0, l_lo + (l_hi - l_lo) * j as f64 / 11.0);
            let (v, _) = profiled(lr, ll);
            if v < best.0 {
                best = (v, lr, ll);
            }
        }
    }
    let (_, sigma2) = profiled(best.1, best.2);
    let (s_lo, s_hi) = (sigma_bounds.0.ln(), sigma_bounds.1.ln());
    // ln σ, ln σ_δ, ln ℓ, inside the prior's support
    let mut x = [
        (0.5 * sigma2.ln()).clamp(s_lo, s_hi),
        (0.5 * sigma2.ln() + best.1).clamp(s_lo, s_hi),
        best.2,
    ];
    let bounds = [(s_lo, s_hi), (s_lo, s_hi), (l_lo, l_hi)];
    let minus_two_ll = |x: &[f64; 3]| -> f64 {
        let process = Process::new(kernel, x[1].exp(), x[2].exp(), run.step_s);
        let mut value = 0.0;
        filter_run(
            run,
            &process,
            x[0].exp(),
            observed.strain_var,
            observed.stiffness,
            r,
            |_, v, s| value += s.ln() + v * v / s,
        );
        value
    };
    let widths = [1.0, (r_hi - r_lo) / 11.0, (l_hi - l_lo) / 11.0];
    for pass in 0..4 {
        for i in 0..3 {
            let w = widths[i] / (1 << pass) as f64;
            let (a, b) = ((x[i] - w).max(bounds[i].0), (x[i] + w).min(bounds[i].1));
            x[i] = crate::fit::golden_section(
                |v| {
                    let mut y = x;
                    y[i] = v;
                    minus_two_ll(&y)
                },
                a,
                b,
                24,
            );
        }
    }
    Fit {
        sigma: x[0].exp(),
        sd: x[1].exp(),
        ell: x[2].exp(),
        log_likelihood: -0.5 * minus_two_ll(&x),
    }
}

/// The filter of each lane: ln L = −½ Σ (ln S_k + v_k²/S_k), up to −n/2 ln 2π.
struct Scorer<'a> {
    run: &'a RunData,
    strain_var: f64,
    sigma2: [f64; LANES],
    processes: [Process; LANES],
    filters: [Filter; LANES],
    ll: [f64; LANES],
}

impl RunScorer for Scorer<'_> {
    #[inline]
    fn push(&mut self, k: usize, residual: &[f64; LANES], stiffness: &[f64; LANES]) {
        let run = self.run;
        let branch = branch_start(run, k, self.strain_var);
        let dt = run.time[k] - run.time[k - 1];
        for l in 0..LANES {
            if !run.uniform {
                self.processes[l].step(dt);
            }
            let c = stiffness[l];
            self.filters[l].predict(&self.processes[l], branch);
            let (v, s) =
                self.filters[l].update(residual[l], c, self.sigma2[l] + c * c * self.strain_var);
            self.ll[l] -= 0.5 * (s.ln() + v * v / s);
        }
    }

    fn finish(&mut self) -> [f64; LANES] {
        self.ll
    }
}

/// Standardised innovations v_k/√S_k at fixed noise: linear in the
/// residuals (generalised least squares for the MAP).
#[derive(Debug)]
struct Whitening {
    run: RunData,
    process: Process,
    sigma: f64,
    strain_var: f64,
}

impl Whiten for Whitening {
    /// The filter's standardised innovations, the stiffness (with errors in
    /// variables) along the model stress the residuals imply; the
    /// innovations' variances, at least the white noise's σ², follow the
    /// model only through that stiffness.
    fn whiten(&self, residuals: &[f64], g: f64, white: &mut Vec<f64>, terms: &mut Vec<f64>) {
        let stiffness =
            (self.strain_var > 0.0).then(|| stiffness_of_residuals(&self.run, residuals, g));
        let floor = self.sigma * self.sigma;
        filter_run(
            &self.run,
            &self.process,
            self.sigma,
            self.strain_var,
            stiffness.as_deref(),
            residuals,
            |_, v, s| {
                white.push(v / s.sqrt());
                if stiffness.is_some() {
                    terms.push(log_variance_term(s, floor));
                }
            },
        );
    }
}

/// New records' noise: a path of the process from its stationary state,
/// white noise, and the branch offsets of errors in variables.
struct Simulator {
    processes: Vec<Process>,
    sigma: Vec<f64>,
    replicates: usize,
    strain_var: f64,
    v_branch: f64,
    time: Vec<f64>,
    reverses: Vec<bool>,
    uniform: bool,
    /// The next sample.
    k: usize,
    /// (δ, δ′, b) of every path.
    state: Vec<[f64; 3]>,
}

impl NoiseSimulator for Simulator {
    fn next(&mut self, stiffness: &[f64], rng: &mut dyn Rng, out: &mut [f64]) {
        let k = self.k;
        let new_branch = self.strain_var > 0.0 && (k <= 1 || self.reverses[k]);
        for (d, process) in self.processes.iter_mut().enumerate() {
            if k > 0 && !self.uniform {
                process.step(self.time[k] - self.time[k - 1]);
            }
            let factor = process.noise_factor();
            let white = (self.sigma[d] * self.sigma[d]
                + stiffness[d] * stiffness[d] * self.strain_var)
                .sqrt();
            for p in d * self.replicates..(d + 1) * self.replicates {
                let z: [f64; 4] = std::array::from_fn(|_| rng.sample(StandardNormal));
                let s = &mut self.state[p];
                let [x0, x1] = if k == 0 {
                    process.draw_start(z[0], z[1])
                } else {
                    process.advance(factor, [s[0], s[1]], z[0], z[1])
                };
                (s[0], s[1]) = (x0, x1);
                if new_branch {
                    s[2] = self.v_branch.sqrt() * z[3];
                }
                out[p] = s[0] + stiffness[d] * s[2] + white * z[2];
            }
        }
        self.k += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::super::model::HALF_LN_2PI;
    use super::super::testing::{pointwise_sum, run, scored};
    use super::*;
    use nalgebra::{DMatrix, DVector};

    fn model(kernel: Kernel, eiv: bool) -> Discrepancy {
        Discrepancy::new(&NoiseOptions {
            errors_in_variables: eiv,
            discrepancy: DiscrepancySettings { kernel, ..DiscrepancySettings::default() },
            ..NoiseOptions::default()
        })
    }

    /// The Matérn kernel at lag `tau`.
    fn kernel(kernel: Kernel, sd: f64, ell: f64, tau: f64) -> f64 {
        let t = tau.abs();
        match kernel {
            Kernel::Matern12 => sd * sd * (-t / ell).exp(),
            Kernel::Matern32 => {
                let x = 3f64.sqrt() * t / ell;
                sd * sd * (1.0 + x) * (-x).exp()
            }
        }
    }

    /// The noise and stiffness of the dense comparisons.
    const SIGMA: f64 = 120.0;
    const SD: f64 = 400.0;
    const ELL: f64 = 0.006;
    const G: f64 = 5e6;

    /// A run's residuals about `path` and their dense covariance, built
    /// directly from the definitions: the kernel K of δ, white noise
    /// σ² + S_k² s_γ² on the diagonal, and v S_i S_j within each branch
    /// (the branch's strain offset) — the independent computation the
    /// filter and the smoother are checked against.
    struct Dense {
        k_delta: DMatrix<f64>,
        cov: DMatrix<f64>,
        r: DVector<f64>,
        stiffness: Vec<f64>,
    }

    impl Dense {
        fn of(kernel_kind: Kernel, run: &RunData, path: &[f64], strain_var: f64) -> Dense {
            let n = run.compared();
            let stiffness = super::super::model::stiffness_path(run, path, G);
            let v = strain_var * run.strain_smoothing_share;
            let k_delta = DMatrix::from_fn(n, n, |i, j| {
                kernel(kernel_kind, SD, ELL, run.time[i + 1] - run.time[j + 1])
            });
            let mut cov = k_delta.clone();
            let branch = super::super::testing::branches(run);
            for i in 0..n {
                cov[(i, i)] += SIGMA * SIGMA + stiffness[i + 1] * stiffness[i + 1] * strain_var;
                for j in 0..n {
                    if branch[i] == branch[j] {
                        cov[(i, j)] += v * stiffness[i + 1] * stiffness[j + 1];
                    }
                }
            }
            let r = DVector::from_fn(n, |i, _| run.tau[i + 1] - path[i + 1]);
            Dense { k_delta, cov, r, stiffness }
        }
    }

    /// Both kernels, without and with errors in variables (strain variance).
    const KERNELS_AND_STRAIN_NOISE: [(Kernel, f64); 4] = [
        (Kernel::Matern32, 0.0),
        (Kernel::Matern12, 0.0),
        (Kernel::Matern32, 1e-8),
        (Kernel::Matern12, 1e-8),
    ];

    /// The scorer and the pointwise terms both equal the multivariate
    /// normal density of the residuals with the dense covariance
    /// K + σ² I (+ the errors-in-variables terms D + v c cᵀ per branch), by
    /// Cholesky — an independent computation — for both kernels.
    #[test]
    fn the_filter_is_the_dense_gaussian_process() {
        for (kernel_kind, strain_var) in KERNELS_AND_STRAIN_NOISE {
            let (run, path) = run(strain_var);
            let (sigma, sd, ell, g) = (SIGMA, SD, ELL, G);
            let n = run.compared();
            let d = Dense::of(kernel_kind, &run, &path, strain_var);
            let (cov, r) = (d.cov, d.r);
            let chol = cov.cholesky().unwrap();
            let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
            let direct = -(n as f64) * HALF_LN_2PI - 0.5 * log_det - 0.5 * r.dot(&chol.solve(&r));
            let m = model(kernel_kind, true);
            let sum = pointwise_sum(&m, &run, &path, [sigma, sd, ell, 0.0], g);
            assert!(
                (sum - direct).abs() < 1e-8 * direct.abs(),
                "{kernel_kind:?}, {strain_var}: pointwise {sum} vs {direct}"
            );
            let scored = scored(&m, &run, &path, [sigma.ln(), sd.ln(), ell.ln(), 0.0], g)
                - n as f64 * HALF_LN_2PI;
            assert!(
                (scored - direct).abs() < 1e-8 * direct.abs(),
                "{kernel_kind:?}, {strain_var}: scorer {scored} vs {direct}"
            );
        }
    }

    /// What the MAP search's least squares weigh is the likelihood: with
    /// errors in variables the whitened residuals and the log-variance terms
    /// of [`Whiten`], the stiffness taken along the residuals, give
    /// Σ w² + Σ (u² − 1) + n ln 2πσ² = −2 ln N(r; 0, Σ), the dense
    /// covariance's density by Cholesky, at two model paths whose
    /// stiffness differs (the second scaled by 1.3), to 1e-8 relative; so
    /// the surrogate's optimum moves with the stiffness as the likelihood's
    /// does.
    #[test]
    fn the_search_weighs_the_likelihood_with_errors_in_variables() {
        let strain_var = 1e-8;
        for kernel_kind in [Kernel::Matern32, Kernel::Matern12] {
            let (run, path) = run(strain_var);
            let scaled: Vec<f64> = path.iter().map(|v| 1.3 * v).collect();
            for p in [&path, &scaled] {
                let d = Dense::of(kernel_kind, &run, p, strain_var);
                let n = run.compared();
                let chol = d.cov.clone().cholesky().unwrap();
                let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|d| d.ln()).sum::<f64>();
                let direct =
                    -(n as f64) * HALF_LN_2PI - 0.5 * log_det - 0.5 * d.r.dot(&chol.solve(&d.r));
                let w = Whitening {
                    run: run.clone(),
                    process: Process::new(kernel_kind, SD, ELL, run.step_s),
                    sigma: SIGMA,
                    strain_var,
                };
                let (mut white, mut terms) = (Vec::new(), Vec::new());
                w.whiten(d.r.as_slice(), G, &mut white, &mut terms);
                assert_eq!((white.len(), terms.len()), (n, n));
                let sum: f64 = white.iter().map(|v| v * v).sum::<f64>()
                    + terms.iter().map(|u| u * u - 1.0).sum::<f64>();
                let searched = -0.5 * (sum + n as f64 * (2.0 * SIGMA.ln() + 2.0 * HALF_LN_2PI));
                assert!(
                    (searched - direct).abs() < 1e-8 * direct.abs(),
                    "{kernel_kind:?}: searched {searched} vs {direct}"
                );
            }
        }
    }

    /// The smoother is the dense Gaussian process's conditional: E[δ | r] =
    /// K Σ⁻¹ r and var = diag(K − K Σ⁻¹ K) with Σ the residuals' covariance
    /// (Cholesky), with and without errors in variables, both kernels, to
    /// 1e-6 of the sd; its innovations are the filter's.
    #[test]
    fn the_smoother_is_the_dense_conditional() {
        for (kernel_kind, strain_var) in KERNELS_AND_STRAIN_NOISE {
            let (run, path) = run(strain_var);
            let (sigma, sd, ell) = (SIGMA, SD, ELL);
            let n = run.compared();
            let Dense { k_delta, cov, r, stiffness } =
                Dense::of(kernel_kind, &run, &path, strain_var);
            let chol = cov.cholesky().unwrap();
            let mean = &k_delta * chol.solve(&r);
            let var = &k_delta - &k_delta * chol.solve(&k_delta);
            let m = model(kernel_kind, true);
            let residuals: Vec<f64> = r.iter().copied().collect();
            let e = m.explain(&run, &residuals, &stiffness, &[sigma, sd, ell, 0.0]).unwrap();
            for i in 0..n {
                let sd_i = var[(i, i)].sqrt();
                assert!(
                    (e.mean[i] - mean[i]).abs() < 1e-6 * sd_i,
                    "{kernel_kind:?}, {strain_var}, {i}: mean {} vs {}",
                    e.mean[i],
                    mean[i]
                );
                assert!(
                    (e.sd[i] - sd_i).abs() < 1e-6 * sd_i,
                    "{kernel_kind:?}, {strain_var}, {i}: sd {} vs {sd_i}",
                    e.sd[i]
                );
            }
            let mut innovations = Vec::new();
            let process = m.process(&run, &[sigma, sd, ell, 0.0]);
            filter_run(
                &run,
                &process,
                sigma,
                m.strain_var(&run),
                (strain_var > 0.0).then_some(&stiffness[..]),
                &residuals,
                |_, v, s| innovations.push(v / s.sqrt()),
            );
            for (a, b) in e.innovations.iter().zip(&innovations) {
                assert!((a - b).abs() < 1e-9, "innovation {a} vs {b}");
            }
        }
    }

    /// Simulated records have the process's covariance: over 20 000 paths,
    /// the variance at a sample is σ_δ² + σ² and the covariance at a lag of
    /// ℓ/2 the kernel's, within 4 % of the variance (the standard error of
    /// a covariance from 20 000 pairs is under 1 %).
    #[test]
    fn simulated_records_have_the_kernels_covariance() {
        let (run, _) = run(0.0);
        for kernel_kind in [Kernel::Matern12, Kernel::Matern32] {
            let m = model(kernel_kind, false);
            let (sigma, sd, ell) = (50.0, 300.0, 0.004);
            let paths = 20_000;
            let mut sim = m.simulator(&run, &[[sigma, sd, ell, 0.0]], paths);
            let mut rng = crate::rng::stream(11, &[]);
            let (mut e, mut at) = (vec![0.0; paths], Vec::new());
            for k in 0..31 {
                sim.next(&[0.0], &mut rng, &mut e);
                if k == 28 || k == 30 {
                    at.push(e.clone());
                }
            }
            let var = at[1].iter().map(|v| v * v).sum::<f64>() / paths as f64;
            let cov = at[0].iter().zip(&at[1]).map(|(a, b)| a * b).sum::<f64>() / paths as f64;
            let total = sd * sd + sigma * sigma;
            assert!((var / total - 1.0).abs() < 0.04, "{kernel_kind:?}: {var} vs {total}");
            let expected = kernel(kernel_kind, sd, ell, run.time[30] - run.time[28]);
            assert!((cov - expected).abs() < 0.04 * total, "{kernel_kind:?}: {cov} vs {expected}");
        }
    }

    /// A path of the process at uneven times has the kernel's covariance:
    /// over 20 000 paths the covariance of every pair among a few samples
    /// (lags from 0 to 2.5 ℓ) is the kernel's within 4 % of σ_δ² (the
    /// standard error of a covariance of 20 000 pairs is under 1 %).
    #[test]
    fn sampled_paths_have_the_kernels_covariance() {
        let time = [0.0, 0.0007, 0.0031, 0.0040, 0.0065, 0.0100];
        let (sd, ell, paths) = (2.0, 0.004, 20_000);
        for kernel_kind in [Kernel::Matern12, Kernel::Matern32] {
            let mut rng = crate::rng::stream(23, &[]);
            let samples: Vec<Vec<f64>> =
                (0..paths).map(|_| sample_path(kernel_kind, sd, ell, &time, &mut rng)).collect();
            for i in 0..time.len() {
                for j in i..time.len() {
                    let cov = samples.iter().map(|p| p[i] * p[j]).sum::<f64>() / paths as f64;
                    let expected = kernel(kernel_kind, sd, ell, time[j] - time[i]);
                    assert!(
                        (cov - expected).abs() < 0.04 * sd * sd,
                        "{kernel_kind:?} ({i}, {j}): {cov} vs {expected}"
                    );
                }
            }
        }
    }

    /// The profile recovers the noise of a simulated record: σ_δ and ℓ
    /// within a factor 1.5, σ within 20 % (one record of 2000 samples with
    /// ℓ = 20 samples: about 100 independent stretches).
    #[test]
    fn the_profile_recovers_known_noise() {
        let n = 2001;
        let time: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        let gamma: Vec<f64> =
            time.iter().map(|t| (2.0 * std::f64::consts::PI * 2.0 * t).sin()).collect();
        let flat = RunData::new(
            "r".into(),
            time.clone(),
            gamma.clone(),
            vec![0.0; n],
            0.0,
            1.0,
            (1.0, 1.0),
            (0.0, 1.0),
        );
        let m = model(Kernel::Matern32, false);
        let (sigma, sd, ell) = (40.0, 200.0, 0.02);
        let mut sim = m.simulator(&flat, &[[sigma, sd, ell, 0.0]], 1);
        let mut rng = crate::rng::stream(5, &[]);
        let mut e = [0.0];
        let mut r = Vec::new();
        for k in 0..n {
            sim.next(&[0.0], &mut rng, &mut e);
            if k > 0 {
                r.push(e[0]);
            }
        }
        let p = m.profile(&flat, &r, 1e6);
        let [s, d, l, _] = p.coordinates.map(f64::exp);
        assert!((s / sigma - 1.0).abs() < 0.2, "σ {s}");
        assert!((d / sd).ln().abs() < 1.5f64.ln(), "σ_δ {d}");
        assert!((l / ell).ln().abs() < 1.5f64.ln(), "ℓ {l}");
        // the whitened residuals are close to independent standard normals
        let mut w = Vec::new();
        p.whitening.whiten(&r, 1e6, &mut w, &mut Vec::new());
        let var = w.iter().map(|v| v * v).sum::<f64>() / w.len() as f64;
        let lag1 = w.windows(2).map(|p| p[0] * p[1]).sum::<f64>() / w.len() as f64;
        assert!((var - 1.0).abs() < 0.1 && lag1.abs() < 0.1, "variance {var}, lag-1 {lag1}");
    }
}
