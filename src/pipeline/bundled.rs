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
                leave_one_out: LooOptions {
                    leave_one_out,
                    loo_steps: crate::validate::LooSettings::default().steps,
                    loo_refit: false,
                }
                .request(),
                current_law: false,
            })
        };
        let replace = SampleOptions { force: true, ..Default::default() };
        let into = |manifest: &Path| -> Result<PathBuf> {
            Ok(Path::new("reports").join(Manifest::read(manifest)?.name))
        };
        let (manifest, measured) = (Path::new(BUNDLED), Path::new(MEASURED));
        let mut parts = vec![(manifest, into(manifest)?, job(replace.clone(), true)?)];
        if measured.exists() {
            parts.push((
                measured,
                into(measured)?,
                job(SampleOptions { current: Some(MEASURED_CURRENT_A), ..replace }, false)?,
            ));
        }
        let reports =
            self.side_by_side(&parts, |p, (manifest, out, options)| p.run(manifest, out, options))?;
        Ok(reports.into_iter().flatten().collect())
    }
}
