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
}

/// Points evaluated together in one [`LogDensity::log_density_batch`] call
/// by [`log_densities`]: fixed, so that no result depends on the threads.
const BATCH: usize = 8;

/// The log-densities at `points` (each `target.dim()` coordinates, one
/// after another), batches of [`BATCH`] evaluated in parallel.
pub fn log_densities(target: &impl LogDensity, points: &[f64]) -> Vec<f64> {
    use rayon::prelude::*;
    let d = target.dim().max(1);
    let mut out = vec![0.0; points.len() / d];
    points.par_chunks(BATCH * d).zip(out.par_chunks_mut(BATCH)).for_each(|(x, o)| target.log_density_batch(x, o));
    out
}
