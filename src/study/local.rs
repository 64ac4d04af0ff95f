//! A study on this machine: its unfinished tasks, `jobs` at a time, each as
//! its own `mrbp study run-task` process — exactly what a cluster's worker
//! runs, so local and cluster results are the same files.

use std::collections::VecDeque;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::Instant;

use super::plan::{task_dir, task_ids};
use super::task::read_outcome;
use crate::error::{Error, Result};

/// Runs every task of the study in `dir` that has not ended, `jobs` at a
/// time with `threads` threads each; `say` hears one line per task. Tasks
/// whose process failed are named in the error (their folders keep a
/// checkpoint; running the study again resumes them).
pub fn run_local(
    dir: &Path,
    jobs: usize,
    threads: usize,
    say: &(dyn Fn(&str) + Sync),
) -> Result<()> {
    if jobs == 0 || threads == 0 {
        return Err(Error::Usage("--jobs and --threads must be at least 1".into()));
    }
    let exe = std::env::current_exe()
        .map_err(|e| Error::Compute(format!("cannot find the mrbp executable: {e}")))?;
    let mut pending = VecDeque::new();
    for id in task_ids(dir)? {
        if read_outcome(&task_dir(dir, &id))?.is_none() {
            pending.push_back(id);
        }
    }
    let total = pending.len();
    say(&format!("{total} task(s) to run, {jobs} at a time, {threads} thread(s) each"));
    let queue = Mutex::new(pending);
    let lost = Mutex::new(Vec::new());
    let finished = Mutex::new(0usize);
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| loop {
                let Some(id) = queue.lock().expect("queue").pop_front() else { break };
                let clock = Instant::now();
                let folder = task_dir(dir, &id);
                let log = std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(folder.join("log.txt"));
                let (out, err) = match log.and_then(|f| Ok((f.try_clone()?, f))) {
                    Ok((a, b)) => (Stdio::from(a), Stdio::from(b)),
                    Err(_) => (Stdio::null(), Stdio::null()),
                };
                let status = Command::new(&exe)
                    .args(["--threads", &threads.to_string(), "study", "run-task"])
                    .arg(dir)
                    .arg(&id)
                    .stdout(out)
                    .stderr(err)
                    .status();
                let n = {
                    let mut f = finished.lock().expect("counter");
                    *f += 1;
                    *f
                };
                match (status, read_outcome(&folder)) {
                    (Ok(s), Ok(Some(o))) if s.success() => {
                        let note = if o.status == "ok" {
                            String::new()
                        } else {
                            format!(": {}", o.message)
                        };
                        say(&format!(
                            "task {id}: {} in {:.1} s ({n}/{total}){note}",
                            o.status,
                            clock.elapsed().as_secs_f64()
                        ));
                    }
                    (s, _) => {
                        let why = match s {
                            Ok(s) => format!(
                                "exit status {}",
                                s.code().map_or("signal".into(), |c| c.to_string())
                            ),
                            Err(e) => e.to_string(),
                        };
                        say(&format!(
                            "task {id}: did not finish ({why}; see {}) ({n}/{total})",
                            folder.join("log.txt").display()
                        ));
                        lost.lock().expect("lost").push(id);
                    }
                }
            });
        }
    });
    let lost = lost.into_inner().expect("lost");
    if !lost.is_empty() {
        return Err(Error::Compute(format!(
            "{} task(s) did not finish: {}; `mrbp study run` again resumes them",
            lost.len(),
            lost.join(", ")
        )));
    }
    Ok(())
}
