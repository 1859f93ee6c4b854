"""A TUM RGB-D sequence folder (depth.txt, depth/*.png, groundtruth.txt): 16-bit depth in metres x 5000, the
intrinsics of the Freiburg camera its name says (fr1 otherwise), the mocap ground truth interpolated at the depth
stamps."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

from line_odom import bags, datasets
from line_odom.evaluation import Trajectory
from line_odom.readers.base import Frame, ReaderError, Sensor, Source


class TumRgbd(Source):
    format = "tum"
    kind = "depth"
    frame_id = bags.TUM_FRAME

    def __init__(self, path: str | Path, frames: int | None = None, camera: str | None = None):
        super().__init__(path)
        camera = camera or bags.tum_camera_from_path(self.path)
        try:
            self.seq = datasets.TumSequence.open(self.path, frames, camera)
        except (FileNotFoundError, ValueError) as exc:
            raise ReaderError(str(exc)) from None
        self.K = self.seq.K
        self.count = len(self.seq)
        self.sensor = Sensor("tum_kinect", {}, f"TUM RGB-D depth frames, {camera} intrinsics")
        if self.seq.poses is not None and self.seq.pose_valid.any():
            valid = self.seq.pose_valid
            self.ground_truth = Trajectory(self.seq.poses[valid], self.seq.stamps[valid])
            self.ground_truth_source = "groundtruth.txt (mocap), interpolated at the depth stamps"

    def frames(self) -> Iterator[Frame]:
        for i in range(len(self.seq)):
            try:
                depth = self.seq.depth(i)
            except (OSError, ValueError) as exc:
                raise ReaderError(f"{self.seq.depth_paths[i]}: cannot read the depth PNG ({exc})") from None
            if depth.ndim != 2:
                raise ReaderError(f"{self.seq.depth_paths[i]}: expected a single-channel 16-bit depth PNG, got shape "
                                  f"{depth.shape}")
            yield Frame(round(self.seq.stamps[i] * 1e9), depth=depth)
