//! Settings of a calibration: likelihood, integrator, sampler and priors.
//! Read from `--config FILE` (TOML, every table optional) and written back
//! beside the outputs as `config.toml` with the values actually used: this
//! module owns that format, both ways.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::data::Campaign;
use crate::data::RecordPart;
use crate::error::{Error, Result};
use crate::identify::IdentifySettings;
use crate::laws::LawKind;
use crate::model::{Integrator, Scheme, PARAM_NAMES};
use crate::noise::{NoiseKind, NoiseModel};
use crate::posterior::parameters::law_priors;
use crate::posterior::prior::default_priors;
use crate::posterior::{
    Coordinates, LikelihoodSettings, Memory, ModelKind, ModelTerms, ParameterModel, Posterior,
    Prior,
};
use crate::sampler::{Move, RunControl, SamplerSettings};

fn is_bodner_partom(law: &LawKind) -> bool {
    law.is_bodner_partom()
}

/// Which Euler scheme integrates the likelihood.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SchemeChoice {
    /// The cheaper scheme at the step rule's accuracy; chosen at the start.
    Auto,
    Explicit,
    LinearlyImplicit,
}

impl SchemeChoice {
    /// The scheme to integrate with (explicit until `auto` is resolved).
    pub fn scheme(self) -> Scheme {
        match self {
            SchemeChoice::LinearlyImplicit => Scheme::LinearlyImplicit,
            SchemeChoice::Auto | SchemeChoice::Explicit => Scheme::Explicit,
        }
    }

    pub fn of(scheme: Scheme) -> Self {
        match scheme {
            Scheme::Explicit => SchemeChoice::Explicit,
            Scheme::LinearlyImplicit => SchemeChoice::LinearlyImplicit,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntegratorSettings {
    /// `auto`: of the two schemes, each at the step the step rule gives it,
    /// the one that costs fewer Euler steps per log-density at the MAP.
    pub scheme: SchemeChoice,
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
        IntegratorSettings {
            scheme: SchemeChoice::Auto,
            extrapolate: true,
            substeps: 0,
            max_rule_substeps: 16,
            max_substeps: 1000,
        }
    }
}

impl IntegratorSettings {
    /// The integrator with `substeps` sub-steps per sample (at least 1).
    pub fn integrator(&self, substeps: u32) -> Integrator {
        Integrator {
            scheme: self.scheme.scheme(),
            extrapolate: self.extrapolate,
            substeps: substeps.max(1),
            max_substeps: self.max_substeps,
            ..Integrator::default()
        }
    }
}

/// How the posterior is sampled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum SamplerMethod {
    /// The ensemble sampler from walkers about the Laplace approximation.
    #[default]
    Ensemble,
    /// Tempered sequential Monte Carlo from a Student-t (5 degrees of
    /// freedom) about the Laplace approximation to the posterior, each
    /// ensemble a population; the ensemble sampler then continues from its
    /// particles until converged. Gives the log evidence.
    Smc,
}

/// The moves a sampler set to `moves` walks with where the posterior is far
/// from its Laplace approximation: with the default moves, the curved move
/// in the anchored move's place (docs/performance.md, "A start far from
/// equilibrium"); other moves, a user's choice, are kept (`None`).
pub fn moves_far_from_laplace(moves: &[(Move, f64)]) -> Option<Vec<(Move, f64)>> {
    (moves == SamplingSettings::default().moves.as_slice())
        .then(|| vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)])
}

/// Degrees of freedom of the Student-t about the Laplace approximation
/// that sequential Monte Carlo starts from: tails heavy enough to reach a
/// basin or a ridge the approximation misses.
pub const SMC_REFERENCE_DF: f64 = 5.0;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SamplingSettings {
    /// The ensemble sampler, or sequential Monte Carlo before it.
    pub method: SamplerMethod,
    /// Walkers per ensemble (particles per population); 0:
    /// [`SamplingSettings::walkers_for`] the dimension, or
    /// [`SamplingSettings::walkers_near`] where the start is near.
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
    /// The coordinates the sampler walks θ in.
    pub coordinates: Coordinates,
}

impl SamplingSettings {
    /// The default walkers per ensemble for a posterior of `dim`
    /// coordinates: the smallest even number ≥ max(64, 6 dim). The
    /// independence move fits a covariance to the complementary half; its
    /// acceptance grows with the points per coordinate (about 0.27 with 32
    /// points in 10 dimensions, 0.42 with 64; docs/performance.md).
    pub fn walkers_for(dim: usize) -> usize {
        (6 * dim).max(64).div_ceil(2) * 2
    }

    /// The walkers per ensemble where the posterior is near its Laplace
    /// approximation at the mode (the initial walkers' ln p/q spreads by at
    /// most the probe's 8 nats): the smallest even number ≥
    /// max(32, 3 dim). There the anchored move, shrunk toward that
    /// approximation, is accepted as often with half the points, and the
    /// ESS a log-density buys is the same (docs/performance.md, "Fewer
    /// walkers where the start is near"), so a calibration
    /// stopped at the rule's shortest length costs half as much.
    pub fn walkers_near(dim: usize) -> usize {
        (3 * dim).max(32).div_ceil(2) * 2
    }

    /// [`SamplingSettings::walkers_near`] where the default walkers are
    /// [`SamplingSettings::walkers_for_posterior`]'s and fewer: not with
    /// sequential Monte Carlo (whose evidence wants its particles), nor
    /// where each run's noise is moved on its own (the discrepancy model,
    /// whose walkers are already sized for the coordinates proposed).
    pub fn walkers_near_posterior(&self, posterior: &crate::posterior::Posterior) -> Option<usize> {
        let full = Self::walkers_for_posterior(posterior, self.ensembles);
        let near = Self::walkers_near(posterior.layout.dim());
        (self.walkers == 0
            && self.method == SamplerMethod::Ensemble
            && crate::sampler::LogDensity::blocks(posterior).is_empty()
            && near < full)
            .then_some(near)
    }

    /// [`SamplingSettings::walkers_for`] the coordinates the ensemble moves
    /// propose on `posterior` with `ensembles` ensembles: where each run's
    /// noise is moved on its own (the discrepancy model), θ and the model
    /// terms only, else every coordinate. The ensemble's width follows the
    /// dimension it explores; the blocks move against their own ensemble's
    /// complementary half.
    pub fn walkers_for_posterior(
        posterior: &crate::posterior::Posterior,
        ensembles: usize,
    ) -> usize {
        // no walkers' memos always fit: the dimension without the blocks
        // (and at least the sampler's 2 × dimension)
        let dim = posterior.layout.dim();
        let fewer = Self::walkers_for(posterior.proposed_dimension(0)).max(2 * dim);
        match posterior.proposed_dimension(fewer * ensembles.max(1)) < dim {
            true => fewer,
            false => Self::walkers_for(dim),
        }
    }

    /// The sampler with `walkers` per ensemble and a seed of its own.
    pub fn sampler(&self, walkers: usize, seed: u64) -> SamplerSettings {
        SamplerSettings { walkers, ensembles: self.ensembles, moves: self.moves.clone(), seed }
    }

    /// How long to run: a fixed number of steps, or until converged.
    pub fn control(&self) -> RunControl {
        RunControl {
            max_steps: if self.steps > 0 { self.steps } else { self.max_steps },
            until_converged: self.steps == 0,
            check_every: self.check_every,
            min_ess: self.min_ess,
            ..RunControl::fixed(0)
        }
    }
}

impl Default for SamplingSettings {
    fn default() -> Self {
        SamplingSettings {
            method: SamplerMethod::Ensemble,
            walkers: 0,
            ensembles: 4,
            seed: 1,
            moves: vec![(Move::anchored(), 0.9), (Move::differential_evolution(), 0.1)],
            steps: 0,
            max_steps: 5_000,
            min_ess: 400.0,
            check_every: 10,
            burn_in: 0,
            coordinates: Coordinates::Hardening,
        }
    }
}

/// The options of `mrbp sample` (and `run`, `study plan`) that override the
/// settings file, in emcee's words where they exist.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct Overrides {
    /// Settings file (TOML): priors, likelihood, integrator, sampler; the
    /// options below override it
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// How the B-P parameters relate to the runs (default: per-current)
    #[arg(long, value_enum)]
    pub model: Option<ModelKind>,
    /// The damper law (default: bodner-partom; docs/calibration.md, "Damper
    /// laws"); `run` takes several, comma separated, and ranks them by what
    /// they predict (with --leave-one-out)
    #[arg(long, value_enum, value_delimiter = ',')]
    pub law: Vec<LawKind>,
    /// Walkers per ensemble (default: the smallest even number ≥ max(64, 6 × the dimension the ensemble moves explore: with `--noise discrepancy` each run's noise, moved on its own, is not counted); of which a start near its Laplace approximation keeps max(32, 3 × that dimension))
    #[arg(long)]
    pub walkers: Option<usize>,
    /// Independent ensembles (default 4)
    #[arg(long)]
    pub ensembles: Option<usize>,
    /// The sampler (default: ensemble; `smc`: tempered sequential Monte
    /// Carlo from the Laplace approximation to the posterior, each ensemble
    /// a population, then the ensemble sampler from its particles; gives
    /// the log evidence)
    #[arg(long, value_enum)]
    pub sampler: Option<SamplerMethod>,
    /// A fixed number of steps (default: until converged, R̂ < 1.01, ESS ≥ 400)
    #[arg(long)]
    pub steps: Option<usize>,
    /// Seed of the sampler's random streams (default 1); the same seed gives
    /// the same chains on any number of threads
    #[arg(long)]
    pub seed: Option<u64>,
    /// Residual model (default: gaussian)
    #[arg(long, value_enum)]
    pub noise: Option<NoiseKind>,
    /// How the residuals' memory enters the likelihood (default: auto —
    /// independent where the MAP residuals have no memory, else adjusted;
    /// `independent`: every residual new evidence; `tempered`: each run
    /// counts once per integrated autocorrelation time of its MAP
    /// residuals; `adjusted`: each parameter widened by the memory of the
    /// part of the records that informs it, docs/calibration.md)
    #[arg(long, value_enum)]
    pub memory: Option<crate::posterior::Memory>,
    /// Samples in the likelihood (default: whole-record)
    #[arg(long, value_enum)]
    pub part: Option<RecordPart>,
    /// Take the measured displacement as exact (by default its noise,
    /// estimated from the record, reaches the stress through the model's
    /// stiffness: errors in variables, with gaussian noise; docs/calibration.md)
    #[arg(long)]
    pub exact_input: bool,
    /// Integrator sub-steps per sample, at least 1 (default: chosen by the step rule)
    #[arg(long)]
    pub substeps: Option<u32>,
}

impl Overrides {
    /// The settings file with the options applied, checked.
    pub fn settings(&self) -> Result<CalibrationSettings> {
        let mut s = match &self.config {
            Some(path) => CalibrationSettings::read(path)?,
            None => CalibrationSettings::default(),
        };
        let positive = |v: usize, name: &str| {
            if v == 0 {
                Err(Error::Usage(format!("{name} must be at least 1")))
            } else {
                Ok(v)
            }
        };
        if let Some(v) = self.walkers {
            s.sampler.walkers = positive(v, "--walkers")?;
        }
        if let Some(v) = self.ensembles {
            s.sampler.ensembles = positive(v, "--ensembles")?;
        }
        if let Some(v) = self.steps {
            s.sampler.steps = positive(v, "--steps")?;
        }
        if let Some(v) = self.substeps {
            s.integrator.substeps = positive(v as usize, "--substeps")? as u32;
        }
        s.sampler.seed = self.seed.unwrap_or(s.sampler.seed);
        s.sampler.method = self.sampler.unwrap_or(s.sampler.method);
        s.likelihood.noise = self.noise.unwrap_or(s.likelihood.noise);
        s.likelihood.part = self.part.unwrap_or(s.likelihood.part);
        s.likelihood.memory = self.memory.unwrap_or(s.likelihood.memory);
        if self.exact_input {
            s.likelihood.errors_in_variables = false;
        }
        s.model = self.model.unwrap_or(s.model);
        if let Some(law) = self.law.first() {
            s.set_law(*law);
        }
        s.check().map_err(Error::Usage)?;
        Ok(s)
    }
}

/// Everything that defines a calibration besides the data.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationSettings {
    pub model: ModelKind,
    /// The damper law (`law = "spencer"`; the B-P law where absent).
    #[serde(skip_serializing_if = "is_bodner_partom")]
    pub law: LawKind,
    /// Reference current of the current law (A): R0, R1, D1 are its values there.
    pub reference_current_a: f64,
    /// The current curves' anchor currents (A): their `*_low` and `*_high`
    /// parameters are the values there. Unset: the lowest and highest
    /// current calibrated (filled in when the calibration starts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anchor_currents_a: Option<(f64, f64)>,
    /// A law's coil lag τ_c as a parameter (`coil_lag_s`): by default on
    /// where a run's current varies within its record, off otherwise
    /// (filled in when the calibration starts); `false` takes the record's
    /// current as the field's (a measured coil current that already lags).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coil_lag: Option<bool>,
    pub likelihood: LikelihoodSettings,
    pub integrator: IntegratorSettings,
    pub sampler: SamplingSettings,
    pub identify: IdentifySettings,
    /// Priors by parameter name (the law's: G, R0, R1, D1, m1, m2, n for
    /// the B-P law).
    pub prior: BTreeMap<String, Prior>,
    /// Bounds of every noise scale σ (Pa); log-uniform prior between them.
    pub sigma_bounds_pa: (f64, f64),
    /// Terms a real damper adds to the fluid's force, and their priors.
    pub terms: ModelTerms,
    /// Where the MAP search starts, by parameter name (SI units; the law's
    /// parameters and the model terms), in place of the identification or
    /// the starts a law reads off the records; the prior medians are
    /// searched beside it as always. A run calibrated alone (`--per-run`)
    /// starts from its joint calibration's MAP where that calibration
    /// started near its Laplace approximation (docs/calibration.md,
    /// "Consistency across runs"). A name the calibration does not have is
    /// refused. Empty: the usual starts.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub map_start: BTreeMap<String, f64>,
}

impl Default for CalibrationSettings {
    fn default() -> Self {
        CalibrationSettings {
            model: ModelKind::PerCurrent,
            law: LawKind::BodnerPartom,
            reference_current_a: 1.0,
            anchor_currents_a: None,
            coil_lag: None,
            likelihood: LikelihoodSettings::default(),
            integrator: IntegratorSettings::default(),
            sampler: SamplingSettings::default(),
            identify: IdentifySettings::default(),
            prior: PARAM_NAMES
                .iter()
                .zip(default_priors())
                .map(|(n, p)| (n.to_string(), p))
                .collect(),
            sigma_bounds_pa: (1.0, 1.0e6),
            terms: ModelTerms::default(),
            map_start: BTreeMap::new(),
        }
    }
}

impl CalibrationSettings {
    /// Reads a settings file; missing tables and keys keep their defaults,
    /// priors not named keep theirs.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        let mut s: CalibrationSettings = toml::from_str(&text)
            .map_err(|e| Error::input(path, format!("invalid settings: {}", e.message())))?;
        // priors not named keep the B-P law's defaults, which give way to
        // the file's law's own
        let law = std::mem::take(&mut s.law);
        for (name, prior) in PARAM_NAMES.iter().zip(default_priors()) {
            s.prior.entry(name.to_string()).or_insert(prior);
        }
        s.set_law(law);
        s.check().map_err(|m| Error::input(path, m))?;
        Ok(s)
    }

    /// These settings with the damper law `law`: the priors the old law's
    /// defaults filled in give way to the new law's (a prior set by hand
    /// stays, and is refused by [`Self::check`] if the law has no such
    /// parameter).
    pub fn set_law(&mut self, law: LawKind) {
        let old = law_priors(self.law);
        let old_names = self.law.law().names();
        self.prior.retain(|name, p| {
            old_names.iter().position(|n| n == name).is_none_or(|i| *p != old[i])
        });
        self.law = law;
        for (name, prior) in law.law().names().iter().zip(law_priors(law)) {
            self.prior.entry(name.to_string()).or_insert(prior);
        }
    }

    pub fn check(&self) -> std::result::Result<(), String> {
        let names = self.law.law().names();
        for name in self.prior.keys() {
            if !names.contains(&name.as_str()) {
                return Err(format!(
                    "prior for unknown parameter '{name}' (the {} law's are {})",
                    self.law.name(),
                    names.join(", ")
                ));
            }
        }
        ParameterModel::check_law(self.model, self.law).map_err(|e| e.to_string())?;
        for (name, p) in &self.prior {
            p.check(name)?;
        }
        let (lo, hi) = self.sigma_bounds_pa;
        if !(lo > 0.0 && hi > lo) {
            return Err("sigma_bounds_pa must be 0 < lower < upper".into());
        }
        self.likelihood.check()?;
        if let Some(a) = self.likelihood.adjustment() {
            let d = self.parameter_model().names().len();
            if self.parameter_model().is_current_law() || a.centre.len() != d {
                return Err(format!(
                    "memory_adjustment: {} parameters, but the adjusted likelihood takes the {d} of one parameter set per current (not the current law)",
                    a.centre.len(),
                ));
            }
        }
        self.noise_model().check()?;
        self.terms.check()?;
        if !(self.reference_current_a > 0.0) {
            return Err("reference_current_a must be positive".into());
        }
        if let Some((lo, hi)) = self.anchor_currents_a {
            if !(lo >= 0.0 && hi > lo && hi.is_finite()) {
                return Err(format!(
                    "anchor_currents_a must be two currents 0 ≤ low < high; got [{lo}, {hi}]"
                ));
            }
        }
        if self.sampler.ensembles == 0 {
            return Err("at least one ensemble".into());
        }
        Ok(())
    }

    /// The priors of the law's parameters, in their order.
    pub fn priors(&self) -> Vec<Prior> {
        let defaults = law_priors(self.law);
        self.law
            .law()
            .names()
            .iter()
            .zip(defaults)
            .map(|(n, d)| self.prior.get(*n).copied().unwrap_or(d))
            .collect()
    }

    /// How θ gives the law's parameters of each run.
    pub fn parameter_model(&self) -> ParameterModel {
        ParameterModel::new(
            self.model,
            self.law,
            self.reference_current_a,
            self.anchor_currents_a,
            self.coil_lag.unwrap_or(false),
        )
    }

    /// Whether a calibration whose settings resolved to `done` (its
    /// config.toml) is the one these settings ask for: where these leave a
    /// choice to the start — the scheme and its sub-steps, the walkers, the
    /// residuals' memory and what was measured of it, a law's anchors and
    /// coil lag, the moves of a start far from its Laplace approximation —
    /// `done`'s choice is taken; every other setting must be equal.
    pub fn asks_for(&self, done: &CalibrationSettings) -> bool {
        let mut asked = self.clone();
        let (integ, lik) = (&mut asked.integrator, &mut asked.likelihood);
        if integ.scheme == SchemeChoice::Auto {
            integ.scheme = done.integrator.scheme;
        }
        if integ.substeps == 0 {
            integ.substeps = done.integrator.substeps;
        }
        if asked.sampler.walkers == 0 {
            asked.sampler.walkers = done.sampler.walkers;
        }
        if lik.memory == Memory::Auto {
            lik.memory = done.likelihood.memory;
        }
        if lik.memory_times.is_empty() {
            lik.memory_times = done.likelihood.memory_times.clone();
        }
        if lik.memory_adjustment.is_none() {
            lik.memory_adjustment = done.likelihood.memory_adjustment.clone();
        }
        asked.anchor_currents_a = asked.anchor_currents_a.or(done.anchor_currents_a);
        asked.coil_lag = asked.coil_lag.or(done.coil_lag);
        if moves_far_from_laplace(&asked.sampler.moves).as_ref() == Some(&done.sampler.moves) {
            asked.sampler.moves = done.sampler.moves.clone();
        }
        asked == *done
    }

    /// The curves' anchors, where unset, from the currents calibrated: the
    /// lowest and the highest.
    pub fn fill_anchors(&mut self, currents: &[f64]) {
        if self.model == ModelKind::CurrentCurves
            && self.anchor_currents_a.is_none()
            && currents.len() >= 2
        {
            let lo = currents.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = currents.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            self.anchor_currents_a = Some((lo, hi));
        }
    }

    /// The coil's lag, where unset: on for a law when some run's current
    /// varies (`varies`).
    pub fn fill_coil_lag(&mut self, varies: bool) {
        if self.coil_lag.is_none() && self.model.is_law() {
            self.coil_lag = Some(varies);
        }
    }

    /// The noise model of the likelihood, with its scales' bounds.
    pub fn noise_model(&self) -> Arc<dyn NoiseModel> {
        self.likelihood.noise_model(self.sigma_bounds_pa)
    }

    /// The posterior of the runs of `campaign` with these settings.
    pub fn posterior(&self, campaign: &Campaign, integrator: Integrator) -> Posterior {
        let model = self.parameter_model();
        Posterior::new(
            campaign,
            model,
            model.priors(&self.priors()),
            &self.likelihood,
            self.sigma_bounds_pa,
            integrator,
            self.sampler.coordinates,
            &self.terms,
        )
    }

    /// Writes the settings file (`config.toml`: the settings a calibration
    /// actually used, which `--config` takes back to repeat it).
    pub fn write(&self, path: &Path) -> Result<()> {
        let text =
            toml::to_string(self).map_err(|e| Error::Compute(format!("writing settings: {e}")))?;
        let header =
            "# Settings actually used by this calibration; pass back with --config to repeat it.\n";
        crate::atomic::write(path, format!("{header}{text}").as_bytes())
    }
}
