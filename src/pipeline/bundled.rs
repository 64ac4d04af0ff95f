//! The bundled job: `mrbp` alone, in the project folder.

use std::path::{Path, PathBuf};

use super::{LooOptions, Pipeline, RunOptions, SampleOptions};
use crate::data::Manifest;
use crate::error::Result;

/// The bundled virtual campaign, relative to the project folder.
pub const BUNDLED: &str = "data/campaign.toml";

/// The bundled measured campaign.
pub const MEASURED: &str = "data/utfsm-mts/campaign.toml";

/// The current at which the bundled job calibrates the measured damper.
const MEASURED_CURRENT_A: f64 = 1.0;

impl Pipeline<'_> {
    /// The whole job on the bundled campaigns (run from the project folder,
    /// where [`BUNDLED`] is): the virtual paper replica — every current,
    /// leave-one-out and the comparison — into `reports/<its name>`, then
    /// the measured damper at 1 A (the B-P law alone, the variant that
    /// predicts held-out runs best; docs/real-data.md) into
    /// `reports/utfsm-mts`. Its leave-one-out, which refits most runs, is
    /// left to `--leave-one-out`; the current-law studies to `just law`.
    /// The job is the demo: it replaces its own earlier results. Returns
    /// the reports written.
    pub fn bundled(&mut self) -> Result<Vec<PathBuf>> {
        let job = |sample: SampleOptions, leave_one_out: bool| -> Result<RunOptions> {
            Ok(RunOptions {
                sample: sample.request()?,
                predict: Default::default(),
                leave_one_out: LooOptions { leave_one_out, loo_steps: crate::validate::LooSettings::default().steps }.steps(),
                current_law: false,
            })
        };
        let replace = SampleOptions { force: true, ..Default::default() };
        let into = |manifest: &Path| -> Result<PathBuf> { Ok(Path::new("reports").join(Manifest::read(manifest)?.name)) };
        let manifest = Path::new(BUNDLED);
        let mut reports = self.run(manifest, &into(manifest)?, &job(replace.clone(), true)?)?;
        let measured = Path::new(MEASURED);
        if measured.exists() {
            let sample = SampleOptions { current: Some(MEASURED_CURRENT_A), ..replace };
            reports.extend(self.run(measured, &into(measured)?, &job(sample, false)?)?);
        }
        Ok(reports)
    }
}
