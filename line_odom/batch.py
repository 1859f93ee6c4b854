"""Odometry over an archive of recordings: ``line_odom batch INPUTS --out DIR``.

Each recording (any format :func:`line_odom.readers.guess_format` recognizes) is one task that runs
:func:`line_odom.replay.replay` in-process (deterministic) and writes replay's outputs to ``DIR/<label>/``. Tasks
run on Dask's distributed engine: ``workers=N`` starts a ``LocalCluster`` of N single-threaded worker processes for
the run, ``cluster=ADDRESS`` submits the same tasks to an existing scheduler (whose workers must see INPUTS and DIR
at the same paths and run the same line_odom).

Safety: a task writes into ``DIR/.batch_tmp/`` and renames its finished output directory to ``DIR/<label>`` in one
step, so an interrupted run leaves complete outputs or none. ``batch.json`` in an output directory records the
task it ran (input, parameters, overrides, frames); outputs whose record matches the task are skipped unless
``force``. A recording that raises is a failed row with its one-line error; a task whose worker process dies is
submitted once more, then reported as failed.

``DIR/summary.csv``, ``summary.md`` and ``summary.png`` hold one row per recording (status, seconds, metrics, the
machine and commit that produced it), mean / median / worst per metric and a bar chart of the per-recording RPE.
"""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import os
import platform
import shutil
import socket
import statistics
import subprocess
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from line_odom.progress import ProgressBar

RECORD = "batch.json"
TMP_DIR = ".batch_tmp"
LOCK = ".batch.lock"
SUMMARY_CSV, SUMMARY_MD, SUMMARY_PLOT = "summary.csv", "summary.md", "summary.png"
REPLAY_OUTPUTS = ("trajectory_tum.txt", "trajectory_kitti.txt", "metrics.json")
MANIFEST_FIELDS = ("path", "label", "params", "set", "format", "ground_truth")
# recording files whose format cannot be guessed because they are unreadable: still tasks, so they fail visibly
RECORDING_SUFFIXES = {".pcap": "velodyne", ".pcapng": "velodyne", ".osf": "ouster", ".bag": "ros1"}
# the metric keys in the order evaluation prints them; others follow alphabetically
METRIC_ORDER = ("frames", "frames_dropped", "frames_with_ground_truth", "path_length_m", "rpe_trans_mean_m",
                "rpe_trans_max_m", "rpe_rot_mean_deg", "rpe_rot_max_deg", "ate_rmse_m", "kitti_t_err_pct",
                "kitti_r_err_deg_per_m", "latency_mean_ms", "latency_p95_ms")
# "worst" of a metric is its largest value or its smallest; keys in neither set (path length, input counters) are
# properties of the recording and have none
LARGER_IS_BETTER = {"frames", "frames_with_ground_truth"}
SMALLER_IS_BETTER = {"frames_dropped", "rpe_trans_mean_m", "rpe_trans_max_m", "rpe_rot_mean_deg", "rpe_rot_max_deg",
                     "ate_rmse_m", "kitti_t_err_pct", "kitti_r_err_deg_per_m", "latency_mean_ms", "latency_p95_ms",
                     "seconds"}
PLOT_METRICS = (("rpe_trans_mean_m", "RPE translation mean [m]"), ("rpe_rot_mean_deg", "RPE rotation mean [deg]"),
                ("kitti_t_err_pct", "KITTI drift t_err [%]"))
DEPENDENCY_HINT = ("line_odom batch needs Dask's distributed engine: pip install dask distributed "
                   "(the versions pinned in requirements/dev.txt)")


# --------------------------------------------------------------------------------------------- recordings


@dataclasses.dataclass
class Recording:
    """One task: a recording, the label of its output directory, and the parameters to replay it with."""

    path: Path
    label: str
    kind: str | None  # "rosbag2", "kitti", "tum", a reader's format name, or None (not a recording: fails)
    params: str | None = None
    overrides: dict = dataclasses.field(default_factory=dict)
    ground_truth: str | None = None  # a TUM / KITTI trajectory file instead of the recording's own

    def spec(self, frames: int | None) -> dict:
        """What the outputs depend on; outputs recorded with another spec are not reused."""
        return {"input": str(self.path), "kind": self.kind, "params": self.params,
                "params_sha256": _sha256(self.params), "ground_truth": self.ground_truth,
                "ground_truth_sha256": _sha256(self.ground_truth),
                "overrides": {k: self.overrides[k] for k in sorted(self.overrides)}, "frames": frames}


def _sha256(path: str | None) -> str | None:
    if path is None or not Path(path).is_file():
        return None
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def detect(path: str | Path) -> str | None:
    """The format of the recording at `path` as line_odom.readers names it ("rosbag2", "kitti", "tum", "ouster",
    ...), or None if it is none replay reads."""
    from line_odom import readers

    path = Path(path)
    try:
        return readers.guess_format(path)
    except Exception:  # not a recording, or a recording file that cannot be read: that one is a failed task
        return None if path.is_dir() else RECORDING_SUFFIXES.get(path.suffix.lower())


def discover(root: str | Path, exclude: Iterable[str | Path] = ()) -> list[Recording]:
    """Every recording under `root` (itself included), in path order; a recording's own folder is not searched
    further. Labels are the paths relative to `root` with '/' as '__'."""
    root = Path(root)
    if not root.exists():
        raise FileNotFoundError(f"{root}: no such folder or manifest")
    excluded = {Path(p).resolve() for p in exclude}
    kind = detect(root)
    if kind is not None:
        return [Recording(root.resolve(), root.resolve().name, kind)]
    found = []
    visited = {root.resolve()}  # archives link folders; a link back up must not loop
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        here = Path(dirpath)
        dirnames.sort()
        keep = []
        for name in dirnames:
            sub = here / name
            if name.startswith(".") or sub.resolve() in excluded or sub.resolve() in visited:
                continue
            visited.add(sub.resolve())
            kind = detect(sub)
            if kind is not None:
                found.append(Recording(sub.resolve(), "__".join(sub.relative_to(root).parts), kind))
            else:
                keep.append(name)
        dirnames[:] = keep
        for name in sorted(filenames):
            sub = here / name
            if not name.startswith("."):
                kind = detect(sub)
                if kind is not None:
                    found.append(Recording(sub.resolve(), "__".join(sub.relative_to(root).parts), kind))
    found.sort(key=lambda r: r.label)
    _check_labels(found, str(root))
    return found


def _check_labels(recordings: list[Recording], source: str) -> None:
    seen: dict[str, Path] = {}
    for rec in recordings:
        label = rec.label
        if not label or label in (".", "..") or "/" in label or "\\" in label or label.startswith("."):
            raise ValueError(f"{source}: label {label!r} of {rec.path}: expected a folder name without '/' that does "
                             f"not start with '.'")
        if label in (SUMMARY_CSV, SUMMARY_MD, SUMMARY_PLOT):
            raise ValueError(f"{source}: label {label!r} of {rec.path} is the name of a summary file; choose another")
        if label in seen:
            raise ValueError(f"{source}: label {label!r} is given to both {seen[label]} and {rec.path}; labels must "
                             f"be unique (set them in a manifest)")
        seen[label] = rec.path


def _overrides_from(value: Any, where: str) -> dict:
    from line_odom.cli import parse_overrides

    if value is None or value == "":
        return {}
    if isinstance(value, Mapping):
        return {str(k): v for k, v in value.items()}
    if isinstance(value, str):
        value = [item for item in (part.strip() for part in value.split(";")) if item]
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        try:
            return parse_overrides(value)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
    raise ValueError(f"{where}: 'set' must be a mapping NAME: VALUE or a list of 'NAME=VALUE' strings, got {value!r}")


def read_manifest(path: str | Path) -> list[Recording]:
    """Recordings of a YAML manifest (a list of entries, or {recordings: [...]}) or a CSV manifest (header row).
    Entry fields: path (required; relative to the manifest's folder, as the files below), label (default: the
    path's name), params (a parameter file), set (overrides: a mapping or 'NAME=VALUE' items, ';'-separated in CSV),
    format (one of line_odom.readers.FORMATS instead of the guess), ground_truth (a TUM / KITTI trajectory file
    instead of the recording's own)."""
    from line_odom import readers

    path = Path(path)
    base = path.resolve().parent
    if path.suffix.lower() == ".csv":
        entries = _read_csv_manifest(path)
    elif path.suffix.lower() in (".yaml", ".yml"):
        entries = _read_yaml_manifest(path)
    else:
        raise ValueError(f"{path}: a manifest must be .yaml, .yml or .csv (or INPUTS a folder of recordings)")
    if not entries:
        raise ValueError(f"{path}: the manifest lists no recordings")
    recordings = []
    for where, entry in entries:
        unknown = sorted(set(entry) - set(MANIFEST_FIELDS))
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {', '.join(map(str, unknown))} (expected "
                             f"{', '.join(MANIFEST_FIELDS)})")
        if not entry.get("path"):
            raise ValueError(f"{where}: 'path' is missing (the recording to replay)")
        rec_path = Path(os.path.expanduser(str(entry["path"])))
        rec_path = (rec_path if rec_path.is_absolute() else base / rec_path).resolve()
        params, ground_truth = (_resolve(entry.get(key), base) for key in ("params", "ground_truth"))
        label = str(entry.get("label") or rec_path.name)
        kind = entry.get("format") or None
        if kind is not None and kind not in readers.FORMATS:
            raise ValueError(f"{where}: format {kind!r}: expected one of {', '.join(readers.FORMATS)}")
        recordings.append(Recording(rec_path, label, kind or detect(rec_path), params,
                                    _overrides_from(entry.get("set"), where), ground_truth))
    _check_labels(recordings, str(path))
    return recordings


def _resolve(value, base: Path) -> str | None:
    if not value:
        return None
    path = Path(os.path.expanduser(str(value)))
    return str((path if path.is_absolute() else base / path).resolve())


def _read_yaml_manifest(path: Path) -> list[tuple[str, dict]]:
    import yaml

    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if isinstance(data, Mapping):
        if set(data) != {"recordings"}:
            raise ValueError(f"{path}: expected a list of entries or a mapping with the one key 'recordings', got "
                             f"keys {', '.join(map(str, data))}")
        data = data["recordings"]
    if not isinstance(data, list):
        raise ValueError(f"{path}: expected a list of entries (path, label, params, set)")
    out = []
    for i, entry in enumerate(data):
        where = f"{path}: entry {i + 1}"
        if isinstance(entry, str):
            entry = {"path": entry}
        if not isinstance(entry, Mapping):
            raise ValueError(f"{where}: expected a mapping with 'path' (and label, params, set) or a path, got "
                             f"{entry!r}")
        out.append((where, dict(entry)))
    return out


def _read_csv_manifest(path: Path) -> list[tuple[str, dict]]:
    with open(path, newline="") as f:
        rows = [row for row in csv.reader(f) if row and any(c.strip() for c in row)
                and not row[0].lstrip().startswith("#")]
    if not rows:
        return []
    header = [c.strip().lower() for c in rows[0]]
    if "path" not in header:
        raise ValueError(f"{path}: the first row must name the columns, with 'path' among them (expected "
                         f"{', '.join(MANIFEST_FIELDS)}), got {', '.join(rows[0])}")
    out = []
    for n, row in enumerate(rows[1:], start=2):
        if len(row) > len(header):
            raise ValueError(f"{path}: row {n}: {len(row)} cells for {len(header)} columns")
        entry = {h: c.strip() for h, c in zip(header, row) if c.strip()}
        out.append((f"{path}: row {n}", entry))
    return out


def recordings_from(inputs: str | Path, *, params: str | None = None, overrides: Mapping[str, Any] | None = None,
                    exclude: Iterable[str | Path] = ()) -> list[Recording]:
    """INPUTS as a folder (searched recursively) or a manifest file; `params` and `overrides` apply to every
    recording, a manifest entry's own params and set taking precedence."""
    inputs = Path(inputs)
    if inputs.is_file() and detect(inputs) is None:
        recordings = read_manifest(inputs)
    else:
        recordings = discover(inputs, exclude=exclude)
        if not recordings:
            from line_odom import readers

            raise ValueError(f"{inputs}: no recording found (expected recordings replay reads, formats "
                             f"{', '.join(readers.FORMATS)}, or a .yaml/.csv manifest)")
    if params is not None:
        params = str(Path(params).resolve())
    for rec in recordings:
        rec.params = rec.params or params
        rec.overrides = {**(overrides or {}), **rec.overrides}
    return recordings


# --------------------------------------------------------------------------------------------- provenance


def provenance() -> dict:
    """The machine and the line_odom commit running this process."""
    import line_odom_core

    source = Path(__file__).resolve().parents[1]
    commit = "unknown (not a git checkout)"
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(source), *args], capture_output=True, text=True, timeout=10,
                              check=True).stdout.strip()

    try:
        # an installed copy inside some other repository (a venv in a project) is not that repository's commit
        if Path(git("rev-parse", "--show-toplevel")).resolve() == source:
            dirty = git("status", "--porcelain", "--untracked-files=no")
            commit = git("rev-parse", "HEAD") + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        pass
    return {"host": socket.gethostname(), "platform": platform.platform(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "line_odom": getattr(line_odom_core, "__version__", "unknown"),
            "commit": commit}


# --------------------------------------------------------------------------------------------- one task


def one_line_error(exc: BaseException) -> str:
    message = str(exc) or type(exc).__name__
    if isinstance(exc, (FileNotFoundError, PermissionError)) and exc.filename and str(exc.filename) not in message:
        message = f"{exc.filename}: {message}"
    if not isinstance(exc, (ValueError, OSError, RuntimeError, KeyError)):
        message = f"{type(exc).__name__}: {message}"
    return message.strip().splitlines()[0] if message.strip() else type(exc).__name__


def read_complete(out_dir: Path, spec: dict) -> dict | None:
    """The record of `out_dir` when it holds complete outputs of the task `spec`, else None."""
    try:
        record = json.loads((out_dir / RECORD).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("status") != "ok" or record.get("spec") != spec:
        return None
    if not all((out_dir / name).is_file() for name in REPLAY_OUTPUTS):
        return None
    return record


def _replay(rec: Recording, out: Path, frames: int | None) -> dict:
    from line_odom import readers, replay

    kind = rec.kind or readers.guess_format(rec.path)  # none: the readers' error, naming the formats expected
    return replay.replay(rec.path, out, format=kind, params=rec.params, overrides=rec.overrides, frames=frames,
                         ground_truth=rec.ground_truth, progress=False, title=rec.label).metrics


def run_recording(rec: Recording, out_root: str | Path, frames: int | None = None) -> dict:
    """Replay one recording into `out_root/<label>/` (replacing what is there) and return its summary row. Never
    raises for a failing recording: the row says failed, with the error."""
    start = time.monotonic()
    out_root = Path(out_root)
    spec = rec.spec(frames)
    info = provenance()
    row = {"label": rec.label, "input": str(rec.path), "kind": rec.kind, "status": "failed", "error": "",
           "host": info["host"], "commit": info["commit"], "metrics": {}}
    tmp_root = out_root / TMP_DIR
    tmp_root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"{rec.label}.", dir=tmp_root))
    try:
        out = work / "out"
        try:
            row["metrics"] = numeric_metrics(_replay(rec, out, frames))
        except Exception as exc:  # a failing recording is a row of the summary, not the end of the batch
            row["error"] = one_line_error(exc)
            row["seconds"] = time.monotonic() - start
            return row
        row["status"] = "ok"
        row["seconds"] = time.monotonic() - start
        record = {**row, "spec": spec, "machine": info}
        (out / RECORD).write_text(json.dumps(record, indent=2) + "\n")
        final = out_root / rec.label
        if final.exists():
            os.rename(final, work / "replaced")
        os.rename(out, final)
        return row
    finally:
        shutil.rmtree(work, ignore_errors=True)


# --------------------------------------------------------------------------------------------- engine


def _distributed():
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

    distributed = _distributed()
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        # no dashboard; the scheduler's HTTP routes on a free loopback port instead of the usual 8787. Its log stays
        # quiet: a worker's death and a task's failure are the summary's rows, each with its one line
        return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                        dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                                        silence_logs=logging.CRITICAL, preload=[__name__])


def connect(address: str):
    """A client of the scheduler at `address` (tcp://host:port), or of the one a scheduler file names (the JSON that
    `dask scheduler --scheduler-file` writes, as on a batch-queue cluster)."""
    distributed = _distributed()
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
    distributed = _distributed()
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


# --------------------------------------------------------------------------------------------- progress


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


# --------------------------------------------------------------------------------------------- summary


def numeric_metrics(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The metrics that are numbers (metrics.json also describes the input: format, topic, preset)."""
    return {k: v for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


def metric_keys(rows: list[dict]) -> list[str]:
    keys = {k for row in rows for k in row.get("metrics", {})}
    return [k for k in METRIC_ORDER if k in keys] + sorted(keys - set(METRIC_ORDER))


def aggregates(rows: list[dict]) -> dict[str, dict[str, float]]:
    """mean / median / worst of each metric (and seconds) over the recordings that have outputs."""
    good = [r for r in rows if r["status"] in ("ok", "skipped")]
    out = {}
    for key in metric_keys(good) + ["seconds"]:
        values = [float(r["seconds"] if key == "seconds" else r["metrics"][key]) for r in good
                  if (key == "seconds" or key in r["metrics"])]
        if not values:
            continue
        worst = min(values) if key in LARGER_IS_BETTER else max(values) if key in SMALLER_IS_BETTER else None
        out[key] = {"mean": statistics.fmean(values), "median": statistics.median(values), "worst": worst}
    return out


def _fmt(value) -> str:
    if value is None or value == "":
        return ""
    if isinstance(value, float):
        return "nan" if value != value else f"{value:.6g}"
    return str(value)


def _atomic_write(path: Path, text: str | bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    if isinstance(text, bytes):
        tmp.write_bytes(text)
    else:
        tmp.write_text(text)
    os.replace(tmp, path)


def summary_csv(rows: list[dict]) -> str:
    keys = metric_keys(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["label", "input", "kind", "status", "seconds", "attempts", "error", "host", "commit"] + keys)
    for r in rows:
        w.writerow([r["label"], r["input"], r["kind"] or "", r["status"], _fmt(r.get("seconds")),
                    _fmt(r.get("attempts")), r.get("error", ""), r.get("host", ""), r.get("commit", "")]
                   + [_fmt(r["metrics"].get(k)) for k in keys])
    agg = aggregates(rows)
    for stat in ("mean", "median", "worst"):
        w.writerow([stat, "", "", "aggregate", _fmt(agg.get("seconds", {}).get(stat)), "", "", "", ""]
                   + [_fmt(agg[k][stat]) if k in agg else "" for k in keys])
    return buf.getvalue()


def summary_md(rows: list[dict], run_info: dict) -> str:
    keys = metric_keys(rows)
    failed = [r for r in rows if r["status"] == "failed"]
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "skipped", "failed")}
    m = run_info["machine"]
    lines = [
        "# line_odom batch",
        "",
        f"- inputs: `{run_info['inputs']}`; engine: {run_info['engine']}; frames: {run_info['frames'] or 'all'}",
        f"- machine: {m['host']} ({m['platform']}, {m['cpus']} cores, Python {m['python']}); line_odom "
        f"{m['line_odom']}, commit {m['commit']}; started {run_info['started']}, {run_info['wall_s']:.1f} s",
        f"- recordings: {len(rows)}; ran {counts['ok']}, skipped (complete) {counts['skipped']}, "
        f"failed {counts['failed']}",
        "",
        "| label | status | seconds | " + " | ".join(keys) + " |",
        "|---|---|---:|" + "---:|" * len(keys),
    ]
    for r in rows:
        lines.append(f"| {r['label']} | {r['status']} | {_fmt(r.get('seconds'))} | "
                     + " | ".join(_fmt(r["metrics"].get(k)) for k in keys) + " |")
    agg = aggregates(rows)
    lines += ["", "| aggregate | " + " | ".join(["seconds"] + keys) + " |", "|---|" + "---:|" * (len(keys) + 1)]
    for stat in ("mean", "median", "worst"):
        lines.append(f"| {stat} | " + " | ".join(_fmt(agg[k][stat]) if k in agg else ""
                                                for k in ["seconds"] + keys) + " |")
    lines += ["", f"failed: {len(failed)}"]
    for r in failed:
        lines.append(f"- {r['label']} (`{r['input']}`): {r['error']}")
    lines.append("")
    lines.append("Rows' machine and commit (a skipped row keeps those of the run that wrote it): see summary.csv.")
    return "\n".join(lines) + "\n"


def plot_summary(path: Path, rows: list[dict]) -> Path:
    """Bar chart of the per-recording RPE (and the KITTI drift where any recording has it); failed recordings
    and recordings without ground truth are marked."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    panels = [(k, t) for k, t in PLOT_METRICS if any(k in r["metrics"] for r in rows)] or [PLOT_METRICS[0]]
    labels = [r["label"] for r in rows]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels) + 2, 0.45 * len(rows) + 1.6), squeeze=False)
    y = list(range(len(rows)))
    for ax, (key, title) in zip(axes[0], panels):
        values = [r["metrics"].get(key, 0.0) for r in rows]
        colors = ["tab:red" if r["status"] == "failed" else "tab:blue" for r in rows]
        ax.barh(y, values, color=colors)
        top = max(values) if any(values) else 1.0
        for i, r in enumerate(rows):
            if r["status"] == "failed":
                ax.text(0, i, " failed", va="center", color="tab:red", fontsize=8)
            elif key not in r["metrics"]:
                ax.text(0, i, " n/a", va="center", color="gray", fontsize=8)
        ax.set_xlim(0, top * 1.15)
        ax.set_title(title, fontsize=10)
        ax.set_yticks(y)
        ax.set_yticklabels(labels if ax is axes[0][0] else [""] * len(rows), fontsize=8)
        ax.invert_yaxis()
        ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    _atomic_write(path, buf.getvalue())
    return path


def write_summary(out_root: Path, rows: list[dict], run_info: dict) -> list[Path]:
    out_root.mkdir(parents=True, exist_ok=True)
    _atomic_write(out_root / SUMMARY_CSV, summary_csv(rows))
    _atomic_write(out_root / SUMMARY_MD, summary_md(rows, run_info))
    plot_summary(out_root / SUMMARY_PLOT, rows)
    return [out_root / SUMMARY_CSV, out_root / SUMMARY_MD, out_root / SUMMARY_PLOT]


# --------------------------------------------------------------------------------------------- the run


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
    _distributed()
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
                client = _distributed().Client(cluster_obj)
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
