//! The seven identified B-P parameters and their physical range.

use serde::{Deserialize, Serialize};

/// Limiting shear rate D₀ (1/s). Fixed, not identified (paper §3).
pub const D0: f64 = 1.0e4;

/// Parameter names, in the order of [`Params::to_array`]. These are the
/// column names of every output table.
pub const PARAM_NAMES: [&str; 7] = ["G", "R0", "R1", "D1", "m1", "m2", "n"];

/// Units of each parameter, for tables and axis labels.
pub const PARAM_UNITS: [&str; 7] = ["Pa", "Pa", "Pa", "Pa", "1/Pa", "1/Pa", "-"];

/// The physical range of each parameter (lower, upper), in the order of
/// [`PARAM_NAMES`]. Wider than the plausible values of an RD-1005-3-class
/// damper (design page) by one to two decades, so that it constrains only
/// what is physically absurd: it is the support of the default priors and
/// the box that the identification clamps its results into.
pub const PHYSICAL_RANGE: [(f64, f64); 7] = [
    (1.0e3, 1.0e8),   // G
    (1.0e3, 1.0e7),   // R0
    (1.0e3, 1.0e7),   // R1
    (1.0e1, 1.0e7),   // D1
    (1.0e-9, 1.0e-2), // m1
    (1.0e-7, 1.0),    // m2
    (0.1, 10.0),      // n
];

/// The plausible values of each parameter for an RD-1005-3-class damper
/// (design notes), in the order of [`PARAM_NAMES`]: the ±1 sd span of the
/// default priors, and where an identification takes what the records do
/// not show.
pub const PLAUSIBLE_RANGE: [(f64, f64); 7] = [
    (1e4, 1e6),   // G
    (5e4, 3e5),   // R0
    (5e4, 5e5),   // R1
    (1e4, 1e5),   // D1
    (1e-6, 1e-4), // m1
    (1e-4, 1e-2), // m2
    (0.5, 3.0),   // n
];

/// θ = (G, R0, R1, D1, m1, m2, n) in SI units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Shear modulus of the fluid before yield (Pa).
    #[serde(rename = "G")]
    pub g: f64,
    /// Initial isotropic hardening (Pa).
    #[serde(rename = "R0")]
    pub r0: f64,
    /// Saturated isotropic hardening (Pa).
    #[serde(rename = "R1")]
    pub r1: f64,
    /// Saturated kinematic hardening (Pa).
    #[serde(rename = "D1")]
    pub d1: f64,
    /// Rate of isotropic hardening with inelastic work (1/Pa).
    pub m1: f64,
    /// Rate of kinematic hardening with inelastic work (1/Pa).
    pub m2: f64,
    /// Rate-sensitivity exponent (dimensionless).
    pub n: f64,
}

impl Params {
    pub fn to_array(&self) -> [f64; 7] {
        [self.g, self.r0, self.r1, self.d1, self.m1, self.m2, self.n]
    }

    pub fn from_array(a: [f64; 7]) -> Self {
        Params { g: a[0], r0: a[1], r1: a[2], d1: a[3], m1: a[4], m2: a[5], n: a[6] }
    }

    /// Checks that every parameter is finite and inside [`PHYSICAL_RANGE`];
    /// the message names the first one that is not.
    pub fn validate(&self) -> Result<(), String> {
        for ((name, value), (lo, hi)) in PARAM_NAMES.iter().zip(self.to_array()).zip(PHYSICAL_RANGE)
        {
            if !value.is_finite() || value < lo || value > hi {
                return Err(format!(
                    "parameter {name} = {value:e} is outside its physical range [{lo:e}, {hi:e}]"
                ));
            }
        }
        Ok(())
    }

    /// The nearest parameter set inside [`PHYSICAL_RANGE`]; a non-finite
    /// value becomes the geometric middle of its range. Returns the names of
    /// the parameters that had to be moved.
    pub fn clamped(&self) -> (Params, Vec<&'static str>) {
        let mut a = self.to_array();
        let mut moved = Vec::new();
        for (i, (lo, hi)) in PHYSICAL_RANGE.iter().enumerate() {
            let v = a[i];
            let c = if v.is_finite() { v.clamp(*lo, *hi) } else { (lo * hi).sqrt() };
            if c != v {
                moved.push(PARAM_NAMES[i]);
                a[i] = c;
            }
        }
        (Params::from_array(a), moved)
    }

    /// The geometric middle of [`PLAUSIBLE_RANGE`] of parameter `i`.
    pub fn plausible_centre(i: usize) -> f64 {
        let (a, b) = PLAUSIBLE_RANGE[i];
        (a * b).sqrt()
    }

    /// Plausible values at 1 A for an RD-1005-3-class damper (design page):
    /// peak force about 2.5–2.9 kN at 100–400 rpm with A = 0.05 m².
    pub fn reference_1a() -> Self {
        Params { g: 2.0e5, r0: 1.2e5, r1: 1.6e5, d1: 3.0e4, m1: 4.0e-6, m2: 2.0e-4, n: 1.2 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_is_inside_range_and_roundtrips() {
        let p = Params::reference_1a();
        assert!(p.validate().is_ok());
        assert_eq!(Params::from_array(p.to_array()), p);
    }

    #[test]
    fn validation_names_the_offender() {
        let mut p = Params::reference_1a();
        p.n = -1.0;
        let e = p.validate().unwrap_err();
        assert!(e.contains("parameter n"), "{e}");
        p.n = f64::NAN;
        assert!(p.validate().is_err());
    }

    #[test]
    fn clamping_moves_only_what_is_outside() {
        let mut p = Params::reference_1a();
        p.m1 = -3.0;
        p.g = f64::INFINITY;
        let (c, moved) = p.clamped();
        assert_eq!(moved, vec!["G", "m1"]);
        assert_eq!(c.m1, PHYSICAL_RANGE[4].0);
        assert!((c.g - (1.0e3f64 * 1.0e8).sqrt()).abs() < 1.0);
        assert_eq!(c.r0, p.r0);
        assert!(c.validate().is_ok());
    }
}
