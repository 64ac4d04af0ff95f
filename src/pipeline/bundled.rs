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
    /// leave-one-out and the comparison — into `reports/<its name>`, and
    /// the measured damper at 1 A (the B-P law alone, the variant that
    /// predicts held-out runs best; docs/real-data.md) into
    /// `reports/utfsm-mts`. Its leave-one-out, which refits most runs, is
    /// left to `--leave-one-out`; the current-law studies to `just law`.
    /// The job is the demo: it replaces its own earlier results. Returns
    /// the reports written.
    ///
    /// With a renderer ([`Pipeline::rendering`]) the two parts run side by
    /// side, on threads sharing the sampler's thread pool, so the serial
    /// stretches of one (figures, reports, tables) overlap the other's
    /// sampling; each part's numbers are the same bits as alone. The
    /// measured part's events are told after the virtual part's.
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
        let virtual_job = (into(manifest)?, job(replace.clone(), true)?);
        let measured = Path::new(MEASURED);
        let measured_job = match measured.exists() {
            true => Some((into(measured)?, job(SampleOptions { current: Some(MEASURED_CURRENT_A), ..replace }, false)?)),
            false => None,
        };
        let Some(render) = self.render else {
            let mut reports = self.run(manifest, &virtual_job.0, &virtual_job.1)?;
            if let Some((out, options)) = measured_job {
                reports.extend(self.run(measured, &out, &options)?);
            }
            return Ok(reports);
        };
        std::thread::scope(|scope| {
            let other = measured_job.map(|(out, options)| scope.spawn(move || Pipeline::beside(render, |p| p.run(measured, &out, &options))));
            let reports = self.run(manifest, &virtual_job.0, &virtual_job.1);
            let measured_reports = other.map(|o| self.join_beside(o.join()));
            let mut reports = reports?;
            if let Some(more) = measured_reports {
                reports.extend(more?);
            }
            Ok(reports)
        })
    }
}
