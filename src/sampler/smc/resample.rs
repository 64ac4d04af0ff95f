//! Systematic resampling: one uniform draw places N evenly spaced points
//! on the weights' cumulative sum; particle i is picked about N wᵢ times
//! (never fewer than ⌊N wᵢ⌋ nor more than ⌈N wᵢ⌉).

use rand::RngExt;

use crate::numeric::log_sum_exp;

/// The indices of `n` particles drawn from weights given by their logs
/// (not all −∞), in increasing order.
pub fn systematic(log_w: &[f64], n: usize, rng: &mut impl rand::Rng) -> Vec<usize> {
    let total = log_sum_exp(log_w);
    let u: f64 = rng.random();
    let mut picks = Vec::with_capacity(n);
    // rounding may leave the sum short of 1: the last point then takes
    // the last particle that has weight
    let last = log_w.iter().rposition(|v| *v > f64::NEG_INFINITY).unwrap_or(0);
    let (mut cumulative, mut i) = (0.0, 0);
    for k in 0..n {
        let point = (k as f64 + u) / n as f64;
        while i < last {
            let next = cumulative + (log_w[i] - total).exp();
            if point < next {
                break;
            }
            cumulative = next;
            i += 1;
        }
        picks.push(i);
    }
    picks
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Weights (0.5, 0.25, 0.125, 0.125) and 8 picks: exactly 4, 2, 1, 1
    /// whatever the uniform draw (N wᵢ are integers); a −∞ weight is never
    /// picked.
    #[test]
    fn integer_expected_counts_are_met_exactly() {
        let log_w: Vec<f64> = [0.5f64, 0.25, 0.125, 0.125, 0.0].iter().map(|w| w.ln()).collect();
        for seed in 0..20 {
            let picks = systematic(&log_w, 8, &mut crate::rng::stream(seed, &[]));
            let counts: Vec<usize> =
                (0..5).map(|i| picks.iter().filter(|p| **p == i).count()).collect();
            assert_eq!(counts, vec![4, 2, 1, 1, 0], "seed {seed}");
        }
    }
}
