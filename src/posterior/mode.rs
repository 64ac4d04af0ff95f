//! The posterior's mode and its curvature, from the log-density itself.
//!
//! The MAP search ([`super::map`]) fits a Gaussian surrogate: each run's
//! noise is held fixed while θ moves and its curvature is Gauss-Newton's.
//! Where the noise depends on θ (errors in variables: the strain's noise
//! reaches the stress through G) the surrogate's optimum is not the mode,
//! and where the posterior is not Gaussian its width is not the surrogate's:
//! on the measured 0.25 A records a posterior without one run lies
//! 3.5–4.4 of its sds from the surrogate's optimum in G and is up to 1.7×
//! wider in one direction, so importance sampling from the surrogate fails;
//! walkers started there spent most of a calibration's steps drifting in G
//! (and a chain judged converged still carried 4 MCSE of that start).
//!
//! [`newton`] starts from the surrogate's Laplace approximation and, in the
//! coordinates that approximation whitens, takes Newton steps on the
//! log-density with derivatives by central differences, then measures the
//! curvature at the mode it reached: the Laplace approximation of the
//! posterior itself, from which a calibration's walkers start and
//! leave-one-out draws its importance samples. It is generic over
//! [`LogDensity`].

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use super::map::{self, MapEstimate};
use super::Posterior;
use crate::sampler::density::log_densities;
use crate::sampler::{Elliptical, LogDensity};

/// Finite-difference steps in the whitened coordinates (surrogate sds):
/// the gradient's small, so that the mode it finds is the density's (its
/// bias is about step²/6 of the third derivative); the Hessian's wider, the
/// curvature of the posterior's bulk rather than of the last digits of the
/// integrated records.
const GRADIENT_STEP: f64 = 0.05;
const HESSIAN_STEP: f64 = 0.25;

/// Newton steps at most; the search stops earlier once a step would gain
/// less than [`GAIN_TOL`] (gᵀ Σ g, twice the nats it expects: 0.01 is a
/// point about 0.1 sd from the mode; on the measured records the
/// differences' noise showed in gains of a few 1e-3).
const MAX_STEPS: usize = 12;
const GAIN_TOL: f64 = 1e-2;

/// Hessians measured at most on the way (each 2d² log-densities), the
/// first where the search begins, then each time a full Newton step did not
/// rise as its quadratic model said (the search began far from the mode);
/// one more at the mode if the last was measured elsewhere.
const MAX_HESSIANS: usize = 4;

/// Smallest curvature kept along any direction (whitened): a direction in
/// which the log-density is flat or convex is given a sd 5× the
/// surrogate's.
const MIN_CURVATURE: f64 = 0.04;

/// The mode and the Laplace approximation there.
#[derive(Clone, Debug)]
pub struct Mode {
    pub x: Vec<f64>,
    pub log_density: f64,
    /// Whether the search stopped because a step would gain less than
    /// [`GAIN_TOL`] (not at the step limit or a failed line search).
    pub converged: bool,
    /// Gaussian about the mode whose precision is the negated Hessian
    /// (flat or convex directions held at [`MIN_CURVATURE`]).
    pub laplace: Elliptical,
}

/// The Laplace approximation of `post` at its mode, reached by [`newton`]
/// from the MAP's; the MAP's own where the differences cannot be taken.
pub fn laplace_from(post: &Posterior, map: &MapEstimate) -> Elliptical {
    from_map(post, map).map_or_else(|| map::laplace(post, map), |m| m.laplace)
}

/// The mode of `post` reached by [`newton`] from the MAP's Laplace
/// approximation; `None` where the differences cannot be taken.
pub fn from_map(post: &Posterior, map: &MapEstimate) -> Option<Mode> {
    newton(post, &map::laplace(post, map))
}

/// The log-density in the coordinates z of `start` (x = mean + L z).
struct Whitened<'a, T: LogDensity> {
    target: &'a T,
    start: &'a Elliptical,
}

impl<T: LogDensity> Whitened<'_, T> {
    fn x(&self, z: &DVector<f64>) -> Vec<f64> {
        self.start.point(z.as_slice(), 1.0)
    }

    fn at(&self, zs: &[DVector<f64>]) -> Vec<f64> {
        let points: Vec<f64> = zs.iter().flat_map(|z| self.x(z)).collect();
        log_densities(self.target, &points)
    }

    /// Gradient by central differences: 2 points per axis not held. An
    /// axis whose points leave the support (a mode on a prior's bound) is
    /// held from then on, its component 0.
    fn gradient(&self, z: &DVector<f64>, held: &mut [bool]) -> DVector<f64> {
        let h = GRADIENT_STEP;
        let axes: Vec<usize> = (0..z.len()).filter(|&i| !held[i]).collect();
        let zs: Vec<DVector<f64>> = axes.iter().flat_map(|&i| [-h, h].map(|s| offset(z, &[(i, s)]))).collect();
        let f = self.at(&zs);
        let mut g = DVector::zeros(z.len());
        for (k, &i) in axes.iter().enumerate() {
            match (f[2 * k], f[2 * k + 1]) {
                (a, b) if a.is_finite() && b.is_finite() => g[i] = (b - a) / (2.0 * h),
                _ => held[i] = true,
            }
        }
        g
    }

    /// Hessian by central differences over the axes not held: 2 points per
    /// axis, each mixed derivative from its four points (±h, ±h). The rule
    /// at half the points (each pair's two diagonal points z ± h(eᵢ + eⱼ)
    /// less the axis points, the same order of error) was tried and
    /// dropped: it carries the axis points' rounding into every
    /// off-diagonal entry (about three times the four-point rule's noise),
    /// and on the measured 1 A records with the model terms it put one
    /// principal curvature at 0.075 where the log-density one sd either side
    /// says 0.84 — a Laplace approximation 3.4× too wide in R0, R1, D1,
    /// walkers started far out, and a run of 800 steps instead of about 50
    /// (docs/performance.md, "The Hessian at half the points").
    ///
    /// An axis whose points leave the support is held from then on (of a
    /// pair, the later axis): its row and column are those of the start's
    /// own spread, curvature 1 and no correlation. The discrepancy model
    /// puts a run's white noise σ at the record's resolution, its prior's
    /// lower bound, on the measured damper; without the hold the search gave
    /// up there and the walkers started about the surrogate's optimum, 35
    /// nats below the mode (docs/performance.md).
    fn hessian(&self, z: &DVector<f64>, f0: f64, held: &mut [bool]) -> DMatrix<f64> {
        let h = HESSIAN_STEP;
        let axes: Vec<usize> = (0..z.len()).filter(|&i| !held[i]).collect();
        let mut zs: Vec<DVector<f64>> = axes.iter().flat_map(|&i| [-h, h].map(|s| offset(z, &[(i, s)]))).collect();
        let pairs: Vec<(usize, usize)> = axes.iter().enumerate().flat_map(|(k, &i)| axes[..k].iter().map(move |&j| (i, j))).collect();
        for &(i, j) in &pairs {
            for (si, sj) in [(h, h), (h, -h), (-h, h), (-h, -h)] {
                zs.push(offset(z, &[(i, si), (j, sj)]));
            }
        }
        let f = self.at(&zs);
        let na = axes.len();
        for (k, &i) in axes.iter().enumerate() {
            if !(f[2 * k].is_finite() && f[2 * k + 1].is_finite()) {
                held[i] = true;
            }
        }
        for (k, &(i, j)) in pairs.iter().enumerate() {
            if !held[i] && !held[j] && f[2 * na + 4 * k..2 * na + 4 * k + 4].iter().any(|v| !v.is_finite()) {
                held[i] = true;
            }
        }
        let h2 = h * h;
        let mut hess = DMatrix::from_diagonal_element(z.len(), z.len(), -1.0);
        for (k, &i) in axes.iter().enumerate() {
            if !held[i] {
                hess[(i, i)] = (f[2 * k + 1] - 2.0 * f0 + f[2 * k]) / h2;
            }
        }
        for (k, &(i, j)) in pairs.iter().enumerate() {
            if !held[i] && !held[j] {
                let q = &f[2 * na + 4 * k..2 * na + 4 * k + 4];
                let v = (q[0] - q[1] - q[2] + q[3]) / (4.0 * h2);
                hess[(i, j)] = v;
                hess[(j, i)] = v;
            }
        }
        hess
    }
}

/// Backtracking from the full `step` until the log-density rises by a
/// share of the `gain` the quadratic model expects: the share of the step
/// taken, the point and its log-density.
fn line_search<T: LogDensity>(w: &Whitened<T>, z: &DVector<f64>, f: f64, step: &DVector<f64>, gain: f64) -> Option<(f64, DVector<f64>, f64)> {
    let mut alpha = 1.0;
    for _ in 0..12 {
        let trial = z + step * alpha;
        let ft = w.at(std::slice::from_ref(&trial))[0];
        if ft.is_finite() && ft >= f + 1e-4 * alpha * gain {
            return Some((alpha, trial, ft));
        }
        alpha *= 0.5;
    }
    None
}

/// `z` moved by each listed amount along its coordinate.
fn offset(z: &DVector<f64>, moves: &[(usize, f64)]) -> DVector<f64> {
    let mut y = z.clone();
    for &(i, s) in moves {
        y[i] += s;
    }
    y
}

/// The inverse of the negated Hessian `hess`, every eigenvalue of −hess
/// held at [`MIN_CURVATURE`] or above.
fn covariance(hess: &DMatrix<f64>) -> DMatrix<f64> {
    let eig = SymmetricEigen::new(-hess.clone());
    let inv = eig.eigenvalues.map(|v| 1.0 / v.max(MIN_CURVATURE));
    &eig.eigenvectors * DMatrix::from_diagonal(&inv) * eig.eigenvectors.transpose()
}

/// The mode of `target` and the Laplace approximation there, from `start`
/// (the surrogate's Laplace approximation: its mean is where the search
/// begins, its factor whitens the coordinates). A whitened axis along
/// which the differences leave the support (a mode on a prior's bound) is
/// held where the start put it, with the start's spread; the others reach
/// their mode given it. `None` where the log-density is not finite at the
/// start: the caller keeps the surrogate.
pub fn newton(target: &impl LogDensity, start: &Elliptical) -> Option<Mode> {
    let w = Whitened { target, start };
    let d = start.dim();
    let mut z = DVector::zeros(d);
    let mut f = w.at(std::slice::from_ref(&z))[0];
    if !f.is_finite() {
        return None;
    }
    // the axes whose differences leave the support, held where the start
    // put them (a step is not taken along them)
    let mut held = vec![false; d];
    // the Hessian where the search begins serves the steps until one falls
    // short of its model; the gradient is measured afresh after each, and
    // the search ends where a Hessian measured there expects no gain
    let mut cov = covariance(&w.hessian(&z, f, &mut held));
    let mut fresh = true;
    let mut measured = 1;
    let mut g = w.gradient(&z, &mut held);
    let mut converged = false;
    for _ in 0..MAX_STEPS {
        let step = hold(&cov * &hold(g.clone(), &held), &held);
        let gain = g.dot(&step);
        let moved = if gain < GAIN_TOL { None } else { line_search(&w, &z, f, &step, gain) };
        match moved {
            Some((alpha, trial, ft)) => {
                (z, f, fresh) = (trial, ft, false);
                if alpha < 1.0 && measured < MAX_HESSIANS {
                    (cov, fresh, measured) = (covariance(&w.hessian(&z, f, &mut held)), true, measured + 1);
                }
                g = w.gradient(&z, &mut held);
            }
            // no gain left, or none found, by the curvature measured here
            None if fresh => {
                converged = gain < GAIN_TOL;
                break;
            }
            // … or by one measured elsewhere: measure it here and go on
            None => (cov, fresh, measured) = (covariance(&w.hessian(&z, f, &mut held)), true, measured + 1),
        }
    }
    if !fresh {
        cov = covariance(&w.hessian(&z, f, &mut held));
    }
    let l = start.factor();
    let cov_x = l * cov * l.transpose();
    let factor = cov_x.cholesky()?.l();
    let x = w.x(&z);
    Some(Mode { laplace: Elliptical::from_factor(DVector::from_column_slice(&x), factor), x, log_density: f, converged })
}

/// `v` with its held entries set to 0.
fn hold(mut v: DVector<f64>, held: &[bool]) -> DVector<f64> {
    v.iter_mut().zip(held).filter(|(_, h)| **h).for_each(|(x, _)| *x = 0.0);
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A correlated Gaussian with a known mean and covariance.
    struct Target {
        mean: DVector<f64>,
        precision: DMatrix<f64>,
    }

    impl LogDensity for Target {
        fn dim(&self) -> usize {
            self.mean.len()
        }
        fn log_density(&self, x: &[f64]) -> f64 {
            let r = DVector::from_column_slice(x) - &self.mean;
            -0.5 * (r.transpose() * &self.precision * &r)[(0, 0)]
        }
    }

    fn gaussian() -> (Target, DMatrix<f64>) {
        let cov = DMatrix::from_row_slice(3, 3, &[4.0, 1.2, -0.3, 1.2, 1.0, 0.1, -0.3, 0.1, 0.25]);
        let precision = cov.clone().try_inverse().unwrap();
        (Target { mean: DVector::from_column_slice(&[1.0, -2.0, 0.5]), precision }, cov)
    }

    /// A start 3 target sds off in every coordinate, its scale half the
    /// target's and without the correlations.
    fn poor_start() -> Elliptical {
        Elliptical::from_factor(DVector::from_column_slice(&[7.0, 1.0, -1.0]), DMatrix::from_diagonal(&DVector::from_column_slice(&[1.0, 0.5, 0.25])))
    }

    #[test]
    fn finds_the_mode_and_covariance_of_a_gaussian() {
        // a quadratic log-density: central differences are exact up to
        // rounding, so the mode and covariance come out to 1e-6
        let (target, cov) = gaussian();
        let mode = newton(&target, &poor_start()).unwrap();
        for (a, b) in mode.x.iter().zip(target.mean.iter()) {
            assert!((a - b).abs() < 1e-6, "mode {:?}", mode.x);
        }
        let got = mode.laplace.covariance();
        assert!((got - &cov).abs().max() < 1e-6, "covariance {}", mode.laplace.covariance());
        assert!(mode.log_density.abs() < 1e-9);
    }

    #[test]
    fn finds_the_mode_of_a_skewed_density() {
        // f = a x₀ − e^(x₀) − 2 (x₁ − x₀)² − x₂²/2: a log-gamma margin in x₀,
        // x₁ tied to it. The gradient vanishes at x₀ = x₁ = ln a, x₂ = 0,
        // where the Hessian is [[−a − 4, 4, 0], [4, −4, 0], [0, 0, −1]]. The
        // search stops once a Newton step would gain less than GAIN_TOL,
        // within √GAIN_TOL = 0.1 sd of the mode; the sd of x₀ is
        // √(4/12) = 0.58 (the inverse Hessian), so the tolerance is 0.06 in
        // x₀ and x₁ (the central differences' bias, ln(1 + h²/6) ≈ 4e-4 at
        // h = GRADIENT_STEP, is far below it). The start is 3.6 sd away.
        struct Skewed;
        const A: f64 = 3.0;
        impl LogDensity for Skewed {
            fn dim(&self) -> usize {
                3
            }
            fn log_density(&self, x: &[f64]) -> f64 {
                A * x[0] - x[0].exp() - 2.0 * (x[1] - x[0]).powi(2) - 0.5 * x[2] * x[2]
            }
        }
        let start = Elliptical::from_factor(DVector::from_column_slice(&[-1.0, 0.5, 2.0]), DMatrix::identity(3, 3));
        let mode = newton(&Skewed, &start).unwrap();
        let expected = [A.ln(), A.ln(), 0.0];
        for (a, b) in mode.x.iter().zip(expected) {
            assert!((a - b).abs() < 0.06, "mode {:?}", mode.x);
        }
        assert!(mode.converged);
        // the curvature at the mode found: e^(x₀) + 4 in the first entry,
        // e^(x₀) within a (e^0.06 − 1) = 0.19 of a, times 1 + h²/12 = 1.005
        // over ±HESSIAN_STEP: within 0.21 = 3 % of a + 4; the rest exact
        let precision = mode.laplace.covariance().try_inverse().unwrap();
        let exact = DMatrix::from_row_slice(3, 3, &[A + 4.0, -4.0, 0.0, -4.0, 4.0, 0.0, 0.0, 0.0, 1.0]);
        assert!((precision - &exact).abs().max() < 0.03 * (A + 4.0), "precision {}", mode.laplace.covariance().try_inverse().unwrap());
    }

    #[test]
    fn a_coordinate_on_its_bound_is_held_and_the_rest_reach_their_conditional_mode() {
        // the correlated Gaussian of `gaussian()` cut at x₂ ≥ 0.45 (its
        // mean 0.5 lies inside, but the start sits at 0.46, within one
        // difference step of the cut): x₂ is held at 0.46 and (x₀, x₁)
        // reach the Gaussian's conditional mean given x₂, m₀₁ +
        // Σ₀₁,₂ Σ₂₂⁻¹ (x₂ − m₂) (exact for a quadratic: 1e-6); x₂ keeps
        // the start's variance and no correlation
        struct Cut(Target);
        impl LogDensity for Cut {
            fn dim(&self) -> usize {
                3
            }
            fn log_density(&self, x: &[f64]) -> f64 {
                if x[2] < 0.45 { f64::NEG_INFINITY } else { self.0.log_density(x) }
            }
        }
        let (target, cov) = gaussian();
        let mean = target.mean.clone();
        let start = Elliptical::from_factor(DVector::from_column_slice(&[2.0, -1.0, 0.46]), DMatrix::from_diagonal(&DVector::from_column_slice(&[1.0, 0.5, 0.25])));
        let mode = newton(&Cut(target), &start).unwrap();
        let dx2 = 0.46 - mean[2];
        for i in 0..2 {
            let expected = mean[i] + cov[(i, 2)] / cov[(2, 2)] * dx2;
            assert!((mode.x[i] - expected).abs() < 1e-6, "mode {:?}, expected {expected} at {i}", mode.x);
        }
        assert_eq!(mode.x[2], 0.46);
        let got = mode.laplace.covariance();
        assert!((got[(2, 2)] - 0.0625).abs() < 1e-12 && got[(0, 2)].abs() < 1e-12 && got[(1, 2)].abs() < 1e-12, "covariance {got}");
    }

    #[test]
    fn a_flat_direction_keeps_a_bounded_spread() {
        // no information on the third coordinate: its sd is held at
        // 1/√MIN_CURVATURE start sds, not infinite
        struct Flat;
        impl LogDensity for Flat {
            fn dim(&self) -> usize {
                2
            }
            fn log_density(&self, x: &[f64]) -> f64 {
                -0.5 * x[0] * x[0]
            }
        }
        let start = Elliptical::from_factor(DVector::from_column_slice(&[0.5, 0.0]), DMatrix::identity(2, 2));
        let mode = newton(&Flat, &start).unwrap();
        let cov = mode.laplace.covariance();
        assert!((cov[(0, 0)] - 1.0).abs() < 1e-6);
        assert!((cov[(1, 1)] - 1.0 / MIN_CURVATURE).abs() < 1e-6);
    }

    #[test]
    fn the_hessian_rule_is_exact_to_cubic_order_and_for_a_product_quartic() {
        // f = −½ xᵀ P x + b x₀³ + c x₀² x₁² at z = (0.3, −0.2, 0.1) (start:
        // the origin, unit factor, so z = x). Analytic Hessian:
        // H₀₀ = −P₀₀ + 6b x₀ + 2c x₁², H₁₁ = −P₁₁ + 2c x₀², H₀₁ = −P₀₁ + 4c x₀x₁,
        // the rest −P. Central differences are exact for the cubic term and,
        // on the diagonal, for the quartic one (f₀₀₀₀ = f₁₁₁₁ = 0); the
        // four-point mixed difference of c x₀² x₁² factorises into two
        // central first differences, each exact for a square: exact too
        // (the two-point diagonal rule errs there by h² c).
        struct Quartic;
        const B: f64 = 0.7;
        const C: f64 = -0.4;
        const P: [[f64; 3]; 3] = [[2.0, 0.5, -0.2], [0.5, 1.0, 0.3], [-0.2, 0.3, 0.8]];
        impl LogDensity for Quartic {
            fn dim(&self) -> usize {
                3
            }
            fn log_density(&self, x: &[f64]) -> f64 {
                let quad: f64 = (0..3).flat_map(|i| (0..3).map(move |j| x[i] * P[i][j] * x[j])).sum();
                -0.5 * quad + B * x[0].powi(3) + C * x[0].powi(2) * x[1].powi(2)
            }
        }
        let start = Elliptical::from_factor(DVector::zeros(3), DMatrix::identity(3, 3));
        let w = Whitened { target: &Quartic, start: &start };
        let z = DVector::from_column_slice(&[0.3, -0.2, 0.1]);
        let f0 = Quartic.log_density(z.as_slice());
        let got = w.hessian(&z, f0, &mut [false; 3]);
        let (x0, x1) = (z[0], z[1]);
        let mut exact = DMatrix::from_fn(3, 3, |i, j| -P[i][j]);
        exact[(0, 0)] += 6.0 * B * x0 + 2.0 * C * x1 * x1;
        exact[(1, 1)] += 2.0 * C * x0 * x0;
        exact[(0, 1)] += 4.0 * C * x0 * x1;
        exact[(1, 0)] = exact[(0, 1)];
        // rounding: a few ε of |f| over h² (~1e-14 / 0.0625)
        assert!((&got - &exact).abs().max() < 1e-12, "Hessian {got}, exact {exact}");
    }
}
