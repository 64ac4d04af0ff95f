//! The posterior of the B-P parameters and the noise, from every run of a
//! calibration, as a [`LogDensity`] for the sampler.
//!
//! Coordinates (all unconstrained): ln G, ln R0, ln R1, ln D1, ln m1, ln m2,
//! ln n, then ln σ of each run, then (AR(1) noise only) atanh ρ of each run.
//! The model side knows nothing of MCMC: the likelihood integrates the B-P
//! law along each run's measured strain history and compares stresses.

pub mod current_law;
pub mod map;
pub mod prior;
pub mod settings;

use statrs::function::gamma::ln_gamma;

use crate::data::{local_polynomial, Campaign, Run};
use crate::model::{Integrator, Params, LANES};
use crate::sampler::LogDensity;
pub use current_law::CurrentLaw;
pub use prior::Prior;
pub use settings::{CalibrationSettings, ModelKind, NoiseModel, RecordPart};

/// One run as the likelihood sees it.
#[derive(Clone, Debug)]
pub struct RunData {
    pub id: String,
    pub time: Vec<f64>,
    pub gamma: Vec<f64>,
    pub tau: Vec<f64>,
    pub initial_tau: f64,
    pub current_a: f64,
}

impl RunData {
    /// The samples of `run` that `part` selects (always from the first
    /// sample: the state at any point depends on the whole history before it).
    pub fn from_run(run: &Run, part: RecordPart, smooth_strain_ms: f64) -> RunData {
        let end = match part {
            RecordPart::WholeRecord => run.shear.len(),
            RecordPart::FirstBranch => run.branches[0].end,
            RecordPart::AllBranches => {
                // the end of the last branch that ends at a reversal
                let complete = run.branches.len().saturating_sub(1).max(1);
                run.branches[complete - 1].end
            }
        };
        let sh = &run.shear;
        let dt = (sh.time[sh.len() - 1] - sh.time[0]) / (sh.len() - 1) as f64;
        let half_window = (smooth_strain_ms * 1e-3 / dt).round() as usize;
        let gamma = if half_window >= 2 {
            let mut g = local_polynomial(&sh.time, &sh.gamma, half_window, 3).0;
            g[0] = sh.gamma[0]; // the record starts from rest at its reference position
            g
        } else {
            sh.gamma.clone()
        };
        RunData {
            id: run.id().to_string(),
            time: sh.time[..end].to_vec(),
            gamma: gamma[..end].to_vec(),
            tau: run.shear.tau[..end].to_vec(),
            initial_tau: run.shear.initial_tau,
            current_a: run.spec.current_a,
        }
    }

    /// Residuals compared: every sample after the first.
    pub fn compared(&self) -> usize {
        self.time.len() - 1
    }
}

/// Sufficient statistics of the residuals r_k = τ_obs − τ_model of one run,
/// k = 1.. (the first sample is the fixed initial state).
#[derive(Clone, Copy, Debug, Default)]
pub struct ResidualStats {
    pub n: f64,
    /// Σ r_k²
    pub sum_sq: f64,
    /// Σ_{k≥2} r_k r_{k−1}, Σ_{k≥2} r_{k−1}², r_1 (for AR(1))
    pub lag_cross: f64,
    pub lag_sq: f64,
    pub first: f64,
    /// Σ ln(1 + r²/(ν s²)) (Student-t, with the run's scale)
    pub log_t: f64,
}

/// The posterior density.
pub struct Posterior {
    pub runs: Vec<RunData>,
    /// Priors of the θ coordinates: the seven B-P parameters, or the
    /// current law's nine.
    pub priors: Vec<Prior>,
    /// The B-P parameters as functions of the current (None: one set for all runs).
    pub law: Option<CurrentLaw>,
    pub noise: NoiseModel,
    pub student_nu: f64,
    pub sigma_bounds: (f64, f64),
    pub integrator: Integrator,
}

impl Posterior {
    pub fn new(campaign: &Campaign, settings: &CalibrationSettings, integrator: Integrator) -> Posterior {
        Posterior {
            runs: campaign
                .runs
                .iter()
                .map(|r| RunData::from_run(r, settings.likelihood.part, settings.likelihood.smooth_strain_ms))
                .collect(),
            priors: settings.theta_priors(),
            law: (settings.model == ModelKind::CurrentLaw).then(|| settings.law()),
            noise: settings.likelihood.noise,
            student_nu: settings.likelihood.student_nu,
            sigma_bounds: settings.sigma_bounds_pa,
            integrator,
        }
    }

    pub fn with_integrator(&self, integrator: Integrator) -> Posterior {
        Posterior {
            runs: self.runs.clone(),
            priors: self.priors.clone(),
            law: self.law,
            noise: self.noise,
            student_nu: self.student_nu,
            sigma_bounds: self.sigma_bounds,
            integrator,
        }
    }

    /// Number of θ coordinates (before the noise ones).
    pub fn theta_len(&self) -> usize {
        self.priors.len()
    }

    /// Names of the coordinates in SI (`G` … `n` or the law's, `sigma_<run>`, `rho_<run>`).
    pub fn names(&self) -> Vec<String> {
        let kind = if self.law.is_some() { ModelKind::CurrentLaw } else { ModelKind::PerCurrent };
        let mut names: Vec<String> = kind.theta_names().iter().map(|s| s.to_string()).collect();
        names.extend(self.runs.iter().map(|r| format!("sigma_{}", r.id)));
        if self.noise == NoiseModel::Ar1 {
            names.extend(self.runs.iter().map(|r| format!("rho_{}", r.id)));
        }
        names
    }

    /// Coordinate `i` in SI units: θ and σ are logarithms, ρ is atanh ρ.
    pub fn coordinate_to_si(&self, i: usize, v: f64) -> f64 {
        if i < self.theta_len() + self.runs.len() {
            v.exp()
        } else {
            v.tanh()
        }
    }

    /// A point in SI units (θ, σ, ρ) from unconstrained coordinates.
    pub fn to_si(&self, x: &[f64]) -> Vec<f64> {
        x.iter().enumerate().map(|(i, v)| self.coordinate_to_si(i, *v)).collect()
    }

    /// The unconstrained coordinates of a point in SI units (inverse of [`Self::to_si`]).
    pub fn from_si(&self, si: &[f64]) -> Vec<f64> {
        let positive = self.theta_len() + self.runs.len();
        si.iter().enumerate().map(|(i, v)| if i < positive { v.ln() } else { v.atanh() }).collect()
    }

    /// The B-P parameters of the seven-parameter model at ln θ = `x[..7]`.
    pub fn params(x: &[f64]) -> Params {
        Params::from_array(std::array::from_fn(|i| x[i].exp()))
    }

    /// The B-P parameters at a coil current, from the θ coordinates `x`.
    pub fn params_at_current(&self, x: &[f64], current_a: f64) -> Params {
        match &self.law {
            Some(law) => {
                let theta: [f64; current_law::LAW_NAMES.len()] = std::array::from_fn(|i| x[i].exp());
                law.params(&theta, current_a)
            }
            None => Self::params(x),
        }
    }

    /// Log-prior of the coordinates (with the Jacobian of ρ = tanh z).
    pub fn log_prior(&self, x: &[f64]) -> f64 {
        let (nr, nt) = (self.runs.len(), self.theta_len());
        let mut lp: f64 = self.priors.iter().zip(x).map(|(p, v)| p.log_density(*v)).sum();
        let (lo, hi) = (self.sigma_bounds.0.ln(), self.sigma_bounds.1.ln());
        for v in &x[nt..nt + nr] {
            if !(*v >= lo && *v <= hi) {
                return f64::NEG_INFINITY;
            }
        }
        if self.noise == NoiseModel::Ar1 {
            for z in &x[nt + nr..] {
                let rho = z.tanh();
                // uniform ρ on (−1, 1); |ρ| < 0.999 keeps the AR(1) stationary
                if !(rho.abs() < 0.999) {
                    return f64::NEG_INFINITY;
                }
                lp += (1.0 - rho * rho).ln();
            }
        }
        lp
    }

    /// Integrates run `r` for up to [`LANES`] parameter sets at once and
    /// gathers each lane's residual statistics (`None` where the
    /// integration failed). `scales` are the Student-t scales of the lanes.
    pub fn residual_stats(&self, params: &[Params; LANES], r: &RunData, scales: [f64; LANES]) -> [Option<ResidualStats>; LANES] {
        let mut st = [ResidualStats::default(); LANES];
        let mut prev = [0.0; LANES];
        let inv_nu_s2 = scales.map(|s| 1.0 / (self.student_nu * s * s));
        let student = self.noise == NoiseModel::StudentT;
        let outcome = self.integrator.run_lanes(params, &r.time, &r.gamma, r.initial_tau, |k, s| {
            if k == 0 {
                return;
            }
            let obs = r.tau[k];
            for lane in 0..LANES {
                let res = obs - s.tau[lane];
                let stl = &mut st[lane];
                stl.sum_sq += res * res;
                if k == 1 {
                    stl.first = res;
                } else {
                    stl.lag_cross += res * prev[lane];
                    stl.lag_sq += prev[lane] * prev[lane];
                }
                if student {
                    stl.log_t += (res * res * inv_nu_s2[lane]).ln_1p();
                }
                prev[lane] = res;
            }
        });
        std::array::from_fn(|lane| {
            outcome[lane].is_ok().then(|| ResidualStats { n: r.compared() as f64, ..st[lane] })
        })
    }

    /// Log-densities of up to [`LANES`] points integrated together.
    fn log_density_lanes(&self, xs: &[f64], out: &mut [f64]) {
        let d = self.dim();
        let (nr, nt) = (self.runs.len(), self.theta_len());
        let count = out.len();
        let mut params = [Params::reference_1a(); LANES];
        for lane in 0..count {
            let x = &xs[lane * d..(lane + 1) * d];
            out[lane] = self.log_prior(x);
            if out[lane] > f64::NEG_INFINITY && self.law.is_none() {
                params[lane] = Self::params(x); // the same for every run
            }
        }
        if out.iter().all(|v| *v == f64::NEG_INFINITY) {
            return;
        }
        for (i, r) in self.runs.iter().enumerate() {
            if self.law.is_some() {
                for lane in (0..count).filter(|&l| out[l] > f64::NEG_INFINITY) {
                    params[lane] = self.params_at_current(&xs[lane * d..(lane + 1) * d], r.current_a);
                }
            }
            let scales = std::array::from_fn(|lane| if lane < count { xs[lane * d + nt + i].exp() } else { 1.0 });
            let stats = self.residual_stats(&params, r, scales);
            for lane in 0..count {
                if out[lane] == f64::NEG_INFINITY {
                    continue;
                }
                let x = &xs[lane * d..(lane + 1) * d];
                out[lane] = match &stats[lane] {
                    Some(st) => {
                        let rho = if self.noise == NoiseModel::Ar1 { x[nt + nr + i].tanh() } else { 0.0 };
                        out[lane] + self.log_likelihood_run(st, x[nt + i], rho)
                    }
                    None => f64::NEG_INFINITY,
                };
            }
        }
        for v in out.iter_mut() {
            if !v.is_finite() {
                *v = f64::NEG_INFINITY;
            }
        }
    }

    /// Log-likelihood of one run from its statistics and noise parameters.
    pub fn log_likelihood_run(&self, st: &ResidualStats, log_sigma: f64, rho: f64) -> f64 {
        let sigma2 = (2.0 * log_sigma).exp();
        match self.noise {
            NoiseModel::Gaussian => -st.n * log_sigma - 0.5 * st.sum_sq / sigma2,
            NoiseModel::StudentT => {
                let nu = self.student_nu;
                st.n * (ln_gamma(0.5 * (nu + 1.0)) - ln_gamma(0.5 * nu) - 0.5 * (nu * std::f64::consts::PI).ln())
                    - st.n * log_sigma
                    - 0.5 * (nu + 1.0) * st.log_t
            }
            NoiseModel::Ar1 => {
                // r_1 ~ N(0, σ²/(1−ρ²)), r_k − ρ r_{k−1} ~ N(0, σ²)
                let tail_sq = st.sum_sq - st.first * st.first;
                let innov = tail_sq - 2.0 * rho * st.lag_cross + rho * rho * st.lag_sq;
                let one = 1.0 - rho * rho;
                -st.n * log_sigma + 0.5 * one.ln() - 0.5 * (one * st.first * st.first + innov) / sigma2
            }
        }
    }
}

impl LogDensity for Posterior {
    fn dim(&self) -> usize {
        self.theta_len() + self.runs.len() * if self.noise == NoiseModel::Ar1 { 2 } else { 1 }
    }

    fn log_density(&self, x: &[f64]) -> f64 {
        let mut out = [0.0];
        self.log_density_lanes(x, &mut out);
        out[0]
    }

    /// Walkers go through the integrator [`LANES`] at a time, one per SIMD
    /// lane; a point's value does not depend on its neighbours.
    fn log_density_batch(&self, xs: &[f64], out: &mut [f64]) {
        let d = self.dim();
        for (x, o) in xs.chunks(d * LANES).zip(out.chunks_mut(LANES)) {
            self.log_density_lanes(x, o);
        }
    }
}
