//! Studies: many independent calibrations whose results are read together
//! — replicate (coverage) studies and simulation-based calibration on
//! virtual campaigns with known parameters, fleets and sweeps over real
//! campaigns.
//!
//! A study is data: a folder with `study.toml`, `tasks.csv` (one task id
//! per line, for drivers) and `tasks/<id>/task.toml`, each task one
//! calibration fully specified (its records or how to make them, its
//! current, its settings with its seed, and what is known of the truth).
//! [`run_task`] runs one task into its own folder, idempotently and under a
//! lock, so a task can be handed to any process that sees the folder: this
//! machine's cores ([`run_local`]), a Dask or Ray cluster, a Slurm job
//! array (docs/studies.md). [`collect`] gathers the results into one
//! Parquet dataset partitioned by study and task.
//!
//! | file | written by |
//! |---|---|
//! | `study.toml`, `tasks.csv`, `tasks/<id>/task.toml` | [`plan`] |
//! | `tasks/<id>/calibration/` | [`run_task`]: the calibration folder |
//! | `tasks/<id>/result.parquet`, then `tasks/<id>/status.toml` | [`run_task`]: the task's rows; its end |
//! | `collected/results/study=<name>/task=<id>/part-0.parquet`, `collected/tasks.parquet`, `collected/coverage.parquet`, `collected/ranks.svg` | [`collect`] |

mod collect;
mod local;
pub mod plan;
pub mod statistics;
mod task;

pub use collect::{collect, Collected};
pub use local::run_local;
pub use plan::{
    plan, read_record, read_task, task_dir, task_ids, Design, PlanOptions, Source, StudyRecord,
    TaskSpec,
};
pub use task::{run_task, TaskOutcome};
