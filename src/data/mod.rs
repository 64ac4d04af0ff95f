//! Test campaigns: the manifest, the stand records, and the shear quantities
//! derived from them (paper eqs. 1–2).

pub mod branches;
pub mod campaign;
pub mod shear;
pub mod table;

pub use branches::loading_branches;
pub use campaign::{Campaign, Columns, Geometry, Manifest, Run, RunSpec};
pub use shear::{local_polynomial, Inelastic, Shear};
pub use table::Record;
