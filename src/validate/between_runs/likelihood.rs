//! One run's likelihood as the between-run layer takes it: the normal of
//! its calibration's draws in the layer's coordinates, with the prior under
//! which they were drawn divided out.

use nalgebra::{Cholesky, DMatrix, DVector};

/// One run's likelihood in the layer's coordinates, as a normal:
/// ln L(z) = −½ zᵀ Λ z + bᵀ z + const.
#[derive(Clone, Debug, PartialEq)]
pub struct RunLikelihood {
    pub precision: DMatrix<f64>,
    pub shift: DVector<f64>,
}

/// The smallest eigenvalue a run's likelihood precision keeps, relative to
/// the posterior's largest: a direction the record does not determine
/// carries (almost) nothing.
const FLAT: f64 = 1e-8;

impl RunLikelihood {
    /// From draws `points` of the run's posterior under its prior, ln p₀ =
    /// `log_prior`, whose finite-difference steps are `steps` per
    /// coordinate: the posterior's moments, p₀'s gradient g and curvature
    /// P₀ at their mean m divided out (Λ = C⁻¹ − P₀ with its eigenvalues
    /// kept positive, b = Λ m − g). `None` with fewer draws than two per
    /// coordinate.
    pub fn from_draws(
        points: &[Vec<f64>],
        log_prior: &dyn Fn(&[f64]) -> f64,
        steps: &[f64],
    ) -> Option<RunLikelihood> {
        let d = steps.len();
        if points.len() < 2 * d + 2 {
            return None;
        }
        let flat: Vec<f64> = points.iter().flatten().copied().collect();
        let moments = crate::sampler::Moments::of(&flat, d);
        let posterior = Cholesky::new(moments.cov.clone())?.inverse();
        let m = moments.mean;
        let f = |z: &DVector<f64>| log_prior(z.as_slice());
        let at = |k: usize, h: f64| {
            let mut z = m.clone();
            z[k] += h;
            z
        };
        let f0 = f(&m);
        let mut gradient = DVector::zeros(d);
        let mut curvature = DMatrix::zeros(d, d);
        if f0.is_finite() {
            for k in 0..d {
                let (fp, fm) = (f(&at(k, steps[k])), f(&at(k, -steps[k])));
                if fp.is_finite() && fm.is_finite() {
                    gradient[k] = (fp - fm) / (2.0 * steps[k]);
                    curvature[(k, k)] = -(fp - 2.0 * f0 + fm) / (steps[k] * steps[k]);
                }
                for j in 0..k {
                    let corner = |a: f64, b: f64| {
                        let mut z = m.clone();
                        z[k] += a * steps[k];
                        z[j] += b * steps[j];
                        f(&z)
                    };
                    let v = (corner(1.0, 1.0) - corner(1.0, -1.0) - corner(-1.0, 1.0)
                        + corner(-1.0, -1.0))
                        / (4.0 * steps[k] * steps[j]);
                    if v.is_finite() {
                        curvature[(k, j)] = -v;
                        curvature[(j, k)] = -v;
                    }
                }
            }
        }
        let eigen = nalgebra::SymmetricEigen::new(&posterior - &curvature);
        let floor = FLAT * nalgebra::SymmetricEigen::new(posterior.clone()).eigenvalues.max();
        let values = eigen.eigenvalues.map(|v| v.max(floor));
        let precision =
            &eigen.eigenvectors * DMatrix::from_diagonal(&values) * eigen.eigenvectors.transpose();
        let shift = &precision * &m - gradient;
        Some(RunLikelihood { precision, shift })
    }
}
