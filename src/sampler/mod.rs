//! An affine-invariant ensemble MCMC sampler (Goodman & Weare 2010), generic
//! over any log-density.
//!
//! * [`LogDensity`]: what a target implements (one point, or a batch);
//! * [`moves`]: the stretch, differential-evolution and snooker moves;
//! * [`ensemble`]: several independent ensembles stepped with the parallel
//!   red-blue update, and when to stop; [`settings`]: what a sampler is;
//! * [`chains`]: the history of a run;
//! * [`observer`]: progress, diagnostics lines and checkpoints beside the
//!   loop; [`checkpoint`]: the state on disk;
//! * [`diagnostics`]: autocorrelation time, R̂, ESS, MCSE, acceptance.
//!
//! Randomness is counter-based ([`crate::rng::stream`]): the draws of walker
//! w of ensemble e at step s depend on (seed, e, s, w) only, so the chains are
//! the same bit for bit whatever the number of threads, and a resumed run
//! equals an uninterrupted one.

pub mod chains;
pub mod checkpoint;
pub mod diagnostics;
pub mod ensemble;
pub mod moves;
pub mod observer;
pub mod settings;

pub use chains::Chains;
pub use diagnostics::{quantile, quantile_sorted, Diagnostics, ParameterDiagnostics};
pub use ensemble::{RunControl, Sampler};
pub use moves::Move;
pub use observer::{Checkpointer, Observer, Progress, RunState};
pub use settings::SamplerSettings;

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
