//! Each B-P parameter its own smooth curve in the coil current.
//!
//! A measured damper does not follow [`super::CurrentLaw`]: its pre-yield
//! modulus may fall with the current, its stresses saturate at different
//! rates, and without current its fluid still has a viscous and yield-like
//! force. Here every parameter p has its own curve through its values at
//! two anchor currents I_lo < I_hi (the lowest and highest currents a
//! calibration sees, by default), bent by its own factor κ_p > 0:
//!
//! ln p(I) = ln p(I_lo) + [ln p(I_hi) − ln p(I_lo)] · b(κ_p, x),
//! x = (I − I_lo)/(I_hi − I_lo),  b(κ, x) = (κˣ − 1)/(κ − 1),
//!
//! with b(1, x) = x. So κ = 1 is a straight line in ln p against I, κ < 1
//! a curve that saturates toward I_hi (most of the change near I_lo),
//! κ > 1 one that changes late; either sign of change is allowed, every
//! value stays positive, and the off-state (0 A) value p(0) is finite: the
//! curve continued to x = −I_lo/(I_hi − I_lo). Between the anchors the
//! parameters lie between their anchor values, whatever κ.
//!
//! The anchor values are what records at those currents determine, so the
//! sampler's coordinates are nearly independent: the data at other
//! currents set only the bends.

use serde::{Deserialize, Serialize};

use super::params::Params;

/// The curves' parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurrentCurves {
    /// I_lo (A).
    pub low_a: f64,
    /// I_hi (A), above I_lo.
    pub high_a: f64,
    /// The parameters at I_lo.
    pub low: Params,
    /// The parameters at I_hi.
    pub high: Params,
    /// κ of each parameter, in the order of [`Params::to_array`].
    pub bend: [f64; 7],
}

/// b(κ, x) = (κˣ − 1)/(κ − 1), continuous through κ = 1.
pub fn bend_shape(kappa: f64, x: f64) -> f64 {
    let c = kappa.ln();
    if c.abs() < 1e-9 {
        // (e^{cx} − 1)/(e^c − 1) = x (1 + c(x − 1)/2 + O(c²))
        x * (1.0 + 0.5 * c * (x - 1.0))
    } else {
        (c * x).exp_m1() / c.exp_m1()
    }
}

impl CurrentCurves {
    /// The curves through `p` at every current: both anchors `p`, no bend.
    pub fn flat(p: &Params, low_a: f64, high_a: f64) -> CurrentCurves {
        CurrentCurves { low_a, high_a, low: *p, high: *p, bend: [1.0; 7] }
    }

    /// The position x of `current_a` between the anchors (0 at I_lo, 1 at I_hi).
    pub fn position(&self, current_a: f64) -> f64 {
        (current_a - self.low_a) / (self.high_a - self.low_a)
    }

    /// The B-P parameters at `current_a`.
    pub fn params_at(&self, current_a: f64) -> Params {
        let x = self.position(current_a);
        let (lo, hi) = (self.low.to_array(), self.high.to_array());
        Params::from_array(std::array::from_fn(|k| {
            let (a, b) = (lo[k].ln(), hi[k].ln());
            (a + (b - a) * bend_shape(self.bend[k], x)).exp()
        }))
    }

    /// The parameters without current: the curves continued to 0 A.
    pub fn off_state(&self) -> Params {
        self.params_at(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bend_shape_by_hand() {
        // κ = 4 at x = 1/2: (2 − 1)/(4 − 1) = 1/3; at x = −1: (1/4 − 1)/3 = −1/4
        assert!((bend_shape(4.0, 0.5) - 1.0 / 3.0).abs() < 1e-15);
        assert!((bend_shape(4.0, -1.0) + 0.25).abs() < 1e-15);
        // through κ = 1 the shape is continuous and is x there
        for x in [-1.0, 0.0, 0.3, 1.0, 2.0] {
            assert!((bend_shape(1.0, x) - x).abs() < 1e-15);
            let near = bend_shape(1.0 + 1e-7, x);
            let exact = ((1e-7f64).ln_1p() * x).exp_m1() / 1e-7;
            assert!((near - exact).abs() < 1e-12, "{x}: {near} vs {exact}");
        }
        for k in [0.01, 0.5, 3.0, 100.0] {
            assert!(bend_shape(k, 0.0).abs() < 1e-15 && (bend_shape(k, 1.0) - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn curves_pass_through_their_anchors_and_have_an_off_state() {
        let low =
            Params { g: 2.5e5, r0: 4.0e4, r1: 5.0e4, d1: 3.0e4, m1: 2e-7, m2: 2.5e-3, n: 0.33 };
        let high =
            Params { g: 1.7e5, r0: 8.5e4, r1: 6.0e4, d1: 1.65e5, m1: 8e-6, m2: 3.6e-4, n: 0.36 };
        let c = CurrentCurves {
            low_a: 0.25,
            high_a: 1.0,
            low,
            high,
            bend: [4.0, 0.25, 1.0, 2.0, 0.1, 3.0, 1.0],
        };
        for (k, (a, b)) in c.params_at(0.25).to_array().iter().zip(low.to_array()).enumerate() {
            assert!((a / b - 1.0).abs() < 1e-14, "{k}");
        }
        for (k, (a, b)) in c.params_at(1.0).to_array().iter().zip(high.to_array()).enumerate() {
            assert!((a / b - 1.0).abs() < 1e-14, "{k}");
        }
        // G with κ = 4 at 0.625 A (x = 1/2): ln G = ln G_lo + (ln G_hi − ln G_lo)/3
        let g = (2.5e5f64.ln() + (1.7e5f64 / 2.5e5).ln() / 3.0).exp();
        assert!((c.params_at(0.625).g / g - 1.0).abs() < 1e-14);
        // G falls with current, so its off-state value lies above G_lo;
        // D1 rises, so below; both positive. x(0) = −1/3.
        let off = c.off_state();
        let d1 = (3.0e4f64.ln() + (1.65e5f64 / 3.0e4).ln() * bend_shape(2.0, -1.0 / 3.0)).exp();
        assert!((off.d1 / d1 - 1.0).abs() < 1e-14);
        assert!(off.g > low.g && off.d1 < low.d1 && off.d1 > 0.0);
        // between the anchors every parameter lies between its anchor values
        for i in 0..=20 {
            let p = c.params_at(0.25 + 0.75 * i as f64 / 20.0).to_array();
            for k in 0..7 {
                let (a, b) = (low.to_array()[k], high.to_array()[k]);
                assert!(p[k] >= a.min(b) * (1.0 - 1e-12) && p[k] <= a.max(b) * (1.0 + 1e-12));
            }
        }
    }
}
