//! Comparing calibrations (of current levels, dampers, settings …): their
//! summaries side by side, the posterior of the difference and of the ratio
//! of a parameter between two independent calibrations, and the probability
//! that one exceeds the other.
//!
//! Two calibrations of different records have independent posteriors, so
//! (a, b) pairs drawn one from each are draws of the joint posterior.

use crate::model::PARAM_NAMES;
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
    /// The currents a law calibration saw (A); empty for one current.
    pub law_currents: Vec<f64>,
    /// The between-run layer's centre at this calibration's current
    /// (`--per-run`): per B-P parameter its values over the layer's draws,
    /// and the fit they came from.
    pub layer: Option<LayerCentre>,
}

/// The centre of the between-run layer at one current: the typical test
/// there, draw by draw.
pub struct LayerCentre {
    /// The layer's draw indices.
    pub draw: Vec<f64>,
    /// The law's parameters' names, and per parameter its values at the
    /// draws (SI; NaN where none).
    pub names: Vec<String>,
    pub centre: Vec<Vec<f64>>,
    /// Which fit: equal for the currents of one fit, whose draws pair.
    pub fit: String,
}

/// The suffix of a calibration's label in the rows that compare the
/// between-run layer's centres.
pub const TYPICAL_TEST: &str = " (typical test)";

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
    /// Every calibration's summary, and for every pair of one damper law
    /// the difference of every parameter both have (noise scales are per
    /// run and left out).
    /// A law also says how its B-P parameters differ between currents: each
    /// pair of the currents it saw or a per-current entry stands for,
    /// labelled "`label` at I A", from the same draws (paired).
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
            // parameters of one name in two laws are not one quantity
            for b in
                entries[i + 1..].iter().filter(|b| b.sample.model.law() == a.sample.model.law())
            {
                for name in a.sample.layout.theta_names() {
                    if let (Some(da), Some(db)) =
                        (a.sample.values(name, &a.positions), b.sample.values(name, &b.positions))
                    {
                        differences.push(DifferenceRow {
                            a: a.label.clone(),
                            b: b.label.clone(),
                            parameter: name.clone(),
                            difference: difference(&da, &db),
                        });
                    }
                }
            }
        }
        let mut currents: Vec<f64> = entries
            .iter()
            .flat_map(|e| e.law_currents.iter().copied().chain([e.current_a]))
            .collect();
        currents.sort_by(f64::total_cmp);
        currents.dedup();
        for law in entries.iter().filter(|e| !e.law_currents.is_empty()) {
            differences.extend(law_differences(&law.label, law.sample, &law.positions, &currents));
        }
        differences.extend(layer_differences(entries));
        Comparison { rows, differences }
    }
}

/// How the between-run layer's centres (the typical test at each current)
/// differ between each pair of entries whose layers come from one fit:
/// draw by draw (one posterior of the layer), labelled "`label` (typical
/// test)". Draws where either centre has no θ are left out.
pub fn layer_differences(entries: &[Entry]) -> Vec<DifferenceRow> {
    let mut rows = Vec::new();
    for (i, a) in entries.iter().enumerate() {
        let Some(la) = &a.layer else { continue };
        for b in &entries[i + 1..] {
            if let Some(lb) = &b.layer {
                rows.extend(centre_differences(&a.label, la, &b.label, lb).unwrap_or_default());
            }
        }
    }
    rows
}

/// [`layer_differences`] of one pair; `None` unless both come from one
/// fit (their draws pair).
pub fn centre_differences(
    label_a: &str,
    a: &LayerCentre,
    label_b: &str,
    b: &LayerCentre,
) -> Option<Vec<DifferenceRow>> {
    if a.fit != b.fit || a.draw != b.draw || a.names != b.names {
        return None;
    }
    let mut rows = Vec::new();
    for (k, parameter) in a.names.iter().enumerate() {
        let (x, y): (Vec<f64>, Vec<f64>) = a.centre[k]
            .iter()
            .zip(&b.centre[k])
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .map(|(x, y)| (*x, *y))
            .unzip();
        if x.len() >= 2 {
            rows.push(DifferenceRow {
                a: format!("{label_a}{TYPICAL_TEST}"),
                b: format!("{label_b}{TYPICAL_TEST}"),
                parameter: parameter.to_string(),
                difference: paired_difference(&x, &y),
            });
        }
    }
    Some(rows)
}

/// How a law's B-P parameters differ between each pair of `currents_a`:
/// a at the higher current, b at the lower, from the same draws.
pub fn law_differences(
    label: &str,
    sample: &PosteriorSample,
    positions: &[(usize, usize)],
    currents_a: &[f64],
) -> Vec<DifferenceRow> {
    let at: Vec<Vec<[f64; 7]>> = currents_a
        .iter()
        .map(|&i| positions.iter().map(|&(s, c)| sample.params_at(s, c, i).to_array()).collect())
        .collect();
    let name = |i: f64| format!("{label} at {i:?} A");
    let mut rows = Vec::new();
    for (lo, low) in currents_a.iter().zip(&at) {
        for (hi, high) in currents_a.iter().zip(&at).filter(|(hi, _)| *hi > lo) {
            for (k, parameter) in PARAM_NAMES.iter().enumerate() {
                let (a, b): (Vec<f64>, Vec<f64>) =
                    high.iter().zip(low).map(|(h, l)| (h[k], l[k])).unzip();
                rows.push(DifferenceRow {
                    a: name(*hi),
                    b: name(*lo),
                    parameter: parameter.to_string(),
                    difference: paired_difference(&a, &b),
                });
            }
        }
    }
    rows
}

/// Where a current of [`against_current`] lies for the law.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CurrentKind {
    /// One of the currents the law was calibrated on.
    Calibrated,
    /// Between its lowest and highest calibrated current.
    Between,
    /// Below its lowest or above its highest: an extrapolation.
    Outside,
}

impl CurrentKind {
    pub fn name(self) -> &'static str {
        match self {
            CurrentKind::Calibrated => "calibrated",
            CurrentKind::Between => "between",
            CurrentKind::Outside => "outside",
        }
    }

    pub fn parse(name: &str) -> Option<CurrentKind> {
        [CurrentKind::Calibrated, CurrentKind::Between, CurrentKind::Outside]
            .into_iter()
            .find(|k| k.name() == name)
    }
}

/// One row of `against_current.parquet`: a B-P parameter of a law at one
/// coil current, over the posterior.
#[derive(Clone, Debug, PartialEq)]
pub struct CurrentRow {
    pub parameter: String,
    pub current_a: f64,
    pub kind: CurrentKind,
    pub mean: f64,
    pub sd: f64,
    pub q05: f64,
    pub q50: f64,
    pub q95: f64,
}

/// About this many steps between 0 A and the top of [`current_grid`].
const GRID_STEPS: f64 = 48.0;
/// The grid's top as a multiple of the highest calibrated current.
const GRID_TOP: f64 = 1.2;

/// The currents a law is shown at: 0 A (the off-state) and on up to 1.2×
/// the highest calibrated current in round steps (1, 2, 2.5 or 5 × 10ᵏ A,
/// about 48 of them), and the calibrated currents themselves.
pub fn current_grid(calibrated_a: &[f64]) -> Vec<f64> {
    let top = GRID_TOP * calibrated_a.iter().copied().fold(0.0, f64::max);
    if top <= 0.0 || !top.is_finite() {
        return calibrated_a.to_vec();
    }
    let raw = top / GRID_STEPS;
    let decade = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * decade)
        .find(|s| *s >= raw * (1.0 - 1e-9))
        .unwrap_or(10.0 * decade);
    let count = (top / step - 1e-9).ceil() as usize;
    let near = |v: f64| calibrated_a.iter().any(|c| (v - c).abs() <= 1e-9 * top);
    // k·step rounded to the step's decimals, so that 0.1·3 reads 0.3
    let round = |v: f64| (v / decade * 1e3).round() * decade / 1e3;
    let mut grid: Vec<f64> = (0..=count)
        .map(|k| round(k as f64 * step))
        .filter(|v| !near(*v))
        .chain(calibrated_a.iter().copied())
        .collect();
    grid.sort_by(f64::total_cmp);
    grid.dedup();
    grid
}

/// Each B-P parameter of a law against the coil current: its posterior
/// (over the draws at `positions`) on [`current_grid`] of the currents
/// `calibrated_a` it saw.
pub fn against_current(
    sample: &PosteriorSample,
    positions: &[(usize, usize)],
    calibrated_a: &[f64],
) -> Vec<CurrentRow> {
    let (lo, hi) = calibrated_a
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &c| (a.min(c), b.max(c)));
    let mut rows = Vec::new();
    for current_a in current_grid(calibrated_a) {
        let kind = if calibrated_a.contains(&current_a) {
            CurrentKind::Calibrated
        } else if (lo..=hi).contains(&current_a) {
            CurrentKind::Between
        } else {
            CurrentKind::Outside
        };
        let draws: Vec<[f64; 7]> =
            positions.iter().map(|&(s, c)| sample.params_at(s, c, current_a).to_array()).collect();
        for (k, parameter) in PARAM_NAMES.iter().enumerate() {
            let mut v: Vec<f64> = draws.iter().map(|p| p[k]).collect();
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let sd =
                (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
            v.sort_by(f64::total_cmp);
            rows.push(CurrentRow {
                parameter: parameter.to_string(),
                current_a,
                kind,
                mean,
                sd,
                q05: quantile_sorted(&v, 0.05),
                q50: quantile_sorted(&v, 0.5),
                q95: quantile_sorted(&v, 0.95),
            });
        }
    }
    rows
}

/// The posterior of a − b and a / b where `a[i]` and `b[i]` come from the
/// same draw (two functions of one posterior, not two posteriors).
pub fn paired_difference(a: &[f64], b: &[f64]) -> Difference {
    let diffs: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let ratios: Vec<f64> = a.iter().zip(b).map(|(x, y)| x / y).collect();
    let greater: f64 = diffs
        .iter()
        .map(|d| {
            if *d > 0.0 {
                1.0
            } else if *d == 0.0 {
                0.5
            } else {
                0.0
            }
        })
        .sum();
    let p_greater = greater / diffs.len().max(1) as f64;
    Difference::of(diffs, ratios, p_greater)
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

impl Difference {
    /// The quantiles of the draws of a − b (`diffs`) and a / b (`ratios`),
    /// beside P(a > b).
    fn of(mut diffs: Vec<f64>, mut ratios: Vec<f64>, p_greater: f64) -> Difference {
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
    Difference::of(diffs, ratios, p_greater)
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

    /// The layer's centres at two currents pair by draw: b = a − 0.1 in
    /// every draw is P(a > b) = 1 although their marginals (sd 1) overlap
    /// almost wholly (as independent posteriors, P would be about 0.53);
    /// centres of two fits do not pair at all; a draw without θ (NaN) is
    /// left out.
    #[test]
    fn layer_centres_compare_draw_by_draw_within_one_fit() {
        let x = normal_draws(0.0, 1.0, 1000, 3);
        let centre = |shift: f64, fit: &str| LayerCentre {
            draw: (0..1000).map(|i| i as f64).collect(),
            names: PARAM_NAMES.iter().map(|n| n.to_string()).collect(),
            centre: (0..7)
                .map(|_| {
                    x.iter()
                        .enumerate()
                        .map(|(i, v)| if i == 7 { f64::NAN } else { 10.0 + v + shift })
                        .collect()
                })
                .collect(),
            fit: fit.to_string(),
        };
        let (a, b) = (centre(0.0, "f"), centre(-0.1, "f"));
        let rows = centre_differences("a", &a, "b", &b).expect("one fit");
        assert_eq!(rows.len(), 7);
        assert_eq!(rows[0].a, "a (typical test)");
        assert!(
            rows.iter().all(
                |r| r.difference.p_greater == 1.0 && (r.difference.diff_q50 - 0.1).abs() < 1e-9
            ),
            "{:?}",
            rows[0]
        );
        assert!(
            difference(&a.centre[0][..7], &b.centre[0][..7]).p_greater < 0.9,
            "the premise: the marginals overlap"
        );
        assert!(
            centre_differences("a", &a, "b", &centre(-0.1, "g")).is_none(),
            "two fits do not pair"
        );
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

    /// Two strongly correlated functions of one posterior: a = x + 0.05 z,
    /// b = x with x ~ N(1, 1) and z ~ N(0, 1), so a − b ~ N(0, 0.05²)
    /// exactly; pairing by draw gives P(a > b) = 0.5 and 5 %/95 % quantiles
    /// of ∓1.645·0.05 (MC errors with 4000 draws: 0.008 and 0.002;
    /// tolerances 0.03 and 0.01). Taken as independent posteriors the same
    /// draws would give a − b a spread 28× wider: the pairing matters.
    #[test]
    fn paired_difference_keeps_the_draws_together() {
        let x = normal_draws(1.0, 1.0, 4000, 5);
        let z = normal_draws(0.0, 1.0, 4000, 6);
        let a: Vec<f64> = x.iter().zip(&z).map(|(x, z)| x + 0.05 * z).collect();
        let d = paired_difference(&a, &x);
        assert!((d.p_greater - 0.5).abs() < 0.03, "{}", d.p_greater);
        assert!((d.diff_q05 + 1.645 * 0.05).abs() < 0.01, "{}", d.diff_q05);
        assert!((d.diff_q95 - 1.645 * 0.05).abs() < 0.01, "{}", d.diff_q95);
        assert!(difference(&a, &x).diff_q95 > 1.5, "independent pairing is much wider");
    }

    /// The grid starts at the off-state, reaches 1.2× the top current in
    /// round steps and holds every calibrated current exactly once.
    #[test]
    fn the_current_grid_holds_the_calibrated_currents() {
        let g = current_grid(&[0.25, 1.0, 0.5]);
        // 1.2 A / 48 = 0.025 A: a round step already
        assert_eq!(g.len(), 49);
        assert_eq!((g[0], g[1], g[30], g[48]), (0.0, 0.025, 0.75, 1.2));
        for c in [0.25, 0.5, 1.0] {
            assert_eq!(g.iter().filter(|v| (**v - c).abs() < 1e-9).count(), 1, "{c}");
        }
        assert!(g.windows(2).all(|w| w[0] < w[1]));
        // 1.8 A / 48 = 0.0375 A: steps of 0.05 A, 1.0 A on the grid, 0.33 A added
        let g = current_grid(&[0.33, 1.5]);
        assert_eq!((g[0], g[1], g[g.len() - 1]), (0.0, 0.05, 1.8));
        assert!(g.contains(&1.0) && g.contains(&0.33) && g.contains(&0.3));
    }
}
