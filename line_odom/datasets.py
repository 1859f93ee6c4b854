"""Readers for the datasets line_odom is measured on: KITTI odometry (velodyne .bin) and TUM RGB-D (depth PNG).

Ground truth is returned in the sensor's own frame: KITTI poses are given for camera 0, so the LiDAR pose is
``inv(Tr) @ P @ Tr`` (KITTI devkit); TUM poses are those of the (registered) depth camera's optical frame.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

# ../shared/data beside the checkout (tests, benchmarks, CI); LINE_ODOM_DATA points elsewhere.
SHARED_DATA = Path(os.environ.get("LINE_ODOM_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))

# Intrinsics of the TUM RGB-D cameras (fx, fy, cx, cy), from the dataset documentation.
TUM_INTRINSICS = {
    "fr1": (517.3, 516.5, 318.6, 255.3),
    "fr2": (520.9, 521.0, 325.1, 249.7),
    "fr3": (535.4, 539.2, 320.1, 247.6),
    "ros_default": (525.0, 525.0, 319.5, 239.5),
}
TUM_DEPTH_FACTOR = 5000.0


def _pose_from_row(values) -> np.ndarray:
    T = np.eye(4)
    T[:3, :4] = np.asarray(values, dtype=float).reshape(3, 4)
    return T


def read_kitti_bin(path: str | Path) -> np.ndarray:
    """One velodyne scan as (N, 4) float32: x, y, z, reflectance."""
    size = os.path.getsize(path)
    if size % 16:
        raise ValueError(f"{path}: size {size} bytes is not a multiple of 16 (x, y, z, reflectance float32)")
    raw = np.fromfile(path, dtype=np.float32)
    return raw.reshape(-1, 4)


def read_kitti_calib(path: str | Path) -> dict[str, np.ndarray]:
    calib = {}
    for line in Path(path).read_text().splitlines():
        if ":" not in line:
            continue
        key, values = line.split(":", 1)
        numbers = np.array(values.split(), dtype=float)
        calib[key.strip()] = _pose_from_row(numbers) if numbers.size == 12 else numbers
    return calib


def read_kitti_poses(path: str | Path) -> np.ndarray:
    rows = np.loadtxt(path, ndmin=2)
    if rows.shape[1] != 12:
        raise ValueError(f"{path}: expected 12 numbers per line (3x4 row-major pose), got {rows.shape[1]}")
    return np.stack([_pose_from_row(r) for r in rows])


@dataclasses.dataclass
class KittiSequence:
    """A KITTI odometry sequence directory (velodyne/, times.txt, calib.txt, optional poses_gt.txt)."""

    root: Path
    scan_paths: list[Path]
    times: np.ndarray
    Tr: np.ndarray  # velodyne -> camera 0
    poses: np.ndarray | None  # (N, 4, 4) LiDAR poses in the first LiDAR frame's world, or None

    @classmethod
    def open(cls, root: str | Path, frames: int | None = None) -> "KittiSequence":
        root = Path(root)
        if not (root / "velodyne").is_dir():
            raise FileNotFoundError(f"{root}: no velodyne/ directory (expected a KITTI odometry sequence)")
        scans = sorted((root / "velodyne").glob("*.bin"))
        if not scans:
            raise FileNotFoundError(f"{root / 'velodyne'}: no .bin scans")
        if frames is not None:
            scans = scans[:frames]
        times_path = root / "times.txt"
        times = np.loadtxt(times_path, ndmin=1)[: len(scans)] if times_path.exists() else np.arange(len(scans)) * 0.1
        calib_path = root / "calib.txt"
        Tr = read_kitti_calib(calib_path).get("Tr", np.eye(4)) if calib_path.exists() else np.eye(4)
        poses = None
        for name in ("poses_gt.txt", "poses.txt"):
            if (root / name).exists():
                cam = read_kitti_poses(root / name)[: len(scans)]
                Tr_inv = np.linalg.inv(Tr)
                poses = np.stack([Tr_inv @ P @ Tr for P in cam])
                break
        return cls(root, scans, np.asarray(times, dtype=float), Tr, poses)

    def __len__(self) -> int:
        return len(self.scan_paths)

    def every_kth_scan(self, k: int) -> "KittiSequence":
        """Every k-th scan with its stamp and pose: each scan moved k times as far as in the run, as a sensor that slow
        (or a drive that fast) would see it."""
        return dataclasses.replace(self, scan_paths=self.scan_paths[::k], times=self.times[::k],
                                   poses=None if self.poses is None else self.poses[::k])

    def from_scan(self, first: int) -> "KittiSequence":
        """The run from scan `first` on, stamps and poses kept: a cold start mid-drive, at the speed it has there."""
        if not 0 <= first < len(self):
            raise ValueError(f"first scan {first}: expected 0 <= first < {len(self)} (the run's scans)")
        return dataclasses.replace(self, scan_paths=self.scan_paths[first:], times=self.times[first:],
                                   poses=None if self.poses is None else self.poses[first:])

    def played_backwards(self) -> "KittiSequence":
        """The scans in reverse order, each interval between two scans kept: the drive backwards, from its end (a
        stop becomes a start from standing still, a braking car an accelerating one)."""
        times = np.asarray(self.times)
        return dataclasses.replace(self, scan_paths=self.scan_paths[::-1], times=times[-1] - times[::-1],
                                   poses=None if self.poses is None else self.poses[::-1])

    def points(self, i: int) -> np.ndarray:
        return read_kitti_bin(self.scan_paths[i])

    def xyz(self, i: int) -> np.ndarray:
        """Scan i's points (N, 3) float32, contiguous: what Odometry.register_points reads in place."""
        return np.ascontiguousarray(self.points(i)[:, :3])


def kitti_sequence(seq: str, frames: int | None = None) -> KittiSequence:
    """A sequence of the shared KITTI mini set ("00", "04", "07")."""
    return KittiSequence.open(SHARED_DATA / "kitti_odometry_mini" / "sequences" / seq, frames)


def read_tum_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """TUM trajectory file (timestamp tx ty tz qx qy qz qw) -> (stamps (N,), poses (N, 4, 4))."""
    rows = np.loadtxt(path, comments="#", ndmin=2)
    if rows.shape[1] != 8:
        raise ValueError(f"{path}: expected 8 columns (timestamp tx ty tz qx qy qz qw), got {rows.shape[1]}")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    poses[:, :3, 3] = rows[:, 1:4]
    return rows[:, 0], poses


def interpolate_poses(stamps: np.ndarray, poses: np.ndarray, query: np.ndarray, max_gap: float = 0.05):
    """Poses at `query` times, interpolated (slerp + linear) between ground-truth samples no more than
    `max_gap` seconds apart; returns (poses (M, 4, 4), valid (M,) bool)."""
    query = np.asarray(query, dtype=float)
    idx = np.clip(np.searchsorted(stamps, query), 1, len(stamps) - 1)
    t0, t1 = stamps[idx - 1], stamps[idx]
    valid = (query >= stamps[0]) & (query <= stamps[-1]) & (t1 - t0 <= max_gap)
    alpha = np.clip((query - t0) / np.maximum(t1 - t0, 1e-12), 0.0, 1.0)
    out = np.tile(np.eye(4), (len(query), 1, 1))
    out[:, :3, 3] = (1 - alpha)[:, None] * poses[idx - 1, :3, 3] + alpha[:, None] * poses[idx, :3, 3]
    for k, (i, a) in enumerate(zip(idx, alpha)):
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(poses[[i - 1, i], :3, :3]))
        out[k, :3, :3] = slerp([a]).as_matrix()[0]
    return out, valid


@dataclasses.dataclass
class TumSequence:
    """A TUM RGB-D sequence directory (depth.txt, depth/*.png, optional groundtruth.txt)."""

    root: Path
    stamps: np.ndarray
    depth_paths: list[Path]
    K: np.ndarray
    poses: np.ndarray | None  # (N, 4, 4) camera poses at the depth stamps, or None
    pose_valid: np.ndarray | None
    ground_truth: tuple[np.ndarray, np.ndarray] | None = None  # groundtruth.txt as read: stamps (M,), poses (M, 4, 4)

    def poses_at_offset(self, offset: float) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth poses at the depth stamps + `offset` seconds (a depth image stamped after the scene it shows:
        a negative offset) and their validity, interpolated as `poses` is."""
        if self.ground_truth is None:
            raise ValueError(f"{self.root}: no groundtruth.txt")
        if not np.isfinite(offset):
            raise ValueError(f"offset: expected finite seconds, got {offset!r}")
        return interpolate_poses(*self.ground_truth, self.stamps + offset)

    @classmethod
    def open(cls, root: str | Path, frames: int | None = None, camera: str = "fr1") -> "TumSequence":
        root = Path(root)
        listing = root / "depth.txt"
        if not listing.exists():
            raise FileNotFoundError(f"{root}: no depth.txt (expected a TUM RGB-D sequence)")
        entries = [ln.split() for ln in listing.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
        if frames is not None:
            entries = entries[:frames]
        stamps = np.array([float(e[0]) for e in entries])
        paths = [root / e[1] for e in entries]
        if camera not in TUM_INTRINSICS:
            raise ValueError(f"camera: expected one of {sorted(TUM_INTRINSICS)}, got {camera!r}")
        fx, fy, cx, cy = TUM_INTRINSICS[camera]
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
        poses = valid = ground_truth = None
        if (root / "groundtruth.txt").exists():
            ground_truth = read_tum_trajectory(root / "groundtruth.txt")
            poses, valid = interpolate_poses(*ground_truth, stamps)
        return cls(root, stamps, paths, K, poses, valid, ground_truth)

    def __len__(self) -> int:
        return len(self.depth_paths)

    def depth_raw(self, i: int) -> np.ndarray:
        """16-bit depth image as stored (metres * 5000, 0 = no measurement)."""
        from PIL import Image

        with Image.open(self.depth_paths[i]) as img:
            return np.asarray(img, dtype=np.uint16)

    def depth(self, i: int) -> np.ndarray:
        """Depth in metres as float32 (0 = no measurement)."""
        return self.depth_raw(i).astype(np.float32) / TUM_DEPTH_FACTOR


def tum_sequence(frames: int | None = None) -> TumSequence:
    """The shared TUM fr1/xyz frames."""
    return TumSequence.open(SHARED_DATA / "tum_rgbd_fr1_xyz", frames)
