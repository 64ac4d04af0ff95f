//! The log evidence ln Z = ln ∫ p(x) dx of a target from its populations,
//! with its Monte Carlo error measured two ways.
//!
//! Each population's estimate is the product over temperatures of the
//! mean incremental weight, Ẑ = Π_t (1/N) Σᵢ w_tᵢ (unbiased for Z). Its
//! variance, by the delta method with the particles of a temperature taken
//! as independent, is Σ_t (1/ESS_t − 1/N) in ln Ẑ (the weights' squared
//! coefficient of variation over N); the mutations leave some dependence
//! between particles, which this does not see. The spread of the
//! populations' estimates, which are independent runs, sees it: both are
//! reported, and the larger is the one to quote.

use serde::{Deserialize, Serialize};

use crate::numeric::log_mean_exp;

/// The log evidence of a run and its Monte Carlo errors.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// ln of the mean of the populations' Ẑ.
    pub log_z: f64,
    /// Its standard error from the incremental weights (delta method).
    pub se_weights: f64,
    /// Its standard error from the spread of the populations' ln Ẑ (their
    /// standard deviation over √P); NaN for one population.
    pub se_spread: f64,
    /// Each population's ln Ẑ.
    pub per_population: Vec<f64>,
}

impl Evidence {
    /// From each population's ln Ẑ and its delta-method variance.
    pub fn combine(log_z: &[f64], variances: &[f64]) -> Evidence {
        let p = log_z.len() as f64;
        // the mean of the Ẑ: Var(ln mean) ≈ Σ Var(ln Ẑ_p) / P² where the
        // Ẑ_p are near one another
        let se_weights = variances.iter().sum::<f64>().sqrt() / p;
        let se_spread = if log_z.len() > 1 {
            crate::numeric::variance(log_z).sqrt() / p.sqrt()
        } else {
            f64::NAN
        };
        Evidence {
            log_z: log_mean_exp(log_z),
            se_weights,
            se_spread,
            per_population: log_z.to_vec(),
        }
    }

    /// The standard error to quote: the larger of the two.
    pub fn se(&self) -> f64 {
        if self.se_spread.is_nan() {
            self.se_weights
        } else {
            self.se_weights.max(self.se_spread)
        }
    }
}
