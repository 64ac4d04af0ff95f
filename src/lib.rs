//! mrbp: Bayesian calibration and uncertainty quantification of the
//! Bodner-Partom viscoplastic model of MR fluid in MR dampers.
//!
//! The modules, from the ground floor up (each uses only those before it in
//! this list; docs/architecture.md says more):
//!
//! * [`model`], [`fit`], [`numeric`], [`interrupt`], [`rng`], [`error`],
//!   [`atomic`], [`lock`], [`plot`]: the B-P law (paper eqs. 3–4), its
//!   current law and its Euler integrators; least squares, a covariance's
//!   factor and log-sum-exp, Ctrl-C, random streams, errors and exit codes,
//!   atomic file writing, one writer per folder, figures;
//! * [`data`]: test campaigns, records, shear quantities (eqs. 1–2), a run
//!   as the model sees it;
//! * [`sampler`]: the ensemble MCMC sampler, generic over a log-density, and
//!   its diagnostics; knows nothing of the model;
//! * [`noise`]: the noise models of the force record, one a file;
//! * [`identify`]: the paper's deterministic identification;
//! * [`synth`]: virtual experiments on a crank-driven stand;
//! * [`posterior`]: the posterior density, its layout, start and samples;
//! * [`predict`]: posterior draws through the integrator: bands, coverage,
//!   and where the calibrated law misses a record;
//! * [`compare`]: comparisons between calibrations;
//! * [`calibrate`]: one calibration, identification to posterior sample;
//! * [`pointwise`]: the pointwise log-likelihood of posterior draws;
//! * [`validate`]: leave-one-out validation;
//! * [`store`]: the files of a results folder, written and read;
//! * [`report`]: figures, HTML reports and the terminal's tables;
//! * [`pipeline`]: the stages as library calls;
//! * [`study`]: studies of many calibrations;
//! * [`cli`]: the command line.

pub mod atomic;
pub mod calibrate;
pub mod cli;
pub mod compare;
pub mod data;
pub mod error;
pub mod fit;
pub mod identify;
pub mod interrupt;
pub mod laws;
pub mod lock;
pub mod model;
pub mod newton;
pub mod noise;
pub mod numeric;
pub mod pipeline;
pub mod plot;
pub mod pointwise;
pub mod posterior;
pub mod predict;
pub mod report;
pub mod rng;
pub mod sampler;
pub mod store;
pub mod study;
pub mod synth;
pub mod validate;

pub use error::{Error, Result};
