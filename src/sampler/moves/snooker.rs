//! The DE snooker update (ter Braak & Vrugt 2008).

use rand::RngExt;

use super::{distinct_pair, point};

/// A jump along the line through x and a third walker z, by γ times the
/// projection of x_k − x_l on it; factor (|y − z| / |x − z|)^(d−1).
pub fn propose(
    gamma: f64,
    x: &[f64],
    others: &[f64],
    rng: &mut impl rand::Rng,
    y: &mut [f64],
) -> f64 {
    let d = x.len();
    let (j, k, l) = distinct_triple(rng, others.len() / d);
    let (z, z1, z2) = (point(others, d, j), point(others, d, k), point(others, d, l));
    let norm = dist(x, z);
    if norm == 0.0 {
        y.copy_from_slice(x);
        return 0.0;
    }
    // projection of z1 − z2 on the unit vector from z to x
    let proj: f64 = (0..d).map(|i| (x[i] - z[i]) / norm * (z1[i] - z2[i])).sum();
    for i in 0..d {
        y[i] = x[i] + gamma * proj * (x[i] - z[i]) / norm;
    }
    (d as f64 - 1.0) * (dist(y, z).ln() - norm.ln())
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).powi(2)).sum::<f64>().sqrt()
}

fn distinct_triple(rng: &mut impl rand::Rng, n: usize) -> (usize, usize, usize) {
    let (j, k) = distinct_pair(rng, n);
    let mut l = rng.random_range(0..n - 2);
    // skip j and k in increasing order so l is uniform over the rest
    let (lo, hi) = (j.min(k), j.max(k));
    if l >= lo {
        l += 1;
    }
    if l >= hi {
        l += 1;
    }
    (j, k, l)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distinct_picks_are_distinct_and_cover_all() {
        let mut rng = crate::rng::stream(2, &[]);
        let mut seen = [0usize; 4];
        for _ in 0..4000 {
            let (j, k, l) = distinct_triple(&mut rng, 4);
            assert!(j != k && k != l && j != l);
            seen[l] += 1;
        }
        assert!(seen.iter().all(|&c| c > 700), "{seen:?}");
    }
}
