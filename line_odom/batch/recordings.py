"""The recordings of a batch: found in a folder (every format line_odom.readers recognizes) or listed in a YAML or CSV
manifest, each with the label of its output folder and the parameters to replay it with."""
from __future__ import annotations

import csv
import dataclasses
import hashlib
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

from line_odom.batch.outputs import SUMMARY_CSV, SUMMARY_MD, SUMMARY_PLOT

MANIFEST_FIELDS = ("path", "label", "params", "set", "format", "ground_truth")
# recording files whose format cannot be guessed because they are unreadable: still tasks, so they fail visibly
RECORDING_SUFFIXES = {".pcap": "velodyne", ".pcapng": "velodyne", ".osf": "ouster", ".bag": "ros1"}


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
