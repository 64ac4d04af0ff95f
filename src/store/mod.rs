//! The files of a calibration folder and of a comparison, one module per
//! artifact, each owning both its writing and its reading. Every file is
//! written atomically ([`crate::atomic`]).
//!
//! | file | module |
//! |---|---|
//! | `identification.parquet` | [`identification`] |
//! | `chains.parquet` | [`chains`] |
//! | `summary.parquet` | [`summary`] |
//! | `calibration.toml` | [`record`] |
//! | `config.toml` | [`crate::calibrate::settings`] (also `--config`) |
//! | `bands.parquet`, `loo_bands.parquet` | [`bands`] |
//! | `coverage.parquet`, `loo.parquet` | [`coverage`] |
//! | `adequacy.parquet` | [`adequacy`] |
//! | `prediction.toml` | [`prediction`] |
//! | `comparison.parquet`, `differences.parquet` | [`comparison`] |
//! | `consistency.parquet` | [`consistency`] |
//! | `between_runs.parquet`, `loo_new_test.parquet` | [`between_runs`] |
//! | `against_current.parquet` (a law) | [`against_current`] |
//! | `inference.zarr` (ArviZ) | [`inference`] |
//!
//! [`folder`] writes and reads a whole calibration folder; [`parquet`]
//! holds the table helpers.

pub mod adequacy;
pub mod against_current;
pub mod bands;
pub mod between_runs;
pub mod chains;
pub mod comparison;
pub mod consistency;
pub mod coverage;
pub mod folder;
pub mod identification;
pub mod inference;
pub mod laws;
pub mod parquet;
pub mod prediction;
pub mod record;
pub mod simulation;
pub mod status;
pub mod summary;

pub use crate::calibrate::command_line;
pub use parquet::{
    check_derived, column_names, f64_column, parquet_meta, read_parquet, str_column, write_parquet,
    Table, CALIBRATION_ID,
};
