//! The centres' curve in the coil current: how the between-run layer ties
//! the typical test of each current to its neighbours', and predicts a
//! current no run was calibrated at.

use nalgebra::{Cholesky, DMatrix, DVector};
use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

/// The current's coordinate along the centres' curve: asinh(I / I_s),
/// I_s = [`CURRENT_SCALE_A`] — ln(2I/I_s) above a few tenths of an ampere
/// (a power law in the current is a line), finite and smooth down to 0 A.
pub fn current_coordinate(current_a: f64) -> f64 {
    (current_a / CURRENT_SCALE_A).asinh()
}

/// The current (A) below which the centres' curve stops being a power law.
pub const CURRENT_SCALE_A: f64 = 0.1;

/// The centres' curve: the GP residual's length scale, in the current's
/// coordinate (about 1.4 doublings of the current).
const CURVE_LENGTH: f64 = 1.0;

/// Prior sd of the GP residual's amplitude η_k, in units of the
/// coordinate's prior scale (half-normal): a departure from a power law
/// of half an e-fold over the currents at one prior sd.
pub(super) const CURVE_AMPLITUDE: f64 = 0.5;

/// Prior sd of the curve's level and slope, in units of the coordinate's
/// prior scale: flat for every purpose.
const CURVE_FLAT: f64 = 100.0;

/// How the centres of the currents are tied: each coordinate k follows a
/// curve in the current's coordinate x ([`current_coordinate`]),
/// μ_k(x) = a_k + b_k x + f_k(x), a_k and b_k flat, f_k a Gaussian process
/// of amplitude η_k ~ half-normal(0, ½ A_k) and length scale 1.
#[derive(Clone, Debug, PartialEq)]
pub struct CurrentCurve {
    /// x of each calibrated current (group), in the groups' order.
    pub x: Vec<f64>,
    /// x of the currents to predict.
    pub predict: Vec<f64>,
}

impl CurrentCurve {
    /// The prior covariance of f + a + b x between `xs` and `ys` for
    /// amplitude `eta`, the coordinate's prior scale `scale` (x centred on
    /// the calibrated currents' mean).
    pub(super) fn covariance(&self, xs: &[f64], ys: &[f64], eta: f64, scale: f64) -> DMatrix<f64> {
        let centre = self.x.iter().sum::<f64>() / self.x.len() as f64;
        let flat = (CURVE_FLAT * scale).powi(2);
        DMatrix::from_fn(xs.len(), ys.len(), |i, j| {
            let (u, v) = (xs[i] - centre, ys[j] - centre);
            eta * eta * (-(u - v).powi(2) / (2.0 * CURVE_LENGTH * CURVE_LENGTH)).exp()
                + flat * (1.0 + u * v)
        })
    }

    /// The prior precision of every calibrated centre at once (current-major:
    /// current c, coordinate k at c·d + k) given the amplitudes `eta`: each
    /// coordinate's curve across the currents.
    pub(super) fn precision(&self, eta: &[f64], scales: &[f64]) -> DMatrix<f64> {
        let (groups, d) = (self.x.len(), eta.len());
        let mut p = DMatrix::zeros(groups * d, groups * d);
        for k in 0..d {
            let kk = self.covariance(&self.x, &self.x, eta[k], scales[k])
                + DMatrix::identity(groups, groups) * (1e-10 * scales[k] * scales[k]);
            let inverse =
                Cholesky::new(kk).map_or_else(|| DMatrix::zeros(groups, groups), |c| c.inverse());
            for g in 0..groups {
                for q in 0..groups {
                    p[(g * d + k, q * d + k)] = inverse[(g, q)];
                }
            }
        }
        p
    }

    /// ln p(μ_k at the calibrated currents | η) + ln p(η) + ln η, at u = ln η.
    pub(super) fn log_amplitude_density(&self, u: f64, mu: &DVector<f64>, scale: f64) -> f64 {
        let eta = u.exp();
        let k = self.covariance(&self.x, &self.x, eta, scale)
            + DMatrix::identity(self.x.len(), self.x.len()) * (1e-10 * scale * scale);
        let Some(chol) = Cholesky::new(k) else { return f64::NEG_INFINITY };
        let log_det: f64 = chol.l().diagonal().iter().map(|v| 2.0 * v.ln()).sum();
        -0.5 * log_det
            - 0.5 * mu.dot(&chol.solve(mu))
            - 0.5 * (eta / (CURVE_AMPLITUDE * scale)).powi(2)
            + u
    }
}

/// The centres at the curve's predicted currents given those at the
/// calibrated ones: for each coordinate, the Gaussian process's
/// conditional (the level and slope integrated over their flat prior).
pub(super) fn predict_centres(
    curve: &CurrentCurve,
    means: &[DVector<f64>],
    eta: &[f64],
    scales: &[f64],
    rng: &mut impl Rng,
) -> Vec<DVector<f64>> {
    let (c, p, d) = (curve.x.len(), curve.predict.len(), eta.len());
    let mut out = vec![DVector::<f64>::zeros(d); p];
    for k in 0..d {
        let jitter = 1e-10 * scales[k] * scales[k];
        let kxx = curve.covariance(&curve.x, &curve.x, eta[k], scales[k])
            + DMatrix::identity(c, c) * jitter;
        let kxs = curve.covariance(&curve.x, &curve.predict, eta[k], scales[k]);
        let kss = curve.covariance(&curve.predict, &curve.predict, eta[k], scales[k])
            + DMatrix::identity(p, p) * jitter;
        let Some(chol) = Cholesky::new(kxx) else { continue };
        let mu = DVector::from_iterator(c, means.iter().map(|m| m[k]));
        let mean = kxs.transpose() * chol.solve(&mu);
        let cov = &kss - kxs.transpose() * chol.solve(&kxs);
        let e = DVector::from_iterator(p, (0..p).map(|_| rng.sample::<f64, _>(StandardNormal)));
        let draw = mean + crate::numeric::draw_factor(&((&cov + cov.transpose()) * 0.5)) * e;
        for (j, o) in out.iter_mut().enumerate() {
            o[k] = draw[j];
        }
    }
    out
}
