//! The bridge from a reference density to the target: π_β ∝ r^(1−β) p^β,
//! and the next temperature a population can reach.

use super::super::density::LogDensity;
use super::super::elliptical::Elliptical;
use crate::numeric::log_sum_exp;

/// A normalised density the tempering starts from, which can be drawn
/// from: a Student-t with `df` degrees of freedom (Gaussian without) whose
/// scale matrix is `dist`'s. With the prior as reference, π_β is the
/// prior times the likelihood to the power β (likelihood tempering); with
/// a Laplace approximation, fewer temperatures are needed where it is
/// close.
#[derive(Clone, Debug)]
pub struct Reference {
    pub dist: Elliptical,
    pub df: Option<f64>,
}

impl Reference {
    /// ln r(x), normalised.
    pub fn log_density(&self, x: &[f64]) -> f64 {
        self.dist.log_density(self.df, x, 1.0)
    }

    /// A draw into `y`.
    pub fn draw(&self, rng: &mut impl rand::Rng, y: &mut [f64]) {
        self.dist.draw(self.df, 1.0, rng, y);
    }
}

/// The tempered density r^(1−β) p^β of `target` p and `reference` r, as
/// the ensemble moves see it. Its support is the target's.
pub struct Tempered<'a, T: LogDensity> {
    pub target: &'a T,
    pub reference: &'a Reference,
    pub beta: f64,
}

impl<T: LogDensity> Tempered<'_, T> {
    /// ln π_β from ln p and ln r.
    pub fn combine(&self, log_p: f64, log_r: f64) -> f64 {
        if log_p == f64::NEG_INFINITY || log_p.is_nan() {
            return f64::NEG_INFINITY;
        }
        if self.beta == 1.0 {
            return log_p;
        }
        self.beta * log_p + (1.0 - self.beta) * log_r
    }

    /// ln p from ln π_β and ln r (β > 0): what [`Tempered::combine`] took.
    pub fn target_part(&self, log_tempered: f64, log_r: f64) -> f64 {
        if self.beta == 1.0 || log_tempered == f64::NEG_INFINITY {
            return log_tempered;
        }
        (log_tempered - (1.0 - self.beta) * log_r) / self.beta
    }
}

impl<T: LogDensity> LogDensity for Tempered<'_, T> {
    fn dim(&self) -> usize {
        self.target.dim()
    }

    fn log_density(&self, x: &[f64]) -> f64 {
        self.combine(self.target.log_density(x), self.reference.log_density(x))
    }

    fn log_density_batch(&self, xs: &[f64], out: &mut [f64]) {
        self.target.log_density_batch(xs, out);
        for (x, o) in xs.chunks_exact(self.dim()).zip(out.iter_mut()) {
            *o = self.combine(*o, self.reference.log_density(x));
        }
    }
}

/// The effective sample size of importance weights given by their logs:
/// (Σ w)² / Σ w²; 0 where every weight is 0.
pub fn ess(log_w: &[f64]) -> f64 {
    let doubled: Vec<f64> = log_w.iter().map(|v| 2.0 * v).collect();
    let ess = (2.0 * log_sum_exp(log_w) - log_sum_exp(&doubled)).exp();
    if ess.is_finite() {
        ess
    } else {
        0.0
    }
}

/// The incremental log-weights (β' − β) δᵢ of the particles at β, where
/// δᵢ = ln p − ln r at particle i (−∞ outside the target's support).
pub fn log_weights(beta: f64, next: f64, delta: &[f64]) -> Vec<f64> {
    delta
        .iter()
        .map(|d| if *d == f64::NEG_INFINITY { f64::NEG_INFINITY } else { (next - beta) * d })
        .collect()
}

/// The next temperature after `beta`: the largest β' ≤ 1 at which the
/// incremental weights keep an effective sample size of at least
/// `target_ess` (by bisection: the ESS falls as β' rises). Where even the
/// smallest step keeps fewer (particles outside the target's support), the
/// smallest step that bisection resolves: the run always advances.
pub fn next_beta(beta: f64, delta: &[f64], target_ess: f64) -> f64 {
    let ess_at = |next: f64| ess(&log_weights(beta, next, delta));
    if ess_at(1.0) >= target_ess {
        return 1.0;
    }
    let (mut lo, mut hi) = (beta, 1.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if ess_at(mid) >= target_ess {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    if lo > beta {
        lo
    } else {
        hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Equal weights keep every particle; one weight of two, one.
    #[test]
    fn ess_counts_equal_and_lone_weights() {
        assert!((ess(&[0.3; 10]) - 10.0).abs() < 1e-12);
        assert!((ess(&[0.0, f64::NEG_INFINITY]) - 1.0).abs() < 1e-12);
        assert_eq!(ess(&[f64::NEG_INFINITY; 3]), 0.0);
    }

    /// The β' returned gives the weights e^{β' δ} the asked ESS, by the
    /// closed form (Σ w)² / Σ w² computed here; no step is possible once
    /// particles have left the support: the smallest one is taken.
    #[test]
    fn the_next_temperature_keeps_the_asked_ess() {
        let delta = [0.0, 1.0, 3.0, -2.0];
        let next = next_beta(0.0, &delta, 3.0);
        let w: Vec<f64> = delta.iter().map(|d| (next * d).exp()).collect();
        let closed = w.iter().sum::<f64>().powi(2) / w.iter().map(|v| v * v).sum::<f64>();
        assert!((closed - 3.0).abs() < 1e-9, "ESS {closed} at β' = {next}");
        assert!(next > 0.0 && next < 1.0);
        // small differences: straight to β = 1
        assert_eq!(next_beta(0.2, &[0.0, 1e-3, -1e-3], 2.5), 1.0);
        // one particle outside the support of two: the smallest step
        let lone = next_beta(0.0, &[0.0, f64::NEG_INFINITY], 1.5);
        assert!(lone > 0.0 && lone < 1e-12);
    }
}
