"""A batch run: the recordings of INPUTS replayed into DIR on local workers or a Dask cluster, outputs already complete
skipped, the progress drawn, the summary written (also when interrupted)."""
from __future__ import annotations

import dataclasses
import os
import shutil
import time
from pathlib import Path
from typing import Any, Mapping

from line_odom.batch.outputs import LOCK, TMP_DIR, read_complete
from line_odom.batch.recordings import Recording, recordings_from
from line_odom.batch.scheduling import connect, execute, local_cluster, require_distributed
from line_odom.batch.summary import write_summary
from line_odom.batch.task import provenance
from line_odom.progress import ProgressBar


class BatchProgress(ProgressBar):
    """ProgressBar counting recordings done and failed, with an ETA from the tasks finished in this run."""

    def __init__(self, total: int, enabled: bool | None = None, stream=None):
        super().__init__("batch", total=total, enabled=enabled, stream=stream)
        self.done = self.failed = self.ran = 0
        self.to_run = total

    def count(self, row: dict) -> None:
        self.done += 1
        self.failed += row["status"] == "failed"
        self.ran += row["status"] != "skipped"
        self.draw()

    def draw(self) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        final = self.done >= (self.total or 0)
        if not final and now - self._last < self.min_interval_s:
            return
        self._last = now
        elapsed = now - self._start
        total = self.total or 0
        filled = int(round(self.width * (self.done / total if total else 1.0)))
        remaining = self.to_run - self.ran
        eta = f"ETA {elapsed / self.ran * remaining:5.0f}s" if self.ran and remaining else "ETA    -"
        self.stream.write(f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{total} done, "
                          f"{self.failed} failed {elapsed:5.1f}s {eta}")
        self.stream.flush()
        self._drawn = True


@dataclasses.dataclass
class BatchResult:
    rows: list[dict]
    files: list[Path]

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.rows if r["status"] == "failed"]


def _size_bytes(path: Path) -> int:
    try:
        if path.is_file():
            return path.stat().st_size
        return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    except OSError:
        return 0


def _skipped_row(rec: Recording, record: dict) -> dict:
    row = {k: record.get(k) for k in ("label", "input", "kind", "seconds", "host", "commit", "metrics")}
    return {**row, "label": rec.label, "status": "skipped", "error": "", "attempts": 0}


def run_batch(inputs: str | Path, out_dir: str | Path, *, workers: int | None = None, cluster: str | None = None,
              params: str | None = None, overrides: Mapping[str, Any] | None = None, frames: int | None = None,
              force: bool = False, progress: bool = True) -> BatchResult:
    """Replay every recording of `inputs` (a folder or a manifest) into `out_dir/<label>/` on `workers` local
    processes (default: the cores) or on the Dask scheduler at `cluster`; write the summary. See the module
    docstring."""
    if workers is not None and cluster is not None:
        raise ValueError("--workers and --cluster: give one (the cluster's workers are its own)")
    if workers is not None and workers < 1:
        raise ValueError(f"--workers: expected a positive integer, got {workers}")
    if params is not None and not Path(params).is_file():
        raise FileNotFoundError(f"{params}: no such parameter file")
    require_distributed()
    out_root = Path(out_dir).resolve()
    recordings = recordings_from(inputs, params=params, overrides=overrides, exclude=[out_root])
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    t0 = time.monotonic()
    out_root.mkdir(parents=True, exist_ok=True)
    with _exclusive(out_root):
        # what is in the scratch now was left by a run that was killed
        shutil.rmtree(out_root / TMP_DIR, ignore_errors=True)
        return _run(recordings, inputs, out_root, workers, cluster, frames, force, progress, started, t0)


def _exclusive(out_root: Path):
    """A lock on DIR for the run: two batches writing into one folder would remove each other's scratch."""
    import contextlib
    import fcntl

    @contextlib.contextmanager
    def held():
        with open(out_root / LOCK, "a") as f:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise RuntimeError(f"{out_root}: another line_odom batch is writing into this folder (it holds "
                                   f"{out_root / LOCK}); wait for it or choose another --out") from None
            try:
                yield
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)

    return held()


def _run(recordings: list[Recording], inputs, out_root: Path, workers: int | None, cluster: str | None,
         frames: int | None, force: bool, progress: bool, started: str, t0: float) -> BatchResult:
    rows: dict[str, dict] = {}
    todo = []
    for rec in recordings:
        record = None if force else read_complete(out_root / rec.label, rec.spec(frames))
        if record is not None:
            rows[rec.label] = _skipped_row(rec, record)
        else:
            todo.append(rec)
    # largest recordings first, so that the last task to finish is a short one (rows keep the recordings' order)
    todo.sort(key=lambda rec: -_size_bytes(rec.path))
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    n_workers = min(workers or cores, max(len(todo), 1))
    engine = f"Dask scheduler {cluster}" if cluster else f"local, {n_workers} worker process(es)"
    run_info = {"inputs": str(inputs), "engine": engine, "frames": frames, "machine": provenance(), "started": started}
    bar = BatchProgress(len(recordings), enabled=None if progress else False)
    bar.to_run = len(todo)
    for row in rows.values():
        bar.count(row)
    bar.draw()

    def finish(row: dict) -> None:
        rows[row["label"]] = row
        bar.count(row)

    def summarize() -> list[dict]:
        ordered = []
        for rec in recordings:
            row = rows.get(rec.label)
            if row is None:  # interrupted: a task may have finished after its result could no longer arrive
                record = read_complete(out_root / rec.label, rec.spec(frames))
                row = ({**_skipped_row(rec, record), "status": "ok", "attempts": 1} if record is not None else
                       {"label": rec.label, "input": str(rec.path), "kind": rec.kind, "status": "interrupted",
                        "error": "not run (interrupted)", "metrics": {}})
            ordered.append(row)
        run_info["wall_s"] = time.monotonic() - t0
        return ordered

    interrupted = False
    cluster_obj = client = None
    try:
        if todo:
            if cluster:
                client = connect(cluster)
            else:
                cluster_obj = local_cluster(n_workers)
                client = require_distributed().Client(cluster_obj)
            execute(client, todo, out_root, frames=frames, on_row=finish)
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        bar.close()
        if client is not None:
            client.close()
        if cluster_obj is not None:
            cluster_obj.close()
        if not (interrupted and cluster):  # a remote task may still be writing its scratch: it cleans up itself
            shutil.rmtree(out_root / TMP_DIR, ignore_errors=True)
        if interrupted:  # what finished is summarized; the rest is marked as not run
            write_summary(out_root, summarize(), run_info)
    ordered = summarize()
    files = write_summary(out_root, ordered, run_info)
    return BatchResult(ordered, files)
