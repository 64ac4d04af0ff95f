//! The bundled job: `mrbp` alone, in the project folder.

use std::path::{Path, PathBuf};

use super::{Event, LooOptions, Pipeline, RunOptions, SampleOptions};
use crate::data::Manifest;
use crate::error::{Error, Result};

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
    /// The two parts run side by side, on threads of their own sharing the
    /// sampler's thread pool, so the serial stretches of one (figures,
    /// reports, tables) overlap the other's sampling; each part's numbers
    /// are the same bits as alone. The measured part tells its events to
    /// `beside`, without progress bars.
    pub fn bundled(&mut self, beside: &mut (dyn FnMut(Event<'_>) + Send)) -> Result<Vec<PathBuf>> {
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
        std::thread::scope(|scope| {
            let other = measured_job.map(|(out, options)| scope.spawn(move || Pipeline::new(beside, false).run(measured, &out, &options)));
            let mut reports = self.run(manifest, &virtual_job.0, &virtual_job.1);
            if let Some(other) = other {
                let measured_reports = other.join().map_err(|_| Error::Compute("the measured damper's part of the job stopped unexpectedly".into()))?;
                match (&mut reports, measured_reports) {
                    (Ok(all), Ok(more)) => all.extend(more),
                    (Ok(_), Err(e)) => reports = Err(e),
                    (Err(_), _) => {}
                }
            }
            reports
        })
    }
}
