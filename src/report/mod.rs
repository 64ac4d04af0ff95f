//! Reports: figures (SVG + PNG) and self-contained HTML pages, rendered
//! from results computed elsewhere.
//!
//! * [`calibration`]: the uncertainty report of one calibration;
//! * [`comparison`]: the report comparing calibrations;
//! * [`prediction`]: the report of a calibration predicting another campaign;
//! * [`simulation`]: the figure of a simulated excitation;
//! * [`identification`]: the paper's Figs. 1–5;
//! * [`adequacy`]: the report's section on where the law misses the records;
//! * [`text`]: the tables the command line prints;
//! * [`figures`]: the figures of a calibration report;
//! * [`html`]: the page writer.

pub mod adequacy;
pub mod calibration;
pub mod comparison;
pub mod figures;
pub mod html;
pub mod identification;
pub mod laws;
pub mod prediction;
pub mod simulation;
pub mod text;

pub use calibration::{CalibrationReport, COVERAGE_OK, HELD_OUT_OK};
pub use prediction::PredictionReport;

pub use figures::Figures;
