"""What every reader gives replay: frames (points with their rings and times, or depth images), the sensor preset
the data suggests, and the ground truth the format carries."""
from __future__ import annotations

import abc
import dataclasses
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from line_odom.evaluation import Trajectory


class ReaderError(ValueError):
    """A recording that cannot be read as the format it was taken for: the message names the file and what was
    expected."""


@dataclasses.dataclass
class Frame:
    """One scan. xyz (N, 3) unorganized or (H, W, 3) organized (rows = beams, NaN = no return); ring and time have
    xyz's shape without the last axis; time in seconds from the stamp. Depth sources set depth (H, W) in metres
    (0 = none) instead of xyz."""

    stamp_ns: int
    xyz: np.ndarray | None = None
    ring: np.ndarray | None = None
    time: np.ndarray | None = None
    intensity: np.ndarray | None = None
    depth: np.ndarray | None = None


@dataclasses.dataclass
class Sensor:
    """The parameters the data suggests: a preset and the overrides on top of it, with the reason."""

    preset: str
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    reason: str = ""


class Source(abc.ABC):
    """A recording opened by a reader. Subclasses set the attributes in __init__ and implement frames()."""

    format: str = ""
    kind: str = "pointcloud"  # or "depth"
    frame_id: str = "sensor"
    K: np.ndarray | None = None  # depth sources: pinhole intrinsics (3, 3)

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.sensor = Sensor("kitti_hdl64")
        self.ground_truth: Trajectory | None = None
        self.ground_truth_source = ""  # what the ground truth is, for the report
        self.count: int | None = None  # frames to come (after the frame limit), None when known only once read
        self.notes: list[str] = []  # what the reader decided (frames skipped, stamps made up), for the report

    @abc.abstractmethod
    def frames(self) -> Iterator[Frame]:
        """The frames in recording order."""

    def close(self) -> None:
        pass

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def sorted_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The files of `folder` with these suffixes in natural order (scan_2 before scan_10)."""
    import re

    def key(p: Path):
        return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]

    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes), key=key)


def nominal_stamps_ns(count: int, start_ns: int = 0, period_s: float = 0.1) -> list[int]:
    return [start_ns + round(i * period_s * 1e9) for i in range(count)]
