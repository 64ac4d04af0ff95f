//! The posterior of the B-P parameters and the noise, from every run of a
//! calibration, as a [`LogDensity`] for the sampler.
//!
//! * [`parameters`]: what θ is (one current, or the current law) and how it
//!   gives each run's B-P parameters;
//! * [`layout`]: θ, σ, ρ in a point, names, and the map to SI units;
//! * [`likelihood`]: the records as the model sees them and the noise models;
//! * [`prior`]: priors of θ;
//! * [`map`]: the start of sampling: MAP, Laplace approximation, step rule;
//! * [`sample`]: a posterior sample in SI units and its draws.
//!
//! The model side knows nothing of MCMC: the likelihood integrates the B-P
//! law along each run's measured strain history and compares stresses.

pub mod layout;
pub mod likelihood;
pub mod map;
pub mod parameters;
pub mod prior;
pub mod sample;
pub mod terms;

use crate::data::Campaign;
use crate::model::{Integrator, Params, LANES};
use crate::sampler::LogDensity;
pub use layout::{unit_of, Coordinates, Layout};
pub use likelihood::{normal_ln_pdf, student_t_log_constant, tangent_stiffness, LikelihoodSettings, NoiseModel, RecordPart, ResidualStats, RunData, HALF_LN_2PI};
pub use parameters::{ModelKind, ParameterModel, LAW_NAMES};
pub use prior::Prior;
pub use sample::{evenly_spaced, Draw, PosteriorSample, SummaryRow};
pub use terms::ModelTerms;

/// The posterior density.
#[derive(Clone)]
pub struct Posterior {
    pub runs: Vec<RunData>,
    pub model: ParameterModel,
    /// Priors of the θ coordinates, in the order of the model's names.
    pub priors: Vec<Prior>,
    pub likelihood: LikelihoodSettings,
    /// Bounds of every noise scale σ (Pa); log-uniform between them.
    pub sigma_bounds: (f64, f64),
    pub integrator: Integrator,
    pub terms: ModelTerms,
    pub layout: Layout,
}

impl Posterior {
    /// The posterior of the runs of `campaign`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        campaign: &Campaign,
        model: ParameterModel,
        priors: Vec<Prior>,
        likelihood: &LikelihoodSettings,
        sigma_bounds: (f64, f64),
        integrator: Integrator,
        coordinates: Coordinates,
        terms: &ModelTerms,
    ) -> Posterior {
        let runs: Vec<RunData> =
            campaign.runs.iter().map(|r| RunData::from_run(r, likelihood.part, likelihood.smooth_strain_ms)).collect();
        let ids: Vec<String> = runs.iter().map(|r| r.id.clone()).collect();
        Posterior {
            layout: Layout::new(&model, &ids, likelihood.noise, coordinates, terms),
            terms: terms.clone(),
            runs,
            model,
            priors,
            likelihood: likelihood.clone(),
            sigma_bounds,
            integrator,
        }
    }

    pub fn with_integrator(&self, integrator: Integrator) -> Posterior {
        Posterior { integrator, ..self.clone() }
    }

    /// The B-P parameters at a coil current, from the sampler's coordinates `x`.
    pub fn params_at_current(&self, x: &[f64], current_a: f64) -> Params {
        let theta: Vec<f64> = self.layout.log_theta(x).into_iter().map(f64::exp).collect();
        self.model.params(&theta, current_a)
    }

    /// Log-prior of the coordinates (the priors are densities of ln θ, and
    /// the θ coordinates map to ln θ with Jacobian 1; with that of ρ = tanh z).
    pub fn log_prior(&self, x: &[f64]) -> f64 {
        let l = &self.layout;
        let mut lp: f64 = self.priors.iter().zip(&l.log_theta(x)).map(|(p, v)| p.log_density(*v)).sum();
        // zero-mean normal priors of the model terms
        let normal = |v: f64, sd: f64| -0.5 * (v / sd) * (v / sd);
        lp += x[l.spring.clone()].iter().map(|v| normal(*v, self.terms.gas_spring_sd_n_per_m)).sum::<f64>();
        lp += x[l.offset.clone()].iter().map(|v| normal(*v, self.terms.force_offset_sd_n)).sum::<f64>();
        let (lo, hi) = (self.sigma_bounds.0.ln(), self.sigma_bounds.1.ln());
        for v in &x[l.sigma.clone()] {
            if !(*v >= lo && *v <= hi) {
                return f64::NEG_INFINITY;
            }
        }
        for z in &x[l.rho.clone()] {
            let rho = z.tanh();
            // uniform ρ on (−1, 1); |ρ| < 0.999 keeps the AR(1) stationary
            if !(rho.abs() < 0.999) {
                return f64::NEG_INFINITY;
            }
            lp += (1.0 - rho * rho).ln();
        }
        lp
    }

    /// Integrates run `r` for up to [`LANES`] parameter sets at once and
    /// gathers each lane's residual statistics (`None` where the
    /// integration failed). `scales` are the Student-t scales of the lanes,
    /// `terms` their gas-spring stiffness and force offset for this run.
    pub fn residual_stats(&self, params: &[Params; LANES], r: &RunData, scales: [f64; LANES], terms: [(f64, f64); LANES]) -> [Option<ResidualStats>; LANES] {
        let with_terms = terms.iter().any(|t| *t != (0.0, 0.0));
        let mut st = [ResidualStats::default(); LANES];
        let mut prev = [0.0; LANES];
        // errors in variables: the strain noise through the tangent stiffness
        let strain_var = if self.likelihood.eiv() { r.strain_noise_var } else { 0.0 };
        let eiv = strain_var > 0.0;
        if eiv {
            for s in st.iter_mut() {
                s.eiv = Some((0.0, 0.0));
            }
        }
        let sigma2 = scales.map(|s| s * s);
        let mut prev_model = [r.initial_tau; LANES];
        // the strain error at a reversal is shared by the stretch after it:
        // a rank-one term per branch, c_k = S_k, variance v (Sherman-Morrison)
        let v = strain_var * r.strain_smoothing_share;
        let mut branch = [(0.0f64, 0.0f64); LANES];
        let mut direction = 0.0f64;
        let close = |st: &mut ResidualStats, b: &mut (f64, f64)| {
            if let Some((log_inflation, weighted)) = st.eiv.as_mut() {
                let (rc, cc) = *b;
                *log_inflation += (v * cc).ln_1p();
                *weighted -= v * rc * rc / (1.0 + v * cc);
            }
            *b = (0.0, 0.0);
        };
        let nu = self.likelihood.student_nu;
        let inv_nu_s2 = scales.map(|s| (self.likelihood.noise == NoiseModel::StudentT).then(|| 1.0 / (nu * s * s)));
        let outcome = self.integrator.run_lanes(params, &r.time, &r.gamma, r.initial_tau, |k, s| {
            if k == 0 {
                return;
            }
            let obs = r.tau[k];
            let dg = r.gamma[k] - r.gamma[k - 1];
            let reversed = eiv && dg != 0.0 && direction != 0.0 && dg.signum() != direction;
            if dg != 0.0 {
                direction = dg.signum();
            }
            for lane in 0..LANES {
                if reversed {
                    close(&mut st[lane], &mut branch[lane]);
                }
                let model = if with_terms { s.tau[lane] + r.terms_stress(k, terms[lane].0, terms[lane].1) } else { s.tau[lane] };
                let res = obs - model;
                st[lane].push(k, res, prev[lane], inv_nu_s2[lane]);
                prev[lane] = res;
                if eiv {
                    let g = params[lane].g;
                    let stiffness = tangent_stiffness(s.tau[lane] - prev_model[lane], dg, g);
                    prev_model[lane] = s.tau[lane];
                    let a = stiffness * stiffness * strain_var;
                    let d = sigma2[lane] + a;
                    if let Some((log_inflation, weighted)) = st[lane].eiv.as_mut() {
                        *log_inflation += (a / sigma2[lane]).ln_1p();
                        *weighted += res * res / d;
                    }
                    branch[lane].0 += res * stiffness / d;
                    branch[lane].1 += stiffness * stiffness / d;
                }
            }
        });
        if eiv {
            for lane in 0..LANES {
                close(&mut st[lane], &mut branch[lane]);
            }
        }
        std::array::from_fn(|lane| outcome[lane].is_ok().then_some(st[lane]))
    }

    /// Log-densities of up to [`LANES`] points integrated together.
    fn log_density_lanes(&self, xs: &[f64], out: &mut [f64]) {
        let (d, l) = (self.dim(), &self.layout);
        let count = out.len();
        let point = |lane: usize| &xs[lane * d..(lane + 1) * d];
        for (lane, o) in out.iter_mut().enumerate() {
            *o = self.log_prior(point(lane));
        }
        if out.iter().all(|v| *v == f64::NEG_INFINITY) {
            return;
        }
        let mut params = [Params::reference_1a(); LANES];
        for (i, r) in self.runs.iter().enumerate() {
            // a current law gives each run its own parameters; one set is
            // the same for every run and computed once
            if i == 0 || self.model.is_current_law() {
                for lane in (0..count).filter(|&lane| out[lane] > f64::NEG_INFINITY) {
                    params[lane] = self.params_at_current(point(lane), r.current_a);
                }
            }
            let scales = std::array::from_fn(|lane| if lane < count { point(lane)[l.sigma.start + i].exp() } else { 1.0 });
            let terms = std::array::from_fn(|lane| if lane < count { l.terms(point(lane), i) } else { (0.0, 0.0) });
            let stats = self.residual_stats(&params, r, scales, terms);
            for lane in 0..count {
                if !(out[lane] > f64::NEG_INFINITY) {
                    continue;
                }
                let x = point(lane);
                out[lane] = match &stats[lane] {
                    Some(st) => {
                        let rho = if l.rho.is_empty() { 0.0 } else { x[l.rho.start + i].tanh() };
                        out[lane] + self.likelihood.noise.log_likelihood(st, x[l.sigma.start + i], rho, self.likelihood.student_nu)
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
}

impl LogDensity for Posterior {
    fn dim(&self) -> usize {
        self.layout.dim()
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
