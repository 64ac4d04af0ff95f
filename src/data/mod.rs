//! Test campaigns: the manifest, the stand records, the shear quantities
//! derived from them (paper eqs. 1–2), loading branches, smoothing, and a
//! run as the model sees it.

pub mod branches;
pub mod campaign;
pub mod run_data;
pub mod shear;
pub mod smooth;
pub mod table;

pub use branches::{loading_branches, REVERSAL_SHARE};
pub use campaign::{
    check_coil_current, current_tag, same_current, Campaign, Manifest, Run, RunSpec,
};
pub use run_data::{RecordPart, RunData};
pub use shear::{Geometry, Inelastic, Shear};
pub use smooth::{local_polynomial, noise_variance, smoothed_strain, MIN_SMOOTH_SAMPLES};
pub use table::{Columns, Limits, Record};
