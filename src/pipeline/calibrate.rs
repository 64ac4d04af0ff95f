//! Identification and calibration into folders.

use std::path::Path;

use super::{folders, Event, Pipeline, SampleRequest};
use crate::calibrate::{self, Calibration, CalibrationSettings};
use crate::data::RunData;
use crate::data::{current_tag, same_current, Campaign};
use crate::error::{Error, Result};
use crate::identify::{identify_campaign, CurrentIdentification, IdentifySettings};
use crate::posterior::ModelKind;
use crate::report;
use crate::sampler::{Checkpointer, Observer};
use crate::store;
use crate::validate::between_runs::{self, BetweenRuns, GibbsSettings, LayerRun, LeftOut};
use crate::validate::consistency::consistency;
use crate::validate::LooSettings;
use std::time::Instant;

/// Steps between two checkpoints of the sampler.
pub const CHECKPOINT_EVERY: usize = 100;

/// Checks a checkpoint against the options before any work: readable, the
/// same sampler (ensembles, walkers where given, moves — or the curved
/// ones a start far from its Laplace approximation took instead — seed),
/// and not longer than a fixed `--steps`.
pub fn check_resumable(checkpoint: &Path, settings: &CalibrationSettings) -> Result<()> {
    if !checkpoint.exists() {
        return Ok(());
    }
    let (saved, chains) = crate::sampler::checkpoint::read(checkpoint)?;
    let s = &settings.sampler;
    let mismatch = |what: &str, theirs: String, ours: String| {
        Err(Error::input(checkpoint, format!("--resume: the checkpoint was made with {what} {theirs}, the options ask for {ours}; use the same options, or start afresh with --force")))
    };
    if saved.seed != s.seed {
        return mismatch("--seed", saved.seed.to_string(), s.seed.to_string());
    }
    if saved.ensembles != s.ensembles {
        return mismatch("--ensembles", saved.ensembles.to_string(), s.ensembles.to_string());
    }
    if s.walkers != 0 && saved.walkers != s.walkers {
        return mismatch("--walkers", saved.walkers.to_string(), s.walkers.to_string());
    }
    // the moves asked for, or those a start far from its Laplace
    // approximation walks with instead (docs/calibration.md, "The start")
    if saved.moves != s.moves
        && crate::calibrate::settings::moves_far_from_laplace(&s.moves)
            .is_none_or(|m| m != saved.moves)
    {
        return mismatch("moves", format!("{:?}", saved.moves), format!("{:?}", s.moves));
    }
    let done = chains.steps().saturating_sub(1);
    if s.steps > 0 && done > s.steps {
        return Err(Error::Usage(format!("--steps {} is fewer than the {done} steps the checkpoint already holds: ask for at least {done}", s.steps)));
    }
    Ok(())
}

impl Pipeline<'_> {
    /// The paper's identification of every current level of `campaign`:
    /// `identification.parquet` and Figs. 1–5 in `out` (an earlier
    /// identification there is replaced only if `force`).
    pub fn identify(
        &mut self,
        campaign: &Campaign,
        out: &Path,
        settings: &IdentifySettings,
        force: bool,
    ) -> Result<Vec<CurrentIdentification>> {
        self.prepare(out, "--out", &[campaign], &folders::IDENTIFICATION, force)?;
        campaign.require_usable("the identification")?;
        let results = identify_campaign(campaign, settings);
        store::identification::write(&out.join(store::identification::FILE), &results, None)?;
        report::identification::write(out, campaign, &results)?;
        self.emit(Event::Identified(&results));
        Ok(results)
    }

    /// Calibrations of `campaign` as `request` says: one per current level
    /// (in `out`, or `out/I<current>A/` when there are several), or one
    /// current law over the currents not held out. Returns the folders.
    pub fn sample(
        &mut self,
        campaign: &Campaign,
        out: &Path,
        request: &SampleRequest,
    ) -> Result<Vec<Calibration>> {
        let settings = &request.settings;
        campaign.require_usable("the calibration")?;
        super::one_current_or_a_law(request.current, settings.model)?;
        self.prepare(out, "--out", &[campaign], &[], true)?;
        if settings.parameter_model().is_current_law() {
            let held = &request.hold_out_current;
            if let Some(h) = held.iter().find(|h| !campaign.has_current(**h)) {
                return Err(Error::Usage(format!(
                    "--hold-out-current {h}: no run at {h} A (currents: {:?})",
                    campaign.currents()
                )));
            }
            let used =
                campaign.filtered(|r| !held.iter().any(|h| same_current(r.spec.current_a, *h)));
            let law = if settings.model == crate::posterior::ModelKind::CurrentCurves {
                "the current curves"
            } else {
                "the current law"
            };
            let what = format!(
                "{law} on {} run(s) at {:?} A{}",
                used.runs.len(),
                used.currents(),
                if held.is_empty() { String::new() } else { format!(" (holding out {held:?} A)") }
            );
            return Ok(vec![self.calibrate_into(&used, out, request, &what, false)?]);
        }
        if !request.hold_out_current.is_empty() {
            return Err(Error::Usage(
                "--hold-out-current needs --model current-law or current-curves".into(),
            ));
        }
        let varying = campaign.varying_runs();
        if !varying.is_empty() {
            self.note(&format!(
                "{}: the current changes within the record; one parameter set per current cannot describe it, so it is left out here (--model current-curves or current-law calibrates it)",
                varying.join(", ")
            ));
        }
        let currents = match request.current {
            Some(c) if !campaign.has_current(c) => {
                return Err(Error::Usage(format!(
                    "no run at {c} A in {} (currents: {:?})",
                    campaign.manifest_path.display(),
                    campaign.currents()
                )))
            }
            Some(c) => vec![c],
            None => campaign.currents(),
        };
        let mut stages = Vec::new();
        for &c in &currents {
            let dir = if currents.len() > 1 { out.join(current_tag(c)) } else { out.to_path_buf() };
            stages.push(self.calibrate_current(campaign, c, &dir, request)?);
        }
        if request.per_run {
            self.between_runs(&stages, None)?;
        }
        Ok(stages.into_iter().map(|s| s.joint).collect())
    }

    /// The runs of `campaign` at current `c` calibrated together into
    /// `dir`, and with `--per-run` each alone into `dir/runs/<run>/`.
    pub fn calibrate_current(
        &mut self,
        campaign: &Campaign,
        c: f64,
        dir: &Path,
        request: &SampleRequest,
    ) -> Result<CurrentCalibrations> {
        let runs = campaign.at_current(c);
        let what = format!("{} run(s) at {c} A", runs.runs.len());
        let joint = self.calibrate_into(&runs, dir, request, &what, false)?;
        let alone =
            if request.per_run { self.runs_alone(&runs, &joint, request)? } else { Vec::new() };
        Ok(CurrentCalibrations { joint, runs, alone })
    }

    /// Each run of `campaign` calibrated alone as `request` says, into
    /// `runs/<run>/` of the joint calibration's folder.
    pub fn runs_alone(
        &mut self,
        campaign: &Campaign,
        joint: &Calibration,
        request: &SampleRequest,
    ) -> Result<Vec<(String, Calibration)>> {
        // each run's MAP search starts from the joint calibration's MAP
        // (the same law at the same current) where the joint posterior is
        // near its Laplace approximation: the same optimum in fewer
        // evaluations. Not where it is far: Spencer's 25 mm / 0.25 Hz test
        // at 1 A alone, started there, found a lower mode whose walkers
        // missed the shape's long tail (sd 0.34 where sequential Monte
        // Carlo gives 2.5; from its own starts 1.8)
        let from_joint = joint.started_near_laplace()
            && joint.settings.model == ModelKind::PerCurrent
            && request.settings.model == ModelKind::PerCurrent
            && joint.settings.law == request.settings.law
            && request.settings.map_start.is_empty();
        let layout = &joint.sample.layout;
        let mut alone = Vec::new();
        for run in &campaign.runs {
            let id = run.id().to_string();
            let one = campaign.filtered(|r| r.id() == id);
            let dir = joint.dir.join(folders::RUNS).join(&id);
            let mut request = request.clone();
            if let Some(j) = layout.run_index(&id).filter(|_| from_joint) {
                // the law's parameters and this run's own terms
                request.settings.map_start = layout
                    .fitted_names_of_run(j)
                    .filter_map(|n| joint.record.map.get(n).map(|v| (n.to_string(), *v)))
                    .collect();
            }
            alone.push((
                id.clone(),
                self.calibrate_into(&one, &dir, &request, &format!("run {id} alone"), true)?,
            ));
        }
        for (id, cal) in &alone {
            let rhat = cal.max_rhat();
            if !(rhat < 1.01) {
                self.note(&format!("  --per-run: {id} alone did not converge (largest R̂ {rhat:.3}): its row in the consistency table is not to be trusted (more --steps, or the history move: docs/calibration.md)"));
            }
        }
        Ok(alone)
    }

    /// The between-run layer fitted to every run calibrated alone in
    /// `stages` (at every current), and in each current's folder what it
    /// says there: the runs' consistency with the joint calibration and the
    /// layer's interval for a new test (`consistency.parquet`), the layer's
    /// draws (`between_runs.parquet`), and, with `loo`, each run predicted
    /// as a new test by the layer fitted without it (`loo_new_test.parquet`).
    pub fn between_runs(
        &mut self,
        stages: &[CurrentCalibrations],
        loo: Option<&LooSettings>,
    ) -> Result<()> {
        let Some(first) = stages.iter().find(|s| !s.alone.is_empty()) else {
            return Ok(());
        };
        if !stages.iter().any(|s| s.alone.len() >= 2) {
            self.note("  --per-run: a single run at each current, nothing to compare it with");
            return Ok(());
        }
        let lik = &first.joint.settings.likelihood;
        let datas: Vec<Vec<RunData>> = stages
            .iter()
            .map(|s| s.runs.runs.iter().map(|r| lik.run_data(r, lik.part)).collect())
            .collect();
        let layer_runs: Vec<LayerRun> = stages
            .iter()
            .zip(&datas)
            .flat_map(|(s, datas)| {
                s.alone.iter().filter_map(move |(id, cal)| {
                    let j = s.runs.runs.iter().position(|r| r.id() == id)?;
                    Some(LayerRun {
                        id,
                        current_a: s.runs.runs[j].spec.current_a,
                        cal,
                        data: &datas[j],
                    })
                })
            })
            .collect();
        let clock = Instant::now();
        let layer = BetweenRuns::fit(
            &layer_runs,
            &[],
            GibbsSettings::default(),
            first.joint.settings.sampler.seed,
        )?;
        let settled = between_runs::settled(layer.max_rhat, layer.min_ess);
        self.note(&format!(
            "\nbetween-run layer: {} runs alone at {:?} A, {} Gibbs chains: largest R̂ {:.4}, smallest ESS {:.0} ({:.1} s){}",
            layer_runs.len(),
            layer.currents,
            between_runs::CHAINS,
            layer.max_rhat,
            layer.min_ess,
            clock.elapsed().as_secs_f64(),
            if settled { "" } else { " — not converged: its new-test intervals are not to be trusted" }
        ));
        let folders: Vec<(&Path, &str)> = layer_runs
            .iter()
            .map(|r| (r.cal.dir.as_path(), r.cal.record.calibration_id.as_str()))
            .collect();
        let typical =
            layer.against_current(store::between_runs::ROWS, first.joint.settings.sampler.seed);
        for stage in stages.iter().filter(|s| !s.alone.is_empty()) {
            let joint = &stage.joint;
            let Some(group) = layer.group(joint.record.current_a) else { continue };
            self.prepare(&joint.dir, "--out", &[], &[], true)?;
            let meta = store::between_runs::layer_runs(&joint.dir, &folders);
            store::between_runs::write(
                &joint.dir, &layer, group, &joint.record.calibration_id, &meta,
            )?;
            if let Some(rows) = &typical {
                store::between_runs::write_typical(
                    &joint.dir, rows, &joint.record.calibration_id, &meta,
                )?;
            }
            if stage.alone.len() >= 2 {
                let parameters = consistency(joint, &stage.alone, &layer);
                let ids: Vec<(String, String)> = stage
                    .alone
                    .iter()
                    .map(|(run, cal)| (run.clone(), cal.record.calibration_id.clone()))
                    .collect();
                store::consistency::write(
                    &joint.dir, &parameters, &joint.record.calibration_id, &ids, &meta,
                )?;
                self.emit(Event::Consistency(&parameters));
            }
            if let Some(loo) = loo {
                let clock = Instant::now();
                let mut rows = Vec::new();
                for left_out in [LeftOut::Run, LeftOut::Current] {
                    rows.extend(between_runs::leave_out(
                        joint, &stage.runs, &layer_runs, left_out, loo.draws, loo.replicates,
                        loo.seed,
                    )?);
                }
                if !rows.is_empty() {
                    store::between_runs::write_leave_one_out(
                        &joint.dir, &rows, &joint.record.calibration_id, &meta,
                    )?;
                    self.emit(Event::NewTestLeftOut {
                        rows: &rows,
                        seconds: clock.elapsed().as_secs_f64(),
                    });
                } else {
                    self.note(&format!("  --per-run --leave-one-out: no run at {} A can be predicted as a new test without itself: the between-run layer fitted without it needs another run at its current, and two runs at one current at least", joint.record.current_a));
                }
            }
        }
        Ok(())
    }

    /// Calibrates `campaign` into `dir` as `request` says: identification,
    /// chains, summary, settings and record; the files derived from an
    /// earlier calibration there are removed. `what` names the calibration
    /// in messages.
    pub fn calibrate_into(
        &mut self,
        campaign: &Campaign,
        dir: &Path,
        request: &SampleRequest,
        what: &str,
        alone: bool,
    ) -> Result<Calibration> {
        let settings = &request.settings;
        let checkpoint = dir.join(store::folder::CHECKPOINT);
        let smc_checkpoint = dir.join(store::folder::SMC_CHECKPOINT);
        // an interrupted calibration's steps are not thrown away unasked
        if let (false, false, Some(found)) =
            (request.force, request.resume, store::folder::checkpoint_in(dir))
        {
            return Err(Error::Usage(format!(
                "{} holds {found}, {}",
                dir.display(),
                store::folder::INTERRUPTED
            )));
        }
        self.prepare(
            dir,
            "--out",
            &[campaign],
            &folders::CALIBRATION,
            request.force || request.resume,
        )?;
        if request.resume {
            check_resumable(&checkpoint, settings)?;
            if let Some(cal) = self.kept(campaign, dir, settings, &checkpoint) {
                self.emit(Event::Calibrated { cal: &cal, alone });
                return Ok(cal);
            }
        }
        let resume = request.resume && {
            let found = store::folder::checkpoint_in(dir).is_some();
            // a complete calibration of other settings was said above
            if !found && !dir.join(store::folder::RECORD).exists() {
                self.note(&format!(
                    "--resume: no {} in {} (stopped before sampling began?): starting from scratch",
                    store::folder::CHECKPOINT,
                    dir.display()
                ));
            }
            found
        };
        self.emit(Event::Calibrating { what, dir });
        let start =
            calibrate::start(campaign, settings, &mut |line| (self.listener)(Event::Note(line)))?;
        if resume {
            self.note(&format!("  resuming from {}", checkpoint.display()));
        }
        let mut observers = self.observers();
        let mut checkpointer = Checkpointer {
            path: checkpoint.clone(),
            every: CHECKPOINT_EVERY,
            stop: crate::interrupt::requested,
        };
        let mut refs: Vec<&mut dyn Observer> =
            observers.iter_mut().map(|o| o.as_mut() as &mut dyn Observer).collect();
        refs.push(&mut checkpointer);
        // where `auto` took the adjusted likelihood and the walkers reach
        // past the records, the tempered one instead (calibrate::edge)
        let listener = &mut *self.listener;
        let made = calibrate::sample_watched(
            campaign,
            settings,
            start,
            resume.then_some(&checkpoint),
            &mut refs,
            &mut |line| listener(Event::Note(line)),
        )
        .map_err(|e| match e {
            // stopped during sequential Monte Carlo's populations
            Error::Interrupted(m) if smc_checkpoint.exists() && !checkpoint.exists() => {
                Error::Interrupted(format!(
                    "{m}: the populations finished before it are in {}; the same command with --resume goes on from the next",
                    smc_checkpoint.display()
                ))
            }
            e => e,
        })?;

        let cal = self.write_calibration(
            campaign,
            dir,
            made.calibration,
            made.start.identification.as_ref(),
        )?;
        // the chains are complete in chains.parquet: the checkpoints have done their job
        let _ = std::fs::remove_file(&checkpoint);
        let _ = std::fs::remove_file(&smc_checkpoint);
        self.emit(Event::Calibrated { cal: &cal, alone });
        Ok(cal)
    }

    /// With `--resume`, the calibration `dir` already holds, complete (no
    /// checkpoint beside it), where it is the one asked for: of the same
    /// runs, its settings those `settings` resolve to
    /// ([`CalibrationSettings::asks_for`]). A long study stopped half-way
    /// (`run --law A,B,…`, say) goes on from the calibrations it finished.
    fn kept(
        &mut self,
        campaign: &Campaign,
        dir: &Path,
        settings: &CalibrationSettings,
        checkpoint: &Path,
    ) -> Option<Calibration> {
        if checkpoint.exists() || !dir.join(store::folder::RECORD).exists() {
            return None;
        }
        let runs: Vec<&str> = campaign.runs.iter().map(|r| r.id()).collect();
        let cal = store::folder::read(dir)
            .ok()
            .filter(|cal| cal.record.runs == runs && settings.asks_for(&cal.settings));
        let Some(cal) = cal else {
            self.note(&format!(
                "--resume: {} holds a calibration of other runs or settings: calibrating afresh",
                dir.display()
            ));
            return None;
        };
        self.note(&format!(
            "--resume: {} already holds this calibration, complete: kept ({})",
            dir.display(),
            cal.record.calibration_id
        ));
        Some(cal)
    }

    /// Writes `cal`, a calibration of `campaign` made in memory (from the
    /// Python package, say) that started from `identification` (the B-P
    /// law's; none for another law), into `dir`
    /// as `mrbp sample` would; an earlier calibration there is replaced
    /// only if `force`.
    /// A campaign that has no manifest on disk (made from records in
    /// memory) is written beside it first, into `records/`, so that the
    /// command line's predict and report find its records.
    pub fn save(
        &mut self,
        campaign: &Campaign,
        dir: &Path,
        mut cal: Calibration,
        identification: Option<&CurrentIdentification>,
        force: bool,
    ) -> Result<Calibration> {
        self.prepare(dir, "the folder", &[campaign], &folders::CALIBRATION, force)?;
        if !campaign.manifest_path.is_file() {
            let records = dir.join(folders::RECORDS);
            if records.exists() {
                std::fs::remove_dir_all(&records).map_err(|e| Error::output(&records, e))?;
            }
            let header = format!("# The records of the calibration in this folder's parent, written by mrbp from records in memory ({}).\n", campaign.manifest_path.display());
            let manifest = campaign.write(&records, &header)?;
            cal.record.manifest =
                std::fs::canonicalize(&manifest).unwrap_or(manifest).display().to_string();
        }
        self.write_calibration(campaign, dir, cal, identification)
    }

    /// The files of a calibration into the folder `dir`, held already.
    fn write_calibration(
        &mut self,
        campaign: &Campaign,
        dir: &Path,
        mut cal: Calibration,
        identification: Option<&CurrentIdentification>,
    ) -> Result<Calibration> {
        // the folder's earlier calibration is incomplete from here on
        // (no calibration.toml) until the new one is whole
        store::folder::retire(dir)?;
        folders::clear_derived(dir)?;
        // the paper's identification and its figures, of a B-P calibration
        let table = dir.join(store::identification::FILE);
        match identification {
            Some(identification) => {
                let group = campaign.at_current(identification.current_a);
                let identification = std::slice::from_ref(identification);
                store::identification::write(
                    &table,
                    identification,
                    Some(&cal.record.calibration_id),
                )?;
                report::identification::write(dir, &group, identification)?;
            }
            None => crate::atomic::remove(&table)?,
        }
        store::folder::write(dir, &mut cal)?;
        Ok(cal)
    }
}

/// One current's calibrations: the joint one of its runs and, with
/// `--per-run`, each run alone.
#[derive(Clone)]
pub struct CurrentCalibrations {
    pub joint: Calibration,
    /// The runs at the current.
    pub runs: Campaign,
    /// Each run alone, by id (empty without `--per-run`).
    pub alone: Vec<(String, Calibration)>,
}
