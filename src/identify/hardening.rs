//! Work hardening: the fit of eq. 7 to τ(γᴵ), the hardening rate ψ(τ) of
//! eq. 9, its two asymptotes (eqs. 11–12) and the solve for R1 and D1.

use nalgebra::DMatrix;

use super::elastic::slope;
use crate::fit::least_squares;

/// τ = a (γᴵ)^b exp(c γᴵ) + d (eq. 7).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eq7 {
    pub a: f64,
    pub b: f64,
    pub c: f64,
    pub d: f64,
}

impl Eq7 {
    pub fn value(&self, x: f64) -> f64 {
        self.a * x.powf(self.b) * (self.c * x).exp() + self.d
    }

    /// dτ/dγᴵ = a (b/γᴵ + c) (γᴵ)^b exp(c γᴵ) (eq. 8; the printed exponent d
    /// is a slip for b).
    pub fn derivative(&self, x: f64) -> f64 {
        self.a * (self.b / x + self.c) * x.powf(self.b) * (self.c * x).exp()
    }

    /// ψ = dτ/dWᴵ = (dτ/dγᴵ)/τ (eq. 9).
    pub fn psi(&self, x: f64) -> f64 {
        self.derivative(x) / self.value(x)
    }
}

/// The fitted curve and how well it fits.
#[derive(Clone, Debug)]
pub struct CurveFit {
    pub eq7: Eq7,
    pub converged: bool,
    /// RMS of τ − eq7 over the fitted points (Pa).
    pub rms: f64,
}

/// Fits eq. 7 to points (γᴵ, τ) by Levenberg-Marquardt with the analytic
/// Jacobian. Start: d at the first stress, b = ½, c = 0, a from the last.
pub fn fit_eq7(x: &[f64], y: &[f64]) -> CurveFit {
    let (x0, y0) = (x[0], y[0]);
    let (xn, yn) = (x[x.len() - 1], y[y.len() - 1]);
    let d0 = y0;
    let a0 = ((yn - d0) / (xn.sqrt() - x0.sqrt())).max(1.0);
    let start = [a0, 0.5, 0.0, d0 - a0 * x0.sqrt()];
    let residuals = |p: &[f64]| {
        let f = Eq7 { a: p[0], b: p[1], c: p[2], d: p[3] };
        Some(x.iter().zip(y).map(|(x, y)| f.value(*x) - y).collect())
    };
    let jacobian = |p: &[f64]| {
        Some(DMatrix::from_fn(x.len(), 4, |i, j| {
            let xi = x[i];
            let core = xi.powf(p[1]) * (p[2] * xi).exp();
            match j {
                0 => core,
                1 => p[0] * core * xi.ln(),
                2 => p[0] * core * xi,
                _ => 1.0,
            }
        }))
    };
    let fit = least_squares(&start, &residuals, Some(&jacobian));
    let eq7 = Eq7 { a: fit.params[0], b: fit.params[1], c: fit.params[2], d: fit.params[3] };
    CurveFit { eq7, converged: fit.converged, rms: (2.0 * fit.cost / x.len() as f64).sqrt() }
}

/// A straight line ψ = intercept − m τ fitted to one end of ψ(τ).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Asymptote {
    /// m (1/Pa): minus the slope.
    pub m: f64,
    pub intercept: f64,
    /// The τ range it was fitted on (Pa).
    pub tau_range: (f64, f64),
    pub points: usize,
}

/// The two ends of the ψ(τ) curve, sampled along increasing γᴵ.
///
/// The rule: with τ spanning [τ_first, τ_last] along the curve, the
/// small-strain end is the leading run of points with τ ≤ τ_first + share ×
/// span, the large-strain end the trailing run with τ ≥ τ_last − share ×
/// span; each gets a least-squares line. The ends are defined by stress, not
/// by sample index, so they do not depend on the sampling rate or on how
/// the curve is discretised. Returns (small end → m2, large end → m1).
pub fn asymptotes(tau: &[f64], psi: &[f64], share: f64) -> Option<(Asymptote, Asymptote)> {
    let (first, last) = (tau[0], tau[tau.len() - 1]);
    let span = last - first;
    if !(span > 0.0) {
        return None;
    }
    let lead = tau.iter().take_while(|t| **t <= first + share * span).count();
    let trail = tau.iter().rev().take_while(|t| **t >= last - share * span).count();
    let line = |r: std::ops::Range<usize>| -> Option<Asymptote> {
        if r.len() < 3 {
            return None;
        }
        let (t, p) = (&tau[r.clone()], &psi[r.clone()]);
        let s = slope(t, p);
        let tm = t.iter().sum::<f64>() / t.len() as f64;
        let pm = p.iter().sum::<f64>() / p.len() as f64;
        Some(Asymptote {
            m: -s,
            intercept: pm - s * tm,
            tau_range: (t[0], t[t.len() - 1]),
            points: t.len(),
        })
    };
    Some((line(0..lead)?, line(tau.len() - trail..tau.len())?))
}

/// R1 and D1 from the two intercepts (eqs. 11–12) with κ = τ0/R0:
///
///   A2 = κ [m1 (R1 − R0) + m2 (R0 + D1)],   A1 = κ m1 (R1 + D1),
///
/// so D1 = (A2 − A1)/(κ (m2 − m1)) − R0 and R1 = A1/(κ m1) − D1.
pub fn solve_r1_d1(a1: f64, a2: f64, m1: f64, m2: f64, r0: f64, kappa: f64) -> (f64, f64) {
    let d1 = (a2 - a1) / (kappa * (m2 - m1)) - r0;
    let r1 = a1 / (kappa * m1) - d1;
    (r1, d1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_matches_finite_difference() {
        let f = Eq7 { a: 2.0e4, b: 0.3, c: -0.05, d: 3.0e4 };
        for x in [0.003, 0.1, 2.0, 8.0] {
            let h = 1e-6 * x;
            let fd = (f.value(x + h) - f.value(x - h)) / (2.0 * h);
            assert!((fd - f.derivative(x)).abs() < 1e-6 * fd.abs(), "{x}");
        }
    }

    #[test]
    fn lm_recovers_a_known_curve() {
        let truth = Eq7 { a: 1.5e4, b: 0.35, c: -0.04, d: 3.2e4 };
        let x: Vec<f64> = (0..120).map(|i| 0.002 * (10f64).powf(i as f64 * 3.6 / 119.0)).collect();
        let y: Vec<f64> = x.iter().map(|x| truth.value(*x)).collect();
        let fit = fit_eq7(&x, &y);
        assert!(fit.converged);
        let e = fit.eq7;
        assert!((e.a / truth.a - 1.0).abs() < 1e-5, "{e:?}");
        assert!(
            (e.b - truth.b).abs() < 1e-6
                && (e.c - truth.c).abs() < 1e-7
                && (e.d / truth.d - 1.0).abs() < 1e-6,
            "{e:?}"
        );
        assert!(fit.rms < 1e-3);
    }

    #[test]
    fn asymptotes_of_a_two_slope_curve() {
        // ψ(τ) built from eqs. 11–12 with known m1, m2, R0, R1, D1, κ: the
        // piecewise form ψ = max of the two lines, as the B-P law gives when
        // D saturates long before R moves
        let (m1, m2, r0, r1, d1, kappa) = (4.0e-6, 2.0e-4, 1.2e5, 1.6e5, 3.0e4, 0.25);
        let a2 = kappa * (m1 * (r1 - r0) + m2 * (r0 + d1));
        let a1 = kappa * m1 * (r1 + d1);
        let tau: Vec<f64> = (0..400).map(|i| 3.0e4 + 17.5e3 * i as f64 / 399.0).collect();
        let psi: Vec<f64> = tau.iter().map(|t| (a2 - m2 * t).max(a1 - m1 * t)).collect();
        let (small, large) = asymptotes(&tau, &psi, 0.15).unwrap();
        assert!((small.m - m2).abs() < 1e-9 * m2 && (large.m - m1).abs() < 1e-9 * m1);
        let (r1_hat, d1_hat) =
            solve_r1_d1(large.intercept, small.intercept, large.m, small.m, r0, kappa);
        assert!((r1_hat - r1).abs() < 1e-6 * r1, "{r1_hat}");
        assert!((d1_hat - d1).abs() < 1e-6 * d1, "{d1_hat}");
    }
}
