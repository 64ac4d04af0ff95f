//! The likelihood of one run: its settings, and the loop that integrates
//! the law along the run for [`LANES`] points at once and hands every
//! sample's residuals to the noise model's scorer ([`crate::noise`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::data::{RecordPart, RunData};
use crate::laws::bodner_partom::values_of;
use crate::laws::{LawKind, LawValues};
use crate::model::{tangent_stiffness, FieldLaw, IntegrationError, Integrator, Params, LANES};
use crate::noise::{DiscrepancySettings, NoiseKind, NoiseModel, NoiseOptions, NoiseValues};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LikelihoodSettings {
    pub noise: NoiseKind,
    /// Half-width (ms) of the local cubic fit that smooths the measured
    /// strain before it drives the model, at least [`crate::data::smooth::MIN_SMOOTH_SAMPLES`]
    /// samples; 0 uses the raw samples. The model turns displacement noise
    /// (and the quantisation of a digital displacement channel) into stress
    /// noise G δγ and biases G (an errors-in-variables effect); a stand's
    /// displacement is smooth on this scale, so the fit removes noise, not
    /// signal.
    pub smooth_strain_ms: f64,
    /// The displacement channel's delay behind the force channel (ms): the
    /// law is driven at each sample by the displacement recorded this much
    /// later (0: the samples as recorded). A stand's two channels may be
    /// filtered or sampled apart; docs/real-data.md measures it on the
    /// measured damper. Every law takes it.
    #[serde(skip_serializing_if = "is_zero")]
    pub displacement_lag_ms: f64,
    /// Degrees of freedom of the Student-t model.
    pub student_nu: f64,
    pub part: RecordPart,
    /// Errors in variables: the measured strain is noisy too, and its noise
    /// reaches the stress through the model's tangent stiffness S_k = dτ/dγ
    /// along the path (G when elastic, near 0 in flow). Each residual then
    /// has variance σ² + S_k² s_γ², with s_γ² the strain noise estimated
    /// from the record, and the error of the strain at each reversal, which
    /// the whole branch after it shares, as one random offset per branch
    /// (docs/calibration.md). On by default; it applies to the noise models
    /// that take it (the Gaussian one).
    pub errors_in_variables: bool,
    /// The discrepancy model's kernel and the bounds of its time scale
    /// (`--noise discrepancy`).
    pub discrepancy: DiscrepancySettings,
    /// How the memory the noise model leaves in a run's residuals enters
    /// its likelihood (`--memory`; docs/calibration.md, "The tempered
    /// likelihood").
    pub memory: Memory,
    /// With `memory = "tempered"`: each run's integrated autocorrelation
    /// time k of its whitened MAP residuals (samples), by run id, filled in
    /// when the calibration starts; the run's log-likelihood counts 1/k.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub memory_times: BTreeMap<String, f64>,
    /// With `memory = "adjusted"`: the curvature adjustment measured with
    /// the independent likelihood, filled in when the calibration starts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory_adjustment: Option<MemoryAdjustment>,
}

/// How a calibration's likelihood allowed for its residuals' memory.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Allowance {
    /// Each run's log-likelihood divided by its memory time k (samples).
    Tempered { lo: f64, hi: f64 },
    /// The curvature adjusted, each principal direction's variance
    /// inflated by lo–hi.
    Adjusted { lo: f64, hi: f64 },
}

impl Allowance {
    /// The summary's words: ", likelihood tempered by …".
    pub fn note(&self) -> String {
        match *self {
            Allowance::Tempered { lo, hi } => format!(", likelihood tempered by the residuals' memory (k {lo:.1}–{hi:.1} samples)"),
            Allowance::Adjusted { lo, hi } => format!(", likelihood adjusted for the residuals' memory (variance ×{lo:.1}–{hi:.1} by direction)"),
        }
    }
}

/// The curvature adjustment of the likelihood for the memory of its
/// residuals (docs/calibration.md, "The adjusted likelihood"): the
/// likelihood is evaluated at x* = c + C (x − c) instead of x, x the
/// sampler's θ coordinates (ln G, ln (R0 + D1), …, in which the likelihood
/// is close to Gaussian), c the mode of the independent posterior and C
/// chosen so that the likelihood's curvature there becomes H V⁻¹ H (H its
/// curvature, V the covariance of its score given the residuals' memory;
/// Chandler & Bate 2007, Ribatet, Cooley & Davison 2012). θ is the B-P
/// parameter set of one current.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MemoryAdjustment {
    /// The runs it was measured on (a calibration of some of them, such as
    /// a held-out posterior, keeps it; one of other runs measures anew).
    pub runs: Vec<String>,
    /// The θ coordinates x, by name (the calibration's own; a calibration
    /// in other coordinates refuses the adjustment).
    pub coordinates: Vec<String>,
    /// The reference plastic work W* (Pa) of the hardening coordinates it
    /// was measured in, which a calibration of some of the runs keeps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_work_pa: Option<f64>,
    /// c: x at the independent posterior's mode.
    pub centre: Vec<f64>,
    /// C, row by row.
    pub matrix: Vec<Vec<f64>>,
    /// The variance inflation of each principal direction (the eigenvalues
    /// of H^(−½) V H^(−½), at least 1), largest first: by how much fewer
    /// than independent the residuals count along it.
    pub inflation: Vec<f64>,
}

impl MemoryAdjustment {
    /// x* from the θ coordinates x.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        let c = &self.centre;
        self.matrix
            .iter()
            .zip(c)
            .map(|(row, ci)| {
                ci + row.iter().zip(x.iter().zip(c)).map(|(a, (v, cj))| a * (v - cj)).sum::<f64>()
            })
            .collect()
    }

    /// The smallest and largest variance inflation.
    pub fn inflation_range(&self) -> (f64, f64) {
        (
            self.inflation.last().copied().unwrap_or(1.0),
            self.inflation.first().copied().unwrap_or(1.0),
        )
    }

    fn check(&self) -> Result<(), String> {
        let d = self.centre.len();
        if d == 0
            || self.matrix.len() != d
            || self.matrix.iter().any(|r| r.len() != d)
            || self.coordinates.len() != d
        {
            return Err(format!("memory_adjustment: the matrix must be {d} × {d} and name {d} coordinates, as many as centre has values"));
        }
        if self.reference_work_pa.is_some_and(|w| !(w > 0.0 && w.is_finite())) {
            return Err("memory_adjustment: reference_work_pa must be positive".into());
        }
        if self
            .centre
            .iter()
            .chain(self.matrix.iter().flatten())
            .chain(&self.inflation)
            .any(|v| !v.is_finite())
        {
            return Err("memory_adjustment: every value must be finite".into());
        }
        if self.inflation.iter().any(|v| *v < 1.0) {
            return Err("memory_adjustment: a variance inflation is at least 1".into());
        }
        Ok(())
    }
}

/// How the memory left in a run's residuals enters its likelihood.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Memory {
    /// Chosen at the MAP: independent where the residuals have no memory
    /// (every run's whitened lag-1 autocorrelation at most
    /// `calibrate::MEMORY_WARNING`), else adjusted (one parameter set per
    /// current) or tempered (a parameter model across currents). The
    /// calibration's config.toml keeps the choice.
    #[default]
    Auto,
    /// Every residual is new evidence (the noise model's own likelihood).
    Independent,
    /// Each run's log-likelihood divided by the integrated autocorrelation
    /// time of its whitened residuals at the MAP: a run of n correlated
    /// samples counts as about n/k independent ones.
    Tempered,
    /// The likelihood's curvature adjusted at the MAP to the covariance of
    /// its score given the residuals' memory, direction by direction (the
    /// sandwich H⁻¹VH⁻¹): each parameter widened by the memory of the part
    /// of the record that informs it.
    Adjusted,
}

impl Default for LikelihoodSettings {
    fn default() -> Self {
        LikelihoodSettings {
            noise: NoiseKind::Gaussian,
            smooth_strain_ms: 2.0,
            displacement_lag_ms: 0.0,
            student_nu: 5.0,
            part: RecordPart::WholeRecord,
            errors_in_variables: true,
            discrepancy: DiscrepancySettings::default(),
            memory: Memory::Auto,
            memory_times: BTreeMap::new(),
            memory_adjustment: None,
        }
    }
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl LikelihoodSettings {
    /// The samples of `run` that `part` selects, as the likelihood takes
    /// them: the strain smoothed, and shifted by the displacement's lag.
    pub fn run_data(&self, run: &crate::data::Run, part: RecordPart) -> RunData {
        let data = RunData::from_run(run, part, self.smooth_strain_ms);
        match self.displacement_lag_ms {
            0.0 => data,
            lag => data.with_strain_lag(1e-3 * lag),
        }
    }

    pub fn check(&self) -> Result<(), String> {
        if !(self.displacement_lag_ms.abs() <= 100.0) {
            return Err(format!(
                "displacement_lag_ms must lie within ±100 ms, not {}",
                self.displacement_lag_ms
            ));
        }
        if !(self.smooth_strain_ms >= 0.0) {
            return Err("smooth_strain_ms must be 0 or positive".into());
        }
        if let Some((id, k)) =
            self.memory_times.iter().find(|(_, k)| !(**k >= 1.0 && k.is_finite()))
        {
            return Err(format!(
                "memory_times: run {id} has {k}; an integrated autocorrelation time is at least 1"
            ));
        }
        if let Some(a) = &self.memory_adjustment {
            a.check()?;
        }
        Ok(())
    }

    /// The weight of run `id`'s log-likelihood: 1/k with the tempered
    /// likelihood and the run's memory time k known, else 1.
    pub fn weight(&self, id: &str) -> f64 {
        match (self.memory, self.memory_times.get(id)) {
            (Memory::Tempered, Some(k)) => 1.0 / k,
            _ => 1.0,
        }
    }

    /// The smallest and largest memory time of a tempered likelihood;
    /// `None` where the residuals are taken as independent (or no time is
    /// known yet).
    pub fn memory_range(&self) -> Option<(f64, f64)> {
        (self.memory == Memory::Tempered && !self.memory_times.is_empty()).then(|| {
            self.memory_times
                .values()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &k| (a.min(k), b.max(k)))
        })
    }

    /// The curvature adjustment in force: with `memory = "adjusted"` and
    /// the adjustment measured.
    pub fn adjustment(&self) -> Option<&MemoryAdjustment> {
        self.memory_adjustment.as_ref().filter(|_| self.memory == Memory::Adjusted)
    }

    /// How the memory of the residuals has been allowed for, once measured.
    pub fn allowance(&self) -> Option<Allowance> {
        if let Some((lo, hi)) = self.memory_range() {
            return Some(Allowance::Tempered { lo, hi });
        }
        self.adjustment().map(|a| {
            let (lo, hi) = a.inflation_range();
            Allowance::Adjusted { lo, hi }
        })
    }

    /// The noise model, with its scales bounded by `sigma_bounds` (Pa).
    pub fn noise_model(&self, sigma_bounds: (f64, f64)) -> Arc<dyn NoiseModel> {
        self.noise.model(&NoiseOptions {
            sigma_bounds,
            student_nu: self.student_nu,
            errors_in_variables: self.errors_in_variables,
            discrepancy: self.discrepancy.clone(),
        })
    }
}

/// The law's parameters of up to [`LANES`] points along one run: a set per
/// lane, or (the B-P law) each lane's current law and coil lag where the
/// run's current varies.
// on the stack for one batch of lanes: boxing the larger variant would
// allocate in the likelihood's loop
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug)]
pub enum LaneParams {
    Fixed { law: LawKind, values: [LawValues; LANES] },
    Along { laws: [FieldLaw; LANES], lags_s: [f64; LANES] },
}

impl LaneParams {
    /// The B-P parameter sets of every lane.
    pub fn bodner_partom(params: &[Params; LANES]) -> Self {
        LaneParams::Fixed { law: LawKind::BodnerPartom, values: params.each_ref().map(values_of) }
    }

    /// Integrates every lane along `run` ([`DamperLaw::run_lanes`], or the
    /// B-P law's [`Integrator::run_lanes_along`] the run's current where it
    /// varies), calling `visit(k, stress)` at every sample.
    pub fn integrate(
        &self,
        integrator: &Integrator,
        run: &RunData,
        mut visit: impl FnMut(usize, &[f64; LANES]),
    ) -> [Result<(), IntegrationError>; LANES] {
        match (self, &run.current) {
            (LaneParams::Along { laws, lags_s }, Some(current)) => integrator.run_lanes_along(
                laws,
                lags_s,
                current,
                &run.time,
                &run.gamma,
                run.initial_tau,
                |k, s| visit(k, &s.tau),
            ),
            _ => {
                let (law, values) = self.at(run.current_a);
                law.law().run_lanes(integrator, &values, run, &mut visit)
            }
        }
    }

    /// The Euler steps lane 0's integration along `run` takes
    /// ([`DamperLaw::euler_steps`], or the B-P law's along a varying current).
    pub fn euler_steps(&self, integrator: &Integrator, run: &RunData) -> u64 {
        match (self, &run.current) {
            (LaneParams::Along { laws, lags_s }, Some(current)) => integrator.euler_steps_along(
                &laws[0], lags_s[0], current, &run.time, &run.gamma, run.initial_tau,
            ),
            _ => {
                let (law, values) = self.at(run.current_a);
                law.law().euler_steps(integrator, &values[0], run)
            }
        }
    }

    /// The law and every lane's parameters at a steady current `current_a`.
    pub fn at(&self, current_a: f64) -> (LawKind, [LawValues; LANES]) {
        match self {
            LaneParams::Fixed { law, values } => (*law, *values),
            LaneParams::Along { laws, .. } => (
                LawKind::BodnerPartom,
                std::array::from_fn(|lane| values_of(&laws[lane].params_at(current_a))),
            ),
        }
    }

    /// Each lane's bound of the law's tangent stiffness along `run`
    /// ([`DamperLaw::stiffness_bound`]; for the B-P law G): where the
    /// current varies, the largest (G is monotone in the current, so at the
    /// record's lowest or highest current).
    pub fn g_bound(&self, run: &RunData) -> [f64; LANES] {
        match (self, &run.current) {
            (LaneParams::Along { laws, .. }, Some(current)) => {
                let (lo, hi) = current
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &c| (a.min(c), b.max(c)));
                std::array::from_fn(|lane| {
                    laws[lane].params_at(lo).g.max(laws[lane].params_at(hi).g)
                })
            }
            _ => {
                let (law, values) = self.at(run.current_a);
                values.map(|v| law.law().stiffness_bound(&v, run))
            }
        }
    }
}

/// The log-likelihood of `run` for up to [`LANES`] points: their B-P
/// parameters, noise coordinates and model terms (gas-spring stiffness,
/// force offset); `None` where the integration failed. The law is
/// integrated once for all lanes, and each sample's residuals go straight
/// to the noise model's scorer: nothing of the path is kept.
pub fn run_log_likelihood(
    noise: &dyn NoiseModel,
    integrator: &Integrator,
    run: &RunData,
    params: &LaneParams,
    coordinates: &[NoiseValues; LANES],
    terms: [(f64, f64); LANES],
) -> [Option<f64>; LANES] {
    run_log_likelihood_memo(noise, integrator, run, params, coordinates, terms, &mut [])
}

/// [`run_log_likelihood`], also appending to `memos[lane]` (for the first
/// `memos.len()` lanes) what the noise model scores at each sample k = 1…:
/// the residual, and the stiffness after it where the model takes it
/// ([`run_score`] reads them back).
pub fn run_log_likelihood_memo(
    noise: &dyn NoiseModel,
    integrator: &Integrator,
    run: &RunData,
    params: &LaneParams,
    coordinates: &[NoiseValues; LANES],
    terms: [(f64, f64); LANES],
    memos: &mut [Vec<f64>],
) -> [Option<f64>; LANES] {
    let with_terms = terms.iter().any(|t| *t != (0.0, 0.0));
    let stiff = noise.uses_stiffness(run);
    let g = if stiff { params.g_bound(run) } else { [0.0; LANES] };
    let mut scorer = noise.scorer(run, coordinates);
    let mut residual = [0.0; LANES];
    let mut stiffness = [0.0; LANES];
    let mut prev_model = [run.initial_tau; LANES];
    let outcome = params.integrate(integrator, run, |k, s| {
        if k == 0 {
            return;
        }
        let obs = run.tau[k];
        let dg = run.gamma[k] - run.gamma[k - 1];
        for lane in 0..LANES {
            let model = if with_terms {
                s[lane] + run.terms_stress(k, terms[lane].0, terms[lane].1)
            } else {
                s[lane]
            };
            residual[lane] = obs - model;
            if stiff {
                stiffness[lane] = tangent_stiffness(s[lane] - prev_model[lane], dg, g[lane]);
                prev_model[lane] = s[lane];
            }
        }
        scorer.push(k, &residual, &stiffness);
        for (lane, memo) in memos.iter_mut().enumerate() {
            memo.push(residual[lane]);
            if stiff {
                memo.push(stiffness[lane]);
            }
        }
    });
    let ll = scorer.finish();
    std::array::from_fn(|lane| outcome[lane].is_ok().then_some(ll[lane]))
}

/// The noise model's log-likelihood of `run` for up to [`LANES`] memos of
/// [`run_log_likelihood_memo`] (each this run's part) with these noise
/// coordinates: the same numbers, without integrating the law.
pub fn run_score(
    noise: &dyn NoiseModel,
    run: &RunData,
    coordinates: &[NoiseValues; LANES],
    memos: &[&[f64]],
) -> [f64; LANES] {
    let stride = if noise.uses_stiffness(run) { 2 } else { 1 };
    // a memo cut short (an integration that failed) is never a walker's
    let short: [bool; LANES] =
        std::array::from_fn(|lane| memos[lane.min(memos.len() - 1)].len() < memo_len(noise, run));
    if short.iter().any(|s| *s) {
        return [f64::NEG_INFINITY; LANES];
    }
    let mut scorer = noise.scorer(run, coordinates);
    let (mut residual, mut stiffness) = ([0.0; LANES], [0.0; LANES]);
    for k in 1..run.tau.len() {
        let at = (k - 1) * stride;
        for lane in 0..LANES {
            let memo = memos[lane.min(memos.len() - 1)];
            residual[lane] = memo[at];
            if stride == 2 {
                stiffness[lane] = memo[at + 1];
            }
        }
        scorer.push(k, &residual, &stiffness);
    }
    scorer.finish()
}

/// The length of `run`'s part of a memo ([`run_log_likelihood_memo`]).
pub fn memo_len(noise: &dyn NoiseModel, run: &RunData) -> usize {
    run.tau.len().saturating_sub(1) * if noise.uses_stiffness(run) { 2 } else { 1 }
}
