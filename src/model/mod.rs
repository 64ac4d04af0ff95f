//! The Bodner-Partom law for shear (paper eqs. 3–4) and its time integration.
//!
//! This module knows nothing about data files, identification or sampling:
//! it maps a parameter set and a prescribed strain history to a stress history.

pub mod integrate;
pub mod lanes;
pub mod law;
pub mod params;

pub use integrate::{integrate, IntegrationError, Integrator, LaneStates, Scheme, State, Trajectory};
pub use lanes::LANES;
pub use params::{Params, D0, PARAM_NAMES, PHYSICAL_RANGE};
