//! Ensembles stranded in a mode of negligible mass.
//!
//! Every move proposes from the walker's own ensemble, so an ensemble that
//! starts in a separate mode of the posterior stays there for good, and the
//! run never converges (R̂ between ensembles stays high). At steps 32, 64,
//! 128 and 256 each ensemble's share of the posterior mass is estimated
//! from its walkers by the Laplace approximation,
//!
//! ln Z_e ≈ mean ln p + ½ ln det Σ_e  (+ terms alike for every ensemble),
//!
//! with Σ_e the walkers' covariance. An ensemble more than [`GAP_NATS`]
//! below the best one sits where the posterior has less than e^−20 ≈ 2·10⁻⁹
//! of the best one's mass: its walkers are drawn afresh from the normal of
//! the best ensemble's walkers (mean and covariance), and the burn-in
//! starts again there. Ensembles in one mode differ by a fraction of a nat,
//! so a run without stranded ensembles is not touched, bit for bit.
//!
//! It is a repair of the start (a start that straddles basins, which the
//! ensembles may still be climbing out of at the first checks), so it acts
//! early only: at the checks up to step [`LAST_CHECK`]. A posterior on
//! which the ensembles keep parting after that is not one a normal of the
//! best ensemble describes; R̂ then says so.
//!
//! The decision is a function of the stored positions and the seed alone:
//! it is replayed from the chains (for the burn-in, the report, a resumed
//! run) and does not depend on the number of threads.

use nalgebra::{DMatrix, DVector};
use rand_distr::StandardNormal;

use super::chains::Chains;

/// How far below the best ensemble (nats of estimated log-mass) an
/// ensemble is taken as stranded.
pub const GAP_NATS: f64 = 20.0;

/// The first step that checks; later checks at its doublings, up to
/// [`LAST_CHECK`].
const FIRST_CHECK: usize = 32;

/// The last step that may check.
pub const LAST_CHECK: usize = 256;

/// Index of the stream that draws redrawn walkers.
const REDRAW_STREAM: u64 = u64::MAX - 3;

/// One ensemble drawn afresh.
#[derive(Clone, Debug, PartialEq)]
pub struct Redraw {
    /// The step that started from the new positions.
    pub step: usize,
    pub ensemble: usize,
    /// The ensemble whose normal it was drawn from.
    pub from: usize,
    /// How far below it, in nats of estimated log-mass.
    pub gap: f64,
}

impl Redraw {
    /// What happened, for the calibration's warnings.
    pub fn message(&self) -> String {
        format!(
            "ensemble {} sat in a separate mode {:.0} nats (of estimated log-mass) below ensemble {} at step {}: it was drawn afresh from ensemble {}'s spread and the burn-in restarted there (a second mode of negligible mass exists: check the start, docs/calibration.md)",
            self.ensemble, self.gap, self.from, self.step, self.from
        )
    }
}

/// Whether the step `step` may start with a check.
fn is_check(step: usize) -> bool {
    (FIRST_CHECK..=LAST_CHECK).contains(&step) && step.is_power_of_two()
}

/// The ensembles to draw afresh before step `step` (none unless it is a
/// check).
pub fn due(chains: &Chains, step: usize) -> Vec<Redraw> {
    if !is_check(step) {
        return Vec::new();
    }
    decide(chains, step)
}

/// The ensembles stranded before step `step`, judged on the positions of
/// the step before.
fn decide(chains: &Chains, step: usize) -> Vec<Redraw> {
    if chains.ensembles < 2 || step > chains.steps() {
        return Vec::new();
    }
    let mass: Vec<f64> = (0..chains.ensembles)
        .map(|e| fit(chains, step - 1, e).map_or(f64::NEG_INFINITY, |f| f.2))
        .collect();
    let Some(best) = (0..mass.len())
        .filter(|&e| mass[e].is_finite())
        .max_by(|&a, &b| mass[a].total_cmp(&mass[b]))
    else {
        return Vec::new();
    };
    (0..chains.ensembles)
        .filter(|&e| e != best && mass[best] - mass[e] > GAP_NATS)
        .map(|e| Redraw { step, ensemble: e, from: best, gap: mass[best] - mass[e] })
        .collect()
}

/// Every redraw of the run the chains hold.
pub fn history(chains: &Chains) -> Vec<Redraw> {
    (FIRST_CHECK..chains.steps()).filter(|s| is_check(*s)).flat_map(|s| decide(chains, s)).collect()
}

/// The step of the last redraw, 0 if none.
pub fn last_step(chains: &Chains) -> usize {
    history(chains).last().map_or(0, |r| r.step)
}

/// The new positions of `redraw`'s walkers (walker-major) from the normal of
/// ensemble `redraw.from` at the step before, with the sampler's `seed`.
pub fn positions(chains: &Chains, redraw: &Redraw, seed: u64) -> Vec<f64> {
    let d = chains.dim;
    let Some((mean, l, _)) = fit(chains, redraw.step - 1, redraw.from) else {
        // decide() only names ensembles with a fit
        return Vec::new();
    };
    let mut out = Vec::with_capacity(chains.walkers * d);
    for w in 0..chains.walkers {
        let mut rng = crate::rng::stream(
            seed,
            &[redraw.ensemble as u64, redraw.step as u64, w as u64, REDRAW_STREAM],
        );
        let z = DVector::from_iterator(
            d,
            (0..d).map(|_| rand::RngExt::sample::<f64, _>(&mut rng, StandardNormal)),
        );
        out.extend((&mean + &l * z).iter());
    }
    out
}

/// The walkers of ensemble `e` at `step`: their mean, the Cholesky factor
/// of their covariance (with a ridge of 1e-12 of its trace, so that a
/// collapsed ensemble still has one) and the estimated log-mass; None with
/// fewer walkers than coordinates.
fn fit(chains: &Chains, step: usize, e: usize) -> Option<(DVector<f64>, DMatrix<f64>, f64)> {
    let (d, nw) = (chains.dim, chains.walkers);
    if nw <= d {
        return None;
    }
    let points = DMatrix::from_fn(nw, d, |w, i| chains.at(step, e * nw + w, i));
    let mean = DVector::from_iterator(d, (0..d).map(|i| points.column(i).mean()));
    let centred = DMatrix::from_fn(nw, d, |w, i| points[(w, i)] - mean[i]);
    let mut cov: DMatrix<f64> = centred.transpose() * &centred / (nw - 1) as f64;
    let ridge = 1e-12 * cov.trace().max(f64::MIN_POSITIVE) / d as f64;
    for i in 0..d {
        cov[(i, i)] += ridge;
    }
    let l = cov.cholesky()?.l();
    let log_det = 2.0 * l.diagonal().iter().map(|v| v.ln()).sum::<f64>();
    // the mean (the Laplace estimate): walkers stuck far down count, and
    // redrawing their ensemble frees them
    let mean_lp =
        (0..nw).map(|w| chains.log_prob[step * chains.chains() + e * nw + w]).sum::<f64>()
            / nw as f64;
    Some((mean, l, mean_lp + 0.5 * log_det))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Chains of `ensembles` ensembles of 40 walkers in 2-d at one step,
    /// ensemble e centred at `centres[e]` with log-densities `lp[e]`.
    fn chains(centres: &[f64], lp: &[f64]) -> Chains {
        let (nw, d) = (40, 2);
        let mut positions = Vec::new();
        let mut log_prob = Vec::new();
        for (e, c) in centres.iter().enumerate() {
            for w in 0..nw {
                let u = w as f64 / nw as f64;
                positions.extend([c + (6.0 * u).sin(), c + (11.0 * u).cos()]);
                log_prob.push(lp[e]);
            }
        }
        let steps = 40;
        let one = positions.clone();
        let one_lp = log_prob.clone();
        for _ in 1..steps {
            positions.extend_from_slice(&one);
            log_prob.extend_from_slice(&one_lp);
        }
        Chains {
            dim: d,
            ensembles: centres.len(),
            walkers: nw,
            accepted: vec![true; log_prob.len()],
            positions,
            log_prob,
        }
    }

    #[test]
    fn an_ensemble_far_below_the_others_is_redrawn_from_the_best() {
        let c = chains(&[0.0, 10.0, 0.1], &[-5.0, -60.0, -5.5]);
        let r = due(&c, 32);
        assert_eq!(r.len(), 1);
        assert_eq!((r[0].ensemble, r[0].from, r[0].step), (1, 0, 32));
        // equal spreads: the gap is the log-densities' difference
        assert!((r[0].gap - 55.0).abs() < 1e-9, "{}", r[0].gap);
        assert_eq!(history(&c), r);
        // the new walkers are spread like ensemble 0's: mean near 0
        let x = positions(&c, &r[0], 7);
        let mean: f64 = x.iter().step_by(2).sum::<f64>() / 40.0;
        assert!(mean.abs() < 0.5, "{mean}");
        // a run whose ensembles agree, or steps between checks, keep theirs
        assert!(due(&chains(&[0.0, 10.0], &[-5.0, -20.0]), 32).is_empty());
        assert!(due(&c, 33).is_empty() && due(&c, 31).is_empty());
        // no checks after step 256
        assert!(is_check(256) && !is_check(512));
    }
}
