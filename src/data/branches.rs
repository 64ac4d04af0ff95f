//! Splitting a record into loading branches at displacement reversals.

use std::ops::Range;

/// The hysteresis of a reversal used throughout: a tenth of the range.
pub const REVERSAL_SHARE: f64 = 0.1;

/// Sample ranges between reversals of the displacement `x`.
///
/// A reversal is a running extremum from which `x` has since moved back by
/// more than `fraction` of its total range; that hysteresis keeps sensor noise
/// near a dead centre from splitting a branch. Consecutive branches share the
/// reversal sample. The first branch starts at the first sample; the last
/// ends at the last sample. A record without a reversal is one branch.
pub fn loading_branches(x: &[f64], fraction: f64) -> Vec<Range<usize>> {
    let n = x.len();
    if n < 2 {
        return vec![0..n];
    }
    let (lo, hi) =
        x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let threshold = fraction * (hi - lo);
    if !(threshold > 0.0) {
        return vec![0..n];
    }
    let mut branches = Vec::new();
    let mut start = 0;
    // direction of travel: +1 up, −1 down, 0 not yet known
    let mut direction = 0i8;
    let (mut max_k, mut min_k) = (0usize, 0usize);
    for k in 1..n {
        if x[k] > x[max_k] {
            max_k = k;
        }
        if x[k] < x[min_k] {
            min_k = k;
        }
        match direction {
            0 if x[max_k] - x[start] > threshold => direction = 1,
            0 if x[start] - x[min_k] > threshold => direction = -1,
            1 if x[max_k] - x[k] > threshold => {
                branches.push(start..max_k + 1);
                start = max_k;
                min_k = k;
                direction = -1;
            }
            -1 if x[k] - x[min_k] > threshold => {
                branches.push(start..min_k + 1);
                start = min_k;
                max_k = k;
                direction = 1;
            }
            _ => {}
        }
    }
    if n - start > 1 {
        branches.push(start..n);
    }
    branches
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_cycles_split_at_dead_centres() {
        // two full cycles of 1 − cos: reversals at k = 50, 100, 150
        let x: Vec<f64> =
            (0..=200).map(|k| 1.0 - (std::f64::consts::TAU * k as f64 / 100.0).cos()).collect();
        let b = loading_branches(&x, 0.1);
        assert_eq!(b, vec![0..51, 50..101, 100..151, 150..201]);
    }

    #[test]
    fn noise_below_threshold_does_not_split() {
        let x: Vec<f64> =
            (0..100).map(|k| k as f64 + if k % 2 == 0 { 0.5 } else { -0.5 }).collect();
        assert_eq!(loading_branches(&x, 0.05), vec![0..100]);
        assert_eq!(loading_branches(&[1.0; 10], 0.1), vec![0..10]);
    }
}
