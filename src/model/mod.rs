//! The Bodner-Partom law for shear (paper eqs. 3–4), how its parameters
//! follow the coil current, and its time integration.
//!
//! This module knows nothing about data files, identification or sampling:
//! it maps a parameter set and a prescribed strain history to a stress history.

pub mod current_curves;
pub mod current_law;
pub mod field;
pub mod integrate;
pub mod lanes;
pub mod law;
pub mod params;
pub mod simd;

pub use current_curves::CurrentCurves;
pub use current_law::CurrentLaw;
pub use field::{FieldCurrent, FieldLaw};
pub use integrate::{
    integrate, uses_avx2, IntegrationError, Integrator, LaneStates, Scheme, State, Trajectory,
};
pub use lanes::LANES;
pub use law::tangent_stiffness;
pub use params::{Params, D0, PARAM_NAMES, PARAM_UNITS, PHYSICAL_RANGE, PLAUSIBLE_RANGE};
