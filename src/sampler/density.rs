//! What a target of the sampler implements.

/// An unnormalised log-density over unconstrained real vectors.
///
/// Return `f64::NEG_INFINITY` outside the support or wherever the density
/// cannot be computed; a NaN is treated the same way.
pub trait LogDensity: Sync {
    /// Number of coordinates of a point.
    fn dim(&self) -> usize;

    /// The log-density at `x` (`x.len() == dim()`).
    fn log_density(&self, x: &[f64]) -> f64;

    /// The log-density at `out.len()` points stored one after another in
    /// `xs`. Override it to evaluate several points together (structure of
    /// arrays, SIMD); the sampler always calls this one.
    fn log_density_batch(&self, xs: &[f64], out: &mut [f64]) {
        for (x, o) in xs.chunks_exact(self.dim()).zip(out.iter_mut()) {
            *o = self.log_density(x);
        }
    }

    /// Blocks of coordinates whose conditional density, the other
    /// coordinates held, is cheap once a full evaluation has left its memo
    /// (the noise parameters of a run, given that run's residuals): the
    /// sampler then also updates each block on its own between steps
    /// ([`crate::sampler::ensemble`]). None by default.
    fn blocks(&self) -> Vec<Vec<usize>> {
        Vec::new()
    }

    /// Blocks whose terms a memo scores as [`LogDensity::blocks`]' do
    /// (each run's noise parameters, given that run's residuals), whether
    /// or not the sampler updates them on their own: Newton's differences
    /// take a point that moves one such block from a memo, and no mixed
    /// derivative of two blocks ([`crate::newton`]). [`LogDensity::blocks`]
    /// by default.
    fn scored_blocks(&self) -> Vec<Vec<usize>> {
        self.blocks()
    }

    /// [`LogDensity::log_density_batch`], also writing into `memos[i]`
    /// (cleared first) what [`LogDensity::block_log_density_batch`] needs
    /// of point i, after the values of block 0, 1, … 's terms there (as
    /// [`LogDensity::block_log_density_batch`] gives them; the sampler
    /// keeps them up to date). Only called where [`LogDensity::blocks`]
    /// or [`LogDensity::scored_blocks`] has some.
    fn log_density_batch_memo(&self, xs: &[f64], out: &mut [f64], memos: &mut [Vec<f64>]) {
        self.log_density_batch(xs, out);
        memos.iter_mut().for_each(Vec::clear);
    }

    /// The terms of the log-density of each point of `xs` that depend on
    /// block `b`'s coordinates, every other coordinate being those of the
    /// point `memos[i]` was made at (the memo whole, block terms first):
    /// ln p(x) up to a constant in the block. −∞ outside the support.
    fn block_log_density_batch(&self, _b: usize, _xs: &[f64], _memos: &[&[f64]], out: &mut [f64]) {
        out.fill(f64::NEG_INFINITY);
    }
}

/// The coordinates of `d` in none of `blocks` ([`LogDensity::blocks`]):
/// those the ensemble moves propose.
pub fn free_coordinates(d: usize, blocks: &[Vec<usize>]) -> Vec<usize> {
    (0..d).filter(|i| !blocks.iter().any(|b| b.contains(i))).collect()
}

/// Points evaluated together in one [`LogDensity::log_density_batch`] call
/// by [`log_densities`] (and the sampler): fixed, so that no result depends
/// on the threads.
pub(crate) const BATCH: usize = 8;

/// The log-densities at `points` (each `target.dim()` coordinates, one
/// after another), batches of [`BATCH`] evaluated in parallel; NaN becomes
/// −∞.
pub fn log_densities(target: &impl LogDensity, points: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; points.len() / target.dim().max(1)];
    log_densities_memo(target, points, &mut out, &mut []);
    out
}

/// Log-densities of consecutive points, in parallel batches of [`BATCH`];
/// NaN becomes −∞. With `memos` (one per point; empty: none made), each
/// point's memo for [`LogDensity::block_log_density_batch`] too.
pub fn log_densities_memo<T: LogDensity>(
    target: &T,
    xs: &[f64],
    out: &mut [f64],
    memos: &mut [Vec<f64>],
) {
    use rayon::prelude::*;
    let d = target.dim().max(1);
    if memos.is_empty() {
        xs.par_chunks(BATCH * d)
            .zip(out.par_chunks_mut(BATCH))
            .for_each(|(x, o)| target.log_density_batch(x, o));
    } else {
        xs.par_chunks(BATCH * d)
            .zip(out.par_chunks_mut(BATCH))
            .zip(memos.par_chunks_mut(BATCH))
            .for_each(|((x, o), m)| target.log_density_batch_memo(x, o, m));
    }
    nan_to_neg_infinity(out);
}

/// Block `b`'s terms ([`LogDensity::block_log_density_batch`]) at the
/// points `xs`, each with the memo of the point it differs from in block
/// `b` alone, in parallel batches of [`BATCH`]; NaN becomes −∞.
pub fn block_log_densities<T: LogDensity>(
    target: &T,
    b: usize,
    xs: &[f64],
    memos: &[&[f64]],
) -> Vec<f64> {
    use rayon::prelude::*;
    let d = target.dim().max(1);
    let mut out = vec![0.0; xs.len() / d];
    xs.par_chunks(BATCH * d)
        .zip(out.par_chunks_mut(BATCH))
        .zip(memos.par_chunks(BATCH))
        .for_each(|((x, o), m)| target.block_log_density_batch(b, x, m, o));
    nan_to_neg_infinity(&mut out);
    out
}

/// A NaN log-density is read as −∞ (outside the support).
fn nan_to_neg_infinity(values: &mut [f64]) {
    values.iter_mut().filter(|v| v.is_nan()).for_each(|v| *v = f64::NEG_INFINITY);
}
