//! Ensemble proposals. Each takes the walker's position and the positions of
//! the complementary half of its ensemble, and returns the proposal and the
//! log of the Metropolis-Hastings correction factor.

use rand::RngExt;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

/// A proposal move of the ensemble sampler.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Move {
    /// Goodman & Weare's stretch move: y = x_j + z (x − x_j), z ∝ 1/√z on
    /// [1/a, a]; factor z^(d−1).
    Stretch { a: f64 },
    /// Differential evolution (ter Braak 2006): y = x + γ (x_j − x_k), with
    /// γ = γ₀ (1 + σ ε), ε ~ N(0, 1), γ₀ = 2.38/√(2d) unless given.
    DifferentialEvolution { gamma0: Option<f64>, sigma: f64 },
    /// DE snooker (ter Braak & Vrugt 2008): a jump along the line through x
    /// and a third walker z; factor (|y − z| / |x − z|)^(d−1).
    Snooker { gamma: f64 },
}

impl Default for Move {
    fn default() -> Self {
        Move::Stretch { a: 2.0 }
    }
}

impl Move {
    pub fn differential_evolution() -> Self {
        Move::DifferentialEvolution {
            gamma0: None,
            sigma: 1.0e-5,
        }
    }

    pub fn snooker() -> Self {
        Move::Snooker { gamma: 1.7 }
    }

    /// Smallest complementary half the move can work with.
    pub fn min_complement(&self) -> usize {
        match self {
            Move::Stretch { .. } => 1,
            Move::DifferentialEvolution { .. } => 2,
            Move::Snooker { .. } => 3,
        }
    }

    pub fn check(&self) -> Result<(), String> {
        match *self {
            Move::Stretch { a } if !(a > 1.0) => Err(format!("stretch scale a = {a} must exceed 1")),
            Move::DifferentialEvolution { gamma0: Some(g), .. } if !(g > 0.0) => {
                Err(format!("DE gamma0 = {g} must be positive"))
            }
            Move::DifferentialEvolution { sigma, .. } if !(sigma >= 0.0) => {
                Err(format!("DE sigma = {sigma} must be non-negative"))
            }
            Move::Snooker { gamma } if !(gamma > 0.0) => Err(format!("snooker gamma = {gamma} must be positive")),
            _ => Ok(()),
        }
    }

    /// Writes the proposal for walker position `x` into `y`, with the other
    /// half of the ensemble `others` (`n_others` points of `x.len()`
    /// coordinates), and returns ln of the proposal's correction factor.
    pub fn propose(
        &self,
        x: &[f64],
        others: &[f64],
        rng: &mut impl rand::Rng,
        y: &mut [f64],
    ) -> f64 {
        let d = x.len();
        let n = others.len() / d;
        let other = |j: usize| &others[j * d..(j + 1) * d];
        match *self {
            Move::Stretch { a } => {
                let u: f64 = rng.random();
                let z = ((a - 1.0) * u + 1.0).powi(2) / a;
                let xj = other(rng.random_range(0..n));
                for i in 0..d {
                    y[i] = xj[i] + z * (x[i] - xj[i]);
                }
                (d as f64 - 1.0) * z.ln()
            }
            Move::DifferentialEvolution { gamma0, sigma } => {
                let (j, k) = distinct_pair(rng, n);
                let g0 = gamma0.unwrap_or(2.38 / (2.0 * d as f64).sqrt());
                let eps: f64 = rng.sample(StandardNormal);
                let g = g0 * (1.0 + sigma * eps);
                let (xj, xk) = (other(j), other(k));
                for i in 0..d {
                    y[i] = x[i] + g * (xj[i] - xk[i]);
                }
                0.0
            }
            Move::Snooker { gamma } => {
                let (j, k, l) = distinct_triple(rng, n);
                let (z, z1, z2) = (other(j), other(k), other(l));
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
        }
    }
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).powi(2)).sum::<f64>().sqrt()
}

fn distinct_pair(rng: &mut impl rand::Rng, n: usize) -> (usize, usize) {
    let j = rng.random_range(0..n);
    let mut k = rng.random_range(0..n - 1);
    if k >= j {
        k += 1;
    }
    (j, k)
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
    fn stretch_factor_stays_in_range() {
        let mut rng = crate::rng::stream(1, &[]);
        let x = [1.0, 2.0];
        let others = [0.0, 0.0, 3.0, 3.0];
        let mut y = [0.0; 2];
        for _ in 0..1000 {
            let f = Move::Stretch { a: 2.0 }.propose(&x, &others, &mut rng, &mut y);
            let z = f.exp(); // d − 1 = 1
            assert!((0.5..=2.0).contains(&z));
        }
    }

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
