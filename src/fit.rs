//! Nonlinear least squares by Levenberg-Marquardt (the `levenberg-marquardt`
//! crate), for problems given as closures.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt, TerminationReason};
use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};

/// The outcome of a fit.
#[derive(Clone, Debug)]
pub struct Fit {
    pub params: Vec<f64>,
    /// ½ Σ r² at `params`.
    pub cost: f64,
    /// Whether the solver reported success (not a numerical failure or the
    /// evaluation budget).
    pub converged: bool,
    /// Whether it stopped on its budget of evaluations.
    pub exhausted: bool,
    pub message: String,
}

type Residuals<'a> = dyn Fn(&[f64]) -> Option<Vec<f64>> + 'a;
type Jacobian<'a> = dyn Fn(&[f64]) -> Option<DMatrix<f64>> + 'a;

struct ClosureProblem<'a> {
    p: DVector<f64>,
    residuals: &'a Residuals<'a>,
    jacobian: Option<&'a Jacobian<'a>>,
    /// Length and largest |r| of the last feasible residual vector: an
    /// infeasible point gets residuals far larger, so the solver rejects the
    /// step and shrinks its trust region instead of stopping.
    last: std::cell::Cell<(usize, f64)>,
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for ClosureProblem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, p: &DVector<f64>) {
        self.p.copy_from(p);
    }

    fn params(&self) -> DVector<f64> {
        self.p.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        match (self.residuals)(self.p.as_slice()) {
            Some(r) if r.iter().all(|v| v.is_finite()) => {
                let big = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                self.last.set((r.len(), big));
                Some(DVector::from_vec(r))
            }
            _ => {
                let (len, big) = self.last.get();
                (len > 0).then(|| DVector::from_element(len, 1e6 * (big + 1.0)))
            }
        }
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        match self.jacobian {
            Some(j) => j(self.p.as_slice()).filter(|m| m.iter().all(|v| v.is_finite())),
            None => forward_difference(self.residuals, self.p.as_slice()),
        }
    }
}

/// Jacobian by forward differences with step √ε·(1 + |p|) per parameter.
fn forward_difference(residuals: &Residuals, p: &[f64]) -> Option<DMatrix<f64>> {
    let r0 = residuals(p)?;
    let mut jac = DMatrix::zeros(r0.len(), p.len());
    let mut q = p.to_vec();
    for j in 0..p.len() {
        let h = 1.5e-8 * (1.0 + p[j].abs());
        q[j] = p[j] + h;
        let r1 = residuals(&q)?;
        q[j] = p[j];
        for i in 0..r0.len() {
            jac[(i, j)] = (r1[i] - r0[i]) / h;
        }
    }
    Some(jac)
}

/// Minimises ½ Σ rᵢ(p)² from `start`. `jacobian` may be `None` for forward
/// differences. A residual function that returns `None` or a non-finite
/// value marks the point as infeasible; the solver then backs off. Stops
/// where the solver's own tolerances (30 ε, relative) are met.
pub fn least_squares(start: &[f64], residuals: &Residuals, jacobian: Option<&Jacobian>) -> Fit {
    solve(start, residuals, jacobian, LevenbergMarquardt::new().with_patience(PATIENCE))
}

/// The solver's budget: at most `PATIENCE` (n + 1) evaluations of the
/// residuals for n parameters.
pub const PATIENCE: usize = 200;

/// [`least_squares`], stopping once a step lowers ½ Σ r² by a share of
/// at most `ftol` and the model predicts no more (MINPACK's test; its
/// recommended value is √ε ≈ 1.5e-8). For residuals that carry an
/// integrator's rounding, tolerances near ε are never met by a real
/// gain: the solver creeps on for hundreds of iterations. At most
/// `patience` (n + 1) evaluations ([`PATIENCE`] unless a search screens
/// its starts with less): a fit stopped by that budget is not
/// [`Fit::converged`].
pub fn least_squares_to(
    ftol: f64,
    patience: usize,
    start: &[f64],
    residuals: &Residuals,
    jacobian: Option<&Jacobian>,
) -> Fit {
    let solver = LevenbergMarquardt::new().with_ftol(ftol).with_patience(patience);
    solve(start, residuals, jacobian, solver)
}

fn solve(
    start: &[f64],
    residuals: &Residuals,
    jacobian: Option<&Jacobian>,
    solver: LevenbergMarquardt<f64>,
) -> Fit {
    let problem = ClosureProblem {
        p: DVector::from_column_slice(start),
        residuals,
        jacobian,
        last: std::cell::Cell::new((0, 0.0)),
    };
    let (problem, report) = solver.minimize(problem);
    Fit {
        params: problem.p.as_slice().to_vec(),
        cost: report.objective_function,
        converged: report.termination.was_successful(),
        exhausted: matches!(report.termination, TerminationReason::LostPatience),
        message: format!("{:?}", report.termination),
    }
}

/// The point of [a, b] where `f` is least, by `iterations` golden-section
/// steps (f unimodal there; each step shrinks the interval by 0.618).
pub fn golden_section(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64, iterations: usize) -> f64 {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..iterations {
        let (c, d) = (b - g * (b - a), a + g * (b - a));
        if f(c) < f(d) {
            b = d;
        } else {
            a = c;
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock's valley from (−1.2, 1): a budget of 2 × 3 evaluations
    /// stops the fit far from (1, 1), says so, and does not call it
    /// converged; the full budget reaches (1, 1).
    #[test]
    fn a_fit_stopped_by_its_budget_says_so() {
        let res = |p: &[f64]| Some(vec![10.0 * (p[1] - p[0] * p[0]), 1.0 - p[0]]);
        let short = least_squares_to(1.49e-8, 2, &[-1.2, 1.0], &res, None);
        assert!(short.exhausted && !short.converged, "{}", short.message);
        assert!((short.params[0] - 1.0).abs() > 0.1, "{:?}", short.params);
        let full = least_squares_to(1.49e-8, PATIENCE, &[-1.2, 1.0], &res, None);
        assert!(full.converged && !full.exhausted, "{}", full.message);
        assert!((full.params[0] - 1.0).abs() < 1e-6 && (full.params[1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn fits_an_exponential_with_and_without_jacobian() {
        // y = 3 exp(−0.5 x) exactly: the fit must recover (3, −0.5)
        let x: Vec<f64> = (0..20).map(|i| i as f64 * 0.3).collect();
        let y: Vec<f64> = x.iter().map(|x| 3.0 * (-0.5 * x).exp()).collect();
        let res =
            |p: &[f64]| Some(x.iter().zip(&y).map(|(x, y)| p[0] * (p[1] * x).exp() - y).collect());
        let jac = |p: &[f64]| {
            Some(DMatrix::from_fn(x.len(), 2, |i, j| {
                if j == 0 {
                    (p[1] * x[i]).exp()
                } else {
                    p[0] * x[i] * (p[1] * x[i]).exp()
                }
            }))
        };
        for fit in
            [least_squares(&[1.0, -0.1], &res, Some(&jac)), least_squares(&[1.0, -0.1], &res, None)]
        {
            assert!(fit.converged, "{}", fit.message);
            assert!(
                (fit.params[0] - 3.0).abs() < 1e-6 && (fit.params[1] + 0.5).abs() < 1e-6,
                "{:?}",
                fit.params
            );
        }
    }
}
