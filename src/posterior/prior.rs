//! Priors of a law's parameters, on the log scale.

use serde::{Deserialize, Serialize};

use crate::model::{PHYSICAL_RANGE, PLAUSIBLE_RANGE};

/// A prior for one positive parameter θ, as a density of ln θ.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Prior {
    /// ln θ ~ Normal(ln median, sd_log²), truncated to [lower, upper].
    LogNormal { median: f64, sd_log: f64, lower: f64, upper: f64 },
    /// ln θ uniform on [ln lower, ln upper] (θ log-uniform).
    LogUniform { lower: f64, upper: f64 },
}

impl Prior {
    /// Log-density of ln θ = `log_value` (unnormalised); −∞ outside.
    pub fn log_density(&self, log_value: f64) -> f64 {
        let (lower, upper) = self.bounds();
        if !(log_value >= lower.ln() && log_value <= upper.ln()) {
            return f64::NEG_INFINITY;
        }
        match *self {
            Prior::LogNormal { median, sd_log, .. } => {
                -0.5 * ((log_value - median.ln()) / sd_log).powi(2)
            }
            Prior::LogUniform { .. } => 0.0,
        }
    }

    /// A draw of θ, by inverting the (truncated) distribution function of
    /// ln θ at a uniform draw: exact however little mass the bounds hold.
    pub fn draw(&self, rng: &mut impl rand::Rng) -> f64 {
        use rand::RngExt;
        use statrs::distribution::{ContinuousCDF, Normal};
        let (lower, upper) = self.bounds();
        let u: f64 = rng.random();
        let v = match *self {
            Prior::LogNormal { median, sd_log, .. } => {
                let normal = Normal::standard();
                let at = |bound: f64| normal.cdf((bound / median).ln() / sd_log);
                let (a, b) = (at(lower), at(upper));
                median * (sd_log * normal.inverse_cdf(a + u * (b - a))).exp()
            }
            Prior::LogUniform { .. } => (lower.ln() + u * (upper / lower).ln()).exp(),
        };
        // rounding at a bound far in a tail stays inside the support
        v.clamp(lower, upper)
    }

    /// ln ∫ exp([`Prior::log_density`]) d ln θ: what makes it a density
    /// (the truncated normal's mass between the bounds, the log-uniform's
    /// width).
    pub fn log_normaliser(&self) -> f64 {
        use statrs::distribution::{ContinuousCDF, Normal};
        let (lower, upper) = self.bounds();
        match *self {
            Prior::LogNormal { median, sd_log, .. } => {
                let normal = Normal::standard();
                let at = |bound: f64| (bound / median).ln() / sd_log;
                let mass = normal.cdf(at(upper)) - normal.cdf(at(lower));
                (sd_log * (2.0 * std::f64::consts::PI).sqrt()).ln() + mass.ln()
            }
            Prior::LogUniform { .. } => (upper / lower).ln().ln(),
        }
    }

    pub fn bounds(&self) -> (f64, f64) {
        match *self {
            Prior::LogNormal { lower, upper, .. } | Prior::LogUniform { lower, upper } => {
                (lower, upper)
            }
        }
    }

    /// A log-normal whose ±1 sd spans the plausible values [a, b],
    /// truncated to the physical range [lower, upper].
    pub fn spanning((a, b): (f64, f64), (lower, upper): (f64, f64)) -> Self {
        Prior::LogNormal { median: (a * b).sqrt(), sd_log: 0.5 * (b / a).ln(), lower, upper }
    }

    /// The centre and the scale of ln θ (for pseudo-residuals of the MAP
    /// search); a log-uniform prior has none.
    pub fn centre(&self) -> Option<(f64, f64)> {
        match *self {
            Prior::LogNormal { median, sd_log, .. } => Some((median.ln(), sd_log)),
            Prior::LogUniform { .. } => None,
        }
    }

    pub fn check(&self, name: &str) -> Result<(), String> {
        let (lo, hi) = self.bounds();
        if !(lo > 0.0 && hi > lo && hi.is_finite()) {
            return Err(format!("prior of {name}: need 0 < lower < upper < ∞, got [{lo}, {hi}]"));
        }
        if let Prior::LogNormal { median, sd_log, .. } = *self {
            if !(median > 0.0 && sd_log > 0.0 && median.is_finite() && sd_log.is_finite()) {
                return Err(format!("prior of {name}: median and sd_log must be positive"));
            }
        }
        Ok(())
    }
}

/// The default, weakly informative priors: for each parameter a log-normal
/// whose ±1 sd spans the plausible values of an RD-1005-3-class damper
/// (design notes), truncated to the physical range:
///
/// | θ | plausible (±1 sd) |
/// |---|---|
/// | G | 1e4 – 1e6 Pa |
/// | R0 | 5e4 – 3e5 Pa |
/// | R1 | 5e4 – 5e5 Pa |
/// | D1 | 1e4 – 1e5 Pa |
/// | m1 | 1e-6 – 1e-4 1/Pa |
/// | m2 | 1e-4 – 1e-2 1/Pa |
/// | n | 0.5 – 3 |
pub fn default_priors() -> [Prior; 7] {
    std::array::from_fn(|i| Prior::spanning(PLAUSIBLE_RANGE[i], PHYSICAL_RANGE[i]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::PARAM_NAMES;

    /// ln ∫ exp(log_density) over ln θ by the midpoint rule (10⁶ points
    /// over the support) for a truncated log-normal cut on both sides, one
    /// cut far in a tail, and a log-uniform.
    #[test]
    fn the_normaliser_is_the_integral_of_the_density() {
        for prior in [
            Prior::LogNormal { median: 2e5, sd_log: 0.8, lower: 1e5, upper: 1e6 },
            Prior::LogNormal { median: 1.0, sd_log: 0.3, lower: 1e-3, upper: 1.5 },
            Prior::LogUniform { lower: 1.0, upper: 1e6 },
        ] {
            let (lo, hi) = prior.bounds();
            let (a, b, steps) = (lo.ln(), hi.ln(), 1_000_000);
            let h = (b - a) / steps as f64;
            let sum: f64 =
                (0..steps).map(|k| prior.log_density(a + (k as f64 + 0.5) * h).exp()).sum();
            let integral = (sum * h).ln();
            assert!(
                (integral - prior.log_normaliser()).abs() < 1e-6,
                "{prior:?}: integrated {integral}, normaliser {}",
                prior.log_normaliser()
            );
        }
    }

    #[test]
    fn log_normal_is_centred_and_truncated() {
        let p = default_priors()[0];
        assert_eq!(p.log_density((1e5f64).ln()), 0.0);
        // one sd away: ln(1e6) − ln(1e5) = sd_log
        assert!((p.log_density((1e6f64).ln()) + 0.5).abs() < 1e-12);
        assert_eq!(p.log_density((1e9f64).ln()), f64::NEG_INFINITY);
        for (i, p) in default_priors().iter().enumerate() {
            assert!(p.check(PARAM_NAMES[i]).is_ok());
        }
    }
}
