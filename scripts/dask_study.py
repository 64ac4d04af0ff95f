"""Run an mrbp study on a Dask cluster.

    python scripts/dask_study.py STUDY_DIR (--scheduler ADDRESS | --scheduler-file FILE)
                                 [--mrbp PATH] [--threads N]

Every task of STUDY_DIR/tasks.csv becomes one Dask task that runs
`mrbp study run-task STUDY_DIR ID` as a process on a worker; the workers
need only the mrbp binary and the study folder (a shared file system).
A task lost with its worker is run again elsewhere: the new process waits
on the task's lock while a straggler from the lost worker finishes, then
skips it, or resumes from its checkpoint. When every task has ended,
`mrbp study collect` gathers the results. Prints tasks per minute.
"""

import argparse
import csv
import subprocess
import sys
import time
from pathlib import Path

from dask.distributed import Client, as_completed


def task_ids(study):
    with open(Path(study) / "tasks.csv", newline="") as f:
        return [row["task"] for row in csv.DictReader(f) if row["task"].strip()]


def run_study(client, study, mrbp="mrbp", threads=1, on_result=print):
    """Submits every task of `study`, waits for all of them, then collects.
    Returns the wall time in seconds."""
    study = str(Path(study).resolve())
    ids = task_ids(study)
    start = time.time()
    # the workers run subprocess.check_output, which they all have (no code
    # of ours to ship); an exit status other than 0 (interrupted, disk) raises,
    # and Dask runs the task again
    futures = [client.submit(subprocess.check_output, [mrbp, "--threads", str(threads), "study", "run-task", study, t],
                             key=f"mrbp-{study}-{t}", pure=False, retries=3)
               for t in ids]
    for future in as_completed(futures):
        lines = future.result().decode().strip().splitlines()
        on_result(lines[-1] if lines else "task: done")
    seconds = time.time() - start
    collected = subprocess.run([mrbp, "study", "collect", study], capture_output=True, text=True, check=True)
    on_result(collected.stdout.strip())
    on_result(f"{len(ids)} task(s) in {seconds:.1f} s: {60 * len(ids) / seconds:.1f} tasks per minute")
    return seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--scheduler", help="the scheduler's address, e.g. tcp://10.0.0.5:8786")
    where.add_argument("--scheduler-file", help="the file `dask scheduler --scheduler-file` wrote")
    parser.add_argument("--mrbp", default="mrbp", help="the mrbp executable on the workers (default: mrbp on the PATH)")
    parser.add_argument("--threads", type=int, default=1, help="threads of each task (match the workers' --nthreads)")
    args = parser.parse_args()
    client = Client(args.scheduler) if args.scheduler else Client(scheduler_file=args.scheduler_file)
    run_study(client, args.study, args.mrbp, args.threads)


if __name__ == "__main__":
    sys.exit(main())
