//! mrbp: Bayesian calibration and uncertainty quantification of the
//! Bodner-Partom viscoplastic model of MR fluid in MR dampers.
//!
//! The pipeline, one module per stage:
//!
//! * [`model`]: the B-P law (paper eqs. 3–4) and its Euler integrators;
//! * [`data`]: test campaigns, records and the shear quantities of eqs. 1–2;
//! * [`synth`]: virtual experiments on a crank-driven stand;
//! * [`sampler`]: the ensemble MCMC sampler, generic over a log-density;
//! * [`output`]: atomic file writing and Parquet tables;
//! * [`cli`]: the command line.

pub mod calibrate;
pub mod cli;
pub mod compare;
pub mod data;
pub mod error;
pub mod fit;
pub mod identify;
pub mod model;
pub mod output;
pub mod posterior;
pub mod predict;
pub mod report;
pub mod rng;
pub mod sampler;
pub mod stored;
pub mod synth;
pub mod validate;

pub use error::{Error, Result};
