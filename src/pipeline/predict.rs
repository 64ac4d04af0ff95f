//! Bands, leave-one-out and the report of a calibration folder.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::{Event, Pipeline, PredictOptions};
use crate::calibrate::{command_line, Calibration};
use crate::data::{same_current, Campaign, RecordPart, Run, RunData};
use crate::error::{Error, Result};
use crate::pointwise::{pointwise_draws, POINTWISE_DRAWS};
use crate::posterior::Draw;
use crate::predict::adequacy::{self, AdequacyRow};
use crate::predict::{predict_run, Prediction, PredictionRecord, RunBands};
use crate::report::{self, CalibrationReport, PredictionReport};
use crate::store::{self, inference::StoreInfo};
use crate::validate::{leave_one_out, LeaveOneOut, LooRow, LooSettings};

impl Pipeline<'_> {
    /// Posterior draws of `cal` through the integrator along every run of
    /// `campaign` that it should predict (its own runs; every run for a
    /// current law, seen or not): `bands.parquet`, `coverage.parquet`,
    /// `adequacy.parquet` and `prediction.toml` into `out`.
    pub fn predict(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        out: &Path,
        options: &PredictOptions,
    ) -> Result<Prediction> {
        self.prepare(out, "--out", &[campaign], &[], true)?;
        let (prediction, failed) = self.own_prediction(cal, campaign, options)?;
        self.write_prediction(&prediction, out)?;
        self.write_inference_data(cal, campaign, out, options.seed)?;
        unpredicted(&failed, out)?;
        Ok(prediction)
    }

    /// [`Pipeline::prediction`] of the runs of `campaign` that `cal` should
    /// predict (its own runs; every run for a current law, seen or not), in
    /// memory.
    pub fn own_prediction(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        options: &PredictOptions,
    ) -> Result<(Prediction, Vec<(String, String)>)> {
        let runs = if cal.is_current_law() { campaign.clone() } else { cal.used_runs(campaign) };
        self.prediction(cal, &runs, &|run| cal.saw(run.id()), options)
    }

    /// `inference.zarr`: [`Pipeline::inference_data`] into `out`.
    fn write_inference_data(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        out: &Path,
        seed: u64,
    ) -> Result<()> {
        let data = self.inference_data(cal, campaign, seed)?;
        let path = out.join(store::inference::FILE);
        store::inference::write(&path, &data)?;
        self.emit(Event::Wrote(&path));
        Ok(())
    }

    /// The posterior, the pointwise log-likelihood and replicated records of
    /// a thinned set of draws, along the runs of `campaign` the calibration
    /// saw, as ArviZ's InferenceData (in memory).
    pub fn inference_data(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        seed: u64,
    ) -> Result<store::inference::InferenceData> {
        let likelihood = &cal.settings.likelihood;
        let runs: Vec<RunData> = campaign
            .runs
            .iter()
            .filter(|run| cal.saw(run.id()))
            .map(|run| likelihood.run_data(run, likelihood.part))
            .collect();
        if runs.len() != cal.record.runs.len() {
            return Err(Error::Usage(format!(
                "{} does not hold every run of the calibration: {:?}",
                campaign.name, cal.record.runs
            )));
        }
        let chains = &cal.sample.chains;
        let stride = cal.draws().thin;
        let steps = cal.draws().steps(chains, POINTWISE_DRAWS);
        let integrator = cal.predict_settings(1, seed).integrator;
        let draws = pointwise_draws(
            &cal.sample,
            &runs,
            &steps,
            &integrator,
            cal.settings.noise_model().as_ref(),
            seed,
        );
        if draws.failed > 0 {
            self.note(&format!("inference data: {} of {} pointwise draws could not be integrated along every run (their log-likelihood is -inf)", draws.failed, steps.len() * chains.chains()));
        }
        let info = StoreInfo {
            calibration_id: &cal.record.calibration_id,
            burn_in: cal.burn_in(),
            ensembles: chains.ensembles,
            stride,
        };
        Ok(store::inference::inference_data(&cal.sample, draws, &info))
    }

    /// Posterior draws of `cal` along the runs of another campaign — another
    /// excitation, a later test of the same damper, a current the
    /// calibration never saw (a current law's): bands, coverage, adequacy
    /// and a report into `out`. No run counts as seen unless `campaign` is
    /// the calibration's own manifest. A per-current calibration predicts
    /// only the runs at its current.
    pub fn predict_campaign(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        out: &Path,
        options: &PredictOptions,
    ) -> Result<(PathBuf, Prediction)> {
        self.prepare(out, "--out", &[campaign], &[], true)?;
        let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
        let own = canonical(&campaign.manifest_path) == canonical(Path::new(&cal.record.manifest));
        let runs = if cal.is_current_law() {
            let (lo, hi) = cal.current_range();
            for run in campaign
                .runs
                .iter()
                .filter(|r| r.spec.current_a < lo - 1e-9 || r.spec.current_a > hi + 1e-9)
            {
                self.note(&format!("{}: {} A is outside the calibrated currents {lo}–{hi} A: the current law extrapolates", run.id(), run.spec.current_a));
            }
            campaign.clone()
        } else {
            let at = cal.record.current_a;
            let kept = campaign.filtered(|r| same_current(r.spec.current_a, at));
            if kept.runs.is_empty() {
                return Err(Error::Usage(format!(
                    "{} has no run at {at} A, the current of the calibration in {}; a current law (mrbp sample --model current-law) predicts other currents",
                    campaign.manifest_path.display(),
                    cal.dir.display()
                )));
            }
            let skipped = campaign.runs.len() - kept.runs.len();
            if skipped > 0 {
                self.note(&format!("{skipped} run(s) of {} at other currents than {at} A skipped: a per-current calibration does not predict them", campaign.name));
            }
            kept
        };
        let (prediction, failed) =
            self.prediction(cal, &runs, &|run| own && cal.saw(run.id()), options)?;
        self.write_prediction(&prediction, out)?;
        let predicted = runs.filtered(|r| !failed.iter().any(|(id, _)| id == r.id()));
        let path = report::prediction::write(&PredictionReport {
            cal,
            campaign: &predicted,
            dir: out,
            prediction: &prediction,
        })?;
        self.emit(Event::Wrote(&path));
        unpredicted(&failed, out)?;
        Ok((path, prediction))
    }

    /// The prediction's tables and `prediction.toml` into `out`.
    fn write_prediction(&mut self, prediction: &Prediction, out: &Path) -> Result<()> {
        store::prediction::write(out, prediction)?;
        self.emit(Event::Predicted { record: &prediction.record, dir: out });
        Ok(())
    }

    /// Bands, coverage and adequacy of `campaign`'s runs, in memory; `seen`
    /// tells the runs the calibration saw (their own noise level and force
    /// offset) from those it did not (the others' typical ones). A run that
    /// cannot be predicted (no draw integrates along it) is left out, with
    /// why (the second value); if none can be, an error.
    pub fn prediction(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        seen: &dyn Fn(&Run) -> bool,
        options: &PredictOptions,
    ) -> Result<(Prediction, Vec<(String, String)>)> {
        options.check()?;
        let clock = Instant::now();
        let positions = cal.draw_positions(options.draws);
        let settings = cal.predict_settings(options.replicates, options.seed);
        let bar = self.bar((positions.len() * campaign.runs.len()) as u64);
        let mut bands = Vec::new();
        let mut coverage = Vec::new();
        let mut failed = Vec::new();
        for (j, run) in campaign.runs.iter().enumerate() {
            let data = cal.settings.likelihood.run_data(run, RecordPart::WholeRecord);
            let calibrated = seen(run);
            let (id, current) = (run.id(), run.spec.current_a);
            let draws: Vec<Draw> = match calibrated {
                true => cal.sample.draws(&positions, id, current),
                false => positions
                    .iter()
                    .map(|&(s, c)| cal.sample.draw_without(s, c, id, current))
                    .collect(),
            };
            match predict_run(run, &data, j, &draws, &settings, calibrated, &|| bar.inc(1)) {
                Ok(p) => {
                    bands.push(p.bands);
                    coverage.push(p.coverage);
                }
                Err(Error::Compute(why)) => failed.push((id.to_string(), why)),
                Err(e) => return Err(e),
            }
        }
        bar.finish_and_clear();
        if bands.is_empty() {
            let whys: Vec<String> = failed.iter().map(|(_, why)| why.clone()).collect();
            return Err(Error::Compute(format!("no run could be predicted: {}", whys.join("; "))));
        }
        let geometry = &campaign.geometry;
        let adequacy: Vec<AdequacyRow> =
            bands.iter().map(|b| adequacy::assess(b, geometry.area_m2, geometry.gap_m)).collect();
        let record = PredictionRecord {
            mrbp_version: env!("CARGO_PKG_VERSION").to_string(),
            command: command_line(),
            draws: positions.len(),
            burn_in: cal.burn_in(),
            thin: cal.draws().thin,
            noise_replicates: options.replicates,
            seed: options.seed,
            substeps: settings.integrator.substeps,
            seconds: clock.elapsed().as_secs_f64(),
            calibration_id: cal.record.calibration_id.clone(),
            coverage: coverage.clone(),
        };
        let prediction = Prediction { bands, coverage, adequacy, record };
        Ok((prediction, failed))
    }

    /// The leave-one-out study of `cal` (whose runs are in `campaign`):
    /// `loo.parquet` and `loo_bands.parquet` in its folder. A calibration of
    /// a single run has nothing to leave out: `None`.
    pub fn leave_one_out(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        loo: &LooSettings,
    ) -> Result<Option<LeaveOneOut>> {
        if loo.steps < 10 {
            return Err(Error::Usage(format!(
                "--loo-steps must be at least 10, got {}",
                loo.steps
            )));
        }
        let campaign = cal.used_runs(campaign);
        if campaign.runs.len() < 2 {
            self.note(&format!(
                "leave-one-out skipped: the calibration in {} has a single run",
                cal.dir.display()
            ));
            return Ok(None);
        }
        // the study goes into the calibration's folder: held before the work
        self.prepare(&cal.dir, "--out", &[], &[], true)?;
        if loo.resume {
            if let Some(kept) = self.kept_leave_one_out(cal, loo)? {
                return Ok(Some(kept));
            }
        }
        let clock = Instant::now();
        let progress = self.progress;
        let listener = &mut *self.listener;
        let refit = loo.refit;
        let mut observe = |run: &str| {
            let why = if refit {
                "every held-out run refitted (--loo-refit)".to_string()
            } else {
                format!("no importance weights can be trusted for {run} (k̂ > 0.7)")
            };
            listener(Event::Note(&format!("  leave-one-out: {why}: sampling without {run}")));
            Pipeline::observers_for(progress)
        };
        let held = leave_one_out(cal, &campaign, loo, &mut observe)?;
        for (run, why) in
            held.iter().filter_map(|h| Some((&h.row.coverage.run, h.row.failure.as_ref()?)))
        {
            self.note(&format!(
                "  leave-one-out: {run} could not be held out ({why}): loo.parquet marks it \"failed\", without bands; the other runs are held out"
            ));
        }
        let (bands, rows): (Vec<Option<RunBands>>, Vec<LooRow>) =
            held.into_iter().map(|h| (h.prediction.map(|p| p.bands), h.row)).unzip();
        let bands: Vec<RunBands> = bands.into_iter().flatten().collect();
        let study = LeaveOneOut { rows, bands };
        store::coverage::write_leave_one_out(
            &cal.dir,
            &study,
            &cal.record.calibration_id,
            &loo.described(),
        )?;
        self.emit(Event::LeftOneOut { rows: &study.rows, seconds: clock.elapsed().as_secs_f64() });
        Ok(Some(study))
    }

    /// With `--resume`, the leave-one-out study already in `cal`'s folder,
    /// whole, where it was made from this calibration with the settings
    /// `loo` describes: a long study stopped half-way goes on from the
    /// held-out studies it finished as from its calibrations.
    fn kept_leave_one_out(
        &mut self,
        cal: &Calibration,
        loo: &LooSettings,
    ) -> Result<Option<LeaveOneOut>> {
        let made_with = store::coverage::leave_one_out_settings(&cal.dir)?;
        if made_with.as_deref() != Some(loo.described().as_str()) {
            return Ok(None);
        }
        // one derived from another calibration is not this one's
        let Ok(Some(study)) =
            store::coverage::read_leave_one_out(&cal.dir, &cal.record.calibration_id)
        else {
            return Ok(None);
        };
        self.note(&format!(
            "--resume: {} already holds this calibration's leave-one-out, made with the same settings: kept",
            cal.dir.display()
        ));
        self.emit(Event::LeftOneOut { rows: &study.rows, seconds: 0.0 });
        Ok(Some(study))
    }

    /// Bands, leave-one-out (if `loo` is given) and the report of a
    /// calibration just made, from memory.
    pub(super) fn predict_and_report(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        options: &PredictOptions,
        loo: Option<&LooSettings>,
    ) -> Result<(PathBuf, Prediction)> {
        let prediction = self.predict(cal, campaign, &cal.dir, options)?;
        let loo = match loo {
            Some(settings) => self.leave_one_out(cal, campaign, settings)?,
            None => None,
        };
        Ok((self.write_report(cal, campaign, &prediction, loo.as_ref())?, prediction))
    }

    /// The report of the calibration folder `dir`, from its files: the bands
    /// are predicted first if the folder has none, and the leave-one-out
    /// study is run if `loo` is given (else an earlier one is shown).
    pub fn report(
        &mut self,
        dir: &Path,
        options: &PredictOptions,
        loo: Option<&LooSettings>,
    ) -> Result<PathBuf> {
        self.prepare(dir, "DIR", &[], &[], true)?;
        let cal = store::folder::read(dir)?;
        let campaign = cal.full_campaign()?;
        let prediction = match store::prediction::read(dir)? {
            Some(p) if p.record.calibration_id == cal.record.calibration_id => p,
            Some(_) => {
                self.note(&format!("the bands in {} come from another calibration than its chains: predicting again", dir.display()));
                self.predict(&cal, &campaign, dir, options)?
            }
            None => {
                self.note(&format!("no bands in {} yet: predicting first", dir.display()));
                self.predict(&cal, &campaign, dir, options)?
            }
        };
        let loo = match loo {
            Some(settings) => self.leave_one_out(&cal, &campaign, settings)?,
            None => store::coverage::read_leave_one_out(dir, &cal.record.calibration_id)?,
        };
        self.write_report(&cal, &campaign, &prediction, loo.as_ref())
    }

    pub(super) fn write_report(
        &mut self,
        cal: &Calibration,
        campaign: &Campaign,
        prediction: &Prediction,
        loo: Option<&LeaveOneOut>,
    ) -> Result<PathBuf> {
        let consistency = match cal.dir.join(store::consistency::FILE).exists() {
            true => Some(store::consistency::read(&cal.dir, &cal.record.calibration_id)?),
            false => None,
        };
        let new_test_loo =
            store::between_runs::read_leave_one_out(&cal.dir, &cal.record.calibration_id)?;
        let report = CalibrationReport {
            cal,
            campaign: &cal.used_runs(campaign),
            prediction,
            loo,
            consistency: consistency.as_deref(),
            new_test_loo: new_test_loo.as_deref(),
        };
        let path = report::calibration::write(&report)?;
        self.emit(Event::Wrote(&path));
        Ok(path)
    }

    /// A progress bar of `len` steps, hidden unless progress is wanted.
    pub(super) fn bar(&self, len: u64) -> indicatif::ProgressBar {
        if !self.progress {
            return indicatif::ProgressBar::hidden();
        }
        let bar = indicatif::ProgressBar::new(len);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "predicting {bar:30} {pos}/{len} run draws  ETA {eta}",
            )
            .expect("valid template"),
        );
        bar
    }
}

/// The runs a prediction left out, as the error that ends the command
/// (exit 1) once the others are written into `out`.
fn unpredicted(failed: &[(String, String)], out: &Path) -> Result<()> {
    if failed.is_empty() {
        return Ok(());
    }
    let which: Vec<&str> = failed.iter().map(|(id, _)| id.as_str()).collect();
    let whys: Vec<&str> = failed.iter().map(|(_, why)| why.as_str()).collect();
    Err(Error::Compute(format!(
        "{} run(s) could not be predicted ({}): {}; the other runs' bands are in {}",
        failed.len(),
        which.join(", "),
        whys.join("; "),
        out.display()
    )))
}
