//! One calibration: the runs of one current level (or of several, for the
//! current law), from the identification through the MAP start and the
//! step rule ([`start`]) to the posterior sample ([`sample`]), and the
//! calibration itself ([`Calibration`]), the same whether just made or read
//! from its folder.
//!
//! * [`settings`]: what defines a calibration besides the data (the
//!   `config.toml` format);
//! * [`probe`]: the walkers' first steps judge the start (a local mode, a
//!   posterior far from its Laplace approximation);
//! * [`record`]: what a calibration did (`calibration.toml`);
//! * [`sampling`]: one run of the sampler, for a calibration and for each
//!   held-out calibration of leave-one-out alike;
//! * `sequential`: sequential Monte Carlo before the ensemble sampler
//!   (`--sampler smc`);
//! * [`edge`]: where `memory = "auto"` took the adjusted likelihood, the
//!   walkers' own paths checked while sampling, and the tempered
//!   likelihood taken instead where they miss the records;
//! * [`evidence`]: what a log evidence is of, and a calibration's by
//!   bridge sampling from its chains.

pub mod edge;
pub mod evidence;
pub mod probe;
pub mod record;
pub mod sampling;
pub(crate) mod sequential;
pub mod settings;
pub mod start;

use std::path::{Path, PathBuf};

use crate::data::{Campaign, Geometry, Manifest};
use crate::error::{Error, Result};
use crate::posterior::laplace::IntervalRow;
use crate::posterior::{Draws, PosteriorSample, SummaryRow};
use crate::predict::PredictSettings;
use crate::sampler::{Chains, Diagnostics, Observer, Sampler};
pub use edge::{far_from_records, sample_watched};
pub use record::{command_line, CalibrationRecord, SmcRecord, StepRow};
pub use sampling::Sampled;
pub use settings::{
    CalibrationSettings, IntegratorSettings, SamplerMethod, SamplingSettings, SchemeChoice,
    SMC_REFERENCE_DF,
};
pub use start::{
    confounding_warning, start, start_refusing_adjusted, Start, CONFOUNDING_RATIO, MEMORY_REMEDY,
    MEMORY_WARNING,
};

/// A calibration: its settings, what it did, its posterior sample and
/// summary. What `predict`, `report`, `compare`, leave-one-out and studies
/// start from, whether made by this process or read from its folder
/// ([`crate::store::folder`]).
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The folder it was written to or read from (empty until written).
    pub dir: PathBuf,
    pub settings: CalibrationSettings,
    pub record: CalibrationRecord,
    /// One row per coordinate: posterior statistics and diagnostics.
    pub summary: Vec<SummaryRow>,
    pub sample: PosteriorSample,
}

/// What calibrating returns: the calibration, where it started and the
/// sampler's chains in its own coordinates.
pub struct Calibrated {
    pub calibration: Calibration,
    pub start: Start,
    pub chains: Chains,
    /// Diagnostics in SI units after the burn-in.
    pub diagnostics: Diagnostics,
}

impl Calibration {
    /// Wall time of the whole calibration (s): start and sampling.
    pub fn seconds(&self) -> f64 {
        self.record.seconds_start + self.record.seconds_sampling
    }

    /// Whether its walkers started near the posterior's Laplace
    /// approximation (ln p/q over the initial walkers spread by at most
    /// 8 nats; docs/calibration.md, "The start", step 4).
    pub fn started_near_laplace(&self) -> bool {
        self.record.laplace_spread_nats.is_some_and(|s| s <= probe::FAR_FROM_LAPLACE)
    }

    /// What the posterior's intervals hold for, in a phrase (summary.parquet's
    /// `holds_for`, the report): these records — with their residuals'
    /// memory allowed for or modelled, or as if their residuals were
    /// independent where they have memory the likelihood ignores.
    pub fn intervals_hold_for(&self) -> String {
        let lik = &self.settings.likelihood;
        if let Some(a) = lik.allowance() {
            let how = match a {
                crate::posterior::Allowance::Tempered { .. } => "tempered",
                crate::posterior::Allowance::Adjusted { .. } => "adjusted",
            };
            return format!(
                "these records, their residuals' memory allowed for ({how} likelihood)"
            );
        }
        if lik.noise.model(&Default::default()).models_memory() {
            return format!(
                "these records, their residuals' memory modelled ({:?} noise)",
                lik.noise
            );
        }
        if self.record.runs_with_memory() > 0 {
            return "these records if their residuals were independent (they have memory: too narrow)"
                .to_string();
        }
        "these records".to_string()
    }

    /// Where the likelihood allowed for the residuals' memory: each
    /// coordinate's interval had the residuals been taken as independent,
    /// with how many times wider the posterior's 90 % interval is.
    pub fn independent_beside(&self) -> Vec<(&IntervalRow, f64)> {
        self.record
            .independent
            .iter()
            .filter_map(|i| {
                let p = self.summary.iter().find(|p| p.parameter == i.parameter)?;
                Some((i, (p.q95 - p.q05) / (i.q95 - i.q05)))
            })
            .collect()
    }

    /// A short name for tables and legends: the folder's name.
    pub fn label(&self) -> String {
        self.dir
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_else(|| self.dir.display().to_string())
    }

    /// The campaign's runs that this calibration used.
    pub fn campaign(&self) -> Result<Campaign> {
        Ok(self.used_runs(&self.full_campaign()?))
    }

    /// Whether the calibration used the run `id`.
    pub fn saw(&self, id: &str) -> bool {
        self.record.runs.iter().any(|r| r == id)
    }

    /// The runs of `campaign` this calibration used.
    pub fn used_runs(&self, campaign: &Campaign) -> Campaign {
        campaign.filtered(|r| self.saw(r.id()))
    }

    /// Every run of the campaign's manifest (a current law predicts them all).
    pub fn full_campaign(&self) -> Result<Campaign> {
        let manifest = PathBuf::from(&self.record.manifest);
        if !manifest.exists() {
            return Err(Error::input(
                self.dir.join("calibration.toml"),
                format!(
                    "the campaign manifest {} it names is not there any more",
                    manifest.display()
                ),
            ));
        }
        let campaign = Campaign::load(&manifest)?;
        let used = self.used_runs(&campaign);
        if used.runs.len() != self.record.runs.len() {
            return Err(Error::input(
                &manifest,
                format!(
                    "does not hold every run of the calibration in {}: {:?}",
                    self.dir.display(),
                    self.record.runs
                ),
            ));
        }
        Ok(campaign)
    }

    /// The campaign's geometry: from calibration.toml, or (folders written
    /// before it was stored there) from the manifest it names.
    pub fn geometry(&self) -> Option<Geometry> {
        self.record
            .geometry
            .or_else(|| Manifest::read(Path::new(&self.record.manifest)).ok().map(|m| m.geometry))
    }

    pub fn is_current_law(&self) -> bool {
        self.sample.model.is_current_law()
    }

    /// The lowest and highest current the calibration saw (A).
    pub fn current_range(&self) -> (f64, f64) {
        self.record
            .currents
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), c| (l.min(*c), h.max(*c)))
    }

    /// The largest R̂ and the smallest bulk or tail ESS of the summary.
    pub fn max_rhat(&self) -> f64 {
        match self.summary.is_empty() {
            true => f64::NAN,
            false => {
                crate::sampler::diagnostics::largest_rhat(self.summary.iter().map(|r| r.r_hat))
            }
        }
    }

    pub fn min_ess(&self) -> f64 {
        self.summary.iter().map(|r| r.ess_bulk.min(r.ess_tail)).fold(f64::NAN, f64::min)
    }

    /// Band settings with this calibration's integrator and noise model.
    pub fn predict_settings(&self, replicates: usize, seed: u64) -> PredictSettings {
        let integrator = self.settings.integrator.integrator(self.record.substeps);
        PredictSettings { integrator, noise: self.settings.noise_model(), replicates, seed }
    }

    pub fn burn_in(&self) -> usize {
        self.record.burn_in.min(self.sample.chains.steps().saturating_sub(1))
    }

    /// The largest integrated autocorrelation time of the summary (steps).
    pub fn tau_max(&self) -> f64 {
        self.summary.iter().map(|r| r.tau_int).filter(|t| t.is_finite()).fold(1.0, f64::max)
    }

    /// Its posterior draws: after the burn-in, thinned by τ_max.
    pub fn draws(&self) -> Draws {
        Draws::after(self.burn_in(), self.tau_max())
    }

    /// `count` of [`Self::draws`] spread evenly over what remains; each as
    /// the `(step, chain)` it came from.
    pub fn draw_positions(&self, count: usize) -> Vec<(usize, usize)> {
        self.draws().positions(&self.sample.chains, count)
    }
}

/// Calibrates the runs of `campaign` with the default, quiet start and no
/// observers.
pub fn calibrate(campaign: &Campaign, settings: &CalibrationSettings) -> Result<Calibrated> {
    let start = start(campaign, settings, &mut |_| {})?;
    sample_watched(campaign, settings, start, None, &mut [], &mut |_| {})
}

/// Samples the posterior from `start`: from walkers around the MAP, or from
/// the checkpoint at `resume_from` (with `--sampler smc`, also from the
/// populations saved beside it, where a run was stopped before its
/// sampler's first checkpoint). `observers` watch the sampler.
pub fn sample(
    campaign: &Campaign,
    mut start: Start,
    resume_from: Option<&PathBuf>,
    observers: &mut [&mut dyn Observer],
) -> Result<Calibrated> {
    let posterior = &start.posterior;
    let s = &start.settings.sampler;
    let sampler_settings = s.sampler(s.walkers, s.seed);
    // the walkers start about the Laplace approximation at the mode, which
    // the anchored move proposes with, and their first steps judge the start
    // (a function of the start alone, so a resumed run judges it the same)
    let clock = std::time::Instant::now();
    let mut control = s.control();
    // with sequential Monte Carlo, its particles replace the walkers placed
    // about the Laplace approximation (and the probe's steps)
    let smc = s.method == SamplerMethod::Smc;
    // populations of sequential Monte Carlo saved beside the sampler's
    // checkpoint: where a run was stopped during them, or after
    let smc_saved = resume_from
        .map(|p| crate::sampler::checkpoint::smc_beside(p))
        .filter(|p| smc && p.exists());
    let fresh =
        |observers: &mut [&mut dyn Observer]| -> Result<(probe::Probed, Option<SmcRecord>)> {
            let probed = probe::walkers_start(
                posterior,
                &start.map,
                start.laplace.clone(),
                sampler_settings.clone(),
                start.walkers_near,
                &control,
                if smc { &mut [] } else { &mut *observers },
            )?;
            if !smc {
                return Ok((probed, None));
            }
            let (sampler, record) = sequential::from_laplace(
                posterior,
                &probed.laplace,
                &probed.sampler.settings,
                smc_saved.as_deref(),
                observers,
            )?;
            Ok((probe::Probed { sampler, stepping_seconds: 0.0, ..probed }, Some(record)))
        };
    let (probed, smc_record) = match resume_from.filter(|p| p.exists()) {
        Some(path) => {
            // the start judged again, unobserved: a checkpoint saved before
            // the walkers started afresh about a higher mode is of a start
            // the run left, and the run goes on from the new one instead
            let (probed, smc_record) = fresh(&mut [])?;
            let resumed = Sampler::resume(posterior, path)?;
            let first = resumed.chains.chains() * resumed.chains.dim;
            if resumed.chains.positions.get(..first) != probed.sampler.chains.positions.get(..first)
            {
                (probed, smc_record)
            } else if resumed.settings != probed.sampler.settings {
                return Err(Error::input(path, "checkpoint of a sampler with other settings (walkers, ensembles, moves or seed)"));
            } else {
                // the probe's steps were the start's work: the chains are the checkpoint's
                let probed = probe::Probed {
                    sampler: resumed.with_reference(probed.laplace.clone()),
                    stepping_seconds: 0.0,
                    ..probed
                };
                (probed, smc_record)
            }
        }
        None => fresh(observers)?,
    };
    // the Laplace approximation and the walkers' start count with the
    // start; the probe's steps, the chains' first, and sequential Monte
    // Carlo with sampling
    let smc_seconds = smc_record.as_ref().map_or(0.0, |r| r.seconds);
    let walkers_start = clock.elapsed().as_secs_f64() - probed.stepping_seconds - smc_seconds;
    let probe_seconds = probed.stepping_seconds + smc_seconds;
    let misfit = probed.far();
    control.confirm = misfit.is_some();
    let probe::Probed { mut sampler, map, higher, spread, widened, .. } = probed;
    let mut sampled = sampling::run(posterior, &mut sampler, &control, s.burn_in, observers)?;
    sampled.seconds += probe_seconds;
    sampled.diagnostics.warnings.extend(probe::warnings(
        &higher,
        &widened,
        misfit,
        sampler.settings.moves != s.moves,
    ));
    start.settings.sampler.moves = sampler.settings.moves.clone();
    start.settings.sampler.walkers = sampler.settings.walkers;
    if let Some(map) = map {
        start.map = map;
    }
    let mut record = CalibrationRecord::of(campaign, &start, walkers_start, spread, &sampled);
    record.smc = smc_record;
    if let Some(alone) = &start.law_alone_rms {
        let median: Vec<f64> = sampled.diagnostics.coordinates.iter().map(|c| c.q50).collect();
        record.confounding =
            start::confounding(posterior, &posterior.layout.from_si(&median), alone);
    }
    let calibration = Calibration {
        dir: PathBuf::new(),
        settings: start.settings.clone(),
        record,
        summary: SummaryRow::rows(&sampled.sample.layout, &sampled.diagnostics),
        sample: sampled.sample,
    };
    Ok(Calibrated { calibration, start, chains: sampled.chains, diagnostics: sampled.diagnostics })
}
