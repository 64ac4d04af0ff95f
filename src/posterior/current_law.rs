//! A current-dependent B-P model: the parameters that the magnetic field
//! sets follow the coil current through one saturating law, so a single
//! posterior covers every current level of a campaign and predicts levels
//! that were never measured.
//!
//! With s(I) = tanh(I/I_s) / tanh(I_ref/I_s), which is 1 at the reference
//! current I_ref and saturates above the saturation current I_s (the
//! magnetisation of the particles and of the damper's circuit saturates):
//!
//! * R0(I) = R0_ref s(I), R1(I) = R1_ref s(I), D1(I) = D1_ref s(I): the
//!   yield and hardening stresses come from the field-induced particle chains;
//! * G(I) = G_zero + G_field s(I): the carrier fluid and the unchained
//!   particles stiffen the fluid without field, the chains add to it;
//! * m1, m2, n: shared by all currents (rates of hardening and the rate
//!   sensitivity, no physical reason to change with the field).
//!
//! One I_s for all: a single magnetic circuit saturates. The law has nine
//! parameters instead of seven per current.

use super::prior::Prior;
use crate::model::{Params, PHYSICAL_RANGE};

/// Names of the law's coordinates (SI units in outputs).
pub const LAW_NAMES: [&str; 9] = ["G_field", "R0", "R1", "D1", "m1", "m2", "n", "saturation_current_a", "G_zero"];

/// The law and its reference current.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLaw {
    pub reference_a: f64,
}

impl Default for CurrentLaw {
    fn default() -> Self {
        CurrentLaw { reference_a: 1.0 }
    }
}

impl CurrentLaw {
    /// s(I): the share of the reference current's field effect at `current_a`.
    pub fn scale(&self, current_a: f64, saturation_a: f64) -> f64 {
        (current_a / saturation_a).tanh() / (self.reference_a / saturation_a).tanh()
    }

    /// B-P parameters at `current_a` from the law's values `theta` (SI, in
    /// the order of [`LAW_NAMES`]).
    pub fn params(&self, theta: &[f64], current_a: f64) -> Params {
        let s = self.scale(current_a, theta[7]);
        Params {
            g: theta[8] + theta[0] * s,
            r0: theta[1] * s,
            r1: theta[2] * s,
            d1: theta[3] * s,
            m1: theta[4],
            m2: theta[5],
            n: theta[6],
        }
    }

    /// Priors of the law's coordinates, from the per-current priors `bp`
    /// (which then describe the reference current): G_field and G_zero each
    /// get G's prior; I_s a log-normal with median I_ref and a factor e
    /// spread, within [0.05 I_ref, 20 I_ref].
    pub fn priors(&self, bp: &[Prior; 7]) -> Vec<Prior> {
        let mut p = bp.to_vec();
        p.push(Prior::LogNormal { median: self.reference_a, sd_log: 1.0, lower: 0.05 * self.reference_a, upper: 20.0 * self.reference_a });
        p.push(bp[0]);
        p
    }

    /// The law's values (SI) that give `p` at `current_a` with I_s = I_ref
    /// and half of G from the field: a start for the MAP search.
    pub fn start_from(&self, p: &Params, current_a: f64) -> [f64; 9] {
        let s = self.scale(current_a, self.reference_a).max(1e-3);
        let clamp = |v: f64, i: usize| v.clamp(PHYSICAL_RANGE[i].0, PHYSICAL_RANGE[i].1);
        [
            clamp(0.5 * p.g / s, 0),
            clamp(p.r0 / s, 1),
            clamp(p.r1 / s, 2),
            clamp(p.d1 / s, 3),
            p.m1,
            p.m2,
            p.n,
            self.reference_a,
            0.5 * p.g,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The law with I_s = 1 A and G half from the field reproduces the
    /// current dependence of the virtual stand (synth::CurrentLaw).
    #[test]
    fn law_reproduces_the_virtual_stand() {
        let stand = crate::synth::CurrentLaw::default();
        let law = CurrentLaw::default();
        let p = Params::reference_1a();
        let theta = law.start_from(&p, 1.0);
        for i in [0.5, 1.0, 1.5] {
            let a = law.params(&theta, i).to_array();
            let b = stand.params_at(i).to_array();
            for k in 0..7 {
                assert!((a[k] / b[k] - 1.0).abs() < 1e-12, "{i} A, {k}: {} vs {}", a[k], b[k]);
            }
        }
    }
}
