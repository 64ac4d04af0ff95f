//! Whether the draws after burn-in still drift: a start that is not a
//! draw of the posterior (the Laplace approximation of a skewed one, say)
//! leaves every ensemble moving the same way for tens of steps, which R̂,
//! comparing the ensembles with each other, does not see, and which a
//! burn-in of a few autocorrelation times does not cut away.
//!
//! The test, Geweke's (1992) comparison of a chain's early and late
//! means made across the walkers: each walker's mean over the last half
//! of the draws after burn-in less its mean over their first quarter, of
//! the coordinate's rank-normalised draws (so the test is the same in any
//! monotone coordinate: the sampler's, or the outputs' SI), averaged over
//! the walkers, in units of its standard error (the walkers' spread of
//! that difference over √walkers). Under stationarity it is about a
//! standard normal. A transient confined to the first quarter that leaves
//! the kept draws' mean `b` Monte Carlo standard errors off gives a z of
//! about 1.6 b (the halves' comparison, about b).
//!
//! The same comparison of the rank-normalised draws' absolute values
//! tests the spread: a start narrower than the posterior along a ridge
//! (a Laplace approximation whose curvature at the mode overstates the
//! ridge's), out of which every ensemble widens alike, moves no mean and
//! leaves R̂ near 1 while the intervals are still too narrow.
//!
//! Measured (docs/performance.md, "Draws that still drift"): Bouc-Wen's
//! posterior on the measured 0.5 A records, whose walkers drift 1.4 sd in
//! its shape over their first 60 steps, gives z 6.3 after the rule's
//! burn-in of 24 steps at step 100, 3.5 after 32; windows of stationary
//! draws of two 600-step runs of it (80 windows of 20–100 steps, 14
//! coordinates) give a largest |z| of 2.0 at the median and 3.7 at most,
//! and every calibration of the main job at most 2.3. The spread's test
//! on the bp-viscous law at the measured 0.25 A records: z 5.7 in D1 at
//! step 40, where the mean's test and R̂ pass and the intervals are 0.45
//! of the long run's (docs/calibration.md, "Convergence").

use rayon::prelude::*;

use super::Chains;
use crate::numeric::rank_normalize;

/// A mean that moves between the first quarter and the last half of the
/// draws after burn-in by more than this many standard errors drifts:
/// past any chance of stationary draws (two-sided 6·10⁻⁵ a coordinate),
/// with room for the walkers of an ensemble, which share their proposals,
/// varying together.
pub const DRIFT_Z: f64 = 4.0;

/// Fewer steps after burn-in than this are not tested (a first quarter of
/// two steps; R̂ and ESS are hardly estimated there either).
const MIN_STEPS: usize = 12;

/// The burn-ins tried past the rule's, evenly up to half the chain.
const CANDIDATES: usize = 8;

/// Which moment of a coordinate's draws moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Moment {
    /// The mean (the rank-normalised draws): walkers that still travel
    /// from their start to the bulk.
    Mean,
    /// The spread (the rank-normalised draws' absolute value): walkers
    /// started narrower (or wider) than the posterior that all widen (or
    /// narrow) together, which neither R̂ nor the mean sees.
    Spread,
}

/// The coordinate whose mean or spread drifts most over the draws from
/// step `from`, and by how many standard errors.
#[derive(Clone, Debug, PartialEq)]
pub struct Drift {
    pub coordinate: usize,
    pub moment: Moment,
    pub z: f64,
    pub from: usize,
}

/// The drift statistics of one coordinate's traces (one per walker, all
/// the same length), of its mean and of its spread: NaN where the traces
/// are too short or do not spread.
fn z(traces: &[Vec<f64>]) -> (f64, f64) {
    let steps = traces.first().map_or(0, Vec::len);
    if steps < MIN_STEPS || traces.len() < 2 {
        return (f64::NAN, f64::NAN);
    }
    let normal = rank_normalize(traces);
    (z_of(&normal, |x| x), z_of(&normal, f64::abs))
}

/// The statistic of `f` of the rank-normalised traces `normal`.
fn z_of(normal: &[Vec<f64>], f: impl Fn(f64) -> f64) -> f64 {
    let steps = normal[0].len();
    let (quarter, half) = (steps / 4, steps / 2);
    let deltas: Vec<f64> = normal
        .iter()
        .map(|t| {
            let early: f64 = t[..quarter].iter().map(|&x| f(x)).sum::<f64>() / quarter as f64;
            let late: f64 = t[half..].iter().map(|&x| f(x)).sum::<f64>() / (steps - half) as f64;
            late - early
        })
        .collect();
    let n = deltas.len() as f64;
    let mean = deltas.iter().sum::<f64>() / n;
    let var = deltas.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0);
    mean / (var / n).sqrt()
}

/// The statistic of every coordinate of `chains` after `burn_in`, of its
/// mean and of its spread (none where too few steps are left).
pub fn statistics(chains: &Chains, burn_in: usize) -> Vec<Drift> {
    if chains.steps().saturating_sub(burn_in) < MIN_STEPS {
        return Vec::new();
    }
    // every coordinate's draws ranked, on every thread (as R̂'s are)
    (0..chains.dim)
        .into_par_iter()
        .flat_map_iter(|i| {
            let (mean, spread) = z(&chains.traces(i, burn_in));
            [(Moment::Mean, mean), (Moment::Spread, spread)].map(|(moment, z)| Drift {
                coordinate: i,
                moment,
                z,
                from: burn_in,
            })
        })
        .collect()
}

/// The worst drift of `chains` after `burn_in`, of a mean or a spread,
/// where above [`DRIFT_Z`].
pub fn drift(chains: &Chains, burn_in: usize) -> Option<Drift> {
    statistics(chains, burn_in)
        .into_iter()
        .filter(|d| d.z.abs() > DRIFT_Z)
        .max_by(|a, b| a.z.abs().total_cmp(&b.z.abs()))
}

/// The burn-in `rule` (steps), moved past a drift: where the draws after
/// it drift, the first of [`CANDIDATES`] later burn-ins, evenly up to half
/// the chain, after which they do not (half the chain if none: the
/// diagnostics then say the draws drift).
pub fn past_drift(chains: &Chains, rule: usize) -> usize {
    let limit = chains.steps() / 2;
    if rule >= limit || drift(chains, rule).is_none() {
        return rule;
    }
    let stride = (limit - rule).div_ceil(CANDIDATES);
    let mut burn_in = rule;
    while burn_in < limit {
        burn_in = (burn_in + stride).min(limit);
        if drift(chains, burn_in).is_none() {
            return burn_in;
        }
    }
    limit
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;
    use rand_distr::StandardNormal;

    /// Chains of `walkers` walkers in 4 ensembles, one coordinate of AR(1)
    /// draws (ρ 0.6, stream `seed`), plus `shift(step)`.
    fn chains(seed: u64, walkers: usize, steps: usize, shift: impl Fn(usize) -> f64) -> Chains {
        let mut rng = crate::rng::stream(seed, &[1]);
        let n = walkers;
        let mut x: Vec<f64> = (0..n).map(|_| rng.sample(StandardNormal)).collect();
        let mut positions = Vec::with_capacity(steps * n);
        for s in 0..steps {
            for v in x.iter_mut() {
                let e: f64 = rng.sample(StandardNormal);
                *v = 0.6 * *v + 0.8 * e;
            }
            positions.extend(x.iter().map(|v| v + shift(s)));
        }
        Chains {
            dim: 1,
            ensembles: 4,
            walkers: n / 4,
            positions,
            log_prob: vec![0.0; steps * n],
            accepted: vec![false; steps * n],
        }
    }

    /// Stationary draws: no drift, and the rule's burn-in is kept; z of
    /// 200 independent sets of chains, of the mean and of the spread, is
    /// a standard normal (mean within 4 se = 0.28 of 0, sd within
    /// 0.8–1.2: 200 draws estimate an sd to 5 %, and walkers that do not
    /// interact give no design effect), and none is beyond [`DRIFT_Z`] (a
    /// standard normal exceeds 4 once in 16 000).
    #[test]
    fn stationary_draws_do_not_drift() {
        let c = chains(1, 256, 40, |_| 0.0);
        assert_eq!(drift(&c, 3), None);
        assert_eq!(past_drift(&c, 3), 3);
        let zs: Vec<(f64, f64)> =
            (0..200).map(|seed| z(&chains(seed + 10, 64, 20, |_| 0.0).traces(0, 3))).collect();
        let means: Vec<f64> = zs.iter().map(|z| z.0).collect();
        let spreads: Vec<f64> = zs.iter().map(|z| z.1).collect();
        for (name, zs) in [("mean", means), ("spread", spreads)] {
            let mean = zs.iter().sum::<f64>() / 200.0;
            let sd = (zs.iter().map(|z| (z - mean).powi(2)).sum::<f64>() / 199.0).sqrt();
            assert!(mean.abs() < 0.28 && (0.8..1.2).contains(&sd), "{name}: mean {mean}, sd {sd}");
            assert!(zs.iter().all(|z| z.abs() < DRIFT_Z), "{name}: {zs:?}");
        }
    }

    /// Walkers that move 1.4 sd over their first 60 of 140 steps (as
    /// Bouc-Wen's shape did) drift after a burn-in of 17 steps; the burn-in
    /// moves past the drift's end, and no further than the first
    /// candidate after it.
    #[test]
    fn a_common_drift_moves_the_burn_in_past_it() {
        let c = chains(2, 336, 140, |s| 1.4 * (s.min(60) as f64) / 60.0);
        let found = drift(&c, 17).expect("a drift");
        assert!(found.z > DRIFT_Z && found.moment == Moment::Mean, "{found:?}");
        let burn_in = past_drift(&c, 17);
        assert!((45..=70).contains(&burn_in), "burn-in {burn_in}");
        assert_eq!(drift(&c, burn_in), None);
    }

    /// A drift that lasts the whole chain is not cut away: the burn-in
    /// stops at half the chain and the drift is still found there.
    #[test]
    fn a_drift_to_the_end_is_reported() {
        let c = chains(3, 256, 40, |s| 0.05 * s as f64);
        assert_eq!(past_drift(&c, 3), 20);
        assert!(drift(&c, 20).is_some());
    }

    /// Walkers started at 0.3 of the posterior's width that widen to it
    /// over their first 60 of 140 steps, their mean steady (a ridge the
    /// start's curvature saw too narrow): a drift of the spread, whose
    /// burn-in moves past the widening as a mean's does.
    #[test]
    fn walkers_that_widen_drift_in_their_spread() {
        let plain = chains(4, 336, 140, |_| 0.0);
        let widening = Chains {
            positions: plain
                .positions
                .iter()
                .enumerate()
                .map(|(k, x)| x * (0.3 + 0.7 * ((k / 336).min(60) as f64) / 60.0))
                .collect(),
            ..plain
        };
        let found = drift(&widening, 17).expect("a drift");
        assert!(found.z > DRIFT_Z && found.moment == Moment::Spread, "{found:?}");
        let burn_in = past_drift(&widening, 17);
        assert!((45..=70).contains(&burn_in), "burn-in {burn_in}");
        assert_eq!(drift(&widening, burn_in), None);
    }
}
