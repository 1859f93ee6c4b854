"""Trajectory files (TUM, KITTI), time association, and the metrics.json that `replay` and `eval` write.

TUM files: ``timestamp tx ty tz qx qy qz qw`` per line; KITTI files: 12 numbers (3x4 row-major pose) per line,
no timestamps (poses are matched by index). The format is detected from the number of columns.
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom import metrics

ASSOCIATION_MAX_DIFF_S = 0.01  # evo's default for TUM files
KITTI_MIN_PATH_M = 100.0

# Order of the keys in metrics.json and in the printed table.
METRIC_KEYS = ("frames", "frames_dropped", "rpe_trans_mean_m", "rpe_trans_max_m", "rpe_rot_mean_deg",
               "rpe_rot_max_deg", "ate_rmse_m", "latency_mean_ms", "latency_p95_ms", "kitti_t_err_pct",
               "kitti_r_err_deg_per_m")
GT_KEYS = ("rpe_trans_mean_m", "rpe_trans_max_m", "rpe_rot_mean_deg", "rpe_rot_max_deg", "ate_rmse_m",
           "kitti_t_err_pct", "kitti_r_err_deg_per_m")


@dataclasses.dataclass
class Trajectory:
    poses: np.ndarray  # (N, 4, 4)
    stamps: np.ndarray | None = None  # (N,) seconds, None for KITTI files

    def __post_init__(self):
        self.poses = np.asarray(self.poses, dtype=float).reshape(-1, 4, 4)
        if self.stamps is not None:
            self.stamps = np.asarray(self.stamps, dtype=float).reshape(-1)
            if len(self.stamps) != len(self.poses):
                raise ValueError(f"stamps: expected {len(self.poses)} values (one per pose), got {len(self.stamps)}")

    def __len__(self) -> int:
        return len(self.poses)

    def subset(self, idx) -> "Trajectory":
        return Trajectory(self.poses[idx], None if self.stamps is None else self.stamps[idx])


def read_trajectory(path: str | Path) -> Trajectory:
    """A TUM (8 columns) or KITTI (12 columns) trajectory file; raises ValueError/FileNotFoundError with the
    file name and what was expected."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such trajectory file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file is reported below
            rows = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: not a trajectory file (expected numbers only: {exc})") from None
    if rows.size == 0:
        raise ValueError(f"{path}: empty trajectory file")
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"{path}: contains non-finite values")
    if rows.shape[1] == 8:
        quat = rows[:, 4:8]
        norms = np.linalg.norm(quat, axis=1)
        if np.any(norms < 1e-9):
            raise ValueError(f"{path}: zero quaternion on line {int(np.argmin(norms)) + 1}")
        poses = np.tile(np.eye(4), (len(rows), 1, 1))
        poses[:, :3, :3] = Rotation.from_quat(quat).as_matrix()
        poses[:, :3, 3] = rows[:, 1:4]
        return Trajectory(poses, rows[:, 0])
    if rows.shape[1] == 12:
        poses = np.tile(np.eye(4), (len(rows), 1, 1))
        poses[:, :3, :4] = rows.reshape(-1, 3, 4)
        return Trajectory(poses, None)
    raise ValueError(f"{path}: {rows.shape[1]} columns; expected 8 (TUM: timestamp tx ty tz qx qy qz qw) or "
                     f"12 (KITTI: 3x4 row-major pose)")


def write_tum(path: str | Path, traj: Trajectory) -> None:
    if traj.stamps is None:
        raise ValueError("traj: a TUM file needs timestamps")
    quat = Rotation.from_matrix(traj.poses[:, :3, :3]).as_quat() if len(traj) else np.zeros((0, 4))
    rows = np.column_stack([traj.stamps, traj.poses[:, :3, 3], quat])
    np.savetxt(path, rows, fmt=["%.9f"] + ["%.9f"] * 3 + ["%.12f"] * 4,
               header="timestamp tx ty tz qx qy qz qw")


def write_kitti(path: str | Path, traj: Trajectory) -> None:
    np.savetxt(path, traj.poses[:, :3, :4].reshape(-1, 12), fmt="%.12e")


def matching_time_indices(stamps_a: np.ndarray, stamps_b: np.ndarray, max_diff: float) -> tuple[np.ndarray, np.ndarray]:
    """For each stamp of `a` the nearest stamp of sorted `b` within max_diff (ties go to the earlier one)."""
    ia, ib = [], []
    order = np.argsort(stamps_b, kind="stable")
    sorted_b = stamps_b[order]
    for i, s in enumerate(stamps_a):
        k = int(np.searchsorted(sorted_b, s, side="right"))
        best, best_diff = -1, math.inf
        for j in (k - 1, k):
            if 0 <= j < len(sorted_b):
                diff = abs(sorted_b[j] - s)
                if diff <= max_diff and diff < best_diff:
                    best, best_diff = j, diff
        if best >= 0:
            ia.append(i)
            ib.append(int(order[best]))
    return np.array(ia, dtype=int), np.array(ib, dtype=int)


def associate(estimate: Trajectory, ground_truth: Trajectory,
              max_diff: float = ASSOCIATION_MAX_DIFF_S) -> tuple[Trajectory, Trajectory]:
    """Pairs of poses at (nearly) the same time: by timestamp when both have them (each pose of the shorter
    trajectory to the nearest of the longer, as evo does), else by index (lengths must agree)."""
    if estimate.stamps is None or ground_truth.stamps is None:
        if len(estimate) != len(ground_truth):
            raise ValueError(f"estimate has {len(estimate)} poses and ground truth {len(ground_truth)}; without "
                             f"timestamps on both, poses are matched by index and the counts must agree")
        return estimate, ground_truth
    est_shorter = len(estimate) <= len(ground_truth)
    short, long_ = (estimate, ground_truth) if est_shorter else (ground_truth, estimate)
    i_short, i_long = matching_time_indices(short.stamps, long_.stamps, max_diff)
    if len(i_short) == 0:
        raise ValueError(f"no estimate timestamp is within {max_diff} s of a ground-truth timestamp "
                         f"(estimate {estimate.stamps[:1]}..., ground truth {ground_truth.stamps[:1]}...)")
    a, b = short.subset(i_short), long_.subset(i_long)
    return (a, b) if est_shorter else (b, a)


def compute_metrics(estimate: Trajectory, ground_truth: Trajectory | None = None, *,
                    frames_dropped: int | None = None, latencies_ms=None) -> dict:
    """The metrics.json dictionary. Ground-truth keys only with ground truth; the KITTI keys only when the
    ground-truth path is at least 100 m; latency and dropped-frame keys only when given."""
    out: dict = {"frames": int(len(estimate))}
    if frames_dropped is not None:
        out["frames_dropped"] = int(frames_dropped)
    if ground_truth is not None and len(ground_truth):
        est, gt = associate(estimate, ground_truth)
        out["frames_with_ground_truth"] = int(len(est))
        if len(est) >= 2:
            t_err, r_err = metrics.relative_pose_errors(est.poses, gt.poses)
            out["rpe_trans_mean_m"] = float(t_err.mean())
            out["rpe_trans_max_m"] = float(t_err.max())
            out["rpe_rot_mean_deg"] = float(r_err.mean())
            out["rpe_rot_max_deg"] = float(r_err.max())
        ate, _ = metrics.absolute_trajectory_errors(est.poses, gt.poses)
        out["ate_rmse_m"] = float(np.sqrt(np.mean(ate ** 2)))
        out["path_length_m"] = metrics.path_length(gt.poses)
        if out["path_length_m"] >= KITTI_MIN_PATH_M:
            kitti = metrics.kitti_errors(est.poses, gt.poses)
            if kitti is not None:
                out["kitti_t_err_pct"], out["kitti_r_err_deg_per_m"] = kitti
    if latencies_ms is not None and len(latencies_ms):
        lat = np.asarray(latencies_ms, dtype=float)
        out["latency_mean_ms"] = float(lat.mean())
        out["latency_p95_ms"] = float(np.percentile(lat, 95))
    return out


_LABELS = {
    "frames": ("frames", "{:d}"),
    "frames_dropped": ("frames dropped", "{:d}"),
    "frames_with_ground_truth": ("frames with ground truth", "{:d}"),
    "path_length_m": ("path length [m]", "{:.2f}"),
    "rpe_trans_mean_m": ("RPE translation mean [m]", "{:.4f}"),
    "rpe_trans_max_m": ("RPE translation max [m]", "{:.4f}"),
    "rpe_rot_mean_deg": ("RPE rotation mean [deg]", "{:.4f}"),
    "rpe_rot_max_deg": ("RPE rotation max [deg]", "{:.4f}"),
    "ate_rmse_m": ("ATE RMSE (SE(3) aligned) [m]", "{:.4f}"),
    "kitti_t_err_pct": ("KITTI t_err [%]", "{:.3f}"),
    "kitti_r_err_deg_per_m": ("KITTI r_err [deg/m]", "{:.5f}"),
    "latency_mean_ms": ("latency mean [ms]", "{:.1f}"),
    "latency_p95_ms": ("latency p95 [ms]", "{:.1f}"),
}


def format_table(values: dict, title: str | None = None) -> str:
    """A plain two-column text table of the metrics present in `values`."""
    order = ["frames", "frames_dropped", "frames_with_ground_truth", "path_length_m"] + [
        k for k in METRIC_KEYS if k not in ("frames", "frames_dropped")]
    rows = [(label, fmt.format(values[key])) for key in order if key in values
            for label, fmt in [_LABELS[key]]]
    width = max([len(r[0]) for r in rows] + [10])
    vwidth = max([len(r[1]) for r in rows] + [6])
    lines = []
    if title:
        lines.append(title)
    lines.append("-" * (width + vwidth + 3))
    lines += [f"{label:<{width}}   {value:>{vwidth}}" for label, value in rows]
    lines.append("-" * (width + vwidth + 3))
    return "\n".join(lines)
