//! Settings of a calibration: likelihood, integrator, sampler and priors.
//! Read from `--config FILE` (TOML, every table optional) and written back
//! beside the outputs as `config.toml` with the values actually used.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::prior::{default_priors, Prior};
use crate::error::{Error, Result};
use crate::identify::IdentifySettings;
use crate::model::{Scheme, PARAM_NAMES};
use crate::sampler::Move;

/// The residual model of the force record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseModel {
    /// Independent Gaussian residuals, one unknown σ per run.
    Gaussian,
    /// Independent Student-t residuals (fixed ν), one unknown scale per run:
    /// robust to outliers.
    StudentT,
    /// AR(1) residuals, one unknown innovation σ and lag-one correlation ρ
    /// per run: for dense records whose residuals are correlated, where an
    /// independent model claims far too much certainty.
    Ar1,
}

/// Which samples of each record enter the likelihood.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RecordPart {
    /// The first loading branch (the paper's choice).
    FirstBranch,
    /// From the start to the last reversal: every complete branch.
    AllBranches,
    /// Every sample.
    WholeRecord,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LikelihoodSettings {
    pub noise: NoiseModel,
    /// Half-width (ms) of the local cubic fit that smooths the measured
    /// strain before it drives the model; 0 uses the raw samples. The model
    /// turns displacement noise into stress noise (G δγ) and biases G
    /// (an errors-in-variables effect); the crank's displacement is smooth
    /// on this scale, so the fit removes noise, not signal.
    pub smooth_strain_ms: f64,
    /// Degrees of freedom of the Student-t model.
    pub student_nu: f64,
    pub part: RecordPart,
}

impl Default for LikelihoodSettings {
    fn default() -> Self {
        LikelihoodSettings { noise: NoiseModel::Gaussian, smooth_strain_ms: 2.0, student_nu: 5.0, part: RecordPart::WholeRecord }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntegratorSettings {
    pub scheme: Scheme,
    /// Richardson extrapolation of two Euler solutions (steps h and h/2):
    /// second order at three Euler steps per sub-step.
    pub extrapolate: bool,
    /// Sub-steps per sample interval; 0: chosen by the step rule (halving
    /// the step at the MAP must move no parameter by 0.05 sd or more).
    pub substeps: u32,
    /// Most sub-steps the step rule may choose.
    pub max_rule_substeps: u32,
    /// Most sub-steps per sample interval before a point counts as too stiff
    /// (log-density −∞).
    pub max_substeps: u32,
}

impl Default for IntegratorSettings {
    fn default() -> Self {
        IntegratorSettings { scheme: Scheme::Explicit, extrapolate: true, substeps: 0, max_rule_substeps: 16, max_substeps: 1000 }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SamplingSettings {
    /// Walkers per ensemble; 0: the smallest even number ≥ max(24, 2 × dim).
    pub walkers: usize,
    pub ensembles: usize,
    pub seed: u64,
    /// Moves and their weights.
    pub moves: Vec<(Move, f64)>,
    /// A fixed number of steps; 0: run until converged within `max_steps`.
    pub steps: usize,
    pub max_steps: usize,
    /// Convergence also asks for at least this bulk and tail ESS.
    pub min_ess: f64,
    pub check_every: usize,
    /// Burn-in to discard; 0: the rule of the diagnostics (3 τ_max).
    pub burn_in: usize,
}

impl Default for SamplingSettings {
    fn default() -> Self {
        SamplingSettings {
            walkers: 0,
            ensembles: 4,
            seed: 1,
            moves: vec![(Move::differential_evolution(), 0.8), (Move::snooker(), 0.2)],
            steps: 0,
            max_steps: 20_000,
            min_ess: 400.0,
            check_every: 250,
            burn_in: 0,
        }
    }
}

/// How the B-P parameters relate to the runs of a calibration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModelKind {
    /// One parameter set for the runs of one coil current.
    PerCurrent,
    /// The parameters as functions of the current (posterior::current_law),
    /// one posterior for the runs of every current.
    CurrentLaw,
}

impl ModelKind {
    /// Names of the θ coordinates (before the noise ones), SI in outputs.
    pub fn theta_names(self) -> &'static [&'static str] {
        match self {
            ModelKind::PerCurrent => &PARAM_NAMES,
            ModelKind::CurrentLaw => &super::current_law::LAW_NAMES,
        }
    }
}

/// Everything that defines a calibration besides the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationSettings {
    pub model: ModelKind,
    /// Reference current of the current law (A): R0, R1, D1 are its values there.
    pub reference_current_a: f64,
    pub likelihood: LikelihoodSettings,
    pub integrator: IntegratorSettings,
    pub sampler: SamplingSettings,
    pub identify: IdentifySettings,
    /// Priors by parameter name (G, R0, R1, D1, m1, m2, n).
    pub prior: BTreeMap<String, Prior>,
    /// Bounds of every noise scale σ (Pa); log-uniform prior between them.
    pub sigma_bounds_pa: (f64, f64),
}

impl Default for CalibrationSettings {
    fn default() -> Self {
        CalibrationSettings {
            model: ModelKind::PerCurrent,
            reference_current_a: 1.0,
            likelihood: LikelihoodSettings::default(),
            integrator: IntegratorSettings::default(),
            sampler: SamplingSettings::default(),
            identify: IdentifySettings::default(),
            prior: PARAM_NAMES.iter().zip(default_priors()).map(|(n, p)| (n.to_string(), p)).collect(),
            sigma_bounds_pa: (1.0, 1.0e6),
        }
    }
}

impl CalibrationSettings {
    /// Reads a settings file; missing tables and keys keep their defaults,
    /// priors not named keep theirs.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        let mut s: CalibrationSettings =
            toml::from_str(&text).map_err(|e| Error::input(path, format!("invalid settings: {}", e.message())))?;
        for (name, prior) in PARAM_NAMES.iter().zip(default_priors()) {
            s.prior.entry(name.to_string()).or_insert(prior);
        }
        s.check().map_err(|m| Error::input(path, m))?;
        Ok(s)
    }

    pub fn check(&self) -> std::result::Result<(), String> {
        for name in self.prior.keys() {
            if !PARAM_NAMES.contains(&name.as_str()) {
                return Err(format!("prior for unknown parameter '{name}'"));
            }
        }
        for (name, p) in &self.prior {
            p.check(name)?;
        }
        let (lo, hi) = self.sigma_bounds_pa;
        if !(lo > 0.0 && hi > lo) {
            return Err("sigma_bounds_pa must be 0 < lower < upper".into());
        }
        if !(self.likelihood.smooth_strain_ms >= 0.0) {
            return Err("smooth_strain_ms must be 0 or positive".into());
        }
        if self.likelihood.noise == NoiseModel::StudentT && !(self.likelihood.student_nu > 0.0) {
            return Err("student_nu must be positive".into());
        }
        if !(self.reference_current_a > 0.0) {
            return Err("reference_current_a must be positive".into());
        }
        if self.sampler.ensembles == 0 {
            return Err("at least one ensemble".into());
        }
        Ok(())
    }

    /// The priors in parameter order.
    pub fn priors(&self) -> [Prior; 7] {
        std::array::from_fn(|i| self.prior[PARAM_NAMES[i]])
    }

    /// Priors of the θ coordinates, in the order of [`ModelKind::theta_names`].
    pub fn theta_priors(&self) -> Vec<Prior> {
        match self.model {
            ModelKind::PerCurrent => self.priors().to_vec(),
            ModelKind::CurrentLaw => self.law().priors(&self.priors()),
        }
    }

    /// The current law of a `current-law` model.
    pub fn law(&self) -> super::CurrentLaw {
        super::CurrentLaw { reference_a: self.reference_current_a }
    }

    pub fn to_toml(&self) -> Result<String> {
        toml::to_string(self).map_err(|e| Error::Compute(format!("writing settings: {e}")))
    }
}
