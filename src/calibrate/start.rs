//! Where sampling starts: the identification, the MAP search from it (and
//! from the prior's centre), the integrator's step and scheme, and what the
//! MAP's residuals say about the noise model.

use std::collections::BTreeMap;
use std::time::Instant;

use super::settings::{CalibrationSettings, SamplingSettings, SchemeChoice};
use crate::data::Campaign;
use crate::error::{Error, Result};
use crate::identify::{identify_current, CurrentIdentification};
use crate::model::{Integrator, Scheme};
use crate::posterior::laplace::IntervalRow;
use crate::posterior::map::{self, MapEstimate, StepCheck};
use crate::posterior::{laplace, memory, Memory, Posterior};
use crate::sampler::Elliptical;

/// Where sampling starts: the identification, the MAP, the step chosen and
/// the posterior with it.
pub struct Start {
    /// The current the identification used (the law's nearest to its reference).
    pub current_a: f64,
    /// The settings with the walkers and sub-steps filled in.
    pub settings: CalibrationSettings,
    /// Where the walkers were left to the default: the fewer walkers per
    /// ensemble the sampler keeps if the start is near its Laplace
    /// approximation ([`SamplingSettings::walkers_near`]).
    pub walkers_near: Option<usize>,
    /// The paper's identification (the B-P law's start; none for another law).
    pub identification: Option<CurrentIdentification>,
    pub map: MapEstimate,
    /// The best optimum of the MAP search over the starts, before the
    /// likelihood allowed for any memory: what a start asked again
    /// ([`start_refusing_adjusted`]) takes instead of searching again.
    pub searched: MapEstimate,
    pub step_study: Vec<StepCheck>,
    pub posterior: Posterior,
    /// What the start found that the user should know (residuals with memory).
    pub warnings: Vec<String>,
    /// Each run's residual RMS (Pa) with the law fitted alone (independent
    /// noise), where the noise model has a force of its own (a
    /// discrepancy, AR(1)): what [`confounding`] compares the posterior's
    /// law path with.
    pub law_alone_rms: Option<Vec<f64>>,
    /// Where `memory = "auto"` found memory in the MAP residuals: what it
    /// found and the likelihood it chose, in a sentence.
    pub memory_found: Option<String>,
    /// Where the likelihood allows for the residuals' memory (tempered or
    /// adjusted): the same records' intervals with the residuals taken as
    /// independent, in SI ([`laplace::si_intervals`] of the independent
    /// posterior's Laplace approximation), what the narrow intervals of a
    /// calibration that ignored the memory would have said. Empty otherwise.
    pub independent: Vec<IntervalRow>,
    /// The posterior's Laplace approximation at its mode where the start
    /// has it already (the adjusted likelihood's,
    /// [`laplace::adjusted_mode`]); `None`: the walkers' start reaches it
    /// from [`Start::map`].
    pub laplace: Option<Elliptical>,
    pub seconds: f64,
}

/// Identification, MAP and step rule. `log` receives a line per stage.
pub fn start(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    log: &mut dyn FnMut(&str),
) -> Result<Start> {
    start_with(campaign, settings, None, log)
}

/// [`start`] where `memory = "auto"` must not take the adjusted likelihood,
/// for the reason `refused` (a sentence): a calibration under it showed
/// its blind spot ([`super::edge`]). Where auto finds memory
/// it takes the tempered likelihood and says why. `searched` is the first
/// start's [`Start::searched`], of the same campaign and settings: the
/// search over the starts is not repeated (it would give the same bits).
pub fn start_refusing_adjusted(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    refused: &str,
    searched: &MapEstimate,
    log: &mut dyn FnMut(&str),
) -> Result<Start> {
    start_with(campaign, settings, Some((refused, searched)), log)
}

fn start_with(
    campaign: &Campaign,
    settings: &CalibrationSettings,
    refused: Option<(&str, &MapEstimate)>,
    log: &mut dyn FnMut(&str),
) -> Result<Start> {
    let clock = Instant::now();
    let mut settings = settings.clone();
    // an adjustment measured on other runs is measured anew
    let ids: Vec<&str> = campaign.runs.iter().map(|r| r.id()).collect();
    if settings
        .likelihood
        .memory_adjustment
        .as_ref()
        .is_some_and(|a| !ids.iter().all(|id| a.runs.iter().any(|r| r == id)))
    {
        settings.likelihood.memory_adjustment = None;
    }
    settings.fill_anchors(&campaign.currents());
    settings.fill_coil_lag(!campaign.varying_runs().is_empty());
    let model = settings.parameter_model();
    let current_a = model.identification_current(&campaign.currents())?;
    // the paper's identification starts the B-P law and a law built on
    // its element
    let law = model.law();
    let identification = (law.is_bodner_partom() || law.law().builds_on_bodner_partom())
        .then(|| identify_current(campaign, current_a, &settings.identify));
    let integ = settings.integrator.clone();
    // the MAP search runs on the linearly implicit scheme unless told
    // otherwise: its likelihood is smooth on any record; a law with a
    // scheme of its own is the same under either, and is recorded as
    // explicit (the step rule's first)
    let follows_scheme = law.law().follows_scheme();
    let search_scheme = match integ.scheme {
        SchemeChoice::Auto if follows_scheme => Scheme::LinearlyImplicit,
        SchemeChoice::Auto => Scheme::Explicit,
        chosen => chosen.scheme(),
    };
    let base = Integrator { scheme: search_scheme, ..integ.integrator(integ.substeps) };
    let mut stages = Stages {
        campaign,
        settings,
        base,
        independent: Vec::new(),
        unsettled: None,
        warnings: Vec::new(),
    };
    let posterior = stages.posterior();
    let settings = &stages.settings;
    if let Some(a) = posterior.likelihood.adjustment() {
        if a.coordinates != posterior.layout.theta_names() {
            return Err(Error::Usage(format!(
                "memory_adjustment was measured in the coordinates {:?}, this calibration's are {:?}: remove [likelihood.memory_adjustment] to measure it anew",
                a.coordinates,
                posterior.layout.theta_names()
            )));
        }
    }
    // the sampler's settings are checked before minutes of MAP search
    if settings.sampler.walkers != 0 {
        let s = &settings.sampler;
        s.sampler(s.walkers, s.seed).check(posterior.layout.dim())?;
    }
    // ln θ from the identification (the B-P law) or the starts another
    // law reads off the records; either may be far off
    // (docs/identification.md): also from the prior medians (beside a
    // single start, or where no start's search converges), and the best
    // optimum is kept. A law built on the B-P element searches from about
    // the identification first, and from the starts read off the records
    // only where none of those converges (bp-spencer at 1 A: the two
    // about the identification found the optimum in 6–8 s, the two from
    // the records' scales ran out of their budgets in 22–31 s and ended
    // 29–168 nats lower)
    let tiers_ln: Vec<Vec<Vec<f64>>> = match &identification {
        Some(id) if law.is_bodner_partom() => {
            vec![vec![model.start(&id.params, current_a).iter().map(|v| v.ln()).collect()]]
        }
        _ => {
            let law = law.law();
            let n = law.parameters().len();
            let ln =
                |v: crate::laws::LawValues| -> Vec<f64> { v[..n].iter().map(|v| v.ln()).collect() };
            let around: Vec<Vec<f64>> = identification
                .iter()
                .flat_map(|id| law.starts_around(&id.params, &posterior.runs))
                .map(ln)
                .collect();
            let read: Vec<Vec<f64>> = law.starts(&posterior.runs).into_iter().map(ln).collect();
            [around, read].into_iter().filter(|t| !t.is_empty()).collect()
        }
    };
    let medians: Vec<f64> = posterior
        .priors
        .iter()
        .zip(&tiers_ln[0][0])
        .map(|(p, v)| p.centre().map(|(c, _)| c).unwrap_or(*v))
        .collect();
    // θ from each, the model terms (if any) from zero
    let fitted = posterior.layout.fitted.len();
    let at = |log: &[f64]| {
        let mut x = posterior.layout.theta_coordinates(log);
        x.resize(fitted, 0.0);
        x
    };
    let medians = at(&medians);
    let fitted = &posterior.layout.names[posterior.layout.fitted.clone()];
    if let Some(unknown) = settings.map_start.keys().find(|name| !fitted.contains(name)) {
        return Err(Error::Usage(format!(
            "map_start names {unknown}, which this calibration does not have (its parameters and terms: {})",
            fitted.join(", ")
        )));
    }
    // a start asked for by name (a run alone from its joint calibration's
    // MAP) in place of the tiers; the medians beside it as beside any
    // single start
    let starts: Vec<Vec<Vec<f64>>> =
        match named_start(&posterior, &settings.map_start, &at(&tiers_ln[0][0])) {
            Some(x) => {
                log("  MAP search from the start given (map_start) and from the prior medians");
                vec![vec![x]]
            }
            None => tiers_ln.iter().map(|tier| tier.iter().map(|log| at(log)).collect()).collect(),
        };
    let map = match refused {
        Some((_, searched)) => searched.clone(),
        None => map::best_map_or(&posterior, &starts, &medians)
            .ok_or_else(|| Error::Compute("the MAP search failed from every start".into()))?,
    };
    let searched = map.clone();
    let law_alone = stages.law_alone_rms(&posterior, &starts, &medians);
    let (posterior, found) = stages.choose_memory(posterior, &map);
    let (posterior, map) = stages.temper(posterior, map, log)?;
    let (posterior, map, failed) = match found {
        // what `auto` chose must not fail where the tempered likelihood,
        // which takes any posterior, would do
        Some(_) => {
            let adjusted = match refused {
                Some((why, _)) => Err(Error::Compute(why.to_string())),
                None => stages.adjust(posterior.clone(), map.clone()).and_then(|(p, m)| {
                    blind_spot(
                        &p,
                        &laplace::surrogate(&p, &m),
                        &map.x,
                        stages.settings.sampler.seed,
                    )
                    .map(|()| (p, m))
                }),
            };
            match adjusted {
                Ok((posterior, map)) => (posterior, map, None),
                Err(e) => {
                    stages.settings.likelihood.memory = Memory::Tempered;
                    stages.settings.likelihood.memory_adjustment = None;
                    stages.unsettled = None;
                    let (posterior, map) = stages.temper(posterior, map, log)?;
                    (posterior, map, Some(e))
                }
            }
        }
        None => {
            let (posterior, map) = stages.adjust(posterior, map)?;
            (posterior, map, None)
        }
    };
    let memory_found = found.map(|f| {
        let said = f.said(stages.settings.likelihood.memory, failed.as_ref());
        log(&format!("  memory: {said}"));
        said
    });
    log(&format!(
        "  MAP: log-density {:.1} after {:.1} s; choosing the integrator step",
        map.log_density,
        clock.elapsed().as_secs_f64()
    ));
    let schemes: Vec<Scheme> = match integ.scheme {
        SchemeChoice::Auto if follows_scheme => vec![Scheme::Explicit, Scheme::LinearlyImplicit],
        _ => vec![search_scheme],
    };
    let names = posterior.layout.coordinate_names();
    // each scheme's step, and the Euler steps a log-density costs with it at the MAP
    let mut candidates = Vec::new();
    for scheme in schemes {
        let scheme_base = Integrator { scheme, ..base };
        let (substeps, at, study) = if integ.substeps == 0 {
            map::choose_substeps(
                &posterior.with_integrator(scheme_base),
                &map,
                scheme_base,
                integ.max_rule_substeps,
            )
        } else {
            (integ.substeps, map.clone(), vec![])
        };
        for s in &study {
            let (i, v) = s.worst();
            log(&format!(
                "  step rule ({scheme:?}): {} sub-step(s): halving moves {} by {v:.3} sd",
                s.substeps, names[i]
            ));
        }
        let chosen = posterior.with_integrator(Integrator { substeps, ..scheme_base });
        let work = map::euler_steps(&chosen, &at.x);
        log(&format!(
            "  {scheme:?} with {substeps} sub-step(s): {work} Euler steps per log-density"
        ));
        candidates.push((work, chosen, at, study));
    }
    // the cheaper scheme at the accuracy the step rule asks for: explicit on
    // smooth records, linearly implicit where stiffness makes the explicit
    // one cut its steps (and its likelihood rugged)
    let (_, posterior, map, step_study) =
        candidates.into_iter().min_by_key(|c| c.0).expect("at least one scheme");
    // the MAP with the chosen integrator, from the one found (the curvature
    // stays the smooth search's), and an adjustment measured with it
    let (posterior, map, laplace) = stages.settle(posterior, map, log);
    let independent = std::mem::take(&mut stages.independent);
    let mut settings = stages.settings;
    settings.integrator.scheme = SchemeChoice::of(posterior.integrator.scheme);
    settings.integrator.substeps = posterior.integrator.substeps;
    let walkers_near = settings.sampler.walkers_near_posterior(&posterior);
    if settings.sampler.walkers == 0 {
        settings.sampler.walkers =
            SamplingSettings::walkers_for_posterior(&posterior, settings.sampler.ensembles);
    }
    let mut warnings = memory_warnings(&posterior, &map);
    for w in &warnings {
        log(&format!("  warning: {w}"));
    }
    warnings.append(&mut stages.warnings);
    Ok(Start {
        current_a,
        settings,
        walkers_near,
        identification,
        map,
        searched,
        step_study,
        posterior,
        warnings,
        law_alone_rms: law_alone,
        memory_found,
        independent,
        laplace,
        seconds: clock.elapsed().as_secs_f64(),
    })
}

/// What the start's later stages share: the campaign, the settings as the
/// start fills them in, and the integrator of the MAP search. A stage that
/// changes the likelihood writes what it measured into the settings and
/// builds the posterior anew from them ([`Stages::searched_again`]).
struct Stages<'a> {
    campaign: &'a Campaign,
    settings: CalibrationSettings,
    base: Integrator,
    /// [`Start::independent`], once a stage has measured it.
    independent: Vec<IntervalRow>,
    /// The independent likelihood's MAP where a stage allowed for the
    /// residuals' memory here ([`Stages::temper`], [`Stages::adjust`]):
    /// [`Stages::settle`] measures the independent posterior's mode and
    /// Laplace approximation with the integrator chosen from it (and an
    /// adjustment again).
    unsettled: Option<MapEstimate>,
    /// What a stage found that the user should know ([`Start::warnings`]).
    warnings: Vec<String>,
}

impl Stages<'_> {
    fn posterior(&self) -> Posterior {
        self.settings.posterior(self.campaign, self.base)
    }

    /// The posterior of the settings as they are now, and its MAP searched
    /// from the θ of `map` (the `what` in the message if that fails).
    fn searched_again(&self, map: &MapEstimate, what: &str) -> Result<(Posterior, MapEstimate)> {
        let posterior = self.posterior();
        let x = map.x[..posterior.layout.fitted.len()].to_vec();
        let map = map::refine_near(&posterior, &x)
            .ok_or_else(|| Error::Compute(format!("the MAP search of {what} failed")))?;
        Ok((posterior, map))
    }

    /// `memory = "auto"` resolved at `map`, the MAP of the likelihood with
    /// independent residuals: where every run's whitened residuals have a
    /// lag-1 autocorrelation of at most [`MEMORY_WARNING`] (or the noise
    /// model has memory of its own), independent; else adjusted (one
    /// parameter set per current) or tempered (a parameter model across
    /// currents), and what was found.
    fn choose_memory(
        &mut self,
        mut posterior: Posterior,
        map: &MapEstimate,
    ) -> (Posterior, Option<MemoryFound>) {
        if self.settings.likelihood.memory != Memory::Auto {
            return (posterior, None);
        }
        let rhos = match posterior.noise.models_memory() {
            true => None,
            false => map::whitened_autocorrelation(&posterior, map),
        }
        .unwrap_or_default();
        let with = rhos.iter().filter(|r| **r > MEMORY_WARNING).count();
        if with == 0 {
            self.settings.likelihood.memory = Memory::Independent;
            posterior.likelihood.memory = Memory::Independent;
            return (posterior, None);
        }
        self.settings.likelihood.memory = match self.settings.parameter_model().is_current_law() {
            true => Memory::Tempered,
            false => Memory::Adjusted,
        };
        let (lo, hi) =
            rhos.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &r| (a.min(r), b.max(r)));
        (posterior, Some(MemoryFound { lo, hi, with, runs: rhos.len() }))
    }

    /// With the tempered likelihood ([`Memory::Tempered`]): each run's
    /// memory time k from its whitened residuals at `map` (where not set
    /// already), written into the settings, and the MAP searched again on
    /// the posterior whose runs' log-likelihoods count 1/k. Otherwise
    /// `posterior` and `map` as they are.
    fn temper(
        &mut self,
        posterior: Posterior,
        map: MapEstimate,
        log: &mut dyn FnMut(&str),
    ) -> Result<(Posterior, MapEstimate)> {
        let lik = &mut self.settings.likelihood;
        if lik.memory != Memory::Tempered
            || posterior.runs.iter().all(|r| lik.memory_times.contains_key(&r.id))
        {
            return Ok((posterior, map));
        }
        // the independent posterior's intervals are measured with the
        // integrator chosen ([`Stages::settle`])
        self.unsettled = Some(map.clone());
        let times = map::memory_times(&posterior, &map).ok_or_else(|| {
            Error::Compute("the residuals at the MAP could not be integrated".into())
        })?;
        for (run, k) in posterior.runs.iter().zip(times) {
            lik.memory_times.entry(run.id.clone()).or_insert(k);
        }
        let listed: Vec<String> = posterior
            .runs
            .iter()
            .map(|r| format!("{} {:.1}", r.id, lik.memory_times[&r.id]))
            .collect();
        log(&format!("  memory: each run's log-likelihood counts 1/k, k the integrated autocorrelation time of its whitened MAP residuals (samples): {}", listed.join(", ")));
        self.searched_again(&map, "the tempered likelihood")
    }

    /// With the adjusted likelihood ([`Memory::Adjusted`]): the curvature
    /// adjustment measured at `map`, the MAP of the independent likelihood
    /// (where not set already), written into the settings, and the MAP
    /// searched again on the adjusted posterior: what the step rule needs;
    /// [`Stages::settle`] measures it again with the integrator chosen.
    /// Otherwise `posterior` and `map` as they are.
    fn adjust(
        &mut self,
        posterior: Posterior,
        map: MapEstimate,
    ) -> Result<(Posterior, MapEstimate)> {
        let lik = &self.settings.likelihood;
        if lik.memory != Memory::Adjusted || lik.memory_adjustment.is_some() {
            return Ok((posterior, map));
        }
        if self.settings.parameter_model().is_current_law() {
            return Err(Error::Usage("`--memory adjusted` takes one parameter set per current (not the current law); `--memory tempered` takes any".into()));
        }
        // C measured at this MAP and centred on it, for the step rule (the
        // posterior's spread under the adjusted likelihood); the centre, C
        // and the independent posterior's intervals are measured again with
        // the integrator chosen ([`Stages::settle`])
        let adjustment = memory::adjustment(&posterior, &map, &map.x).ok_or_else(|| {
            Error::Compute("the memory adjustment could not be measured at the MAP".into())
        })?;
        self.settings.likelihood.memory_adjustment = Some(adjustment);
        self.unsettled = Some(map.clone());
        self.searched_again(&map, "the adjusted likelihood")
    }

    /// The MAP `map` of `posterior` (the integrator chosen; the search's
    /// curvature kept) moved to that integrator, where it differs from the
    /// search's. Where a stage allowed for memory here, the independent
    /// posterior's intervals ([`Start::independent`]) are its Laplace
    /// approximation at its mode with the chosen integrator. Where
    /// [`Stages::adjust`] measured the adjustment here with the search's
    /// integrator, it is measured again with the chosen one:
    /// centred on the independent posterior's mode (Newton's method from
    /// its MAP), whose Laplace approximation gives the intervals the
    /// records would have if their residuals were independent, and the
    /// adjusted posterior's own ([`laplace::adjusted_mode`]). A step rule
    /// that asks for a finer step than the search's moves that mode, and
    /// the adjusted posterior C⁻¹ times as far: on the measured records,
    /// centred with the search's step its parameters lay up to 0.3–1.1 sd
    /// from where this puts them (docs/calibration.md).
    fn settle(
        &mut self,
        posterior: Posterior,
        map: MapEstimate,
        log: &mut dyn FnMut(&str),
    ) -> (Posterior, MapEstimate, Option<Elliptical>) {
        // the MAP with the chosen integrator, from the one found
        let moved = |posterior: &Posterior, map: MapEstimate| {
            if posterior.integrator == self.base {
                return map;
            }
            map::refine_near(posterior, &map.x).map(|m| map.curvature_at(m)).unwrap_or(map)
        };
        let Some(independent_map) = self.unsettled.take() else {
            let map = moved(&posterior, map);
            return (posterior, map, None);
        };
        // the independent posterior's mode and Laplace approximation with
        // the chosen integrator, by Newton's method from the search's MAP
        // (one step reaches it where the step rule moved it by a sd or
        // two); its intervals are what the records would say if their
        // residuals were independent (the search's surrogate lies up to 4
        // of its sds from that mode in G where the noise depends on θ)
        let plain = posterior.without_adjustment();
        let mode = laplace::mode(&plain, &independent_map);
        if let Some(short) = mode.as_ref().and_then(|m| m.shortfall()) {
            let centred = match self.settings.likelihood.adjustment() {
                Some(_) => "the adjustment for the residuals' memory and the intervals of independent residuals are centred",
                None => "the intervals of independent residuals are centred",
            };
            let w = format!("the independent likelihood's mode was not reached (Newton's method {short}): {centred} where it stopped");
            log(&format!("  warning: {w}"));
            self.warnings.push(w);
        }
        let independent = mode
            .as_ref()
            .map_or_else(|| laplace::surrogate(&plain, &independent_map), |m| m.laplace.clone());
        self.independent =
            laplace::si_intervals(&plain.layout, &independent, self.settings.sampler.seed);
        if self.settings.likelihood.adjustment().is_none() {
            let map = moved(&posterior, map);
            return (posterior, map, None);
        }
        let centre = mode.map_or_else(|| independent_map.x.clone(), |m| m.x);
        if let Some(adjustment) = memory::adjustment(&plain, &independent_map, &centre) {
            self.settings.likelihood.memory_adjustment = Some(adjustment);
        }
        let (lo, hi) =
            self.settings.likelihood.adjustment().map_or((1.0, 1.0), |a| a.inflation_range());
        log(&format!("  memory: the likelihood's curvature adjusted to its score's covariance given the residuals' memory: variance inflation {lo:.1}–{hi:.1} by direction"));
        let posterior = self.settings.posterior(self.campaign, posterior.integrator);
        // the adjusted posterior's mode from the independent one's (on the
        // measured records 1.4–10 nats above where a search from the step
        // rule's MAP stops); searched where it cannot be derived
        match laplace::adjusted_mode(&posterior, &independent) {
            Some(mode) => {
                let map = map.moved_to(mode.x, mode.log_density);
                (posterior, map, Some(mode.laplace))
            }
            None => {
                let map = map::refine_near(&posterior, &map.x)
                    .map(|m| map.curvature_at(m))
                    .unwrap_or(map);
                (posterior, map, None)
            }
        }
    }

    /// Each run's residual RMS at the MAP of the same posterior with
    /// independent Gaussian noise (the law alone, no force of the noise's
    /// own), from the same `starts`; `None` where the noise model has no
    /// force of its own (it does not model memory) or the search fails.
    fn law_alone_rms(
        &self,
        posterior: &Posterior,
        starts: &[Vec<Vec<f64>>],
        medians: &[f64],
    ) -> Option<Vec<f64>> {
        if !posterior.noise.models_memory() {
            return None;
        }
        let mut alone = self.settings.clone();
        alone.likelihood.noise = crate::noise::NoiseKind::Gaussian;
        alone.likelihood.memory = Memory::Independent;
        let plain = alone.posterior(self.campaign, self.base);
        let fitted = plain.layout.fitted.len();
        let cut = |s: &[f64]| s[..fitted.min(s.len())].to_vec();
        let starts: Vec<Vec<Vec<f64>>> =
            starts.iter().map(|tier| tier.iter().map(|s| cut(s)).collect()).collect();
        let found = map::best_map_or(&plain, &starts, &cut(medians))?;
        Some(map::residual_rms(&plain, &found.x)?.into_iter().map(|(rms, _)| rms).collect())
    }
}

/// What `memory = "auto"` found in the MAP residuals: the range of the
/// runs' whitened lag-1 autocorrelations and how many of them are above
/// [`MEMORY_WARNING`].
struct MemoryFound {
    lo: f64,
    hi: f64,
    with: usize,
    runs: usize,
}

impl MemoryFound {
    /// What was found and the likelihood that allows for it (`chosen`),
    /// with why the adjusted one was not taken where it `failed`.
    fn said(&self, chosen: Memory, failed: Option<&Error>) -> String {
        let name = if chosen == Memory::Tempered { "tempered" } else { "adjusted" };
        let failed = failed
            .map_or(String::new(), |e| format!(" (the adjusted likelihood failed here: {e})"));
        format!(
            "the MAP residuals have memory (lag-1 autocorrelation {:.2}–{:.2}, above {MEMORY_WARNING} in {} of {} runs), so the {name} likelihood allows for it{failed} (`memory = \"auto\"`; `--memory independent` takes the residuals as independent)",
            self.lo, self.hi, self.with, self.runs
        )
    }
}

/// Draws of the adjusted posterior's Laplace approximation whose own paths
/// [`blind_spot`] checks, and the share of them far from a record above
/// which the adjusted likelihood is not taken. The approximation is the
/// MAP search's, taken before the walkers look further: a few of its draws
/// can miss where the posterior's own do not, while where the adjustment
/// misleads a quarter or more are far (bp-spencer: 17 and 22 of 64 at 1
/// and 0.25 A, its posterior's draws 25–37 %). A tenth parts the two:
/// with 64 draws (7 or more far) a true share of 3 % passes it by chance
/// 0.3 % of the time, one of 5 % 4 %, and one of 25 % falls under it
/// 0.15 % of the time (binomial tails). It does not see every such case:
/// Spencer's model at 1 A had 2 of 64 far, yet its posterior's draws were
/// 24–36 % far, along an internal spring the records leave free near the
/// MAP and rule out further on, an edge the approximation does not reach
/// (docs/real-data.md, "Spencer at 1 A"): [`super::edge`] checks the
/// walkers' own draws while sampling, by the same measure.
const BLIND_SPOT_DRAWS: usize = 64;
pub(super) const BLIND_SPOT_SHARE: f64 = 0.10;

/// Whether the adjusted likelihood can be trusted for `post` (adjusted,
/// `approx` a Laplace approximation of it): it scores θ by the fit at
/// θ* = θ̂ + C (θ − θ̂), so along a direction the records barely fix
/// (bp-spencer's spring k0 on the measured records) it spreads draws whose
/// own paths miss the records by far, and bands from them span several
/// times the peak force (docs/calibration.md, "The adjusted likelihood").
/// The check draws [`BLIND_SPOT_DRAWS`] points of `approx` inside the
/// priors' support and integrates each along every run at its own θ: an
/// error where more than [`BLIND_SPOT_SHARE`] of them miss some run by
/// more than [`crate::predict::FAR`] times the residual RMS there at
/// `best_fit`, the independent likelihood's MAP or mode (the measure of
/// the bands' `far_draws`). Not against the adjusted posterior's own MAP,
/// which the same blind spot can carry past the records: Bouc-Wen on two
/// crank tests of a virtual Spencer damper had its c0 there at 1.6–670
/// times the independent mode's, every draw's path far from the records
/// and none judged far against that MAP's. Costs as many log-densities as
/// it draws. The start checks the MAP search's approximation, and
/// leave-one-out each held-out posterior's ([`crate::validate`]).
pub(crate) fn blind_spot(
    post: &Posterior,
    approx: &crate::sampler::Elliptical,
    best_fit: &[f64],
    seed: u64,
) -> Result<()> {
    use crate::predict::FAR;
    use rand_distr::{Distribution, StandardNormal};
    let plain = post.without_adjustment();
    let Some(at_map) = map::residual_rms(&plain, best_fit) else {
        return Ok(());
    };
    let mut rng = crate::rng::stream(seed, &[0xB1D5]);
    let in_support = |x: &[f64]| {
        let log_theta = post.layout.log_theta(x);
        log_theta.iter().all(|v| v.is_finite()) && post.inside_priors(&log_theta)
    };
    let mut points = Vec::with_capacity(BLIND_SPOT_DRAWS);
    for _ in 0..20 * BLIND_SPOT_DRAWS {
        if points.len() == BLIND_SPOT_DRAWS {
            break;
        }
        let z: Vec<f64> = (0..post.layout.dim()).map(|_| StandardNormal.sample(&mut rng)).collect();
        let x = approx.point(&z, 1.0);
        if in_support(&x) {
            points.push(x);
        }
    }
    let (far, integrated) = far_paths(&plain, &points, &at_map);
    let share = far as f64 / integrated.max(1) as f64;
    match share > BLIND_SPOT_SHARE {
        true => Err(Error::Compute(format!(
            "{far} of {integrated} draws of its Laplace approximation have paths that miss a record by more than {FAR}× the residual RMS of the best fit, the independent likelihood's MAP; it scores each point by the fit at another, and some parameter is barely fixed by these records"
        ))),
        false => Ok(()),
    }
}

/// How many of `points` have paths of their own (`plain`'s, the
/// independent likelihood's) that miss some run by more than
/// [`crate::predict::FAR`] times its MAP's residual RMS `at_map`, and how
/// many could be integrated: the measure of [`blind_spot`] and of
/// [`super::edge`]'s watch.
pub(super) fn far_paths(
    plain: &Posterior,
    points: &[Vec<f64>],
    at_map: &[(f64, usize)],
) -> (usize, usize) {
    let paths: Vec<Vec<f64>> =
        map::residual_rms_many(plain, points).into_iter().flatten().collect();
    let far = paths
        .iter()
        .filter(|rms| rms.iter().zip(at_map).any(|(r, (at, _))| *r > crate::predict::FAR * at))
        .count();
    (far, paths.len())
}

/// Lag-1 autocorrelation of the MAP residuals above which independent noise
/// makes intervals too narrow by more than √3 (AR(1) variance inflation).
pub const MEMORY_WARNING: f64 = 0.5;

/// A warning per run whose MAP residuals, whitened as the noise model
/// whitens them, are still correlated in time: the model reads them as
/// more independent evidence than they are. Under independent noise one
/// more line after them says once what to do about it.
fn memory_warnings(posterior: &Posterior, map: &MapEstimate) -> Vec<String> {
    // the tempered or adjusted likelihood has counted the memory in
    if posterior.likelihood.memory != Memory::Independent {
        return Vec::new();
    }
    let Some(rhos) = map::whitened_autocorrelation(posterior, map) else {
        return Vec::new();
    };
    let models_memory = posterior.noise.models_memory();
    let mut warnings: Vec<String> = posterior
        .runs
        .iter()
        .zip(rhos)
        .filter(|(_, rho)| *rho > MEMORY_WARNING)
        .map(|(run, rho)| {
            let factor = ((1.0 + rho.min(0.999)) / (1.0 - rho.min(0.999))).sqrt();
            if models_memory {
                format!(
                    "{}: the noise model's whitened MAP residuals (one-step-ahead innovations) keep a lag-1 autocorrelation of {rho:.2}: \
                     memory it does not explain; parameter intervals are too narrow by about {factor:.1}× (see the report's model adequacy section)",
                    run.id
                )
            } else {
                format!(
                    "{}: the MAP residuals have a lag-1 autocorrelation of {rho:.2}, but the noise model takes them as independent; \
                     parameter intervals are too narrow by about {factor:.1}×",
                    run.id
                )
            }
        })
        .collect();
    if !warnings.is_empty() && !models_memory {
        warnings.push(MEMORY_REMEDY.to_string());
    }
    warnings
}

/// How many times the law alone's residual RMS the RMS of the law's path at
/// the posterior median of a noise model with a force of its own may be,
/// over all runs together, before the check says the two are confounded.
/// On virtual records whose foreign force the discrepancy model recovers
/// honestly (a viscous force and a smooth random one, docs/calibration.md)
/// single runs reach 2–4× where the foreign force is largest (the fastest
/// crank speed, its shortest record), but all runs together stay below 2;
/// on the measured damper, where held-out runs are predicted worse with
/// the discrepancy than without it, all runs together are 2.2× at 1 A and
/// 4–8× at 0.5 and 0.25 A (docs/calibration.md, "Model discrepancy").
pub const CONFOUNDING_RATIO: f64 = 2.0;

/// [`confounding_warning`] of the law's path at `x` (the posterior's
/// median) against the law alone's RMS (`alone`).
pub(super) fn confounding(posterior: &Posterior, x: &[f64], alone: &[f64]) -> Vec<String> {
    let Some(at) = map::residual_rms(posterior, x) else { return Vec::new() };
    let runs: Vec<(&str, usize)> =
        posterior.runs.iter().zip(&at).map(|(r, (_, n))| (r.id.as_str(), *n)).collect();
    let rms: Vec<f64> = at.iter().map(|(rms, _)| *rms).collect();
    confounding_warning(&runs, &rms, alone).into_iter().collect()
}

/// Where a noise model's own force (the discrepancy, the AR(1) process)
/// leaves the law's path `rms` from the records (`runs`: id and residuals),
/// all runs together, more than [`CONFOUNDING_RATIO`] times what the law
/// fitted alone leaves (`alone`), that force carries force the law's
/// parameters could carry: which of them does is then set by the noise's
/// prior rather than the records, and θ describes the law's share only
/// (Brynjarsdóttir & O'Hagan 2014). One warning with both RMS values, all
/// runs together and run by run, and what to check; `None` below the ratio.
pub fn confounding_warning(runs: &[(&str, usize)], rms: &[f64], alone: &[f64]) -> Option<String> {
    let pooled = |v: &[f64]| {
        let n: usize = runs.iter().map(|r| r.1).sum();
        (runs.iter().zip(v).map(|(r, x)| r.1 as f64 * x * x).sum::<f64>() / n.max(1) as f64).sqrt()
    };
    let (all, all_alone) = (pooled(rms), pooled(alone));
    if all <= CONFOUNDING_RATIO * all_alone {
        return None;
    }
    let by_run: Vec<String> = runs
        .iter()
        .zip(rms.iter().zip(alone))
        .map(|((id, _), (r, a))| format!("{id} {r:.0} Pa against {a:.0} Pa ({:.1}×)", r / a))
        .collect();
    Some(format!(
        "the noise model's own force has taken over force the law can carry: the law's path at the posterior median misses the records by \
         {all:.0} Pa RMS where the law fitted alone with independent noise comes within {all_alone:.0} Pa ({:.1}×; by run: {}); \
         θ and that force are confounded, so the parameters describe the law's share of the force only, and a new test is predicted \
         from that share (compare with the independent model by `--leave-one-out`; docs/calibration.md, \"Model discrepancy\")",
        all / all_alone,
        by_run.join(", ")
    ))
}

/// What to do about residuals with memory under independent noise: said
/// once after the runs' warnings.
pub const MEMORY_REMEDY: &str = "about the runs' residual memory (the report's model adequacy section): the default, `--memory auto`, allows for it \
     (the adjusted likelihood: each parameter widened by the memory of the part of the records that informs it; `--memory tempered`: one factor a run), \
     `--noise discrepancy` models the memory as a force the law lacks, \
     and `--per-run` gives intervals that hold for a new test of this damper \
     (docs/calibration.md, \"Which likelihood for measured records\", \"Model discrepancy\", \"The between-run layer\")";

/// The search's coordinates (θ and the model terms) of the SI values
/// `named` by parameter name, each coordinate not named kept at
/// `default`'s; `None` where nothing is named or a named value is not a
/// finite point of the posterior's coordinates.
fn named_start(
    post: &Posterior,
    named: &BTreeMap<String, f64>,
    default: &[f64],
) -> Option<Vec<f64>> {
    if named.is_empty() {
        return None;
    }
    let layout = &post.layout;
    let mut si = layout.to_si(default);
    for (v, name) in si.iter_mut().zip(&layout.names[layout.fitted.clone()]) {
        if let Some(&given) = named.get(name) {
            *v = given;
        }
    }
    let x = layout.from_si(&si);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The runs' RMS are pooled by their samples: one run far off in a
    /// few samples does not make the warning, the records together do;
    /// below the ratio, no warning.
    #[test]
    fn the_law_path_is_judged_over_all_runs_together() {
        // pooled: √((1000·4697² + 1000·1000²)/2000) = 3395.6 against
        // √((1000·422² + 1000·800²)/2000) = 639.6, 5.3×
        let runs = [("a", 1000), ("b", 1000)];
        let w = confounding_warning(&runs, &[4697.0, 1000.0], &[422.0, 800.0]).unwrap();
        assert!(w.contains("by 3396 Pa RMS where the law fitted alone with independent noise comes within 640 Pa (5.3×"), "{w}");
        assert!(
            w.contains("a 4697 Pa against 422 Pa (11.1×), b 1000 Pa against 800 Pa (1.2×)"),
            "{w}"
        );
        // one short run 3× off among long ones that fit: √((300·9 + 2·900·1.2²)/2100) = 1.59× the law alone's 1
        let short = [("fast", 300), ("slow", 900), ("mid", 900)];
        assert_eq!(confounding_warning(&short, &[3.0, 1.2, 1.2], &[1.0, 1.0, 1.0]), None);
    }
}
