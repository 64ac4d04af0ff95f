//! How the B-P parameters follow the coil current.
//!
//! The field-induced quantities follow the magnetisation of the particles
//! and of the damper's circuit, which saturates. With
//! s(I) = tanh(I/I_s) / tanh(I_ref/I_s), which is 1 at the reference
//! current I_ref and saturates above the saturation current I_s:
//!
//! * R0(I) = R0 s(I), R1(I) = R1 s(I), D1(I) = D1 s(I): the yield and
//!   hardening stresses come from the field-induced particle chains;
//! * G(I) = G_zero + G_field s(I): the carrier fluid and the unchained
//!   particles stiffen the fluid without field, the chains add to it;
//! * m1, m2, n do not change with the field (rates of hardening and the
//!   rate sensitivity).
//!
//! The virtual stand (`synth`) makes its records with this law, and the
//! `current-law` calibration infers its parameters.

use super::params::Params;

/// The law's parameters: values at the reference current and how they scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentLaw {
    /// I_ref (A): R0, R1, D1 are their values there, and G = G_zero + G_field.
    pub reference_a: f64,
    /// I_s (A).
    pub saturation_a: f64,
    /// The field-independent part of G (Pa).
    pub g_zero: f64,
    /// The field-induced part of G at the reference current (Pa).
    pub g_field: f64,
    pub r0: f64,
    pub r1: f64,
    pub d1: f64,
    pub m1: f64,
    pub m2: f64,
    pub n: f64,
}

impl CurrentLaw {
    /// The law whose parameters at `reference_a` are `p`, with the share
    /// `g_field_share` of G from the field.
    pub fn through(
        p: &Params,
        reference_a: f64,
        saturation_a: f64,
        g_field_share: f64,
    ) -> CurrentLaw {
        CurrentLaw {
            reference_a,
            saturation_a,
            g_zero: (1.0 - g_field_share) * p.g,
            g_field: g_field_share * p.g,
            r0: p.r0,
            r1: p.r1,
            d1: p.d1,
            m1: p.m1,
            m2: p.m2,
            n: p.n,
        }
    }

    /// s(I): the share of the reference current's field effect at `current_a`.
    pub fn scale(&self, current_a: f64) -> f64 {
        (current_a / self.saturation_a).tanh() / (self.reference_a / self.saturation_a).tanh()
    }

    /// The B-P parameters at `current_a`.
    pub fn params_at(&self, current_a: f64) -> Params {
        let s = self.scale(current_a);
        Params {
            g: self.g_zero + self.g_field * s,
            r0: self.r0 * s,
            r1: self.r1 * s,
            d1: self.d1 * s,
            m1: self.m1,
            m2: self.m2,
            n: self.n,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn law_is_its_parameters_at_the_reference_and_saturates() {
        let p = Params::reference_1a();
        let law = CurrentLaw::through(&p, 1.0, 1.0, 0.5);
        assert!((law.scale(1.0) - 1.0).abs() < 1e-15);
        let at = law.params_at(1.0).to_array();
        for (a, b) in at.iter().zip(p.to_array()) {
            assert!((a / b - 1.0).abs() < 1e-15);
        }
        let (a, b, c) = (law.scale(0.5), law.scale(1.0), law.scale(1.5));
        assert!(a < b && b < c);
        assert!(c - b < b - a, "saturating");
        // by hand: s(0.5 A) = tanh(0.5)/tanh(1) with I_s = 1 A
        let half = law.params_at(0.5);
        let s = 0.5f64.tanh() / 1.0f64.tanh();
        assert!((half.r0 - p.r0 * s).abs() < 1e-9 * p.r0);
        assert!((half.g - p.g * 0.5 * (1.0 + s)).abs() < 1e-9 * p.g);
        assert_eq!((half.m1, half.m2, half.n), (p.m1, p.m2, p.n));
    }
}
