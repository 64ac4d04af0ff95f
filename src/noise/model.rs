//! What a noise model is ([`NoiseModel`]) and what its answers are made of:
//! its parameters and their coordinates, the lane scorer of the
//! likelihood, the simulator of a new record, the MAP's profile, and the
//! densities every model shares.

use std::sync::Arc;

use rand::Rng;
use serde::{Deserialize, Serialize};
use statrs::function::gamma::ln_gamma;

use crate::data::RunData;
use crate::model::LANES;

/// The most parameters a noise model has per run.
pub const MAX_PARAMETERS: usize = 4;

/// One run's noise parameters, in the order of [`NoiseModel::parameters`]
/// (SI values or the sampler's coordinates, as each use says); unused
/// places are 0.
pub type NoiseValues = [f64; MAX_PARAMETERS];

/// How the sampler walks a noise parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transform {
    /// ln v, for a positive scale.
    Log,
    /// atanh v, for a correlation in (−1, 1).
    Atanh,
}

impl Transform {
    pub fn to_si(self, coordinate: f64) -> f64 {
        match self {
            Transform::Log => coordinate.exp(),
            Transform::Atanh => coordinate.tanh(),
        }
    }

    pub fn to_coordinate(self, si: f64) -> f64 {
        match self {
            Transform::Log => si.ln(),
            Transform::Atanh => si.atanh(),
        }
    }

    /// The coordinate's name in messages, e.g. "ln sigma_a".
    pub fn label(self, name: &str) -> String {
        match self {
            Transform::Log => format!("ln {name}"),
            Transform::Atanh => format!("atanh {name}"),
        }
    }
}

/// How a run the posterior did not see gets a value from the runs it saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pool {
    /// The root mean square (a scale: the typical variance).
    RootMeanSquare,
    /// The mean.
    Mean,
}

impl Pool {
    pub fn of(self, values: &[f64]) -> f64 {
        let n = values.len();
        match self {
            Pool::RootMeanSquare => {
                let sum: f64 = values.iter().map(|v| v.powi(2)).fold(0.0, |s, v| s + v);
                if n == 0 {
                    0.0
                } else {
                    (sum / n as f64).sqrt()
                }
            }
            Pool::Mean => {
                let sum: f64 = values.iter().fold(0.0, |s, v| s + v);
                if n == 0 {
                    0.0
                } else {
                    sum / n as f64
                }
            }
        }
    }
}

/// A noise parameter of a run: outputs name it `<name>_<run>`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Parameter {
    pub name: &'static str,
    pub unit: &'static str,
    pub transform: Transform,
    pub pool: Pool,
}

/// The smoothness of the discrepancy's Matérn kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kernel {
    /// ν = 1/2: an Ornstein-Uhlenbeck process, continuous but rough.
    Matern12,
    /// ν = 3/2: once differentiable, a smooth force.
    #[default]
    Matern32,
}

/// The discrepancy model's settings (`[likelihood.discrepancy]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DiscrepancySettings {
    pub kernel: Kernel,
    /// The shortest time scale, in sampling intervals.
    pub time_scale_min_samples: f64,
    /// The longest time scale, as a share of the excitation's period.
    pub time_scale_max_period: f64,
}

impl Default for DiscrepancySettings {
    fn default() -> Self {
        DiscrepancySettings {
            kernel: Kernel::Matern32,
            time_scale_min_samples: 2.0,
            time_scale_max_period: 0.25,
        }
    }
}

/// What a noise model is built from: the settings that concern it.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseOptions {
    /// Bounds of every noise scale σ (Pa); log-uniform between them.
    pub sigma_bounds: (f64, f64),
    /// Degrees of freedom of Student-t noise.
    pub student_nu: f64,
    /// The measured strain is noisy too (errors in variables), where the
    /// model takes it.
    pub errors_in_variables: bool,
    /// The discrepancy model's kernel and time-scale bounds.
    pub discrepancy: DiscrepancySettings,
}

impl Default for NoiseOptions {
    fn default() -> Self {
        NoiseOptions {
            sigma_bounds: (1.0, 1.0e6),
            student_nu: 5.0,
            errors_in_variables: true,
            discrepancy: Default::default(),
        }
    }
}

/// Scores the residuals of up to [`LANES`] points along one run, sample by
/// sample inside the integrator's loop.
pub trait RunScorer {
    /// Sample `k` ≥ 1: each lane's residual τ_obs − τ_model and, where the
    /// model asks for it ([`NoiseModel::uses_stiffness`]), the law's tangent
    /// stiffness there.
    fn push(&mut self, k: usize, residual: &[f64; LANES], stiffness: &[f64; LANES]);
    /// Each lane's log-likelihood of the samples pushed (up to a constant
    /// that does not depend on the parameters, where the model says so).
    fn finish(&mut self) -> [f64; LANES];
}

/// The noise of new records along a run, sample by sample, for many paths
/// at once: `replicates` paths for each of several draws.
pub trait NoiseSimulator {
    /// The noise at the next sample (from k = 0) of every path, path
    /// d × replicates + r being replicate r of draw d, where the law's
    /// tangent stiffness of draw d is `stiffness[d]`. Random numbers are
    /// drawn path by path, in that order.
    fn next(&mut self, stiffness: &[f64], rng: &mut dyn Rng, out: &mut [f64]);
}

/// Turns one run's residuals (k = 1…) into independent standard ones at
/// fixed noise parameters: what the MAP search's least squares weigh.
pub trait Whiten: Send + Sync + std::fmt::Debug {
    /// Appends the whitened residuals of `residuals` to `white`; `g` is the
    /// law's shear modulus where they were made (with errors in variables
    /// the stiffness through which the strain's noise reaches them is
    /// recomputed along them, so that it follows the model). Where the
    /// residuals' variances v_k follow the model (errors in variables), also
    /// appends to `terms` one pseudo-residual per sample, √(ln(v_k/v₀) + 1)
    /// with v₀ ≤ every v_k (the white noise's variance): with the whitened
    /// residuals their squares sum to −2 ln L up to a constant, so that
    /// least squares over both find the likelihood's maximum at these noise
    /// parameters, not that of variances held where the search began.
    fn whiten(&self, residuals: &[f64], g: f64, white: &mut Vec<f64>, terms: &mut Vec<f64>);
}

/// Whitening by a scale per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct Scales(pub Vec<f64>);

impl Whiten for Scales {
    fn whiten(&self, residuals: &[f64], _g: f64, white: &mut Vec<f64>, _terms: &mut Vec<f64>) {
        white.extend(residuals.iter().zip(&self.0).map(|(v, s)| v / s));
    }
}

/// The pseudo-residual √(ln(v/v₀) + 1) of a variance v ≥ v₀
/// ([`Whiten::whiten`]'s terms).
pub fn log_variance_term(v: f64, v0: f64) -> f64 {
    ((v / v0).ln().max(0.0) + 1.0).sqrt()
}

/// The noise of one run fitted to its residuals at a fixed model: what the
/// MAP search weighs residuals with and where the sampler starts the noise.
#[derive(Clone, Debug)]
pub struct Profile {
    /// The run's noise scale (Pa): its change tells the MAP search that the
    /// noise has settled.
    pub scale: f64,
    pub whitening: Arc<dyn Whiten>,
    /// The noise coordinates that maximise the likelihood of the residuals,
    /// inside the prior's support (the sampler's coordinates).
    pub coordinates: NoiseValues,
}

/// One draw along one run: a term per compared sample (k = 1..n−1).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pointwise {
    /// ln p(y_k | y_earlier, θ), constants included.
    pub log_likelihood: Vec<f64>,
    /// A new record drawn from the noise model around the draw's path.
    pub replicate: Vec<f64>,
}

/// What a noise model makes of one run's residuals at fixed noise values,
/// where it models a force the law lacks: E[δ(t_k) | every residual] and
/// its sd (Pa) — that force as the data show it — and the standardised
/// one-step-ahead innovations, the memory the model leaves (white if it
/// describes the residuals); each for k = 1…n−1.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Explained {
    pub mean: Vec<f64>,
    pub sd: Vec<f64>,
    pub innovations: Vec<f64>,
}

/// A model of the residuals τ_obs − τ_model of a run.
pub trait NoiseModel: Send + Sync + std::fmt::Debug {
    /// The parameters of one run, in the order of their coordinates.
    fn parameters(&self) -> &'static [Parameter];

    /// Refuses settings the model cannot use.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }

    /// ln prior density of the noise coordinates of `run` (Jacobian of the
    /// transform included); −∞ outside the support.
    fn log_prior(&self, run: &RunData, coordinates: &[f64]) -> f64;

    /// ln ∫ exp([`NoiseModel::log_prior`]) over the noise coordinates of
    /// `run`: what makes the prior a density (the evidence needs it).
    fn log_prior_normaliser(&self, run: &RunData) -> f64;

    /// What the scorer's log-likelihood of `run` leaves out: the sum of the
    /// pointwise terms (constants included) less the scorer's value, the
    /// same at every parameter value. By default the normal density's
    /// constant at each compared sample.
    fn log_likelihood_constant(&self, run: &RunData) -> f64 {
        -(run.compared() as f64) * HALF_LN_2PI
    }

    /// Sd of each coordinate of `run` near `coordinates` in a Gaussian
    /// approximation of its posterior (the start of sampling).
    fn laplace_sd(&self, run: &RunData, coordinates: &NoiseValues) -> NoiseValues;

    /// Whether the model takes the law's tangent stiffness along `run`
    /// (errors in variables: the strain noise reaches the stress through it).
    fn uses_stiffness(&self, _run: &RunData) -> bool {
        false
    }

    /// Whether the sampler updates each run's noise parameters on their
    /// own as well, given the run's residuals: worth it where the
    /// parameters are several a run and scoring a run is cheap beside
    /// integrating the law (the discrepancy model's Kalman filter).
    fn updated_alone(&self) -> bool {
        false
    }

    /// Whether the model takes residuals correlated in time (the
    /// residual-memory warning then looks at what it leaves).
    fn models_memory(&self) -> bool {
        false
    }

    /// [`Explained`] for `run`'s residuals `r` (k = 1…) with noise `values`
    /// (SI) and the law's tangent stiffness `stiffness` (from k = 0); None
    /// for a model without a force of its own.
    fn explain(
        &self,
        _run: &RunData,
        _r: &[f64],
        _stiffness: &[f64],
        _values: &NoiseValues,
    ) -> Option<Explained> {
        None
    }

    /// A scorer of `run` for [`LANES`] points with these noise coordinates.
    fn scorer<'a>(
        &'a self,
        run: &'a RunData,
        coordinates: &[NoiseValues; LANES],
    ) -> Box<dyn RunScorer + 'a>;

    /// The pointwise terms of one draw with noise `values` (SI) along `run`,
    /// whose model stress with its terms is `model` and the law's tangent
    /// stiffness `stiffness` (both indexed by sample from 0); the
    /// replicate's noise comes from `rng`.
    fn pointwise(
        &self,
        run: &RunData,
        model: &[f64],
        stiffness: &[f64],
        values: &NoiseValues,
        rng: &mut dyn Rng,
    ) -> Pointwise;

    /// The noise of new records along `run`: `replicates` of them for each
    /// draw's noise `draws` (SI).
    fn simulator(
        &self,
        run: &RunData,
        draws: &[NoiseValues],
        replicates: usize,
    ) -> Box<dyn NoiseSimulator>;

    /// ln density of one residual `r` of `run` on its own (marginally over
    /// the others), where the stiffness is `stiffness`.
    fn marginal_ln_pdf(&self, run: &RunData, r: f64, stiffness: f64, values: &NoiseValues) -> f64;

    /// The noise fitted to the residuals of `run` (k = 1…) at a model whose
    /// shear modulus is `g`.
    fn profile(&self, run: &RunData, residuals: &[f64], g: f64) -> Profile;

    /// ln p(residuals of `run`) with the noise parameters profiled out (up
    /// to a constant): the weight of a run in leave-one-out.
    fn profile_log_likelihood(&self, run: &RunData, residuals: &[f64]) -> f64;
}

/// The law's tangent stiffness at every sample of a model stress `path`
/// of `run` (G at the first).
pub fn stiffness_path(run: &RunData, path: &[f64], g: f64) -> Vec<f64> {
    (0..path.len())
        .map(|k| {
            if k == 0 {
                g
            } else {
                crate::model::tangent_stiffness(
                    path[k] - path[k - 1],
                    run.gamma[k] - run.gamma[k - 1],
                    g,
                )
            }
        })
        .collect()
}

/// ½ ln 2π, the constant of a normal log-density.
pub const HALF_LN_2PI: f64 = 0.918_938_533_204_672_7;

/// ln N(r; 0, sd²).
#[inline]
pub fn normal_ln_pdf(r: f64, sd: f64) -> f64 {
    -HALF_LN_2PI - sd.ln() - 0.5 * (r / sd).powi(2)
}

/// ln Γ((ν+1)/2) − ln Γ(ν/2) − ½ ln(νπ), the constant of a Student-t
/// log-density with ν degrees of freedom.
pub fn student_t_log_constant(nu: f64) -> f64 {
    ln_gamma(0.5 * (nu + 1.0)) - ln_gamma(0.5 * nu) - 0.5 * (nu * std::f64::consts::PI).ln()
}

/// The root mean square of residuals.
pub fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|r| r * r).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// ln ∫ exp([`log_uniform`]) d ln σ: the log of the width of its support.
pub fn log_uniform_normaliser(bounds: (f64, f64)) -> f64 {
    (bounds.1 / bounds.0).ln().ln()
}

/// The log-uniform prior of a scale's ln σ between `bounds`: 0 inside, −∞
/// outside.
pub fn log_uniform(log_sigma: f64, bounds: (f64, f64)) -> f64 {
    if log_sigma >= bounds.0.ln() && log_sigma <= bounds.1.ln() {
        0.0
    } else {
        f64::NEG_INFINITY
    }
}
