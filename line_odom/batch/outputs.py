"""What a batch writes into its output folder: a folder per recording with replay's outputs and the record of the
task that wrote them, a scratch folder, a lock and the summary files (each replaced by a rename: seen whole)."""
from __future__ import annotations

import json
import os
from pathlib import Path

RECORD = "batch.json"
TMP_DIR = ".batch_tmp"
LOCK = ".batch.lock"
SUMMARY_CSV, SUMMARY_MD, SUMMARY_PLOT = "summary.csv", "summary.md", "summary.png"
REPLAY_OUTPUTS = ("trajectory_tum.txt", "trajectory_kitti.txt", "metrics.json")


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


def atomic_write(path: Path, text: str | bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    if isinstance(text, bytes):
        tmp.write_bytes(text)
    else:
        tmp.write_text(text)
    os.replace(tmp, path)
