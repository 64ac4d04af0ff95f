//! The posterior of the B-P parameters and the noise, from every run of a
//! calibration, as a [`LogDensity`] for the sampler.
//!
//! * [`parameters`]: what θ is (one current, or the current law) and how it
//!   gives each run's B-P parameters;
//! * [`layout`]: θ, the model terms and the noise in a point, names, and
//!   the map to SI units;
//! * [`likelihood`]: its settings, and the integration of a run in lanes
//!   whose residuals the noise model ([`crate::noise`]) scores;
//! * [`prior`]: priors of θ;
//! * [`map`]: the start of sampling: MAP, Laplace approximation, step rule;
//! * [`memory`]: the likelihood adjusted for the memory of its residuals;
//! * [`mode`]: the mode and curvature of the log-density itself, from the
//!   MAP's Laplace approximation by Newton's method;
//! * [`sample`]: a posterior sample in SI units and its draws.
//!
//! The model side knows nothing of MCMC: the likelihood integrates the B-P
//! law along each run's measured strain history and compares stresses.

pub mod laplace;
pub mod layout;
pub mod likelihood;
pub mod map;
pub mod memory;
pub mod parameters;
pub mod prior;
pub mod sample;
pub mod terms;

use std::borrow::Cow;
use std::sync::Arc;

use crate::data::{Campaign, RunData};
use crate::laws::LawValues;
use crate::model::{FieldLaw, Integrator, Params, LANES};
use crate::noise::{NoiseModel, NoiseValues, MAX_PARAMETERS};
use crate::sampler::LogDensity;
use layout::Hardening;
pub use layout::{unit_of, Coordinates, Layout};
pub use likelihood::{
    run_log_likelihood, run_log_likelihood_memo, run_score, Allowance, LaneParams,
    LikelihoodSettings, Memory, MemoryAdjustment,
};
pub use parameters::{ModelKind, ParameterModel, CURVE_NAMES, LAG_PRIOR, LAW_NAMES};
pub use prior::Prior;
pub use sample::{evenly_spaced, Draw, Draws, PosteriorSample, SummaryRow};
pub use terms::ModelTerms;

/// The posterior density.
#[derive(Clone)]
pub struct Posterior {
    pub runs: Vec<RunData>,
    pub model: ParameterModel,
    /// Priors of the θ coordinates, in the order of the model's names.
    pub priors: Vec<Prior>,
    pub likelihood: LikelihoodSettings,
    /// The noise model of every run.
    pub noise: Arc<dyn NoiseModel>,
    pub integrator: Integrator,
    pub terms: ModelTerms,
    pub layout: Layout,
    /// With the adjusted likelihood, where this posterior walks other
    /// coordinates than those its matrix acts in (a copy the MAP search
    /// made, [`Self::in_layout`]): those.
    adjusted_in: Option<Arc<Layout>>,
}

impl Posterior {
    /// The posterior of the runs of `campaign`, whose noise scales lie
    /// within `sigma_bounds` (Pa).
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
            campaign.runs.iter().map(|r| likelihood.run_data(r, likelihood.part)).collect();
        let ids: Vec<String> = runs.iter().map(|r| r.id.clone()).collect();
        let noise = likelihood.noise_model(sigma_bounds);
        let mut layout = Layout::new(&model, &ids, noise.as_ref(), coordinates, terms);
        if coordinates == Coordinates::Hardening {
            // the adjusted likelihood's coordinates are those it was measured in
            let stored = likelihood.adjustment().and_then(|a| a.reference_work_pa);
            layout.harden(&model, stored.or_else(|| Hardening::reference_work(&runs)));
        }
        Posterior {
            adjusted_in: None,
            layout,
            noise,
            terms: terms.clone(),
            runs,
            model,
            priors,
            likelihood: likelihood.clone(),
            integrator,
        }
    }

    pub fn with_integrator(&self, integrator: Integrator) -> Posterior {
        Posterior { integrator, ..self.clone() }
    }

    /// How many coordinates the ensemble moves propose with `walkers`
    /// walkers in all: those in no block where the walkers' memos fit the
    /// sampler's budget ([`crate::sampler::ensemble::memos_fit`]; the
    /// discrepancy model's noise is then moved on its own), otherwise all.
    pub fn proposed_dimension(&self, walkers: usize) -> usize {
        let blocks = self.blocks();
        let memo = self.runs.len()
            + self.runs.iter().map(|r| likelihood::memo_len(self.noise.as_ref(), r)).sum::<usize>();
        match !blocks.is_empty() && crate::sampler::ensemble::memos_fit(memo, walkers) {
            true => crate::sampler::density::free_coordinates(self.dim(), &blocks).len(),
            false => self.dim(),
        }
    }

    /// The weight of run `j`'s log-likelihood ([`LikelihoodSettings::weight`]).
    pub fn weight(&self, j: usize) -> f64 {
        self.likelihood.weight(&self.runs[j].id)
    }

    /// Where the likelihood is evaluated for the point `x`: `x` itself, or
    /// with the adjusted likelihood ([`Memory::Adjusted`]) the point whose
    /// θ coordinates are the adjustment's x* (the model terms and the noise
    /// as in `x`). The prior is always evaluated at `x`.
    pub fn likelihood_point<'a>(&self, x: &'a [f64]) -> Cow<'a, [f64]> {
        let Some(a) = self.likelihood.adjustment() else {
            return Cow::Borrowed(x);
        };
        let theta = self.layout.theta.clone();
        let moved = match &self.adjusted_in {
            None => a.apply(&x[theta.clone()]),
            // through ln θ from the coordinates searched in
            Some(own) => {
                let log_theta =
                    own.log_theta(&a.apply(&own.theta_coordinates(&self.layout.log_theta(x))));
                self.layout.theta_coordinates(&log_theta)
            }
        };
        let mut y = x.to_vec();
        y[theta].copy_from_slice(&moved[..self.layout.theta.len()]);
        Cow::Owned(y)
    }

    /// This posterior walked in the coordinates `layout` (the MAP search's):
    /// an adjusted likelihood still acts in those it was measured in.
    pub fn in_layout(&self, layout: Layout) -> Posterior {
        let adjusted_in = self
            .adjusted_in
            .clone()
            .or_else(|| self.likelihood.adjustment().map(|_| Arc::new(self.layout.clone())));
        Posterior { layout, adjusted_in, ..self.clone() }
    }

    /// Whether `log_theta` (ln θ of the law's parameters) lies inside every
    /// prior's support (their truncation bounds).
    pub fn inside_priors(&self, log_theta: &[f64]) -> bool {
        self.priors.iter().zip(log_theta).all(|(p, v)| p.log_density(*v) > f64::NEG_INFINITY)
    }

    /// This posterior with the independent likelihood, in the same
    /// coordinates.
    pub fn without_adjustment(&self) -> Posterior {
        let mut p = self.clone();
        p.likelihood.memory = Memory::Independent;
        p.adjusted_in = None;
        p
    }

    /// This posterior with the tempered likelihood in place of its own:
    /// each run's log-likelihood counting 1/k, `times` the runs' memory
    /// times k in their order.
    pub fn tempered(&self, times: &[f64]) -> Posterior {
        let mut p = self.without_adjustment();
        p.likelihood.memory = Memory::Tempered;
        p.likelihood.memory_adjustment = None;
        p.likelihood.memory_times =
            p.runs.iter().map(|r| r.id.clone()).zip(times.iter().copied()).collect();
        p
    }

    /// This posterior with its adjustment centred on the point `x`.
    pub fn recentred(&self, x: &[f64]) -> Posterior {
        let mut p = self.clone();
        if let Some(a) = p.likelihood.memory_adjustment.as_mut() {
            a.centre = x[self.layout.theta.clone()].to_vec();
        }
        p
    }

    /// The law's parameters at a coil current, from the sampler's coordinates `x`.
    pub fn values_at_current(&self, x: &[f64], current_a: f64) -> LawValues {
        self.model.values(&self.theta(x), current_a)
    }

    /// θ in SI units at the sampler's coordinates `x`.
    fn theta(&self, x: &[f64]) -> Vec<f64> {
        self.layout.log_theta(x).into_iter().map(f64::exp).collect()
    }

    /// A law's field law and coil lag at the sampler's coordinates `x`;
    /// `None` for one parameter set.
    pub fn field_at(&self, x: &[f64]) -> Option<(FieldLaw, f64)> {
        self.model.field(&self.theta(x))
    }

    /// The law's parameters of the points `xs` (sampler coordinates, up to
    /// [`LANES`]; the last repeated) along run `run`: at its current, or
    /// following it where it varies and θ is a law.
    pub fn lane_params(&self, xs: &[&[f64]], run: &RunData) -> LaneParams {
        let point = |lane: usize| xs[lane.min(xs.len() - 1)];
        if run.current.is_some() && self.model.is_current_law() {
            let fields: [(FieldLaw, f64); LANES] =
                std::array::from_fn(|lane| self.field_at(point(lane)).expect("a law"));
            return LaneParams::Along { laws: fields.map(|f| f.0), lags_s: fields.map(|f| f.1) };
        }
        LaneParams::Fixed {
            law: self.model.law(),
            values: std::array::from_fn(|lane| self.values_at_current(point(lane), run.current_a)),
        }
    }

    /// Log-prior of the coordinates (the priors are densities of ln θ,
    /// carried to the θ coordinates by the layout's Jacobian; the noise
    /// model's priors carry their own Jacobians).
    pub fn log_prior(&self, x: &[f64]) -> f64 {
        let l = &self.layout;
        let log_theta = l.log_theta(x);
        let mut lp: f64 = self.priors.iter().zip(&log_theta).map(|(p, v)| p.log_density(*v)).sum();
        if lp == f64::NEG_INFINITY {
            return lp;
        }
        lp += l.log_jacobian(x, &log_theta);
        // zero-mean normal priors of the model terms
        let normal = |v: f64, sd: f64| -0.5 * (v / sd) * (v / sd);
        lp += x[l.spring.clone()]
            .iter()
            .map(|v| normal(*v, self.terms.gas_spring_sd_n_per_m))
            .sum::<f64>();
        lp += x[l.offset.clone()]
            .iter()
            .map(|v| normal(*v, self.terms.force_offset_sd_n))
            .sum::<f64>();
        for (j, run) in self.runs.iter().enumerate() {
            lp += self.noise.log_prior(run, &l.noise_values(x, j));
        }
        lp
    }

    /// What turns ln ∫ exp(log-density) dx into the log evidence of the
    /// records: minus the log of the integral of the prior as
    /// [`Posterior::log_prior`] writes it (each θ prior's, each model
    /// term's normal, each run's noise prior's normaliser), plus the
    /// constants each run's likelihood leaves out, weighted as the run's
    /// likelihood is ([`Posterior::weight`]).
    pub fn log_evidence_offset(&self) -> f64 {
        let (l, half_ln_2pi) = (&self.layout, crate::noise::HALF_LN_2PI);
        let prior = self.priors.iter().map(Prior::log_normaliser).sum::<f64>()
            + l.spring.len() as f64 * (half_ln_2pi + self.terms.gas_spring_sd_n_per_m.ln())
            + l.offset.len() as f64 * (half_ln_2pi + self.terms.force_offset_sd_n.ln())
            + self.runs.iter().map(|r| self.noise.log_prior_normaliser(r)).sum::<f64>();
        let constants: f64 = (0..self.runs.len())
            .map(|j| self.weight(j) * self.noise.log_likelihood_constant(&self.runs[j]))
            .sum();
        constants - prior
    }

    /// Log-densities of up to [`LANES`] points integrated together; with
    /// `memos` (one per point, or none), each point's residuals for the
    /// sampler's block updates of the noise ([`LogDensity::blocks`]).
    fn log_density_lanes(&self, xs: &[f64], out: &mut [f64], memos: &mut [Vec<f64>]) {
        let (d, l) = (self.dim(), &self.layout);
        let count = out.len();
        let point = |lane: usize| &xs[lane * d..(lane + 1) * d];
        for (lane, o) in out.iter_mut().enumerate() {
            *o = self.log_prior(point(lane));
        }
        if out.iter().all(|v| *v == f64::NEG_INFINITY) {
            return;
        }
        // lanes out of the prior's support integrate a point that is in it
        // (their results are dropped; an extreme point would only make the
        // other lanes wait for its sub-steps)
        let first_alive = (0..count).find(|&lane| out[lane] > f64::NEG_INFINITY).unwrap_or(0);
        // each memo: run j's noise terms (filled below), then the runs' residuals
        for m in memos.iter_mut() {
            m.clear();
            m.resize(self.runs.len(), f64::NEG_INFINITY);
        }
        let moved: Vec<Cow<[f64]>> = (0..count)
            .map(|lane| {
                self.likelihood_point(point(if out[lane] > f64::NEG_INFINITY {
                    lane
                } else {
                    first_alive
                }))
            })
            .collect();
        let alive: Vec<&[f64]> = moved.iter().map(|p| p.as_ref()).collect();
        let mut params = LaneParams::bodner_partom(&[Params::reference_1a(); LANES]);
        for (i, r) in self.runs.iter().enumerate() {
            // a current law gives each run its own parameters; one set is
            // the same for every run and computed once
            if i == 0 || self.model.is_current_law() {
                params = self.lane_params(&alive, r);
            }
            let coordinates: [NoiseValues; LANES] = std::array::from_fn(|lane| {
                if lane < count {
                    l.noise_values(point(lane), i)
                } else {
                    [0.0; MAX_PARAMETERS]
                }
            });
            let terms = std::array::from_fn(|lane| {
                if lane < count {
                    l.terms(point(lane), i)
                } else {
                    (0.0, 0.0)
                }
            });
            let ll = run_log_likelihood_memo(
                self.noise.as_ref(),
                &self.integrator,
                r,
                &params,
                &coordinates,
                terms,
                memos,
            );
            let weight = self.weight(i);
            for (lane, m) in memos.iter_mut().enumerate() {
                if let Some(v) = ll[lane] {
                    m[i] = self.noise.log_prior(r, &coordinates[lane]) + weight * v;
                }
            }
            for (o, ll) in out.iter_mut().zip(ll) {
                if *o > f64::NEG_INFINITY {
                    *o = ll.map_or(f64::NEG_INFINITY, |v| *o + weight * v);
                }
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
        self.log_density_lanes(x, &mut out, &mut []);
        out[0]
    }

    /// Walkers go through the integrator [`LANES`] at a time, one per SIMD
    /// lane; a point's value does not depend on its neighbours.
    fn log_density_batch(&self, xs: &[f64], out: &mut [f64]) {
        let d = self.dim();
        for (x, o) in xs.chunks(d * LANES).zip(out.chunks_mut(LANES)) {
            self.log_density_lanes(x, o, &mut []);
        }
    }

    /// Each run's noise parameters, where the noise model asks for it
    /// ([`NoiseModel::updated_alone`]): given the run's residuals, their
    /// conditional is one pass of the noise model's scorer.
    fn blocks(&self) -> Vec<Vec<usize>> {
        if !self.noise.updated_alone() {
            return Vec::new();
        }
        self.scored_blocks()
    }

    /// Each run's noise parameters, whatever the noise model: a run's
    /// noise enters its own terms alone (its prior and its likelihood given
    /// its residuals), so Newton's differences in a run's noise score that
    /// run's residuals from a memo instead of integrating every run (the
    /// current curves' Hessian: 883 of its 2 178 points integrated).
    fn scored_blocks(&self) -> Vec<Vec<usize>> {
        let (l, nr) = (&self.layout, self.runs.len());
        if l.noise.is_empty() {
            return Vec::new();
        }
        (0..nr)
            .map(|j| {
                (0..self.noise.parameters().len()).map(|p| l.noise.start + p * nr + j).collect()
            })
            .collect()
    }

    fn log_density_batch_memo(&self, xs: &[f64], out: &mut [f64], memos: &mut [Vec<f64>]) {
        let d = self.dim();
        for ((x, o), m) in
            xs.chunks(d * LANES).zip(out.chunks_mut(LANES)).zip(memos.chunks_mut(LANES))
        {
            self.log_density_lanes(x, o, m);
        }
    }

    /// Run `b`'s noise prior and its weighted log-likelihood, scored from
    /// the memos' residuals (a memo holds these terms of every run first,
    /// then each run's residuals in turn).
    fn block_log_density_batch(&self, b: usize, xs: &[f64], memos: &[&[f64]], out: &mut [f64]) {
        let (d, l, run) = (self.dim(), &self.layout, &self.runs[b]);
        let start: usize = self.runs.len()
            + self.runs[..b]
                .iter()
                .map(|r| likelihood::memo_len(self.noise.as_ref(), r))
                .sum::<usize>();
        let end = start + likelihood::memo_len(self.noise.as_ref(), run);
        let weight = self.weight(b);
        for ((x, o), m) in xs.chunks(d * LANES).zip(out.chunks_mut(LANES)).zip(memos.chunks(LANES))
        {
            let count = o.len();
            let point = |lane: usize| &x[lane * d..(lane + 1) * d];
            for (lane, o) in o.iter_mut().enumerate() {
                *o = self.noise.log_prior(run, &l.noise_values(point(lane), b));
            }
            let Some(alive) = (0..count).find(|&lane| o[lane] > f64::NEG_INFINITY) else {
                continue;
            };
            let coordinates: [NoiseValues; LANES] = std::array::from_fn(|lane| {
                l.noise_values(
                    point(if lane < count && o[lane] > f64::NEG_INFINITY { lane } else { alive }),
                    b,
                )
            });
            let parts: Vec<&[f64]> =
                m.iter().map(|memo| memo.get(start..end).unwrap_or(&[])).collect();
            let ll = likelihood::run_score(self.noise.as_ref(), run, &coordinates, &parts);
            for (o, ll) in o.iter_mut().zip(ll) {
                *o = if *o > f64::NEG_INFINITY && ll.is_finite() {
                    *o + weight * ll
                } else {
                    f64::NEG_INFINITY
                };
            }
        }
    }
}
