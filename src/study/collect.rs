//! Gathering a study's results: every finished task's rows into one Parquet
//! dataset partitioned by study and task (hive layout, which pandas,
//! polars and DuckDB read as one table with `study` and `task` columns),
//! and one row per task with how it ended; where the truths are known,
//! what they say about the calibration ([`statistics`]).

use std::path::Path;

use super::plan::{read_record, task_dir, task_ids};
use super::statistics::{self, CoverageRow, Tally};
use super::task::read_outcome;
use crate::error::{Error, Result};
use crate::store::Table;

/// What `collect` found.
#[derive(Clone, Debug, PartialEq)]
pub struct Collected {
    pub tasks: usize,
    pub ok: usize,
    pub failed: usize,
    /// Tasks without a result yet (not run, or lost mid-run).
    pub missing: Vec<String>,
    /// Per coordinate with a known truth: coverage, z, ranks.
    pub coverage: Vec<CoverageRow>,
}

/// Writes `collected/results/study=<name>/task=<id>/part-0.parquet` for
/// every task that ended well and `collected/tasks.parquet` (task, status,
/// message, seconds, steps, max_r_hat, min_ess, warnings) into the study
/// folder `dir`, replacing an earlier collection; with known truths also
/// `collected/coverage.parquet` and the rank histograms `collected/ranks`.
pub fn collect(dir: &Path) -> Result<Collected> {
    let record = read_record(dir)?;
    let ids = task_ids(dir)?;
    let out = dir.join("collected");
    std::fs::create_dir_all(&out).map_err(|e| Error::output(&out, e))?;
    // one collection at a time
    let _held = crate::lock::write(&out)?;
    let results = out.join("results").join(format!("study={}", record.name));
    if results.exists() {
        std::fs::remove_dir_all(&results).map_err(|e| Error::output(&results, e))?;
    }
    let mut table = TaskRows::default();
    let mut found =
        Collected { tasks: ids.len(), ok: 0, failed: 0, missing: vec![], coverage: vec![] };
    let mut tally = Tally::default();
    for id in &ids {
        let folder = task_dir(dir, id);
        match read_outcome(&folder)? {
            None => {
                found.missing.push(id.clone());
                table.push(id, "missing", "", f64::NAN, 0, f64::NAN, f64::NAN, "");
            }
            Some(o) => {
                if o.status == "ok" {
                    let from = folder.join("result.parquet");
                    let bytes = std::fs::read(&from)
                        .map_err(|e| Error::input(&from, format!("cannot read: {e}")))?;
                    crate::atomic::write(
                        &results.join(format!("task={id}")).join("part-0.parquet"),
                        &bytes,
                    )?;
                    tally.add(&from)?;
                    found.ok += 1;
                } else {
                    found.failed += 1;
                }
                table.push(
                    id,
                    &o.status,
                    &o.message,
                    o.seconds,
                    o.steps,
                    o.max_r_hat,
                    o.min_ess,
                    &o.warnings.join("; "),
                );
            }
        }
    }
    crate::store::write_parquet(&out.join("tasks.parquet"), table.into_table())?;
    found.coverage = tally.rows();
    if !found.coverage.is_empty() {
        statistics::write(&out, &found.coverage)?;
    }
    Ok(found)
}

/// `collected/tasks.parquet`, column by column.
#[derive(Default)]
struct TaskRows {
    task: Vec<String>,
    status: Vec<String>,
    message: Vec<String>,
    seconds: Vec<f64>,
    steps: Vec<i64>,
    max_r_hat: Vec<f64>,
    min_ess: Vec<f64>,
    warnings: Vec<String>,
}

impl TaskRows {
    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        task: &str,
        status: &str,
        message: &str,
        seconds: f64,
        steps: usize,
        max_r_hat: f64,
        min_ess: f64,
        warnings: &str,
    ) {
        self.task.push(task.into());
        self.status.push(status.into());
        self.message.push(message.into());
        self.seconds.push(seconds);
        self.steps.push(steps as i64);
        self.max_r_hat.push(max_r_hat);
        self.min_ess.push(min_ess);
        self.warnings.push(warnings.into());
    }

    fn into_table(self) -> Table {
        Table::new()
            .str("task", self.task)
            .str("status", self.status)
            .str("message", self.message)
            .f64("seconds", self.seconds)
            .i64("steps", self.steps)
            .f64("max_r_hat", self.max_r_hat)
            .f64("min_ess", self.min_ess)
            .str("warnings", self.warnings)
    }
}
