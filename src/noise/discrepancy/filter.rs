//! The discrepancy's Kalman filter along a run's residuals: the state
//! (δ, δ′, b) — b the branch's strain offset under errors in variables,
//! drawn afresh at every reversal — its one-step-ahead innovations (the
//! likelihood, O(n) per run), and the Rauch–Tung–Striebel smoother of the
//! discrepancy's path (what the report draws).

use super::process::Process;
use crate::data::RunData;
use crate::noise::model::Explained;

/// The Kalman filter of one path: the state (δ, δ′, b) — b the branch's
/// strain offset — its mean and covariance.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Filter {
    m: [f64; 3],
    /// p00, p01, p11, p0b, p1b, pbb.
    p: [f64; 6],
}

impl Filter {
    /// At the stationary state of `process`, before the first sample.
    pub(super) fn start(process: &Process) -> Filter {
        let [p00, p01, p11] = process.stationary();
        Filter { m: [0.0; 3], p: [p00, p01, p11, 0.0, 0.0, 0.0] }
    }

    /// One step of `process`, and a fresh branch offset of variance `v`
    /// where a branch begins.
    #[inline(always)]
    pub(super) fn predict(&mut self, process: &Process, new_branch: Option<f64>) {
        let [[a, b], [c, d]] = process.phi;
        let [p00, p01, p11, p0b, p1b, pbb] = self.p;
        let (m0, m1) = (self.m[0], self.m[1]);
        self.m[0] = a * m0 + b * m1;
        self.m[1] = c * m0 + d * m1;
        // Φ P Φᵀ + Q on the process block
        let (r00, r01) = (a * p00 + b * p01, a * p01 + b * p11);
        let (r10, r11) = (c * p00 + d * p01, c * p01 + d * p11);
        let q = process.q;
        self.p[0] = r00 * a + r01 * b + q[0];
        self.p[1] = r00 * c + r01 * d + q[1];
        self.p[2] = r10 * c + r11 * d + q[2];
        match new_branch {
            Some(v) => {
                self.m[2] = 0.0;
                self.p[3] = 0.0;
                self.p[4] = 0.0;
                self.p[5] = v;
            }
            None => {
                self.p[3] = a * p0b + b * p1b;
                self.p[4] = c * p0b + d * p1b;
                self.p[5] = pbb;
            }
        }
    }

    /// Takes the residual `r` (observed δ + c b + e, e of variance `white`):
    /// returns the innovation and its variance.
    #[inline(always)]
    pub(super) fn update(&mut self, r: f64, c: f64, white: f64) -> (f64, f64) {
        let [p00, p01, p11, p0b, p1b, pbb] = self.p;
        let h = [p00 + c * p0b, p01 + c * p1b, p0b + c * pbb];
        let s = h[0] + c * h[2] + white;
        let v = r - self.m[0] - c * self.m[2];
        let k = [h[0] / s, h[1] / s, h[2] / s];
        self.m[0] += k[0] * v;
        self.m[1] += k[1] * v;
        self.m[2] += k[2] * v;
        self.p = [
            (p00 - k[0] * h[0]).max(0.0),
            p01 - k[0] * h[1],
            (p11 - k[1] * h[1]).max(0.0),
            p0b - k[0] * h[2],
            p1b - k[1] * h[2],
            (pbb - k[2] * h[2]).max(0.0),
        ];
        (v, s)
    }
}

/// The variance of the strain error's offset drawn afresh where sample k of
/// `run` begins a loading branch (the first compared sample, or a
/// reversal), with errors in variables of variance `strain_var`.
#[inline(always)]
pub(super) fn branch_start(run: &RunData, k: usize, strain_var: f64) -> Option<f64> {
    (strain_var > 0.0 && (k == 1 || run.reverses[k]))
        .then_some(strain_var * run.strain_smoothing_share)
}

/// The filter's innovations along a run: for each sample k ≥ 1 of the
/// residuals `r` (indexed from k = 1) the innovation and its variance.
pub(super) fn filter_run(
    run: &RunData,
    process: &Process,
    sigma: f64,
    strain_var: f64,
    stiffness: Option<&[f64]>,
    r: &[f64],
    mut visit: impl FnMut(usize, f64, f64),
) {
    let mut f = Filter::start(process);
    let mut step = *process;
    for (i, &res) in r.iter().enumerate() {
        let k = i + 1;
        if !run.uniform {
            step.step(run.time[k] - run.time[k - 1]);
        }
        let c = stiffness.map_or(0.0, |s| s[k]);
        f.predict(&step, branch_start(run, k, strain_var));
        let (v, s) = f.update(res, c, sigma * sigma + c * c * strain_var);
        visit(k, v, s);
    }
}

/// The Rauch–Tung–Striebel smoother of [`filter_run`]'s filter, on the full
/// state (δ, δ′, b) with explicit matrices: a branch start makes b afresh
/// (its transition 0, its noise the offset's variance). Singular predicted
/// covariances (ν = 1/2 uses one state; no errors in variables, no b) are
/// inverted by SVD.
pub(super) fn smooth_run(
    run: &RunData,
    process: &Process,
    sigma: f64,
    strain_var: f64,
    stiffness: Option<&[f64]>,
    r: &[f64],
) -> Explained {
    use nalgebra::{Matrix3, RowVector3, Vector3};
    let n = r.len();
    let mut step = *process;
    let [p00, p01, p11] = process.stationary();
    let mut m = Vector3::zeros();
    let mut p = Matrix3::new(p00, p01, 0.0, p01, p11, 0.0, 0.0, 0.0, 0.0);
    let mut predicted: Vec<(Vector3<f64>, Matrix3<f64>, Matrix3<f64>)> = Vec::with_capacity(n);
    let mut filtered: Vec<(Vector3<f64>, Matrix3<f64>)> = Vec::with_capacity(n);
    let mut innovations = Vec::with_capacity(n);
    for (i, &res) in r.iter().enumerate() {
        let k = i + 1;
        if !run.uniform {
            step.step(run.time[k] - run.time[k - 1]);
        }
        let [[a, b], [c, d]] = step.phi;
        let [q00, q01, q11] = step.q;
        let branch = branch_start(run, k, strain_var);
        let phi =
            Matrix3::new(a, b, 0.0, c, d, 0.0, 0.0, 0.0, if branch.is_some() { 0.0 } else { 1.0 });
        let q = Matrix3::new(q00, q01, 0.0, q01, q11, 0.0, 0.0, 0.0, branch.unwrap_or(0.0));
        let (mp, pp) = (phi * m, phi * p * phi.transpose() + q);
        let cs = stiffness.map_or(0.0, |s| s[k]);
        let h = RowVector3::new(1.0, 0.0, cs);
        let ph = pp * h.transpose();
        let s = (h * ph)[(0, 0)] + sigma * sigma + cs * cs * strain_var;
        let v = res - (h * mp)[(0, 0)];
        let gain = ph / s;
        m = mp + gain * v;
        p = pp - gain * ph.transpose();
        innovations.push(v / s.sqrt());
        predicted.push((mp, pp, phi));
        filtered.push((m, p));
    }
    let (mut mean, mut sd) = (vec![0.0; n], vec![0.0; n]);
    let Some(&(mut ms, mut ps)) = filtered.last() else {
        return Explained::default();
    };
    for i in (0..n).rev() {
        if i + 1 < n {
            let (mf, pf) = filtered[i];
            let (mp, pp, phi) = predicted[i + 1];
            let inverse = scaled_inverse(&pp);
            let g = pf * phi.transpose() * inverse;
            ms = mf + g * (ms - mp);
            ps = pf + g * (ps - pp) * g.transpose();
        }
        mean[i] = ms[0];
        sd[i] = ps[(0, 0)].max(0.0).sqrt();
    }
    Explained { mean, sd, innovations }
}

/// The (pseudo-)inverse of a covariance whose states differ in scale by many
/// orders (δ in Pa, δ′ in Pa/s, b in strain): inverted as a correlation
/// matrix, by SVD, so a state without variance (unused) drops out.
fn scaled_inverse(p: &nalgebra::Matrix3<f64>) -> nalgebra::Matrix3<f64> {
    let scale =
        nalgebra::Vector3::from_fn(
            |i, _| if p[(i, i)] > 0.0 { 1.0 / p[(i, i)].sqrt() } else { 0.0 },
        );
    let d = nalgebra::Matrix3::from_diagonal(&scale);
    let correlation = d * p * d;
    let inverse = correlation.pseudo_inverse(1e-12).unwrap_or_else(|_| nalgebra::Matrix3::zeros());
    d * inverse * d
}
