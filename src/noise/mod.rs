//! Noise models: how a force record scatters about the model, one model a
//! file behind one trait, [`NoiseModel`].
//!
//! A noise model has parameters of its own for every run (a scale σ, a
//! correlation ρ, …) and answers every question about them, so that the
//! likelihood, the MAP search, the bands, the pointwise terms and
//! leave-one-out never ask which model they hold:
//!
//! | question | method |
//! |---|---|
//! | the parameters: names, units, coordinates, pooling over runs | [`NoiseModel::parameters`] |
//! | their prior, and their spread at the start of sampling | [`NoiseModel::log_prior`], [`NoiseModel::laplace_sd`] |
//! | the log-likelihood of a run's residuals, in the integrator's lanes | [`NoiseModel::scorer`] |
//! | conditional pointwise terms and a replicated record of one draw | [`NoiseModel::pointwise`] |
//! | a new record's noise and its marginal density (predictive bands) | [`NoiseModel::simulator`], [`NoiseModel::marginal_ln_pdf`] |
//! | the noise fitted to residuals and their whitening (the MAP) | [`NoiseModel::profile`] |
//! | a run's likelihood with its noise profiled out (leave-one-out) | [`NoiseModel::profile_log_likelihood`] |
//!
//! **Adding a noise model**: a file here with a type that implements
//! [`NoiseModel`] and has `fn new(&NoiseOptions) -> Self`, and its line in
//! the [`registry!`] at the end of this file (which also makes its name an
//! option of `--noise` and a value of `[likelihood] noise`).

pub mod ar1;
pub mod gaussian;
pub mod student_t;

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
                if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
            }
            Pool::Mean => {
                let sum: f64 = values.iter().fold(0.0, |s, v| s + v);
                if n == 0 { 0.0 } else { sum / n as f64 }
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
}

impl Default for NoiseOptions {
    fn default() -> Self {
        NoiseOptions { sigma_bounds: (1.0, 1.0e6), student_nu: 5.0, errors_in_variables: true }
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

/// A new record's noise, sample by sample: one random number per sample.
pub trait NoiseSimulator {
    /// The noise at the next sample (from k = 0), where the law's tangent
    /// stiffness is `stiffness`.
    fn next(&mut self, stiffness: f64, rng: &mut dyn Rng) -> f64;
}

/// Turns one run's residuals (k = 1…) into independent standard ones at
/// fixed noise parameters; linear in the residuals.
pub trait Whiten: Send + Sync + std::fmt::Debug {
    /// Appends the whitened residuals of `residuals` to `out`.
    fn whiten(&self, residuals: &[f64], out: &mut Vec<f64>);
}

/// Whitening by a scale per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct Scales(pub Vec<f64>);

impl Whiten for Scales {
    fn whiten(&self, residuals: &[f64], out: &mut Vec<f64>) {
        out.extend(residuals.iter().zip(&self.0).map(|(v, s)| v / s));
    }
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

/// A model of the residuals τ_obs − τ_model of a run.
pub trait NoiseModel: Send + Sync + std::fmt::Debug {
    /// The parameters of one run, in the order of their coordinates.
    fn parameters(&self) -> &'static [Parameter];

    /// Refuses settings the model cannot use.
    fn check(&self) -> Result<(), String> {
        Ok(())
    }

    /// ln prior density of one run's noise coordinates (Jacobian of the
    /// transform included); −∞ outside the support.
    fn log_prior(&self, coordinates: &[f64]) -> f64;

    /// Sd of each coordinate in a Gaussian approximation from `compared`
    /// residuals (the start of sampling).
    fn laplace_sd(&self, compared: usize) -> NoiseValues;

    /// Whether the model takes the law's tangent stiffness along `run`
    /// (errors in variables: the strain noise reaches the stress through it).
    fn uses_stiffness(&self, _run: &RunData) -> bool {
        false
    }

    /// Whether the model takes residuals correlated in time (then the
    /// residual-memory warning is moot).
    fn models_memory(&self) -> bool {
        false
    }

    /// A scorer of `run` for [`LANES`] points with these noise coordinates.
    fn scorer<'a>(&'a self, run: &'a RunData, coordinates: &[NoiseValues; LANES]) -> Box<dyn RunScorer + 'a>;

    /// The pointwise terms of one draw with noise `values` (SI) along `run`,
    /// whose model stress with its terms is `model` and the law's tangent
    /// stiffness `stiffness` (both indexed by sample from 0); the
    /// replicate's noise comes from `rng`.
    fn pointwise(&self, run: &RunData, model: &[f64], stiffness: &[f64], values: &NoiseValues, rng: &mut dyn Rng) -> Pointwise;

    /// The noise of a new record with `values` (SI) along `run`.
    fn simulator(&self, run: &RunData, values: &NoiseValues) -> Box<dyn NoiseSimulator>;

    /// ln density of one residual `r` of `run` on its own (marginally over
    /// the others), where the stiffness is `stiffness`.
    fn marginal_ln_pdf(&self, run: &RunData, r: f64, stiffness: f64, values: &NoiseValues) -> f64;

    /// The noise fitted to the residuals of `run` (k = 1…) at a model whose
    /// shear modulus is `g`.
    fn profile(&self, run: &RunData, residuals: &[f64], g: f64) -> Profile;

    /// ln p(residuals) with the noise parameters profiled out (up to a
    /// constant): the weight of a run in leave-one-out.
    fn profile_log_likelihood(&self, residuals: &[f64]) -> f64;
}

/// The law's tangent stiffness at every sample of a model stress `path`
/// of `run` (G at the first).
pub fn stiffness_path(run: &RunData, path: &[f64], g: f64) -> Vec<f64> {
    (0..path.len())
        .map(|k| if k == 0 { g } else { crate::model::tangent_stiffness(path[k] - path[k - 1], run.gamma[k] - run.gamma[k - 1], g) })
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

/// The log-uniform prior of a scale's ln σ between `bounds`: 0 inside, −∞
/// outside.
pub fn log_uniform(log_sigma: f64, bounds: (f64, f64)) -> f64 {
    if log_sigma >= bounds.0.ln() && log_sigma <= bounds.1.ln() {
        0.0
    } else {
        f64::NEG_INFINITY
    }
}

/// The registry: every noise model, by the name the command line and the
/// settings files give it.
macro_rules! registry {
    ($($(#[$attr:meta])* $variant:ident => $model:ty,)+) => {
        /// A noise model by name (`--noise`, `[likelihood] noise`).
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
        #[serde(rename_all = "kebab-case")]
        pub enum NoiseKind {
            $($(#[$attr])* $variant,)+
        }

        impl NoiseKind {
            /// The model of this name with `options`.
            pub fn model(self, options: &NoiseOptions) -> Arc<dyn NoiseModel> {
                match self {
                    $(NoiseKind::$variant => Arc::new(<$model>::new(options)),)+
                }
            }

            /// Every noise model.
            pub const ALL: &'static [NoiseKind] = &[$(NoiseKind::$variant,)+];
        }
    };
}

registry! {
    /// Independent Gaussian residuals, one unknown σ per run; with errors in
    /// variables (the default) the strain's noise joins them.
    #[serde(alias = "Gaussian")]
    Gaussian => gaussian::Gaussian,
    /// Independent Student-t residuals (fixed ν), one unknown scale per run:
    /// robust to outliers.
    #[serde(alias = "StudentT")]
    StudentT => student_t::StudentT,
    /// AR(1) residuals, one unknown innovation σ and lag-one correlation ρ
    /// per run: for dense records whose residuals are correlated, where an
    /// independent model claims far too much certainty.
    #[serde(alias = "Ar1")]
    Ar1 => ar1::Ar1,
}

/// The unit of a noise coordinate named `<parameter>_<run>`, if it is one.
pub fn unit_of(name: &str) -> Option<&'static str> {
    let options = NoiseOptions::default();
    NoiseKind::ALL
        .iter()
        .flat_map(|k| k.model(&options).parameters())
        .find(|p| name.strip_prefix(p.name).is_some_and(|rest| rest.starts_with('_')))
        .map(|p| p.unit)
}

#[cfg(test)]
pub(crate) mod testing {
    //! What every model's tests share: a run with two branches and a
    //! yielding path, and the pointwise terms summed.

    use super::*;

    /// A short run with two branches and a path that yields (so the
    /// tangent stiffness varies), its residuals about the path irregular.
    pub fn run(strain_noise_var: f64) -> (RunData, Vec<f64>) {
        let n = 41;
        let time: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        let gamma: Vec<f64> = (0..n).map(|k| 0.02 * (k as f64 * 0.15).sin()).collect();
        let path: Vec<f64> = gamma.iter().map(|g| 4e4 * (g / 0.01).tanh()).collect();
        let tau: Vec<f64> = path.iter().enumerate().map(|(k, p)| p + 300.0 * ((k as f64) * 1.7).sin() + 120.0 * ((k as f64) * 0.31).cos()).collect();
        let run = RunData::new("r".into(), time, gamma, tau, path[0], 1.0, (1.0, 1.0), (strain_noise_var, 0.3));
        (run, path)
    }

    /// The log-likelihood a model's scorer gives `run` at `coordinates`
    /// (every lane alike), with the residuals about `path`.
    pub fn scored(model: &dyn NoiseModel, run: &RunData, path: &[f64], coordinates: NoiseValues, g: f64) -> f64 {
        let stiffness = stiffness_path(run, path, g);
        let mut scorer = model.scorer(run, &[coordinates; LANES]);
        for k in 1..run.time.len() {
            scorer.push(k, &[run.tau[k] - path[k]; LANES], &[stiffness[k]; LANES]);
        }
        let ll = scorer.finish();
        assert!(ll.iter().all(|v| *v == ll[0]), "lanes disagree");
        ll[0]
    }

    /// The sum of a model's pointwise terms along `path`.
    pub fn pointwise_sum(model: &dyn NoiseModel, run: &RunData, path: &[f64], values: NoiseValues, g: f64) -> f64 {
        let stiffness = stiffness_path(run, path, g);
        let p = model.pointwise(run, path, &stiffness, &values, &mut crate::rng::stream(1, &[]));
        assert_eq!(p.log_likelihood.len(), run.compared());
        p.log_likelihood.iter().sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_model_names_its_parameters_and_units() {
        assert_eq!(unit_of("sigma_I1.0_200rpm"), Some("Pa"));
        assert_eq!(unit_of("rho_a"), Some("1"));
        assert_eq!(unit_of("G"), None);
        for kind in NoiseKind::ALL {
            let m = kind.model(&NoiseOptions::default());
            assert!(!m.parameters().is_empty() && m.parameters().len() <= MAX_PARAMETERS, "{kind:?}");
        }
    }

    #[test]
    fn pooling_takes_the_rms_of_scales_and_the_mean_of_the_rest() {
        assert!((Pool::RootMeanSquare.of(&[3.0, 4.0]) - 12.5f64.sqrt()).abs() < 1e-15);
        assert_eq!(Pool::Mean.of(&[0.2, 0.6]), 0.4);
        assert_eq!(Pool::Mean.of(&[]), 0.0);
    }
}
