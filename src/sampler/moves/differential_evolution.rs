//! Differential evolution (ter Braak 2006).

use rand::RngExt;
use rand_distr::StandardNormal;

use super::{distinct_pair, point};

/// y = x + γ (x_j − x_k), γ = γ₀ (1 + σ ε), γ₀ = 2.38/√(2d) unless given;
/// symmetric, factor 1.
pub fn propose(
    gamma0: Option<f64>,
    sigma: f64,
    x: &[f64],
    others: &[f64],
    rng: &mut impl rand::Rng,
    y: &mut [f64],
) -> f64 {
    let d = x.len();
    let (j, k) = distinct_pair(rng, others.len() / d);
    let g0 = gamma0.unwrap_or(2.38 / (2.0 * d as f64).sqrt());
    let eps: f64 = rng.sample(StandardNormal);
    let g = g0 * (1.0 + sigma * eps);
    let (xj, xk) = (point(others, d, j), point(others, d, k));
    for i in 0..d {
        y[i] = x[i] + g * (xj[i] - xk[i]);
    }
    0.0
}
