"""A KITTI raw drive folder (<date>/<date>_drive_<n>_sync or _extract): velodyne_points/data/*.bin with
velodyne_points/timestamps.txt, and the OXTS GPS/INS (oxts/data/*.txt, oxts/timestamps.txt) as ground truth in the
Velodyne frame through calib_imu_to_velo.txt of the date folder."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from line_odom import bags, datasets
from line_odom.evaluation import Trajectory
from line_odom.readers import oxts
from line_odom.readers.base import Frame, ReaderError, Sensor, Source, nominal_stamps_ns, sorted_files

OXTS_MAX_GAP_S = 0.15  # unsynced (extract) drives: ground truth only between OXTS records this close


def is_drive(path: Path) -> bool:
    return (path / "velodyne_points" / "data").is_dir()


class KittiRaw(Source):
    format = "kitti_raw"
    frame_id = "velo_link"

    def __init__(self, path: str | Path, frames: int | None = None):
        super().__init__(path)
        data = self.path / "velodyne_points" / "data"
        if not data.is_dir():
            raise ReaderError(f"{self.path}: no velodyne_points/data/ (expected a KITTI raw drive folder)")
        self.scans = sorted_files(data, (".bin",))
        if not self.scans:
            raise ReaderError(f"{data}: no .bin scans")
        stamps_file = self.path / "velodyne_points" / "timestamps.txt"
        if stamps_file.is_file():
            stamps = oxts.read_timestamps_ns(stamps_file)
            if len(stamps) < len(self.scans):
                raise ReaderError(f"{stamps_file}: {len(stamps)} timestamps for {len(self.scans)} scans")
        else:
            stamps = nominal_stamps_ns(len(self.scans))
            self.notes.append("no velodyne_points/timestamps.txt: scans stamped 0.1 s apart")
        self.total_scans = len(self.scans)
        if frames is not None:
            self.scans = self.scans[:frames]
        self.stamps_ns = stamps[: len(self.scans)]
        self.count = len(self.scans)
        self.sensor = Sensor("kitti_hdl64", {}, "KITTI raw: Velodyne HDL-64E scans, rings from the point order")
        self._ground_truth()

    def _ground_truth(self) -> None:
        oxts_dir = self.path / "oxts" / "data"
        if not oxts_dir.is_dir():
            self.notes.append("no oxts/data/: no ground truth")
            return
        calib = next((c for c in (self.path.parent / "calib_imu_to_velo.txt", self.path / "calib_imu_to_velo.txt")
                      if c.is_file()), None)
        if calib is None:
            self.notes.append(f"no calib_imu_to_velo.txt in {self.path.parent} (the date folder): the OXTS poses "
                              f"cannot be put in the Velodyne frame, no ground truth")
            return
        files = sorted_files(oxts_dir, (".txt",))
        if not files:
            raise ReaderError(f"{oxts_dir}: no OXTS records (*.txt)")
        records = np.stack([oxts.read_oxts(f) for f in files])
        poses = oxts.velodyne_poses(oxts.oxts_poses(records), oxts.read_calib_rigid(calib))
        stamps = np.asarray(self.stamps_ns, dtype=np.int64)
        oxts_stamps_file = self.path / "oxts" / "timestamps.txt"
        if len(files) == self.total_scans:
            # a synced drive: record i belongs to scan i
            self.ground_truth = Trajectory(poses[: len(self.scans)], stamps * 1e-9)
            how = "record i with scan i (synced drive)"
        elif oxts_stamps_file.is_file():
            oxts_ns = np.asarray(oxts.read_timestamps_ns(oxts_stamps_file)[: len(files)], dtype=np.int64)
            t0 = oxts_ns[0]
            at, valid = datasets.interpolate_poses((oxts_ns - t0) * 1e-9, poses, (stamps - t0) * 1e-9,
                                                   OXTS_MAX_GAP_S)
            if not valid.any():
                self.notes.append("no scan lies between two OXTS records: no ground truth")
                return
            self.ground_truth = Trajectory(at[valid], stamps[valid] * 1e-9)
            how = "interpolated at the scans' stamps"
        else:
            self.notes.append(f"{len(files)} OXTS records for {len(self.scans)} scans and no oxts/timestamps.txt: "
                              f"no ground truth")
            return
        self.ground_truth_source = (f"OXTS GPS/INS (convertOxtsToPose), in the Velodyne frame through "
                                    f"{calib.name}, {how}")

    def frames(self) -> Iterator[Frame]:
        for path, stamp in zip(self.scans, self.stamps_ns):
            try:
                raw = datasets.read_kitti_bin(path)
            except ValueError as exc:
                raise ReaderError(str(exc)) from None
            yield Frame(stamp, np.ascontiguousarray(raw[:, :3]), bags.kitti_rings(raw), None,
                        np.ascontiguousarray(raw[:, 3]))
