//! The coil current along a record and the B-P parameters it sets.
//!
//! A semi-active damper's current changes while it moves: a controller
//! switches it many times a second. The fluid follows the magnetic field,
//! and the field lags the current (the coil's inductance, eddy currents in
//! the steel): to first order the field current I_f obeys
//! dI_f/dt = (I − I_f)/τ_c with time constant τ_c. A record's current is
//! held from one sample to the next (zero-order hold, as a controller
//! commands it); I_f starts at the first sample's current (the coil in
//! steady state). The integrator takes the B-P parameters at I_f at each
//! sample time and linear in time in between.

use super::current_curves::CurrentCurves;
use super::current_law::CurrentLaw;
use super::params::Params;

/// How the B-P parameters follow the coil current.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FieldLaw {
    /// R0, R1, D1 and the field part of G saturating with one tanh.
    Law(CurrentLaw),
    /// Every parameter its own curve, with an off-state.
    Curves(CurrentCurves),
}

impl FieldLaw {
    /// The B-P parameters at field current `current_a`.
    #[inline]
    pub fn params_at(&self, current_a: f64) -> Params {
        match self {
            FieldLaw::Law(l) => l.params_at(current_a),
            FieldLaw::Curves(c) => c.params_at(current_a),
        }
    }
}

/// The field current I_f of a coil with lag `lag_s` (0: the field follows
/// the current at once), stepped along a record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldCurrent {
    lag_s: f64,
    field_a: f64,
}

impl FieldCurrent {
    /// The coil in steady state at `current_a`.
    pub fn steady(lag_s: f64, current_a: f64) -> Self {
        FieldCurrent { lag_s, field_a: current_a }
    }

    /// The field current now.
    pub fn now(&self) -> f64 {
        self.field_a
    }

    /// Holds `current_a` for `dt` seconds: returns I_f at the end.
    #[inline]
    pub fn hold(&mut self, current_a: f64, dt: f64) -> f64 {
        let gap = self.field_a - current_a;
        self.field_a = if !(self.lag_s > 0.0) || gap == 0.0 {
            current_a
        } else {
            current_a + gap * (-dt / self.lag_s).exp()
        };
        self.field_a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A step from 0 to 1 A with τ_c = 10 ms: I_f(t) = 1 − e^{−t/τ}
    /// exactly, however long the intervals.
    #[test]
    fn the_field_follows_a_step_with_its_lag() {
        let tau = 0.01;
        let mut f = FieldCurrent::steady(tau, 0.0);
        let exact = |t: f64| 1.0 - (-t / tau).exp();
        let mut t = 0.0;
        for dt in [0.001, 0.004, 0.02, 0.0005] {
            let end = f.hold(1.0, dt);
            t += dt;
            assert!((end - exact(t)).abs() < 1e-14 && end == f.now(), "at {t}");
        }
        // no lag: the field is the current
        let mut g = FieldCurrent::steady(0.0, 0.3);
        assert_eq!((g.hold(0.8, 0.01), g.now()), (0.8, 0.8));
    }
}
