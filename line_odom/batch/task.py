"""One task of a batch: a recording replayed into its output folder, and the summary row that reports it."""
from __future__ import annotations

import json
import os
import platform
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any, Mapping

from line_odom.batch.outputs import RECORD, TMP_DIR
from line_odom.batch.recordings import Recording


def provenance() -> dict:
    """The machine and the line_odom commit running this process."""
    import line_odom_core

    source = Path(__file__).resolve().parents[2]
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



def one_line_error(exc: BaseException) -> str:
    message = str(exc) or type(exc).__name__
    if isinstance(exc, (FileNotFoundError, PermissionError)) and exc.filename and str(exc.filename) not in message:
        message = f"{exc.filename}: {message}"
    if not isinstance(exc, (ValueError, OSError, RuntimeError, KeyError)):
        message = f"{type(exc).__name__}: {message}"
    return message.strip().splitlines()[0] if message.strip() else type(exc).__name__



def numeric_metrics(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The metrics that are numbers (metrics.json also describes the input: format, topic, preset)."""
    return {k: v for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


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

