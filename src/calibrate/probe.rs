//! How the walkers' start is judged in its first steps: whether the mode
//! they start about is a local one (the walkers climb above it), and how
//! far the posterior lies from its Laplace approximation there.
//!
//! Both are read off what the sampler does anyway — the log-densities of
//! the initial walkers and of their first steps — so a calibration whose
//! start is sound pays a single extra log-density and keeps its chains bit
//! for bit.

use crate::error::Result;
use crate::posterior::{map, mode, Posterior};
use crate::sampler::{Chains, Elliptical, LogDensity, Move, Sampler, SamplerSettings};

/// The walkers' start, judged.
pub(super) struct Probed<'t> {
    /// The sampler at its first steps (at most [`PROBE_STEPS`]).
    pub sampler: Sampler<'t, Posterior>,
    /// The Laplace approximation at the mode the walkers started about.
    pub laplace: Elliptical,
    /// The MAP searched again from higher ground, if the first was local.
    pub map: Option<map::MapEstimate>,
    pub higher: Option<HigherGround>,
    /// ln p/q's spread over the initial walkers, where it is above
    /// [`FAR_FROM_LAPLACE`].
    pub misfit: Option<f64>,
}

/// The walkers (`count`) started about the Laplace approximation at the
/// mode reached from `map`, stepped [`PROBE_STEPS`] times; where they climb
/// above that mode, the MAP is searched again from the highest walker and
/// the walkers start afresh about its mode (at most [`MAX_SEARCHES`]
/// times). Where the posterior is far from the Laplace approximation there
/// and `settings` has the default moves, the sampler walks with the curved
/// move instead ([`curved_moves`]). A function of the start and the seed
/// alone.
pub(super) fn walkers_start<'t>(posterior: &'t Posterior, map: &map::MapEstimate, settings: SamplerSettings, count: usize) -> Result<Probed<'t>> {
    let mut laplace = mode::laplace_from(posterior, map);
    let mut higher: Option<HigherGround> = None;
    let mut new_map = None;
    loop {
        let init = map::initial_walkers(posterior, &laplace, count, settings.seed);
        let mut sampler = Sampler::new(posterior, settings.clone(), &init)?.with_reference(laplace.clone());
        let misfit = Some(laplace_misfit(&sampler.chains, &laplace)).filter(|m| *m > FAR_FROM_LAPLACE);
        if misfit.is_some() && settings.moves == super::settings::SamplingSettings::default().moves {
            sampler.settings.moves = curved_moves();
        }
        let done = |sampler, laplace, new_map, higher| Ok(Probed { sampler, laplace, map: new_map, higher, misfit });
        if higher.as_ref().is_some_and(|h| h.searches == MAX_SEARCHES) {
            return done(sampler, laplace, new_map, higher);
        }
        let top = posterior.log_density(laplace.mean.as_slice());
        match higher_ground(posterior, &mut sampler, top) {
            Some((found, better)) => {
                let gain = higher.as_ref().map_or(0.0, |h| h.gain) + posterior.log_density(better.mean.as_slice()) - top;
                let searches = higher.as_ref().map_or(0, |h| h.searches) + 1;
                higher = Some(HigherGround { gain, searches, first_map: higher.map_or(map.log_density, |h| h.first_map) });
                new_map = Some(found);
                laplace = better;
            }
            None => return done(sampler, laplace, new_map, higher),
        }
    }
}

/// The moves where the posterior is far from its Laplace approximation:
/// the curved move in the anchored move's place (docs/performance.md, "A
/// start far from equilibrium").
pub(super) fn curved_moves() -> Vec<(Move, f64)> {
    vec![(Move::curved(), 0.9), (Move::differential_evolution(), 0.1)]
}

/// What the start's judgement tells the user.
pub(super) fn warnings(higher: &Option<HigherGround>, misfit: Option<f64>, moves_changed: bool) -> Vec<String> {
    let mut out: Vec<String> = higher.iter().map(HigherGround::message).collect();
    out.extend(misfit.map(|m| far_message(m, moves_changed)));
    out
}

/// Steps the walkers take from the Laplace approximation at the mode
/// before the start is judged ([`higher_ground`]).
const PROBE_STEPS: usize = 10;

/// How far (nats) above the mode a walker must climb within
/// [`PROBE_STEPS`] for the mode to be taken as a local one: at a mode no
/// walker should rise above it at all (on the eleven other measured
/// records and the bundled campaigns the walkers' best log-density rises
/// by at most 0.7 nats over their first 40 steps).
const HIGHER_GROUND: f64 = 5.0;

/// Searches from a walker's higher ground at most.
const MAX_SEARCHES: usize = 3;

/// The search's mode was a local one: the walkers found higher ground and
/// the MAP was searched again from there.
pub(super) struct HigherGround {
    /// How much higher (nats) the mode finally used lies.
    gain: f64,
    searches: usize,
    /// The log-density of the first MAP.
    first_map: f64,
}

impl HigherGround {
    fn message(&self) -> String {
        format!(
            "within {PROBE_STEPS} steps the walkers climbed more than {HIGHER_GROUND} nats above the mode the MAP search had found (log-density {:.1}): it was a local one, so the search was repeated from the highest walker ({} time(s)) and the walkers started about a mode {:.1} nats higher (docs/calibration.md, \"The start\")",
            self.first_map, self.searches, self.gain
        )
    }
}

/// Steps `sampler` [`PROBE_STEPS`] times and, if a walker has climbed more
/// than [`HIGHER_GROUND`] above `top` (the log-density at the mode the
/// walkers started about), searches the MAP again from the highest walker
/// and reaches its mode: that MAP and the Laplace approximation at its
/// mode, if the mode is higher ground too; otherwise `None`, and the
/// sampler goes on from where it is.
fn higher_ground(posterior: &Posterior, sampler: &mut Sampler<Posterior>, top: f64) -> Option<(map::MapEstimate, Elliptical)> {
    for _ in 0..PROBE_STEPS {
        sampler.step();
    }
    let d = posterior.dim();
    let chains = &sampler.chains;
    let (best, lp) = chains.log_prob.iter().enumerate().fold((0, f64::NEG_INFINITY), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
    if !(lp > top + HIGHER_GROUND) {
        return None;
    }
    let map = map::refine(posterior, &chains.positions[best * d..(best + 1) * d])?;
    let laplace = mode::laplace_from(posterior, &map);
    (posterior.log_density(laplace.mean.as_slice()) > top + HIGHER_GROUND).then_some((map, laplace))
}

/// The spread (sd, nats) of ln p/q over the initial walkers above which
/// the posterior is taken to be far from its Laplace approximation q. At
/// draws of a q that matches p, ln p/q is constant; the bundled virtual
/// campaigns give 0.55, the measured records 1.7–3.6 (alone and together),
/// the one measured record whose posterior is a long curved ridge 28
/// (docs/performance.md, "A start far from equilibrium").
pub(super) const FAR_FROM_LAPLACE: f64 = 8.0;

/// How many τ_max the chains must hold after burn-in where the posterior
/// is far from its Laplace approximation (emcee's rule of thumb), against
/// [`crate::sampler::diagnostics::MIN_TAU_MULTIPLE`] elsewhere: walkers
/// that started on a Gaussian spread about the mode need that long to fill
/// a curved ridge, and they do it together, so R̂, which compares the
/// ensembles, does not see it.
pub(super) const FAR_TAU_MULTIPLE: f64 = 50.0;

/// The sd of ln p(x) − ln q(x) over the walkers of the chains' first step,
/// draws of q: the Laplace approximation `laplace` spread by
/// [`map::START_SPREAD`] (q's own constant does not matter).
pub(super) fn laplace_misfit(chains: &Chains, laplace: &Elliptical) -> f64 {
    let d = chains.dim;
    let walkers = chains.last_log_prob().len();
    let w: Vec<f64> = (0..walkers).map(|c| chains.log_prob[c] - laplace.log_kernel(None, &chains.positions[c * d..(c + 1) * d], map::START_SPREAD)).filter(|v| v.is_finite()).collect();
    if w.len() < 2 {
        return 0.0;
    }
    let m = w.iter().sum::<f64>() / w.len() as f64;
    (w.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (w.len() - 1) as f64).sqrt()
}

/// The warning for a posterior far from its Laplace approximation.
fn far_message(misfit: f64, moves_changed: bool) -> String {
    let moves = if moves_changed { "the curved move walked in the anchored move's place, and " } else { "" };
    format!(
        "the posterior is far from its Laplace approximation at the mode (ln p/q over the initial walkers spreads by {misfit:.1} nats, above {FAR_FROM_LAPLACE}): walkers that start on that approximation fill a curved or skewed posterior slowly and together, which R̂ does not see, so {moves}the run went on to {FAR_TAU_MULTIPLE} τ after burn-in (docs/calibration.md, \"Convergence\")"
    )
}
