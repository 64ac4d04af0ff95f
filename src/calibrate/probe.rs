//! How the walkers' start is judged in its first steps: whether the mode
//! they start about is a local one (the walkers climb above it), and how
//! far the posterior lies from its Laplace approximation there.
//!
//! Both are read off what the sampler does anyway — the log-densities of
//! the initial walkers and of their first steps — so a calibration whose
//! start is sound pays a single extra log-density and keeps its chains bit
//! for bit.

use crate::error::Result;
use crate::posterior::{laplace, map, Posterior};
use crate::sampler::{
    Chains, Elliptical, LogDensity, Observer, RunControl, Sampler, SamplerSettings,
};

/// The walkers' start, judged.
pub(super) struct Probed<'t> {
    /// The sampler at its first steps (at most [`PROBE_STEPS`]).
    pub sampler: Sampler<'t, Posterior>,
    /// The Laplace approximation at the mode the walkers started about.
    pub laplace: Elliptical,
    /// The MAP searched again from higher ground, if the first was local.
    pub map: Option<map::MapEstimate>,
    pub higher: Option<HigherGround>,
    /// ln p/q's spread over the initial walkers (nats).
    pub spread: f64,
    /// How many times wider the walkers' start is than the Laplace
    /// approximation at the mode along each axis found too narrow
    /// ([`laplace::too_narrow_widened`]), largest first.
    pub widened: Vec<f64>,
    /// The wall time of the sampler's steps so far: the chains' first
    /// steps, which count as sampling, not as the start.
    pub stepping_seconds: f64,
}

impl Probed<'_> {
    /// Whether the posterior is far from its Laplace approximation: the
    /// spread, where it is above [`FAR_FROM_LAPLACE`].
    pub fn far(&self) -> Option<f64> {
        far(self.spread)
    }
}

/// `spread`, where it is above [`FAR_FROM_LAPLACE`].
fn far(spread: f64) -> Option<f64> {
    Some(spread).filter(|m| *m > FAR_FROM_LAPLACE)
}

/// The walkers (`count`) started about the Laplace approximation at the
/// mode reached from `map`, stepped [`PROBE_STEPS`] times; where they climb
/// above that mode, the MAP is searched again from the highest walker and
/// the walkers start afresh about its mode (at most [`MAX_SEARCHES`]
/// times). Where the posterior is far from the Laplace approximation there
/// and `settings` has the default moves, the sampler walks with the curved
/// move instead ([`super::settings::moves_far_from_laplace`]). Where
/// `near` is given (walkers per ensemble, fewer than `settings`'), the
/// spread is judged over the first `near` × ensembles walkers placed, and
/// where it is near the sampler keeps just those (the same walkers as a
/// start placing that many: each walker's draws are its own stream). The
/// probe's steps are the run's first (at most `control`'s length), told
/// to `observers`. A function of the start and the seed alone.
pub(super) fn walkers_start<'t>(
    posterior: &'t Posterior,
    map: &map::MapEstimate,
    laplace: Option<Elliptical>,
    settings: SamplerSettings,
    near: Option<usize>,
    control: &RunControl,
    observers: &mut [&mut dyn Observer],
) -> Result<Probed<'t>> {
    let count = settings.walkers * settings.ensembles;
    let mut near = near.filter(|&w| w < settings.walkers);
    let laplace = laplace.unwrap_or_else(|| laplace::at_mode(posterior, map));
    // the log-density at the mode the walkers start about
    let mut top = posterior.log_density(laplace.mean.as_slice());
    let (mut laplace, mut widened) = laplace::too_narrow_widened(posterior, laplace, top);
    let mut higher: Option<HigherGround> = None;
    let mut new_map = None;
    loop {
        let init = map::initial_walkers(posterior, &laplace, count, settings.seed);
        // the first `s.walkers × ensembles` of the walkers placed (those a
        // start placing that many places), or all of them
        let placed = |s: SamplerSettings| -> Result<Sampler<'t, Posterior>> {
            let kept = s.walkers * s.ensembles;
            let positions = init.positions[..kept * posterior.dim()].to_vec();
            let log_prob = init.log_prob[..kept].to_vec();
            Ok(Sampler::from_state(posterior, s, positions, log_prob)?
                .with_reference(laplace.clone()))
        };
        let mut sampler =
            placed(near.map_or(settings.clone(), |walkers| SamplerSettings {
                walkers,
                ..settings.clone()
            }))?;
        let spread = misfit(posterior, &sampler.chains, &laplace);
        if far(spread).is_some() && sampler.settings.walkers < settings.walkers {
            sampler = placed(settings.clone())?;
        }
        if let Some(moves) =
            far(spread).and_then(|_| super::settings::moves_far_from_laplace(&settings.moves))
        {
            sampler.settings.moves = moves;
        }
        let done = |sampler, laplace, new_map, higher, widened, stepping_seconds| {
            Ok(Probed { sampler, laplace, map: new_map, higher, spread, widened, stepping_seconds })
        };
        if higher.as_ref().is_some_and(|h| h.searches == MAX_SEARCHES) {
            return done(sampler, laplace, new_map, higher, widened, 0.0);
        }
        // the probe's steps are the chains' first: their time is sampling's
        let clock = std::time::Instant::now();
        for _ in 0..PROBE_STEPS.min(control.max_steps) {
            sampler.step_observed(control, observers)?;
        }
        let stepping = clock.elapsed().as_secs_f64();
        // fewer walkers only where the anchored move fits the posterior
        // from the start: else the run starts afresh with all of them
        if sampler.settings.walkers < settings.walkers
            && probe_acceptance(&sampler.chains) < NEAR_ACCEPTANCE
        {
            near = None;
            continue;
        }
        match higher_ground(posterior, &sampler, top) {
            Some((found, (better, better_widened), better_top)) => {
                let gain = higher.as_ref().map_or(0.0, |h| h.gain) + better_top - top;
                let searches = higher.as_ref().map_or(0, |h| h.searches) + 1;
                higher = Some(HigherGround {
                    gain,
                    searches,
                    first_map: higher.map_or(map.log_density, |h| h.first_map),
                });
                new_map = Some(found);
                (laplace, widened, top) = (better, better_widened, better_top);
            }
            None => return done(sampler, laplace, new_map, higher, widened, stepping),
        }
    }
}

/// The share of the proposals accepted over the chains' steps after the
/// initial walkers.
fn probe_acceptance(chains: &Chains) -> f64 {
    let nc = chains.chains();
    let after = &chains.accepted[nc.min(chains.accepted.len())..];
    after.iter().filter(|a| **a).count() as f64 / after.len().max(1) as f64
}

/// The share of proposals the probe's steps must accept for a start near
/// its Laplace approximation to keep its fewer walkers
/// ([`crate::calibrate::settings::SamplingSettings::walkers_near`]). The
/// anchored move proposes from that approximation, shrunk toward the
/// complementary half's moments by as much as their noise allows: where
/// the approximation fits, few points serve, and it accepts about half
/// its proposals (0.46–0.58 on the measured records' calibrations that
/// converged at step 20–30 with the fewer walkers); where the posterior
/// leaves it as the walkers move (Bouc-Wen at 0.5 A on the measured
/// records, the start 1.4 sd from the posterior's mean in its shape:
/// 0.35 over the probe, 0.05 over the run), the half's own moments carry
/// the move, and with half the points the run took 1 280 steps instead of
/// 140 (docs/performance.md, "Fewer walkers where the start is near").
const NEAR_ACCEPTANCE: f64 = 0.45;

/// What the start's judgement tells the user.
pub(super) fn warnings(
    higher: &Option<HigherGround>,
    widened: &[f64],
    misfit: Option<f64>,
    moves_changed: bool,
) -> Vec<String> {
    let mut out: Vec<String> = higher.iter().map(HigherGround::message).collect();
    if let Some(most) = widened.first() {
        out.push(format!(
            "the Laplace approximation at the mode was too narrow along {} of its axes (the log-density falls there as for a posterior up to {most:.0}× wider: the mode's Hessian of finite differences is not its curvature over the bulk), so the walkers started from it widened to the spread measured (docs/calibration.md, \"The start\", step 3)",
            widened.len()
        ));
    }
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

/// After the probe's [`PROBE_STEPS`] steps of `sampler`: if a walker has
/// climbed more than [`HIGHER_GROUND`] above `top` (the log-density at the
/// mode the walkers started about), the MAP searched again from the
/// highest walker, the Laplace approximation at its mode and the
/// log-density there, if that mode is higher ground too; otherwise `None`,
/// and the sampler goes on from where it is.
fn higher_ground(
    posterior: &Posterior,
    sampler: &Sampler<Posterior>,
    top: f64,
) -> Option<(map::MapEstimate, (Elliptical, Vec<f64>), f64)> {
    let d = posterior.dim();
    let chains = &sampler.chains;
    let (best, lp) = chains
        .log_prob
        .iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
    if !(lp > top + HIGHER_GROUND) {
        return None;
    }
    let map = map::refine(posterior, &chains.positions[best * d..(best + 1) * d])?;
    let laplace = laplace::at_mode(posterior, &map);
    let new_top = posterior.log_density(laplace.mean.as_slice());
    (new_top > top + HIGHER_GROUND)
        .then(|| (map, laplace::too_narrow_widened(posterior, laplace, new_top), new_top))
}

/// The spread (sd, nats) of ln p/q over the initial walkers above which
/// the posterior is taken to be far from its Laplace approximation q. At
/// draws of a q that matches p, ln p/q is constant; the bundled virtual
/// campaigns give 0.09–0.12, the measured records 0.15–3.6 (alone and
/// together, with and without the model terms), the one measured record
/// whose posterior is a long curved ridge 30 with the terms (measured
/// 2026-11-27; docs/performance.md, "A start far from equilibrium" and
/// "The Hessian at half the points": the spread is only as good as the
/// mode's Hessian).
pub(super) const FAR_FROM_LAPLACE: f64 = 8.0;

/// The sd of ln p(x) − ln q(x) over the walkers of the chains' first step,
/// draws of q: the Laplace approximation `laplace` spread by
/// [`map::START_SPREAD`] (q's own constant does not matter).
pub(super) fn laplace_misfit(chains: &Chains, laplace: &Elliptical) -> f64 {
    let d = chains.dim;
    let walkers = chains.chains();
    spread((0..walkers).map(|c| {
        chains.log_prob[c]
            - laplace.log_kernel(None, &chains.positions[c * d..(c + 1) * d], map::START_SPREAD)
    }))
}

/// The sd of the finite values of ln p/q (0 with fewer than two).
fn spread(log_ratio: impl Iterator<Item = f64>) -> f64 {
    let w: Vec<f64> = log_ratio.filter(|v| v.is_finite()).collect();
    if w.len() < 2 {
        return 0.0;
    }
    crate::numeric::variance(&w).sqrt()
}

/// [`laplace_misfit`] for the coordinates the ensemble moves propose:
/// where the posterior has blocks the sampler moves on their own
/// ([`LogDensity::blocks`], the discrepancy model's noise of each run), the
/// spread of ln p − ln q over the rest, q's marginal there, with every
/// walker's blocks held at q's mean (one more log-density per walker). A
/// run's noise often presses against its prior's bounds, where the Laplace
/// approximation means little and the initial walkers' log-densities
/// spread by a hundred nats (the measured 1 A records, time scale bounded
/// at 0.02 of the period: 105, and 5.4 so measured), while the ensemble
/// moves never propose those coordinates.
fn misfit(posterior: &Posterior, chains: &Chains, laplace: &Elliptical) -> f64 {
    let blocks = posterior.blocks();
    if blocks.is_empty() {
        return laplace_misfit(chains, laplace);
    }
    let d = chains.dim;
    let free = crate::sampler::density::free_coordinates(d, &blocks);
    let Some(q) = laplace.marginal(&free) else { return laplace_misfit(chains, laplace) };
    let mut points = chains.positions[..chains.chains() * d].to_vec();
    for x in points.chunks_exact_mut(d) {
        for i in blocks.iter().flatten() {
            x[*i] = laplace.mean[*i];
        }
    }
    let lp = crate::sampler::density::log_densities(posterior, &points);
    spread(points.chunks_exact(d).zip(lp).map(|(x, lp)| {
        lp - q.log_kernel(
            None,
            &free.iter().map(|&i| x[i]).collect::<Vec<f64>>(),
            map::START_SPREAD,
        )
    }))
}

/// The warning for a posterior far from its Laplace approximation.
fn far_message(misfit: f64, moves_changed: bool) -> String {
    let moves = if moves_changed {
        "the curved move walked in the anchored move's place, and "
    } else {
        ""
    };
    format!(
        "the posterior is far from its Laplace approximation at the mode (ln p/q over the initial walkers spreads by {misfit:.1} nats, above {FAR_FROM_LAPLACE}): walkers that start on that approximation fill a curved or skewed posterior slowly and together, which R̂ does not see, so {moves}the run went on to twice the step at which R̂, ESS and length first held and checked them again there (docs/calibration.md, \"Convergence\")"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::Moments;
    use nalgebra::{DMatrix, DVector};

    /// Walkers drawn from q with log-densities ln q + c: ln p/q is constant
    /// and its spread 0; with ln p = ln q + c + ½ z₁² (a posterior wider than
    /// q along one axis) the spread is that of ½ z₁², sd 1/√2 (over 2 000
    /// walkers a sample sd of ½ χ²₁, kurtosis 15, has se 0.03: tolerance
    /// 5 se); and the walkers of later steps do not count.
    #[test]
    fn the_misfit_is_the_spread_of_ln_p_over_q() {
        let q = Elliptical::new(Moments {
            mean: DVector::from_vec(vec![1.0, -2.0]),
            cov: DMatrix::from_row_slice(2, 2, &[2.0, 0.5, 0.5, 1.0]),
        })
        .unwrap();
        let mut rng = crate::rng::stream(7, &[]);
        let n = 2000;
        let mut positions = vec![0.0; 2 * n];
        for p in positions.chunks_exact_mut(2) {
            q.draw(None, map::START_SPREAD, &mut rng, p);
        }
        let exact: Vec<f64> = positions
            .chunks_exact(2)
            .map(|x| 3.0 + q.log_kernel(None, x, map::START_SPREAD))
            .collect();
        let wider: Vec<f64> = positions
            .chunks_exact(2)
            .map(|x| {
                let z = q
                    .factor()
                    .solve_lower_triangular(&(DVector::from_column_slice(x) - &q.mean))
                    .unwrap();
                3.0 + q.log_kernel(None, x, map::START_SPREAD) + 0.5 * z[0] * z[0]
            })
            .collect();
        let chains = |first: &[f64]| {
            // a second step far off, which must not count
            let mut log_prob = first.to_vec();
            log_prob.extend(std::iter::repeat_n(-1e6, n));
            let mut pos = positions.clone();
            pos.extend(std::iter::repeat_n(50.0, 2 * n));
            Chains {
                dim: 2,
                ensembles: 4,
                walkers: n / 4,
                positions: pos,
                log_prob,
                accepted: vec![false; 2 * n],
            }
        };
        assert!(laplace_misfit(&chains(&exact), &q) < 1e-9);
        let m = laplace_misfit(&chains(&wider), &q);
        assert!((m - 0.5f64.sqrt()).abs() < 0.15, "misfit {m}");
    }
}
