//! One task of a study: a calibration into its own folder, idempotent and
//! safe to hand to several processes at once.
//!
//! The task holds its folder `tasks/<id>/` ([`crate::lock`], released by
//! the operating system if the process dies) while it runs, so a worker that
//! takes over a task from a lost one waits for a straggler instead of
//! writing beside it. A task whose `status.toml` exists is done and is
//! skipped; an interrupted one resumes from its sampler checkpoint, which
//! gives the chains of an uninterrupted run.

use std::path::Path;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::plan::{read_task, task_dir, Source, TaskSpec};
use crate::calibrate::Calibration;
use crate::error::{Error, Result};
use crate::pipeline::{Pipeline, SampleRequest};
use crate::posterior::Draws;
use crate::sampler::quantile;
use crate::store::Table;

/// Posterior draws (thinned by τ) each truth is ranked among.
pub const RANK_DRAWS: usize = 99;

/// How a task ended: `status.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskOutcome {
    pub task: String,
    /// "ok", or "failed" (the calibration refused the task's input or could
    /// not be computed: a result too, not retried).
    pub status: String,
    #[serde(default)]
    pub message: String,
    pub seconds: f64,
    pub steps: usize,
    pub max_r_hat: f64,
    pub min_ess: f64,
    pub warnings: Vec<String>,
}

/// Runs task `id` of the study in `dir` unless it is done; returns how it
/// ended, and whether it ran now.
pub fn run_task(pipeline: &mut Pipeline, dir: &Path, id: &str) -> Result<(TaskOutcome, bool)> {
    let spec = read_task(dir, id)?;
    let folder = task_dir(dir, id);
    let _held = crate::lock::write_waiting(&folder)?;
    if let Some(done) = read_outcome(&folder)? {
        return Ok((done, false));
    }
    let clock = Instant::now();
    let outcome = match calibrate(pipeline, &spec, &folder) {
        Ok(cal) => {
            let outcome = TaskOutcome {
                task: spec.id.clone(),
                status: "ok".into(),
                message: String::new(),
                seconds: clock.elapsed().as_secs_f64(),
                steps: cal.sample.chains.steps().saturating_sub(1),
                max_r_hat: cal.max_rhat(),
                min_ess: cal.min_ess(),
                warnings: cal
                    .record
                    .warnings
                    .iter()
                    .chain(&cal.record.model_warnings)
                    .chain(&cal.record.confounding)
                    .cloned()
                    .collect(),
            };
            crate::store::write_parquet(
                &folder.join("result.parquet"),
                result_table(&spec, &cal, &outcome),
            )?;
            outcome
        }
        // bad input or a calculation that cannot succeed: the task's result
        Err(e @ (Error::Input { .. } | Error::Compute(_) | Error::Usage(_))) => TaskOutcome {
            task: spec.id.clone(),
            status: "failed".into(),
            message: e.to_string(),
            seconds: clock.elapsed().as_secs_f64(),
            steps: 0,
            max_r_hat: f64::NAN,
            min_ess: f64::NAN,
            warnings: vec![],
        },
        // interrupted, or the disk: the task is not done, run it again
        Err(e) => return Err(e),
    };
    let text =
        toml::to_string(&outcome).map_err(|e| Error::Compute(format!("status.toml: {e}")))?;
    crate::atomic::write(&folder.join("status.toml"), text.as_bytes())?;
    Ok((outcome, true))
}

/// How task folder `folder` ended, if it did.
pub fn read_outcome(folder: &Path) -> Result<Option<TaskOutcome>> {
    let path = folder.join("status.toml");
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path)
        .map_err(|e| Error::input(&path, format!("cannot read: {e}")))?;
    toml::from_str(&text)
        .map(Some)
        .map_err(|e| Error::input(&path, format!("not a task status: {}", e.message())))
}

/// The task's calibration in `folder/calibration`, resumed from its
/// checkpoint if an earlier attempt left one.
fn calibrate(pipeline: &mut Pipeline, spec: &TaskSpec, folder: &Path) -> Result<Calibration> {
    let campaign = match &spec.source {
        Source::Synthetic { synth } => {
            let data = folder.join("data");
            crate::synth::write_campaign(synth, &data)?;
            pipeline.load(&data.join("campaign.toml"))?
        }
        Source::Campaign { manifest } => pipeline.load(manifest)?,
    };
    let out = folder.join("calibration");
    let resume = crate::store::folder::checkpoint_in(&out).is_some();
    let request = SampleRequest {
        settings: spec.settings.clone(),
        laws: vec![],
        current: spec.current_a,
        hold_out_current: vec![],
        resume,
        force: true,
        per_run: false,
        per_run_where_memory: false,
    };
    let mut folders = pipeline.sample(&campaign, &out, &request)?;
    folders.pop().ok_or_else(|| Error::Compute(format!("task {}: no calibration made", spec.id)))
}

/// One row per coordinate: the summary, and against the truth where it is
/// known — z = (mean − truth)/sd, whether the central 50 % and 90 %
/// intervals hold it, and its rank among [`RANK_DRAWS`] thinned draws;
/// then the task's wall time, steps and warnings on every row.
fn result_table(spec: &TaskSpec, cal: &Calibration, outcome: &TaskOutcome) -> Table {
    let all = Draws { burn_in: cal.burn_in(), thin: 1 }.positions(&cal.sample.chains, usize::MAX);
    let thinned = cal.draw_positions(RANK_DRAWS);
    let rows = &cal.summary;
    let truth: Vec<f64> =
        rows.iter().map(|r| spec.truth.get(&r.parameter).copied().unwrap_or(f64::NAN)).collect();
    let mut inside50 = Vec::new();
    let mut inside90 = Vec::new();
    let mut rank = Vec::new();
    for (r, t) in rows.iter().zip(&truth) {
        let draws = cal.sample.values(&r.parameter, &all).unwrap_or_default();
        let within = |lo: f64, hi: f64| {
            t.is_finite() && quantile(&draws, lo) <= *t && *t <= quantile(&draws, hi)
        };
        inside50.push(within(0.25, 0.75));
        inside90.push(within(0.05, 0.95));
        let ranked = cal.sample.values(&r.parameter, &thinned).unwrap_or_default();
        rank.push(if t.is_finite() { ranked.iter().filter(|v| *v < t).count() as i64 } else { -1 });
    }
    let n = rows.len();
    let col =
        |f: &dyn Fn(&crate::posterior::SummaryRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    Table::new()
        .str("parameter", rows.iter().map(|r| r.parameter.clone()).collect())
        .f64("current_a", vec![spec.current_a.unwrap_or(cal.record.current_a); n])
        .i64("seed", vec![spec.settings.sampler.seed as i64; n])
        .f64("mean", col(&|r| r.mean))
        .f64("sd", col(&|r| r.sd))
        .f64("q05", col(&|r| r.q05))
        .f64("q50", col(&|r| r.q50))
        .f64("q95", col(&|r| r.q95))
        .f64("ess_bulk", col(&|r| r.ess_bulk))
        .f64("ess_tail", col(&|r| r.ess_tail))
        .f64("r_hat", col(&|r| r.r_hat))
        .f64("truth", truth.clone())
        .f64("z", rows.iter().zip(&truth).map(|(r, t)| (r.mean - t) / r.sd).collect())
        .bool("inside_50", inside50)
        .bool("inside_90", inside90)
        .i64("rank", rank)
        .i64("rank_draws", vec![thinned.len() as i64; n])
        .f64("seconds", vec![outcome.seconds; n])
        .i64("steps", vec![outcome.steps as i64; n])
        .str("warnings", vec![outcome.warnings.join("; "); n])
}
