//! The constitutive law: flow rule (paper eq. 3) and hardening (paper eq. 4).
//!
//! [`Law`] holds the parameters with the constants of eq. 3 precomputed, so
//! that the integrator's hot loop does no repeated work.

use super::params::{Params, D0};

/// √3, which divides |τ| in eq. 3.
const SQRT_3: f64 = 1.732_050_807_568_877_2;

/// Isotropic and kinematic hardening (R, D) after inelastic work `w` (eq. 4):
///
/// R = R1 [1 − exp(−m1 W)] + R0 exp(−m1 W),  D = D1 [1 − exp(−m2 W)].
#[inline]
pub fn hardening(p: &Params, w: f64) -> (f64, f64) {
    let e1 = (-p.m1 * w).exp();
    let e2 = (-p.m2 * w).exp();
    (p.r1 + (p.r0 - p.r1) * e1, p.d1 * (1.0 - e2))
}

/// Inelastic shear rate γ̇ᴵ (1/s) at stress `tau` with total hardening
/// `z` = R + D (eq. 3, the authoritative form of the design page):
///
/// γ̇ᴵ = 2 D₀ exp[−½ ((R + D)/(√3|τ|))^(2n) (n+1)/n] sgn τ.
#[inline]
pub fn inelastic_rate(p: &Params, tau: f64, z: f64) -> f64 {
    Law::new(p).flow(tau, z).rate
}

/// Stress at which eq. 3 gives the inelastic rate `rate` (> 0) under
/// hardening `z`; the inverse of [`inelastic_rate`] for τ > 0. With z = R0 this
/// is the initial yield stress of eq. 6 (corrected form).
pub fn flow_stress(p: &Params, rate: f64, z: f64) -> f64 {
    let log_term = (2.0 * p.n / (p.n + 1.0)) * (2.0 * D0 / rate).ln();
    z / (SQRT_3 * log_term.powf(1.0 / (2.0 * p.n)))
}

/// The law's tangent stiffness dτ/dγ between two samples of a solution
/// (stress change `dtau` over strain change `dgamma`), within [0, G], and
/// G where the strain stands still: what carries the strain's noise into
/// the stress (errors in variables).
#[inline(always)]
pub fn tangent_stiffness(dtau: f64, dgamma: f64, g: f64) -> f64 {
    if dgamma.abs() > 1e-12 {
        (dtau / dgamma).clamp(0.0, g)
    } else {
        g
    }
}

/// The flow rule evaluated at one state.
#[derive(Clone, Copy, Debug)]
pub struct Flow {
    /// γ̇ᴵ (1/s), with the sign of τ.
    pub rate: f64,
    /// ∂γ̇ᴵ/∂τ ≥ 0 (1/(Pa s)); G times this is the local stiffness λ.
    pub slope: f64,
}

/// The parameters of the law with the constants of eq. 3 precomputed.
#[derive(Clone, Copy, Debug)]
pub struct Law {
    pub p: Params,
    /// ½ (n+1)/n
    half_n1_over_n: f64,
    two_n: f64,
}

impl Law {
    pub fn new(p: &Params) -> Self {
        Law { p: *p, half_n1_over_n: 0.5 * (p.n + 1.0) / p.n, two_n: 2.0 * p.n }
    }

    /// Total hardening R + D after inelastic work `w` (eq. 4).
    #[inline(always)]
    pub fn hardening_sum(&self, w: f64) -> f64 {
        let (r, d) = hardening(&self.p, w);
        r + d
    }

    /// γ̇ᴵ and ∂γ̇ᴵ/∂τ at stress `tau` under hardening `z` (eq. 3).
    ///
    /// With q = ((z/(√3|τ|))^(2n), γ̇ᴵ = 2D₀ exp(−q(n+1)/(2n)) and
    /// ∂|γ̇ᴵ|/∂|τ| = |γ̇ᴵ| (n+1) q / |τ|. At τ = 0 both are 0.
    #[inline(always)]
    pub fn flow(&self, tau: f64, z: f64) -> Flow {
        let abs_tau = tau.abs();
        let q = (z / (SQRT_3 * abs_tau)).powf(self.two_n);
        let magnitude = 2.0 * D0 * (-self.half_n1_over_n * q).exp();
        if magnitude == 0.0 {
            // far below yield (or τ = 0): no flow, and no stiffness either
            return Flow { rate: 0.0, slope: 0.0 };
        }
        Flow { rate: magnitude.copysign(tau), slope: magnitude * (self.p.n + 1.0) * q / abs_tau }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hardening_starts_at_r0_and_saturates() {
        let p = Params::reference_1a();
        let (r, d) = hardening(&p, 0.0);
        assert_eq!((r, d), (p.r0, 0.0));
        let (r, d) = hardening(&p, 1.0e9);
        assert!((r - p.r1).abs() < 1e-6 * p.r1);
        assert!((d - p.d1).abs() < 1e-6 * p.d1);
    }

    #[test]
    fn flow_rule_matches_hand_computation() {
        // n = 1: γ̇ᴵ = 2D₀ exp(−(z/(√3 τ))²), by hand for z/τ = 3: exp(−3).
        let mut p = Params::reference_1a();
        p.n = 1.0;
        let rate = inelastic_rate(&p, 1.0e4, 3.0e4);
        assert!((rate - 2.0 * D0 * (-3.0f64).exp()).abs() < 1e-9 * rate);
        assert_eq!(inelastic_rate(&p, -1.0e4, 3.0e4), -rate);
        assert_eq!(inelastic_rate(&p, 0.0, 3.0e4), 0.0);
    }

    #[test]
    fn flow_stress_inverts_the_flow_rule() {
        let p = Params::reference_1a();
        for rate in [1.0, 45.0, 176.0, 1000.0] {
            let tau = flow_stress(&p, rate, p.r0);
            let back = inelastic_rate(&p, tau, p.r0);
            assert!((back - rate).abs() < 1e-9 * rate, "{rate} -> {back}");
        }
    }

    #[test]
    fn slope_matches_finite_difference() {
        let p = Params::reference_1a();
        let law = Law::new(&p);
        let z = 1.5e5;
        for tau in [2.0e4f64, 3.5e4, -3.5e4, 5.0e4] {
            let h = 1e-4 * tau.abs();
            let fd = (law.flow(tau + h, z).rate - law.flow(tau - h, z).rate) / (2.0 * h);
            let slope = law.flow(tau, z).slope;
            assert!((fd - slope).abs() < 1e-5 * slope.abs().max(1e-300), "{tau}: {fd} vs {slope}");
        }
    }
}
