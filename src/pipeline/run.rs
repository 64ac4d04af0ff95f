//! The whole job on one campaign.

use std::path::{Path, PathBuf};

use super::calibrate::CurrentCalibrations;
use super::{compare, Pipeline, RunOptions, SampleRequest};
use crate::data::{current_tag, Campaign};
use crate::error::Result;
use crate::posterior::ModelKind;
use crate::predict::Prediction;
use crate::report::comparison::Entry;
use crate::validate::{LeaveOneOut, LooSettings};

impl Pipeline<'_> {
    /// The whole job on one campaign: one calibration folder per current in
    /// `out/I<current>A/` (identification, posterior, bands, leave-one-out,
    /// report); then, with several currents, the current law in
    /// `out/current-law…/` and the comparison in `out/comparison/`.
    /// Returns the reports written. With a renderer
    /// ([`Pipeline::rendering`]) the currents are calibrated side by side,
    /// each telling its events whole after the one before; the results are
    /// the same bits as in turn.
    pub fn run(
        &mut self,
        manifest: &Path,
        out: &Path,
        options: &RunOptions,
    ) -> Result<Vec<PathBuf>> {
        super::one_current_or_a_law(options.sample.current, options.sample.settings.model)?;
        if options.sample.laws.len() > 1 {
            return self.run_laws(manifest, out, options);
        }
        let campaign = self.check(manifest)?;
        let all = campaign.currents();
        let currents = match options.sample.current {
            Some(c) => vec![c],
            None => all.clone(),
        };
        let loo = options.leave_one_out.map(|r| crate::validate::LooSettings {
            resume: options.sample.resume,
            ..self.loo_settings(r, &options.predict)
        });
        let several = options.sample.current.is_none() && all.len() >= 2;
        if options.current_law && !several {
            self.note("the current law spans the currents of a campaign, and this one has runs at one current only: each current is calibrated on its own, and no law");
        }
        let held: Vec<f64> =
            if several && all.len() >= 3 { vec![all[all.len() / 2]] } else { vec![] };
        // the law stage fits the law the settings name (`--model
        // current-curves`), else the current law; every current alone is per-current
        let law_kind = if options.sample.settings.model.is_law() {
            options.sample.settings.model
        } else {
            ModelKind::CurrentLaw
        };
        let stem =
            if law_kind == ModelKind::CurrentCurves { "current-curves" } else { "current-law" };
        let law = match held.first() {
            Some(h) => format!("{stem}-without-{}", current_tag(*h)),
            None => stem.to_string(),
        };
        // every folder of the job is held from the start: another command
        // cannot slip into one of them half-way through
        let mut folders: Vec<PathBuf> =
            currents.iter().map(|c| out.join(current_tag(*c))).collect();
        if several {
            folders.extend(options.current_law.then(|| out.join(&law)));
            folders.push(out.join("comparison"));
        }
        for dir in &folders {
            self.prepare(dir, "--out", &[&campaign], &[], true)?;
        }
        let mut reports = Vec::new();
        let mut entries = Vec::new();
        let stages = self.side_by_side(&currents, |p, &c| {
            p.at_current(&campaign, out, c, options, loo.as_ref())
        })?;
        let (done, deferred): (Vec<CurrentStage>, Vec<CurrentStage>) =
            stages.into_iter().partition(|s| s.deferred.is_none());
        for stage in done {
            reports.extend(stage.reports);
            entries.extend(stage.entries);
        }
        // with --per-run, the between-run layer takes every current's runs
        // alone before each current's report shows what it says
        let deferred: Vec<Deferred> = deferred.into_iter().filter_map(|s| s.deferred).collect();
        if !deferred.is_empty() {
            let calibrations: Vec<CurrentCalibrations> =
                deferred.iter().map(|d| d.calibrations.clone()).collect();
            self.between_runs(&calibrations, loo.as_ref())?;
            for d in deferred {
                let joint = d.calibrations.joint;
                reports.push(self.write_report(
                    &joint,
                    &campaign,
                    &d.prediction,
                    d.loo.as_ref(),
                )?);
                entries.push(compare::entry(joint, Some(d.prediction)));
            }
        }
        if several {
            if options.current_law {
                // hold out the middle current: the law must predict it
                let name = law;
                let mut settings = options.sample.settings.clone();
                settings.model = law_kind;
                let request =
                    SampleRequest { settings, hold_out_current: held, ..options.sample.clone() };
                for cal in self.sample(&campaign, &out.join(name), &request)? {
                    let (report, prediction) =
                        self.predict_and_report(&cal, &campaign, &options.predict, None)?;
                    reports.push(report);
                    entries.push(compare::entry(cal, Some(prediction)));
                }
            }
            reports.push(self.compare_entries(entries, &out.join("comparison"), None)?);
        }
        Ok(reports)
    }

    /// One current of the whole job: its calibration, bands, leave-one-out
    /// (if `loo`) and report, in `out/I<current>A/`; with `--per-run` also
    /// each run alone, and the report left for after the between-run layer.
    fn at_current(
        &mut self,
        campaign: &Campaign,
        out: &Path,
        c: f64,
        options: &RunOptions,
        loo: Option<&LooSettings>,
    ) -> Result<CurrentStage> {
        let mut request =
            SampleRequest { current: Some(c), per_run: false, ..options.sample.clone() };
        request.settings.model = ModelKind::PerCurrent;
        let mut stage = CurrentStage { reports: Vec::new(), entries: Vec::new(), deferred: None };
        for joint in self.sample(campaign, &out.join(current_tag(c)), &request)? {
            let runs = campaign.at_current(c);
            let where_memory = options.sample.per_run_where_memory
                && joint.record.memory_found.is_some()
                && runs.runs.len() >= super::PER_RUN_WHERE_MEMORY;
            if options.sample.per_run || where_memory {
                let alone = self.runs_alone(&runs, &joint, &request)?;
                let prediction = self.predict(&joint, campaign, &joint.dir, &options.predict)?;
                let loo = match loo {
                    Some(settings) => self.leave_one_out(&joint, campaign, settings)?,
                    None => None,
                };
                stage.deferred = Some(Deferred {
                    calibrations: CurrentCalibrations { joint, runs, alone },
                    prediction,
                    loo,
                });
                continue;
            }
            let (report, prediction) =
                self.predict_and_report(&joint, campaign, &options.predict, loo)?;
            stage.reports.push(report);
            stage.entries.push(compare::entry(joint, Some(prediction)));
        }
        Ok(stage)
    }
}

/// What one current's stage wrote: its reports, and its calibrations as the
/// comparison takes them; with `--per-run`, what its report waits for.
struct CurrentStage {
    reports: Vec<PathBuf>,
    entries: Vec<Entry>,
    deferred: Option<Deferred>,
}

/// A current whose report waits for the between-run layer.
struct Deferred {
    calibrations: CurrentCalibrations,
    prediction: Prediction,
    loo: Option<LeaveOneOut>,
}
