//! Comparing calibrations (of current levels, dampers, settings …): their
//! summaries side by side, the posterior of the difference and of the ratio
//! of a parameter between two independent calibrations, and the probability
//! that one exceeds the other.
//!
//! Two calibrations of different records have independent posteriors, so
//! (a, b) pairs drawn one from each are draws of the joint posterior.

use crate::posterior::{PosteriorSample, SummaryRow};
use crate::sampler::quantile_sorted;

/// One calibration as a comparison sees it.
pub struct Entry<'a> {
    pub label: String,
    /// The current its parameters describe (a current law's reference).
    pub current_a: f64,
    pub summary: &'a [SummaryRow],
    pub sample: &'a PosteriorSample,
    /// The positions of the draws to compare.
    pub positions: Vec<(usize, usize)>,
}

/// One row of `comparison.parquet`: a calibration's summary of one parameter.
#[derive(Clone, Debug, PartialEq)]
pub struct ComparisonRow {
    pub calibration: String,
    pub current_a: f64,
    pub parameter: String,
    pub mean: f64,
    pub sd: f64,
    pub q05: f64,
    pub q50: f64,
    pub q95: f64,
}

/// One row of `differences.parquet`: a pair of calibrations and a parameter.
#[derive(Clone, Debug, PartialEq)]
pub struct DifferenceRow {
    pub a: String,
    pub b: String,
    pub parameter: String,
    pub difference: Difference,
}

/// The tables of a comparison.
pub struct Comparison {
    pub rows: Vec<ComparisonRow>,
    pub differences: Vec<DifferenceRow>,
}

impl Comparison {
    /// Every calibration's summary, and for every pair the difference of
    /// every parameter both have (noise scales are per run and left out).
    pub fn of(entries: &[Entry]) -> Comparison {
        let rows = entries
            .iter()
            .flat_map(|e| {
                e.summary.iter().map(|r| ComparisonRow {
                    calibration: e.label.clone(),
                    current_a: e.current_a,
                    parameter: r.parameter.clone(),
                    mean: r.mean,
                    sd: r.sd,
                    q05: r.q05,
                    q50: r.q50,
                    q95: r.q95,
                })
            })
            .collect();
        let mut differences = Vec::new();
        for (i, a) in entries.iter().enumerate() {
            for b in &entries[i + 1..] {
                for name in a.sample.layout.theta_names() {
                    if let (Some(da), Some(db)) = (a.sample.values(name, &a.positions), b.sample.values(name, &b.positions)) {
                        differences.push(DifferenceRow { a: a.label.clone(), b: b.label.clone(), parameter: name.clone(), difference: difference(&da, &db) });
                    }
                }
            }
        }
        Comparison { rows, differences }
    }
}

/// The posterior of a − b and a / b for one parameter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Difference {
    pub diff_q05: f64,
    pub diff_q50: f64,
    pub diff_q95: f64,
    pub ratio_q05: f64,
    pub ratio_q50: f64,
    pub ratio_q95: f64,
    /// P(a > b), over every pair of draws.
    pub p_greater: f64,
}

/// Pairings of draws used for the quantiles of a − b and a / b: each draw
/// of `a` meets this many draws of `b`.
const PAIRINGS: usize = 16;

/// The difference of two independent posteriors from their draws.
pub fn difference(a: &[f64], b: &[f64]) -> Difference {
    let mut sorted_b = b.to_vec();
    sorted_b.sort_by(f64::total_cmp);
    // exact over all |a|·|b| pairs: for each a, the b's below it (ties count half)
    let mut greater = 0.0;
    for &x in a {
        let below = sorted_b.partition_point(|&y| y < x);
        let not_above = sorted_b.partition_point(|&y| y <= x);
        greater += below as f64 + 0.5 * (not_above - below) as f64;
    }
    let p_greater = greater / (a.len() as f64 * b.len() as f64);
    // quantiles from shifted pairings (i, i·k + s): many pairs, no RNG
    let (na, nb) = (a.len(), b.len());
    let mut diffs = Vec::with_capacity(na * PAIRINGS);
    let mut ratios = Vec::with_capacity(na * PAIRINGS);
    for s in 0..PAIRINGS {
        let shift = s * nb.div_ceil(PAIRINGS) + s;
        for (i, &x) in a.iter().enumerate() {
            let y = b[(i * 7919 + shift) % nb];
            diffs.push(x - y);
            ratios.push(x / y);
        }
    }
    diffs.sort_by(f64::total_cmp);
    ratios.sort_by(f64::total_cmp);
    Difference {
        diff_q05: quantile_sorted(&diffs, 0.05),
        diff_q50: quantile_sorted(&diffs, 0.5),
        diff_q95: quantile_sorted(&diffs, 0.95),
        ratio_q05: quantile_sorted(&ratios, 0.05),
        ratio_q50: quantile_sorted(&ratios, 0.5),
        ratio_q95: quantile_sorted(&ratios, 0.95),
        p_greater,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;
    use rand_distr::StandardNormal;
    use statrs::distribution::{ContinuousCDF, Normal};

    fn normal_draws(mean: f64, sd: f64, n: usize, seed: u64) -> Vec<f64> {
        let mut rng = crate::rng::stream(seed, &[]);
        (0..n).map(|_| mean + sd * rng.sample::<f64, _>(StandardNormal)).collect()
    }

    /// a ~ N(1.0, 0.3²), b ~ N(0.8, 0.4²): a − b ~ N(0.2, 0.5²), so
    /// P(a > b) = Φ(0.4) = 0.6554 and the 5 % and 95 % quantiles of a − b
    /// are 0.2 ∓ 1.645·0.5. With 4000 draws each, P's standard error is
    /// about 0.006 and the quantiles' about 0.02: tolerances 0.02 and 0.06.
    #[test]
    fn difference_of_two_normals_has_the_known_answer() {
        let a = normal_draws(1.0, 0.3, 4000, 1);
        let b = normal_draws(0.8, 0.4, 4000, 2);
        let d = difference(&a, &b);
        let phi = Normal::new(0.0, 1.0).unwrap();
        assert!((d.p_greater - phi.cdf(0.4)).abs() < 0.02, "{}", d.p_greater);
        assert!((d.diff_q50 - 0.2).abs() < 0.04, "{}", d.diff_q50);
        assert!((d.diff_q05 - (0.2 - 1.645 * 0.5)).abs() < 0.06, "{}", d.diff_q05);
        assert!((d.diff_q95 - (0.2 + 1.645 * 0.5)).abs() < 0.06, "{}", d.diff_q95);
    }

    /// Clearly separated posteriors give P(a > b) of 1 (or 0 the other way),
    /// and the ratio of two narrow posteriors is the ratio of their centres.
    #[test]
    fn separated_posteriors_are_certain() {
        let a = normal_draws(2.0e5, 1.0e3, 2000, 3);
        let b = normal_draws(1.0e5, 1.0e3, 2000, 4);
        assert_eq!(difference(&a, &b).p_greater, 1.0);
        assert_eq!(difference(&b, &a).p_greater, 0.0);
        assert!((difference(&a, &b).ratio_q50 - 2.0).abs() < 0.01);
        // identical draws: a tie everywhere counts half
        assert_eq!(difference(&a, &a).p_greater, 0.5);
    }
}
