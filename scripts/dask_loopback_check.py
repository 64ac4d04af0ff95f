"""A study on a real Dask cluster on loopback, with a worker killed mid-study.

    python scripts/dask_loopback_check.py MRBP LOCAL_STUDY CLUSTER_STUDY

LOCAL_STUDY has been run with `mrbp study run`; CLUSTER_STUDY is the same
plan, not yet run. Starts a scheduler and two workers (one thread each) on
127.0.0.1, runs CLUSTER_STUDY through scripts/dask_study.py, kills a worker
that is running a task (SIGKILL, no nanny to restart it) as soon as the
first task has ended, and checks that the
study still completes with every task's result present exactly once and
equal to the local run's. Exits non-zero with a message otherwise.
"""

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
from dask.distributed import Client

sys.path.insert(0, str(Path(__file__).parent))
from dask_study import run_study, task_ids  # noqa: E402


def fail(message):
    print(f"dask check: {message}", file=sys.stderr)
    sys.exit(1)


def results(study):
    df = pd.read_parquet(Path(study) / "collected" / "results")
    # everything but where it ran and how long it took
    return df.drop(columns=["study", "seconds"]).sort_values(["task", "parameter"]).reset_index(drop=True)


def main(mrbp, local, cluster):
    tmp = Path(tempfile.mkdtemp(prefix="mrbp-dask-"))
    scheduler_file = tmp / "scheduler.json"
    python = sys.executable
    procs = []

    def start(*args):
        p = subprocess.Popen([python, "-m", "distributed.cli.dask_" + args[0], *args[1:]],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        procs.append(p)
        return p

    try:
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address", ":0",
              "--scheduler-file", str(scheduler_file))
        for _ in range(200):
            if scheduler_file.exists():
                break
            time.sleep(0.1)
        for i in (1, 2):
            start("worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1", "--nworkers", "1",
                  "--host", "127.0.0.1", "--dashboard-address", ":0", "--name", f"w{i}", "--no-nanny")
        client = Client(scheduler_file=str(scheduler_file), timeout=60)
        client.wait_for_workers(2, timeout=60)

        killed = []

        pids = client.run(os.getpid)

        def on_result(line):
            print(line)
            # the first task has ended: lose a worker in the middle of a task
            if not killed and line.startswith("task "):
                busy = {w: keys for w, keys in client.processing().items() if keys}
                if not busy:
                    return
                worker, keys = next(iter(busy.items()))
                os.kill(pids[worker], signal.SIGKILL)
                killed.append(worker)
                print(f"killed worker {worker} (pid {pids[worker]}) while it ran {', '.join(str(k).split('-')[-1] for k in keys)}")

        seconds = run_study(client, cluster, mrbp, 1, on_result)
        if not killed:
            fail("no worker was killed: the study ended before its first result arrived")
        client.close()
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    ids = task_ids(cluster)
    ours, theirs = results(local), results(cluster)
    present = sorted(theirs.task.unique())
    if present != sorted(ids):
        fail(f"tasks with results {present}, expected {sorted(ids)}")
    rows = theirs.groupby("task").size()
    if rows.nunique() != 1 or (theirs.groupby(["task", "parameter"]).size() != 1).any():
        fail(f"a task's rows appear more than once: {rows.to_dict()}")
    pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    status = pd.read_parquet(Path(cluster) / "collected" / "tasks.parquet")
    if (status.status != "ok").any():
        fail(f"not every task ended well:\n{status}")
    print(f"ok: {len(ids)} tasks on 2 loopback workers, one killed, in {seconds:.1f} s "
          f"({60 * len(ids) / seconds:.1f} tasks per minute); every result present once and equal to the local run")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
