//! mrbp: Bayesian calibration and uncertainty quantification of the
//! Bodner-Partom viscoplastic model of MR fluid in MR dampers.
//!
//! The modules, from the ground floor up (each uses only those above it in
//! this list; docs/architecture.md says more):
//!
//! * [`error`], [`rng`], [`atomic`], [`fit`], [`plot`], [`interrupt`]:
//!   errors and exit codes, counter-based random streams, atomic file
//!   writing, Levenberg-Marquardt fits, figures, Ctrl-C;
//! * [`model`]: the B-P law (paper eqs. 3–4), its current law and its Euler
//!   integrators; knows nothing of data or MCMC;
//! * [`sampler`]: the ensemble MCMC sampler, generic over a log-density, and
//!   its diagnostics; knows nothing of the model;
//! * [`data`]: test campaigns, records, shear quantities (eqs. 1–2);
//! * [`noise`]: the noise models of the force record, one a file;
//! * [`synth`]: virtual experiments on a crank-driven stand;
//! * [`identify`]: the paper's deterministic identification;
//! * [`posterior`]: the posterior density, its layout, start and samples;
//! * [`calibrate`]: one calibration, identification to posterior sample;
//! * [`predict`]: posterior draws through the integrator: bands, coverage;
//! * [`adequacy`]: where the calibrated law misses a record (residual force
//!   against displacement and velocity, its memory, reversals);
//! * [`validate`]: leave-one-out validation;
//! * [`compare`]: comparisons between calibrations;
//! * [`store`]: the files of a calibration folder, written and read;
//! * [`report`]: figures and HTML reports;
//! * [`pipeline`]: the stages of a study as library calls;
//! * [`cli`]: the command line.

pub mod adequacy;
pub mod atomic;
pub mod calibrate;
pub mod cli;
pub mod compare;
pub mod data;
pub mod error;
pub mod fit;
pub mod interrupt;
pub mod identify;
pub mod model;
pub mod noise;
pub mod pipeline;
pub mod plot;
pub mod posterior;
pub mod pointwise;
pub mod predict;
pub mod report;
pub mod rng;
pub mod sampler;
pub mod store;
pub mod study;
pub mod synth;
pub mod validate;

pub use error::{Error, Result};
