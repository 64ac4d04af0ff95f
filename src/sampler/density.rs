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
