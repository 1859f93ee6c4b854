"""A KITTI odometry sequence folder (velodyne/*.bin, times.txt, calib.txt, poses_gt.txt or poses.txt), read as
kitti2bag reads it: each scan's rings from its point order (bags.kitti_rings), the ground truth in the LiDAR frame."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from line_odom import bags, datasets
from line_odom.evaluation import Trajectory
from line_odom.readers.base import Frame, ReaderError, Sensor, Source


class KittiOdometry(Source):
    format = "kitti"
    frame_id = bags.KITTI_FRAME

    def __init__(self, path: str | Path, frames: int | None = None):
        super().__init__(path)
        try:
            self.seq = datasets.KittiSequence.open(self.path, frames)
        except (FileNotFoundError, ValueError) as exc:
            raise ReaderError(str(exc)) from None
        self.count = len(self.seq)
        self.sensor = Sensor("kitti_hdl64", {}, "KITTI: Velodyne HDL-64E scans, rings from the point order")
        self.stamps_ns = [round(t * 1e9) for t in self.seq.times]
        if not (self.path / "times.txt").exists():
            self.notes.append("no times.txt: scans stamped 0.1 s apart")
        if self.seq.poses is not None:
            self.ground_truth = Trajectory(self.seq.poses, np.asarray(self.stamps_ns) * 1e-9)
            name = "poses_gt.txt" if (self.path / "poses_gt.txt").exists() else "poses.txt"
            self.ground_truth_source = f"{name} (camera 0 poses, in the LiDAR frame through calib.txt's Tr)"

    def frames(self) -> Iterator[Frame]:
        for i in range(len(self.seq)):
            try:
                raw = self.seq.points(i)
            except ValueError as exc:
                raise ReaderError(str(exc)) from None
            yield Frame(self.stamps_ns[i], np.ascontiguousarray(raw[:, :3]), bags.kitti_rings(raw), None,
                        np.ascontiguousarray(raw[:, 3]))
