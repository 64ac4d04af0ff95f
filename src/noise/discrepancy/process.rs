//! The discrepancy's process: a Matérn Gaussian process in time as an
//! exact linear state-space model (Hartikainen & Särkkä 2010) — (δ, δ′) for
//! ν = 3/2, δ alone for ν = 1/2 — its transition and noise over a step,
//! its stationary state, and paths drawn from it (the virtual stand's
//! known discrepancy).

use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use crate::noise::model::Kernel;

/// A path of the Matérn process of scale `sd` and time scale `ell` at the
/// times `time`, started from its stationary state: exact at any spacing
/// (the virtual stand's known discrepancy, `mrbp synth`).
pub fn sample_path(
    kernel: Kernel,
    sd: f64,
    ell: f64,
    time: &[f64],
    rng: &mut impl Rng,
) -> Vec<f64> {
    let mut process = Process::new(kernel, sd, ell, 0.0);
    let mut z = || -> f64 { rng.sample(StandardNormal) };
    let mut state = process.draw_start(z(), z());
    let mut path = Vec::with_capacity(time.len());
    for (k, t) in time.iter().enumerate() {
        if k > 0 {
            process.step(t - time[k - 1]);
            state = process.advance(process.noise_factor(), state, z(), z());
        }
        path.push(state[0]);
    }
    path
}

/// The Matérn process in state-space form at one time step: its transition
/// Φ, the noise Q it gathers over the step and its stationary covariance
/// P∞ (ν = 1/2 uses the first state only).
#[derive(Clone, Copy, Debug)]
pub(super) struct Process {
    kernel: Kernel,
    sd: f64,
    /// λ = √3/ℓ (ν = 3/2) or 1/ℓ (ν = 1/2).
    lambda: f64,
    pub(super) phi: [[f64; 2]; 2],
    pub(super) q: [f64; 3],
}

impl Process {
    pub(super) fn new(kernel: Kernel, sd: f64, ell: f64, dt: f64) -> Process {
        let lambda = match kernel {
            Kernel::Matern12 => 1.0 / ell,
            Kernel::Matern32 => 3f64.sqrt() / ell,
        };
        let mut p = Process { kernel, sd, lambda, phi: [[0.0; 2]; 2], q: [0.0; 3] };
        p.step(dt);
        p
    }

    /// Sets Φ and Q for a step of `dt`.
    pub(super) fn step(&mut self, dt: f64) {
        let (s2, l) = (self.sd * self.sd, self.lambda);
        let x = l * dt;
        let e = (-x).exp();
        let e2 = e * e;
        match self.kernel {
            Kernel::Matern12 => {
                self.phi = [[e, 0.0], [0.0, 0.0]];
                self.q = [-s2 * (-2.0 * x).exp_m1(), 0.0, 0.0];
            }
            Kernel::Matern32 => {
                self.phi = [[e * (1.0 + x), e * dt], [-e * l * x, e * (1.0 - x)]];
                // 1 − e^{−2x}(1 + 2x + 2x²) = 4x³/3 − 2x⁴ + 8x⁵/5 − …
                let q00 = if x < 1e-3 {
                    x * x * x * (4.0 / 3.0 - 2.0 * x + 1.6 * x * x)
                } else {
                    -(-2.0 * x).exp_m1() - e2 * (2.0 * x + 2.0 * x * x)
                };
                let q11 = -(-2.0 * x).exp_m1() + e2 * (2.0 * x - 2.0 * x * x);
                self.q = [s2 * q00, 2.0 * s2 * l * x * x * e2, s2 * l * l * q11];
            }
        }
    }

    /// The Cholesky factor of Q: (l00, l10, l11).
    pub(super) fn noise_factor(&self) -> [f64; 3] {
        let [q00, q01, q11] = self.q;
        let l00 = q00.max(0.0).sqrt();
        let l10 = if l00 > 0.0 { q01 / l00 } else { 0.0 };
        [l00, l10, (q11 - l10 * l10).max(0.0).sqrt()]
    }

    /// A draw of (δ, δ′) from the stationary state, given two standard
    /// normals.
    pub(super) fn draw_start(&self, z0: f64, z1: f64) -> [f64; 2] {
        let [p00, _, p11] = self.stationary();
        [p00.sqrt() * z0, p11.sqrt() * z1]
    }

    /// (δ, δ′) one step on from `x`, given two standard normals and the
    /// Cholesky factor `l` of Q ([`Self::noise_factor`], computed once per
    /// step by a caller that advances many paths).
    #[inline(always)]
    pub(super) fn advance(&self, l: [f64; 3], x: [f64; 2], z0: f64, z1: f64) -> [f64; 2] {
        let [[a, b], [c, d]] = self.phi;
        [a * x[0] + b * x[1] + l[0] * z0, c * x[0] + d * x[1] + l[1] * z0 + l[2] * z1]
    }

    /// The stationary covariance (p00, p01, p11).
    pub(super) fn stationary(&self) -> [f64; 3] {
        let s2 = self.sd * self.sd;
        match self.kernel {
            Kernel::Matern12 => [s2, 0.0, 0.0],
            Kernel::Matern32 => [s2, 0.0, s2 * self.lambda * self.lambda],
        }
    }
}
