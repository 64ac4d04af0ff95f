//! An affine-invariant ensemble MCMC sampler (Goodman & Weare 2010), generic
//! over any log-density.
//!
//! * [`density`]: what a target implements ([`LogDensity`]: one point, or a batch);
//! * [`moves`]: the stretch, differential-evolution, snooker, independence,
//!   history and anchored moves;
//! * [`elliptical`]: a Student-t or Gaussian fitted to points (the
//!   independence proposals, the Laplace approximation);
//! * [`ensemble`]: several independent ensembles stepped with the parallel
//!   red-blue update; [`stopping`]: when to stop, and what a run waits
//!   for; [`settings`]: what a sampler is;
//! * [`chains`]: the history of a run;
//! * [`observer`]: progress, diagnostics lines and checkpoints beside the
//!   loop; [`checkpoint`]: the state on disk;
//! * [`diagnostics`]: autocorrelation time, R̂, ESS, MCSE, acceptance;
//!   [`drift`]: draws that have not yet forgotten their start;
//! * [`stranded`]: an ensemble left in a mode of negligible mass, drawn afresh;
//! * [`smc`]: tempered sequential Monte Carlo from a reference density to the
//!   target, its populations mutated by the same moves; the evidence;
//! * [`bridge`]: the evidence from posterior draws by bridge sampling.
//!
//! Randomness is counter-based ([`crate::rng::stream`]): the draws of walker
//! w of ensemble e at step s depend on (seed, e, s, w) only, so the chains are
//! the same bit for bit whatever the number of threads, and a resumed run
//! equals an uninterrupted one.

pub mod bridge;
pub mod chains;
pub mod checkpoint;
pub mod density;
pub mod diagnostics;
pub mod drift;
pub mod elliptical;
pub mod ensemble;
pub mod moves;
pub mod observer;
pub mod settings;
pub mod smc;
pub mod stopping;
pub mod stranded;

pub use chains::Chains;
pub use density::LogDensity;
pub use diagnostics::{quantile, quantile_sorted, Diagnostics, ParameterDiagnostics};
pub use elliptical::{Elliptical, Moments};
pub use ensemble::Sampler;
pub use moves::Move;
pub use observer::{Checkpointer, Observer, Progress, RunState};
pub use settings::SamplerSettings;
pub use stopping::{RunControl, Waiting};
