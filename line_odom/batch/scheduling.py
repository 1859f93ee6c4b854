"""Running the tasks of a batch on Dask's distributed engine: a local cluster of worker processes or an existing
scheduler, no more tasks in flight than the workers have threads, a task whose worker died submitted once more."""
from __future__ import annotations

import uuid
from pathlib import Path
from typing import Callable

from line_odom.batch.recordings import Recording
from line_odom.batch.task import one_line_error, run_recording

DEPENDENCY_HINT = ("line_odom batch needs Dask's distributed engine: pip install dask distributed "
                   "(the versions pinned in requirements/dev.txt)")


def require_distributed():
    try:
        import distributed
    except ImportError:
        raise RuntimeError(DEPENDENCY_HINT) from None
    return distributed


def dask_setup(worker) -> None:
    """Dask preload hook, run in each local worker process: Ctrl-C at a terminal reaches the whole process group;
    the batch process alone handles it (cancels, closes the cluster, removes the scratch) instead of every worker
    printing its own traceback."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def local_cluster(workers: int):
    """A LocalCluster of `workers` single-threaded worker processes. The scheduler gives up on a task at the
    first death of its worker, so that the one retry is ours (execute) and counted."""
    import logging

    import dask

    distributed = require_distributed()
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        # no dashboard; the scheduler's HTTP routes on a free loopback port instead of the usual 8787. Its log stays
        # quiet: a worker's death and a task's failure are the summary's rows, each with its one line
        return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                        dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                                        silence_logs=logging.CRITICAL, preload=[__name__])


def connect(address: str):
    """A client of the scheduler at `address` (tcp://host:port), or of the one a scheduler file names (the JSON that
    `dask scheduler --scheduler-file` writes, as on a batch-queue cluster)."""
    distributed = require_distributed()
    try:
        if address.endswith(".json") and Path(address).is_file():
            return distributed.Client(scheduler_file=address, timeout=30)
        return distributed.Client(address, timeout=30)
    except (OSError, TimeoutError, ValueError, KeyError) as exc:
        raise RuntimeError(f"--cluster {address}: cannot connect to a Dask scheduler there "
                           f"({one_line_error(exc)})") from None


def _worker_died(exc: BaseException) -> bool:
    from distributed.scheduler import KilledWorker

    return isinstance(exc, KilledWorker)


def execute(client, recordings: list[Recording], out_root: str | Path, *, frames: int | None = None,
            task: Callable = run_recording, on_row: Callable[[dict], None] | None = None) -> list[dict]:
    """Runs `task(rec, out_root, frames)` for every recording on the client's workers and returns the rows in the
    order of `recordings`. No more tasks are in flight than the workers have threads, so a worker that dies takes
    only the task it was running with it; that task is submitted once more."""
    distributed = require_distributed()
    futures = {}
    queue = [(rec, 0) for rec in recordings]

    def capacity() -> int:
        try:
            return max(sum(client.nthreads().values()), 1)
        except Exception:  # scheduler busy restarting a worker: one at a time until it answers
            return 1

    def submit_more(pending) -> None:
        while queue and len(futures) < capacity():
            rec, attempt = queue.pop(0)
            key = f"line_odom-batch-{rec.label}-{uuid.uuid4().hex[:8]}"
            future = client.submit(task, rec, str(out_root), frames, key=key, pure=False, retries=0)
            futures[future] = (rec, attempt)
            pending.add(future)

    rows: dict[str, dict] = {}
    pending = distributed.as_completed()
    submit_more(pending)
    try:
        for future in pending:
            rec, attempt = futures.pop(future)
            try:
                row = future.result()
            except Exception as exc:
                if _worker_died(exc) and attempt == 0:
                    queue.insert(0, (rec, 1))
                    submit_more(pending)
                    continue
                row = {"label": rec.label, "input": str(rec.path), "kind": rec.kind, "status": "failed",
                       "seconds": float("nan"), "host": "", "commit": "", "metrics": {},
                       "error": (f"the worker process running it died twice ({one_line_error(exc)})"
                                 if _worker_died(exc) else one_line_error(exc))}
            row["attempts"] = attempt + 1
            rows[rec.label] = row
            if on_row is not None:
                on_row(row)
            submit_more(pending)
    except BaseException:
        for future in list(futures):
            future.cancel()
        raise
    return [rows[rec.label] for rec in recordings]
