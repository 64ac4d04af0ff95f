//! Newton's method on a log-density: its mode and the curvature there.
//!
//! [`newton`] starts from a Gaussian guess (an [`Elliptical`]: its mean is
//! where the search begins, its factor whitens the coordinates) and, in
//! those coordinates, takes Newton steps on the log-density with
//! derivatives by central differences, then measures the curvature at the
//! mode it reached: the Laplace approximation of the density itself. It is
//! generic over [`LogDensity`] and uses a target's blocks
//! ([`LogDensity::scored_blocks`]) where the guess keeps them apart: a point that
//! differs from an evaluated one only in a block is scored from that
//! point's memo. The posterior's use of it (from the MAP search's
//! surrogate) is `posterior::laplace`.

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::sampler::density::{block_log_densities, log_densities, log_densities_memo};
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
/// differences' noise showed in gains of a few 1e-3). The posteriors of
/// the calibrations' starts reach it in 3–9 steps; leave-one-out's
/// held-out posteriors of Bouc-Wen on the measured 0.25 A records, whose
/// searches begin at a basin 30–90 nats below the mode, in 11–34 (with 12
/// steps at most, three of four stopped at the limit 0.02–26 nats short of
/// it, and the adjusted likelihood was centred there: docs/performance.md,
/// "Newton's method to the mode").
const MAX_STEPS: usize = 40;
const GAIN_TOL: f64 = 1e-2;

/// The gain below which a step that the line search cannot take whole
/// ends the search: there the log-density is rugged at a scale (√gain sd)
/// its quadratic model cannot resolve, and the remaining rise is below
/// gain/2 nats. A smooth log-density takes such steps whole (its model
/// holds within a fraction of a sd of the mode); the measured records
/// integrated by ROS2 (Bouc-Wen at 0.25 A) gave gains of 0.03–0.09 at
/// which the line search took 1/2 to 1/256 of the step, rising by 1e-5
/// nats, seven steps and two Hessians on end.
const RESOLUTION_GAIN: f64 = 0.2;

/// The gain from which a whole step's rise is held against its model's:
/// where it rises by less than half or more than 1.5 times the gain/2 the
/// model said, the Hessian is measured again. Below it the differences'
/// noise (a few 1e-3 nats on the measured records) would call a model off
/// that is not.
const MODEL_CHECK_GAIN: f64 = 2.0;

/// Hessians measured at most where a step's rise is not its model's
/// (each 2d² log-densities): the first where the search begins, then each
/// time a Newton step could not be taken whole or rose by far more or less
/// than its quadratic model said ([`MODEL_CHECK_GAIN`]; the search began
/// far from the mode); one more wherever no step along a Hessian measured
/// elsewhere rises, and at the mode if the last was measured elsewhere.
const MAX_HESSIANS: usize = 8;

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
    /// [`GAIN_TOL`], or less than [`RESOLUTION_GAIN`] where the log-density
    /// is rugged at that step's scale (not at the step limit or a failed
    /// line search farther out).
    pub converged: bool,
    /// Newton steps taken (moves; a retry with the wider gradient is not one).
    pub steps: usize,
    /// The rise its quadratic model still expected where the search
    /// stopped (½ gᵀ Σ g, nats, by the last gradient and Hessian): about 0
    /// at a mode, how far below it the point is otherwise.
    pub short_by: f64,
    /// Gaussian about the mode whose precision is the negated Hessian
    /// (flat or convex directions held at [`MIN_CURVATURE`]).
    pub laplace: Elliptical,
}

/// The log-density in the coordinates z of `start` (x = mean + L z).
struct Whitened<'a, T: LogDensity> {
    target: &'a T,
    start: &'a Elliptical,
    /// The target's block ([`LogDensity::scored_blocks`]) each axis of z moves
    /// alone, `None` for an axis that moves no block's coordinates; empty
    /// where the start's factor mixes a block with other coordinates.
    axis_block: Vec<Option<usize>>,
}

/// A point z at which the search needs the log-density: evaluated in full,
/// or, where it differs from a point evaluated in full only in block b's
/// coordinates (`from`: that point's index among the same request and b),
/// from that point's memo: its log-density less b's terms there plus b's
/// terms at z (a Kalman pass over one run instead of every run's ODE
/// solve, for the discrepancy model).
struct Point {
    z: DVector<f64>,
    from: Option<(usize, usize)>,
}

impl Point {
    fn full(z: DVector<f64>) -> Self {
        Point { z, from: None }
    }
}

impl<'a, T: LogDensity> Whitened<'a, T> {
    fn new(target: &'a T, start: &'a Elliptical) -> Self {
        let axis_block = axis_blocks(&target.scored_blocks(), start.factor()).unwrap_or_default();
        Whitened { target, start, axis_block }
    }

    fn x(&self, z: &DVector<f64>) -> Vec<f64> {
        self.start.point(z.as_slice(), 1.0)
    }

    fn at(&self, zs: &[DVector<f64>]) -> Vec<f64> {
        let points: Vec<f64> = zs.iter().flat_map(|z| self.x(z)).collect();
        log_densities(self.target, &points)
    }

    /// The block axis `i` moves alone, if any.
    fn block(&self, i: usize) -> Option<usize> {
        self.axis_block.get(i).copied().flatten()
    }

    /// The log-density at each of `points`: those evaluated in full first
    /// (with a memo where another point is taken from them), then those
    /// taken from a memo, block by block.
    fn values(&self, points: &[Point]) -> Vec<f64> {
        let mut out = vec![f64::NEG_INFINITY; points.len()];
        let mut sources = vec![false; points.len()];
        points.iter().filter_map(|p| p.from).for_each(|(k, _)| sources[k] = true);
        let full: Vec<usize> = (0..points.len()).filter(|&k| points[k].from.is_none()).collect();
        let (with_memo, plain): (Vec<usize>, Vec<usize>) =
            full.into_iter().partition(|&k| sources[k]);
        let xs =
            |ks: &[usize]| -> Vec<f64> { ks.iter().flat_map(|&k| self.x(&points[k].z)).collect() };
        for (&k, v) in plain.iter().zip(log_densities(self.target, &xs(&plain))) {
            out[k] = v;
        }
        let mut memos = vec![Vec::new(); with_memo.len()];
        let mut values = vec![0.0; with_memo.len()];
        log_densities_memo(self.target, &xs(&with_memo), &mut values, &mut memos);
        let mut memo_of = vec![usize::MAX; points.len()];
        for (m, &k) in with_memo.iter().enumerate() {
            (out[k], memo_of[k]) = (values[m], m);
        }
        let blocks =
            points.iter().filter_map(|p| p.from.map(|(_, b)| b)).max().map_or(0, |b| b + 1);
        for b in 0..blocks {
            let ks: Vec<usize> = (0..points.len())
                .filter(|&k| points[k].from.is_some_and(|(_, c)| c == b))
                .collect();
            let memo_refs: Vec<&[f64]> =
                ks.iter().map(|&k| memos[memo_of[points[k].from.unwrap().0]].as_slice()).collect();
            let terms = block_log_densities(self.target, b, &xs(&ks), &memo_refs);
            for (&k, t) in ks.iter().zip(terms) {
                let (src, _) = points[k].from.unwrap();
                let memo = &memos[memo_of[src]];
                out[k] = match (out[src], memo.get(b)) {
                    (f, Some(&own)) if f.is_finite() && t.is_finite() => f - own + t,
                    _ => f64::NEG_INFINITY,
                };
            }
        }
        out
    }

    /// `base` (pushed first) where an axis among `axes` moves a block
    /// alone: its memo serves the points that differ from z in that block.
    fn with_base(&self, z: &DVector<f64>, axes: &[usize]) -> (Vec<Point>, Option<usize>) {
        if axes.iter().any(|&i| self.block(i).is_some()) {
            (vec![Point::full(z.clone())], Some(0))
        } else {
            (Vec::new(), None)
        }
    }

    /// Gradient by central differences of step `h`: 2 points per axis not
    /// held. An axis whose points leave the support (a mode on a prior's
    /// bound) is held from then on, its component 0.
    fn gradient(&self, z: &DVector<f64>, held: &mut [bool], h: f64) -> DVector<f64> {
        let axes: Vec<usize> = (0..z.len()).filter(|&i| !held[i]).collect();
        let (mut points, base) = self.with_base(z, &axes);
        let first = points.len();
        for &i in &axes {
            let from = self.block(i).and_then(|b| base.map(|k| (k, b)));
            points.extend([-h, h].map(|s| Point { z: offset(z, &[(i, s)]), from }));
        }
        let f = self.values(&points);
        let f = &f[first..];
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
    /// Where the target has blocks the start keeps apart (each run's
    /// noise), a point that differs from an axis point
    /// (or z) only in one block's coordinates is taken from that point's
    /// memo, and two axes in different blocks have no mixed derivative at
    /// all (the log-density is a sum of a term per block given the rest):
    /// at one measured current (24 coordinates, 12 of them noise) 289 ODE
    /// solves a Hessian instead of 1 152.
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
        let (mut points, base) = self.with_base(z, &axes);
        // the axis points: axis k's at s = −h, +h are axis_at[k] + 0, 1
        let axis_at: Vec<usize> = axes
            .iter()
            .map(|&i| {
                let from = self.block(i).and_then(|b| base.map(|k| (k, b)));
                points.extend([-h, h].map(|s| Point { z: offset(z, &[(i, s)]), from }));
                points.len() - 2
            })
            .collect();
        let signs = [(h, h), (h, -h), (-h, h), (-h, -h)];
        // each pair's four points (None: axes in two different blocks)
        let mut pairs: Vec<((usize, usize), Option<usize>)> = Vec::new();
        for (ka, &i) in axes.iter().enumerate() {
            for (kb, &j) in axes[..ka].iter().enumerate() {
                let first = points.len();
                match (self.block(i), self.block(j)) {
                    (Some(a), Some(b)) if a != b => {
                        pairs.push(((i, j), None));
                        continue;
                    }
                    (Some(a), Some(_)) => points.extend(signs.map(|(si, sj)| Point {
                        z: offset(z, &[(i, si), (j, sj)]),
                        from: base.map(|k| (k, a)),
                    })),
                    (None, None) => points
                        .extend(signs.map(|(si, sj)| Point::full(offset(z, &[(i, si), (j, sj)])))),
                    // one free axis, one in block b: from the free axis's point
                    (bi, bj) => {
                        let (b, free_k, free_first) = match bi {
                            Some(b) => (b, kb, false),
                            None => (bj.unwrap(), ka, true),
                        };
                        points.extend(signs.map(|(si, sj)| {
                            let s_free = if free_first { si } else { sj };
                            let source = axis_at[free_k] + usize::from(s_free > 0.0);
                            Point { z: offset(z, &[(i, si), (j, sj)]), from: Some((source, b)) }
                        }));
                    }
                }
                pairs.push(((i, j), Some(first)));
            }
        }
        let f = self.values(&points);
        for (k, &i) in axes.iter().enumerate() {
            if !(f[axis_at[k]].is_finite() && f[axis_at[k] + 1].is_finite()) {
                held[i] = true;
            }
        }
        for &((i, j), first) in &pairs {
            if let Some(p) = first {
                if !held[i] && !held[j] && f[p..p + 4].iter().any(|v| !v.is_finite()) {
                    held[i] = true;
                }
            }
        }
        let h2 = h * h;
        let mut hess = DMatrix::from_diagonal_element(z.len(), z.len(), -1.0);
        for (k, &i) in axes.iter().enumerate() {
            if !held[i] {
                hess[(i, i)] = (f[axis_at[k] + 1] - 2.0 * f0 + f[axis_at[k]]) / h2;
            }
        }
        for &((i, j), first) in &pairs {
            if !held[i] && !held[j] {
                let v = first.map_or(0.0, |p| (f[p] - f[p + 1] - f[p + 2] + f[p + 3]) / (4.0 * h2));
                hess[(i, j)] = v;
                hess[(j, i)] = v;
            }
        }
        hess
    }
}

/// The block of `blocks` each column of the factor `l` moves (`None`: no
/// block's coordinates), where every column moves at most one block and
/// nothing else with it; `None` otherwise (or without blocks).
fn axis_blocks(blocks: &[Vec<usize>], l: &DMatrix<f64>) -> Option<Vec<Option<usize>>> {
    if blocks.is_empty() {
        return None;
    }
    let mut owner = vec![None; l.nrows()];
    for (b, block) in blocks.iter().enumerate() {
        for &i in block {
            *owner.get_mut(i)? = Some(b);
        }
    }
    (0..l.ncols())
        .map(|c| {
            let mut moved = (0..l.nrows()).filter(|&r| l[(r, c)] != 0.0).map(|r| owner[r]);
            let first = moved.next()?;
            moved.all(|o| o == first).then_some(first)
        })
        .collect()
}

/// Backtracking from the full `step` until the log-density rises by a
/// share of the `gain` the quadratic model expects: the share of the step
/// taken, the point and its log-density.
fn line_search<T: LogDensity>(
    w: &Whitened<T>,
    z: &DVector<f64>,
    f: f64,
    step: &DVector<f64>,
    gain: f64,
) -> Option<(f64, DVector<f64>, f64)> {
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

/// The gradient and Hessian of `target` at `at`'s mean in the coordinates
/// z it whitens (x = mean + L z), by the central differences Newton's
/// method takes; `None` where the log-density there is not finite or a
/// difference leaves the support.
pub fn derivatives(
    target: &impl LogDensity,
    at: &Elliptical,
) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let w = Whitened::new(target, at);
    let z = DVector::zeros(at.dim());
    let f = w.at(std::slice::from_ref(&z))[0];
    if !f.is_finite() {
        return None;
    }
    let mut held = vec![false; at.dim()];
    let g = w.gradient(&z, &mut held, GRADIENT_STEP);
    let h = w.hessian(&z, f, &mut held);
    (!held.contains(&true)).then_some((g, h))
}

/// The inverse of the negated Hessian `hess`, every eigenvalue of −hess
/// held at [`MIN_CURVATURE`] or above (whitened coordinates).
pub fn covariance(hess: &DMatrix<f64>) -> DMatrix<f64> {
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
    let w = Whitened::new(target, start);
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
    let mut g = w.gradient(&z, &mut held, GRADIENT_STEP);
    // whether g is the wider differences' (below)
    let mut widened = false;
    let mut converged = false;
    let mut steps = 0;
    for _ in 0..MAX_STEPS {
        let step = hold(&cov * &hold(g.clone(), &held), &held);
        let gain = g.dot(&step);
        let moved = if gain < GAIN_TOL { None } else { line_search(&w, &z, f, &step, gain) };
        // a step the quadratic model could not take, where it expects
        // little: the log-density is rugged at the step's scale, and the
        // search is at its resolution
        let short = moved.as_ref().is_none_or(|m| m.0 < 1.0);
        if (GAIN_TOL..RESOLUTION_GAIN).contains(&gain) && short {
            converged = true;
            break;
        }
        match moved {
            Some((alpha, trial, ft)) => {
                // a whole step whose rise is off its model's (gain/2) by
                // half or more: the curvature where the search began is not
                // the curvature here (too large, and the steps crawl)
                let model_off = alpha == 1.0
                    && gain >= MODEL_CHECK_GAIN
                    && !(0.5..1.5).contains(&((ft - f) / (0.5 * gain)));
                let (from, g_from) = (std::mem::replace(&mut z, trial), g.clone());
                (f, fresh, steps) = (ft, false, steps + 1);
                if (alpha < 1.0 || model_off) && measured < MAX_HESSIANS {
                    (cov, fresh, measured) =
                        (covariance(&w.hessian(&z, f, &mut held)), true, measured + 1);
                }
                (g, widened) = (w.gradient(&z, &mut held, GRADIENT_STEP), false);
                // the Hessians spent: the curvature learnt along each step
                // from the gradients at its ends instead, as quasi-Newton
                // methods do (a stale Hessian's steps crawl up a curved
                // ridge at 1/16–1/128 of their length: Bouc-Wen's held-out
                // posterior on the measured 0.5 A records without its 5 mm
                // / 3 Hz run)
                if !fresh && measured >= MAX_HESSIANS {
                    cov = bfgs(cov, &hold(&z - from, &held), &hold(g_from - &g, &held));
                }
            }
            // no rise along the step by a curvature measured here, where
            // it expects one: the gradient again by the Hessian's wider
            // differences, which a log-density rugged at the narrow ones'
            // scale does not mislead (Bouc-Wen on the measured 0.25 A
            // records without the folder's terms: a gain of 3.5 there, of
            // less than RESOLUTION_GAIN by the wider differences)
            None if fresh && gain >= RESOLUTION_GAIN && !widened => {
                (g, widened) = (w.gradient(&z, &mut held, HESSIAN_STEP), true);
            }
            // no gain left, or none found, by the curvature measured here
            None if fresh => {
                converged = gain < GAIN_TOL;
                break;
            }
            // … or by one measured elsewhere: measure it here and go on
            None => {
                (cov, fresh, measured) =
                    (covariance(&w.hessian(&z, f, &mut held)), true, measured + 1)
            }
        }
    }
    if !fresh {
        cov = covariance(&w.hessian(&z, f, &mut held));
    }
    let held_g = hold(g, &held);
    let short_by = 0.5 * held_g.dot(&hold(&cov * &held_g, &held));
    let l = start.factor();
    let cov_x = l * cov * l.transpose();
    let factor = cov_x.cholesky()?.l();
    let x = w.x(&z);
    Some(Mode {
        laplace: Elliptical::from_factor(DVector::from_column_slice(&x), factor),
        x,
        log_density: f,
        converged,
        steps,
        short_by,
    })
}

impl Mode {
    /// Where the search stopped short of the mode, how far, in words
    /// ("stopped after 40 steps, 3.2 nats below its mode by the
    /// curvature there"); `None` where it converged.
    pub fn shortfall(&self) -> Option<String> {
        (!self.converged).then(|| {
            format!(
                "stopped after {} step(s), {:.2} nats below its mode by the curvature there",
                self.steps, self.short_by
            )
        })
    }
}

/// The covariance (inverse negated Hessian) updated by BFGS for a step
/// `s` over which the gradient fell by `y`: the inverse of a curvature that
/// matches the gradients' change along `s` and keeps the rest. Unchanged
/// where the curvature seen along the step, sᵀy / sᵀs, is below
/// [`MIN_CURVATURE`], the least [`covariance`] keeps (a flat or convex
/// direction, or gradients that differ by their rounding).
fn bfgs(cov: DMatrix<f64>, s: &DVector<f64>, y: &DVector<f64>) -> DMatrix<f64> {
    let sy = s.dot(y);
    if !(sy >= MIN_CURVATURE * s.dot(s)) {
        return cov;
    }
    let rho = 1.0 / sy;
    let left = DMatrix::identity(s.len(), s.len()) - s * y.transpose() * rho;
    let updated = &left * cov * left.transpose() + s * s.transpose() * rho;
    (&updated + updated.transpose()) * 0.5
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
        Elliptical::from_factor(
            DVector::from_column_slice(&[7.0, 1.0, -1.0]),
            DMatrix::from_diagonal(&DVector::from_column_slice(&[1.0, 0.5, 0.25])),
        )
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

    /// A Gaussian with ruggedness of 0.03 nats at a scale of 1e-4 sd, as
    /// an integrated log-density shows at its discretisation's
    /// resolution, its evaluations counted.
    struct Rugged {
        target: Target,
        calls: std::sync::atomic::AtomicUsize,
    }

    impl LogDensity for Rugged {
        fn dim(&self) -> usize {
            3
        }
        fn log_density(&self, x: &[f64]) -> f64 {
            self.calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let wiggle: f64 =
                x.iter().enumerate().map(|(i, v)| (v * (7.0e4 + 1.3e4 * i as f64)).sin()).sum();
            self.target.log_density(x) + 0.03 * wiggle / 3.0_f64.sqrt()
        }
    }

    #[test]
    fn stops_at_the_resolution_of_a_rugged_density() {
        // near the mode the central differences' gradient is the
        // ruggedness's (0.03 nats over 0.05 sd: gains of order 0.01–0.1),
        // and a Newton step there rises only by chance. The search stops
        // within √RESOLUTION_GAIN ≈ 0.45 of the mode's sd in every
        // coordinate (measured: within 0.33), after 59–81 evaluations;
        // chasing the ruggedness (the rule off) spent 203 from the first
        // start and did not converge.
        let (target, cov) = gaussian();
        let rugged = Rugged { target, calls: 0.into() };
        for start in 0..5 {
            let offset = 0.5 + 0.5 * start as f64;
            let guess = Elliptical::from_factor(
                DVector::from_column_slice(&[
                    1.0 + 2.0 * offset,
                    -2.0 - offset,
                    0.5 + 0.5 * offset,
                ]),
                DMatrix::from_diagonal(&DVector::from_column_slice(&[1.5, 0.8, 0.4])),
            );
            rugged.calls.store(0, std::sync::atomic::Ordering::Relaxed);
            let mode = newton(&rugged, &guess).unwrap();
            let calls = rugged.calls.load(std::sync::atomic::Ordering::Relaxed);
            for (i, (a, b)) in mode.x.iter().zip(rugged.target.mean.iter()).enumerate() {
                let sd = cov[(i, i)].sqrt();
                assert!((a - b).abs() < 0.45 * sd, "start {start}: mode {:?}", mode.x);
            }
            assert!(mode.converged, "start {start}");
            assert!(calls < 120, "start {start}: {calls} evaluations");
        }
    }

    /// f = a x₀ − e^(x₀) − 2 (x₁ − x₀)² − x₂²/2: a log-gamma margin in x₀,
    /// x₁ tied to it, x₂ apart; its mode x₀ = x₁ = ln a, x₂ = 0.
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

    #[test]
    fn reaches_a_mode_far_from_a_start_whose_curvature_misleads() {
        // `Skewed`, started at x₀ = x₁ = s, x₂ = 0, 4–11
        // whitened units to the right of the mode ln a: there the
        // curvature e^s is 50–55 000 times the mode's, so Newton's steps
        // by the start's Hessian are whole yet crawl (each about e^(x −
        // s) long). Each rises by about twice what its model said; the
        // Hessian is measured again where the rise is off the model's by
        // half, and the search reaches the mode (its sd 0.58 in x₀,
        // tolerance 0.1 sd as `finds_the_mode_of_a_skewed_density`'s).
        // With the Hessian measured only where a step fell short, and 12
        // steps, it stopped 0.5, 3.2 and 7.1 short from 5, 8 and 12.
        reaches_the_skewed_mode_from(&[5.0, 8.0, 12.0]);
    }

    /// `Skewed` searched from x₀ = x₁ = s, x₂ = 0 for each s: the search
    /// converges (its model expects under GAIN_TOL / 2 more) within 0.1
    /// sd of the mode (0.06 in x₀ and x₁).
    fn reaches_the_skewed_mode_from(starts: &[f64]) {
        for &s in starts {
            let start = Elliptical::from_factor(
                DVector::from_column_slice(&[s, s, 0.0]),
                DMatrix::identity(3, 3),
            );
            let mode = newton(&Skewed, &start).unwrap();
            assert!(mode.converged, "from {s}: {:?}", mode.x);
            assert!(mode.short_by < 0.5 * GAIN_TOL && mode.shortfall().is_none(), "from {s}");
            for (v, m) in mode.x.iter().zip([A.ln(), A.ln(), 0.0]) {
                assert!((v - m).abs() < 0.06, "from {s}: mode {:?}", mode.x);
            }
        }
    }

    #[test]
    fn learns_the_curvature_once_its_hessians_are_spent() {
        // `Skewed` started at x₀ = x₁ = s, 17–22 whitened units right of
        // its mode: each Newton step by a Hessian measured where it stands
        // moves about one unit left (Δ = (a − eˣ)/eˣ), so the search
        // spends its MAX_HESSIANS long before the mode; after them, steps
        // by the last Hessian crawl (each about e^(x − x_last) long), and
        // the search stopped 4.0 and 9.0 units short at MAX_STEPS
        // (measured with the update off). With the curvature updated from
        // the gradients at each step's ends (BFGS) it reaches the mode.
        reaches_the_skewed_mode_from(&[18.0, 23.0]);
    }

    #[test]
    fn a_search_stopped_short_says_how_far() {
        // f = x₀ − x₁²/2 rises without end in x₀: its curvature there is
        // 0, held at MIN_CURVATURE (sd 5 whitened units), so every step is
        // 25 units long, taken whole, and rises by 25 where its model said
        // 12.5. The search stops at the step limit, not converged, and the
        // model at its end expects ½ g² / MIN_CURVATURE = 12.5 nats more.
        struct Ramp;
        impl LogDensity for Ramp {
            fn dim(&self) -> usize {
                2
            }
            fn log_density(&self, x: &[f64]) -> f64 {
                x[0] - 0.5 * x[1] * x[1]
            }
        }
        let start = Elliptical::from_factor(
            DVector::from_column_slice(&[0.0, 1.0]),
            DMatrix::identity(2, 2),
        );
        let mode = newton(&Ramp, &start).unwrap();
        assert!(!mode.converged);
        assert_eq!(mode.steps, MAX_STEPS);
        let expected = 0.5 / MIN_CURVATURE;
        assert!((mode.short_by - expected).abs() < 1e-6 * expected, "short by {}", mode.short_by);
        let said = mode.shortfall().unwrap();
        assert!(said.contains("40 step(s), 12.50 nats below"), "{said}");
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
        let start = Elliptical::from_factor(
            DVector::from_column_slice(&[-1.0, 0.5, 2.0]),
            DMatrix::identity(3, 3),
        );
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
        let exact =
            DMatrix::from_row_slice(3, 3, &[A + 4.0, -4.0, 0.0, -4.0, 4.0, 0.0, 0.0, 0.0, 1.0]);
        assert!(
            (precision - &exact).abs().max() < 0.03 * (A + 4.0),
            "precision {}",
            mode.laplace.covariance().try_inverse().unwrap()
        );
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
                if x[2] < 0.45 {
                    f64::NEG_INFINITY
                } else {
                    self.0.log_density(x)
                }
            }
        }
        let (target, cov) = gaussian();
        let mean = target.mean.clone();
        let start = Elliptical::from_factor(
            DVector::from_column_slice(&[2.0, -1.0, 0.46]),
            DMatrix::from_diagonal(&DVector::from_column_slice(&[1.0, 0.5, 0.25])),
        );
        let mode = newton(&Cut(target), &start).unwrap();
        let dx2 = 0.46 - mean[2];
        for i in 0..2 {
            let expected = mean[i] + cov[(i, 2)] / cov[(2, 2)] * dx2;
            assert!(
                (mode.x[i] - expected).abs() < 1e-6,
                "mode {:?}, expected {expected} at {i}",
                mode.x
            );
        }
        assert_eq!(mode.x[2], 0.46);
        let got = mode.laplace.covariance();
        assert!(
            (got[(2, 2)] - 0.0625).abs() < 1e-12
                && got[(0, 2)].abs() < 1e-12
                && got[(1, 2)].abs() < 1e-12,
            "covariance {got}"
        );
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
        let start = Elliptical::from_factor(
            DVector::from_column_slice(&[0.5, 0.0]),
            DMatrix::identity(2, 2),
        );
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
                let quad: f64 =
                    (0..3).flat_map(|i| (0..3).map(move |j| x[i] * P[i][j] * x[j])).sum();
                -0.5 * quad + B * x[0].powi(3) + C * x[0].powi(2) * x[1].powi(2)
            }
        }
        let start = Elliptical::from_factor(DVector::zeros(3), DMatrix::identity(3, 3));
        let w = Whitened::new(&Quartic, &start);
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

    /// A Gaussian over two free coordinates and two blocks ([2, 3] and
    /// [4]), coupled to the free ones but not to each other, that exposes
    /// its blocks (`blocks`) or hides them: the memo of a point holds each
    /// block's terms there, then the free coordinates.
    struct Blocked {
        precision: DMatrix<f64>,
        mean: DVector<f64>,
        blocks: bool,
        full: std::sync::atomic::AtomicUsize,
    }

    const BLOCKS: [&[usize]; 2] = [&[2, 3], &[4]];

    impl Blocked {
        fn new(blocks: bool) -> Self {
            // free (0, 1) correlated; each block coupled to the free ones
            let p = DMatrix::from_row_slice(
                5,
                5,
                &[
                    3.0, 0.8, 0.5, -0.3, 0.4, //
                    0.8, 2.0, 0.2, 0.1, -0.6, //
                    0.5, 0.2, 1.5, 0.4, 0.0, //
                    -0.3, 0.1, 0.4, 1.2, 0.0, //
                    0.4, -0.6, 0.0, 0.0, 0.9,
                ],
            );
            let mean = DVector::from_column_slice(&[0.3, -1.0, 2.0, 0.5, -0.7]);
            Blocked { precision: p, mean, blocks, full: 0.into() }
        }
        /// Block b's terms at x: −½ rᵦᵀ Pᵦᵦ rᵦ − rᵦᵀ Pᵦf r_f (r = x − mean).
        fn block_terms(&self, b: usize, x: &[f64], free: &[f64]) -> f64 {
            let r = |i: usize, v: f64| v - self.mean[i];
            let mut t = 0.0;
            for &i in BLOCKS[b] {
                for &j in BLOCKS[b] {
                    t -= 0.5 * r(i, x[i]) * self.precision[(i, j)] * r(j, x[j]);
                }
                for j in 0..2 {
                    t -= r(i, x[i]) * self.precision[(i, j)] * r(j, free[j]);
                }
            }
            t
        }
    }

    impl LogDensity for Blocked {
        fn dim(&self) -> usize {
            5
        }
        fn log_density(&self, x: &[f64]) -> f64 {
            self.full.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let r = DVector::from_column_slice(x) - &self.mean;
            -0.5 * (r.transpose() * &self.precision * &r)[(0, 0)]
        }
        fn blocks(&self) -> Vec<Vec<usize>> {
            if self.blocks {
                BLOCKS.iter().map(|b| b.to_vec()).collect()
            } else {
                Vec::new()
            }
        }
        fn log_density_batch_memo(&self, xs: &[f64], out: &mut [f64], memos: &mut [Vec<f64>]) {
            for ((x, o), m) in xs.chunks_exact(5).zip(out.iter_mut()).zip(memos.iter_mut()) {
                *o = self.log_density(x);
                *m = vec![
                    self.block_terms(0, x, &x[..2]),
                    self.block_terms(1, x, &x[..2]),
                    x[0],
                    x[1],
                ];
            }
        }
        fn block_log_density_batch(&self, b: usize, xs: &[f64], memos: &[&[f64]], out: &mut [f64]) {
            for ((x, o), m) in xs.chunks_exact(5).zip(out.iter_mut()).zip(memos) {
                *o = self.block_terms(b, x, &m[2..4]);
            }
        }
    }

    /// A start that keeps the blocks apart: free coordinates correlated,
    /// block [2, 3] correlated within, [4] alone.
    fn blocked_start() -> Elliptical {
        let mut l = DMatrix::zeros(5, 5);
        l[(0, 0)] = 0.8;
        l[(1, 0)] = 0.2;
        l[(1, 1)] = 0.6;
        l[(2, 2)] = 0.9;
        l[(3, 2)] = -0.3;
        l[(3, 3)] = 0.7;
        l[(4, 4)] = 1.1;
        Elliptical::from_factor(DVector::from_column_slice(&[1.0, 0.0, 1.0, 1.5, 0.5]), l)
    }

    #[test]
    fn points_that_differ_in_one_block_come_from_a_memo() {
        // a quadratic: the differences are exact up to rounding, with the
        // blocks or without; the Hessian in z is −Lᵀ P L. With the blocks
        // the Hessian costs 1 + 2·2 + 4·1 = 9 full evaluations (z, the two
        // free axes' points, the free pair's four) instead of 2·5² = 50.
        let start = blocked_start();
        let z = DVector::from_column_slice(&[0.3, -0.4, 0.2, 0.1, -0.5]);
        let (with, without) = (Blocked::new(true), Blocked::new(false));
        let exact = -(start.factor().transpose() * &with.precision * start.factor());
        let w = Whitened::new(&with, &start);
        assert_eq!(w.axis_block, vec![None, None, Some(0), Some(0), Some(1)]);
        let f0 = with.log_density(&w.x(&z));
        with.full.store(0, std::sync::atomic::Ordering::Relaxed);
        let got = w.hessian(&z, f0, &mut [false; 5]);
        assert_eq!(with.full.load(std::sync::atomic::Ordering::Relaxed), 9);
        assert!((&got - &exact).abs().max() < 1e-10, "Hessian {got}, exact {exact}");
        let plain = Whitened::new(&without, &start).hessian(&z, f0, &mut [false; 5]);
        assert_eq!(without.full.load(std::sync::atomic::Ordering::Relaxed), 50);
        assert!((&plain - &exact).abs().max() < 1e-10);
        // the gradient: −Lᵀ P (x − mean), 1 + 2·2 full evaluations
        with.full.store(0, std::sync::atomic::Ordering::Relaxed);
        let g = w.gradient(&z, &mut [false; 5], GRADIENT_STEP);
        assert_eq!(with.full.load(std::sync::atomic::Ordering::Relaxed), 5);
        let r = DVector::from_column_slice(&w.x(&z)) - &with.mean;
        let exact_g = -(start.factor().transpose() * &with.precision * r);
        assert!((&g - &exact_g).abs().max() < 1e-9, "gradient {g}, exact {exact_g}");
        // and the search reaches the mean and the covariance P⁻¹
        let mode = newton(&with, &start).unwrap();
        for (a, b) in mode.x.iter().zip(with.mean.iter()) {
            assert!((a - b).abs() < 1e-6, "mode {:?}", mode.x);
        }
        let cov = with.precision.clone().try_inverse().unwrap();
        assert!((mode.laplace.covariance() - cov).abs().max() < 1e-6);
    }

    #[test]
    fn a_start_that_mixes_a_block_with_other_coordinates_evaluates_in_full() {
        // a factor whose column moves block [4] with a free coordinate:
        // no structure, every point evaluated in full
        let mut l = blocked_start().factor().clone();
        l[(4, 1)] = 0.05;
        assert_eq!(axis_blocks(&Blocked::new(true).blocks(), &l), None);
        // one that moves the two blocks together
        let mut l = blocked_start().factor().clone();
        l[(4, 2)] = 0.05;
        assert_eq!(axis_blocks(&Blocked::new(true).blocks(), &l), None);
        assert_eq!(axis_blocks(&[], &l), None);
    }
}
