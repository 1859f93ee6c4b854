"""The motion guess from another odometry source (wheel odometry, an IMU-aided filter): nav_msgs/Odometry
messages kept for a few seconds, their pose read at each scan's stamp, and the base's motion between two scans.

The engine registers each scan from this motion instead of the constant-velocity prediction, so the directions a
scan does not observe (the forward motion on a sparse highway, along a corridor) follow the other source and a
start mid-drive begins at its speed (docs/NODE.md, "Motion guess")."""
from __future__ import annotations

import bisect
import math

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom import convert
from line_odom_core._core import rotation_vector


class GuessError(convert.ConversionError):
    def __init__(self, field: str, reason: str):
        super().__init__("Odometry", field, reason)


def keep_window(stamps: list[int], values: list, newest_ns: int, window_ns: int) -> None:
    """Drops from the parallel lists the entries more than window_ns before newest_ns, keeping at least the newest
    two (something to interpolate or extrapolate between)."""
    cut = bisect.bisect_left(stamps, newest_ns - window_ns)
    cut = min(cut, len(stamps) - 2) if len(stamps) >= 2 else 0
    if cut > 0:
        del stamps[:cut], values[:cut]


def odometry_pose(msg, base_frame: str) -> tuple[int, np.ndarray]:
    """(stamp in ns, T_source_base 4x4) of a nav_msgs/Odometry; GuessError naming the field when it is unusable."""
    child = str(msg.child_frame_id)
    if child and child != base_frame:
        raise GuessError("child_frame_id", f"expected the base frame {base_frame!r} (the guess is the base's "
                                           f"motion), got {child!r}")
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    position = np.array([p.x, p.y, p.z], dtype=float)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
    if not np.isfinite(position).all():
        raise GuessError("pose.pose.position", f"expected finite values, got {position.tolist()}")
    norm = float(np.linalg.norm(quat))
    if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
        raise GuessError("pose.pose.orientation", f"expected a unit quaternion, got {quat.tolist()} (norm {norm:g})")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(quat).as_matrix()
    T[:3, 3] = position
    return convert.header_stamp_ns(msg.header.stamp, "Odometry"), T


class MotionGuess:
    """Poses of the base from another odometry source, by stamp.

    tolerance: how far (s) a scan's stamp may lie past the newest pose (extrapolated along the last two) or before
    the oldest (no pose then); window: seconds of poses kept behind the newest."""

    def __init__(self, base_frame: str, *, tolerance: float = 0.1, window: float = 5.0):
        self.base_frame = base_frame
        self.tolerance_ns = int(round(tolerance * 1e9))
        self.window_ns = int(round(window * 1e9))
        self._stamps: list[int] = []
        self._poses: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def clear(self) -> None:
        self._stamps.clear()
        self._poses.clear()

    def add(self, msg) -> bool:
        """Keeps the message's pose. GuessError when it is unusable; a stamp older than the newest kept clears the
        poses first (a bag looping, a restarted source) and returns False; a repeated stamp replaces the pose."""
        stamp, T = odometry_pose(msg, self.base_frame)
        restarted = bool(self._stamps) and stamp < self._stamps[-1]
        if restarted:
            self.clear()
        if self._stamps and stamp == self._stamps[-1]:
            self._poses[-1] = T
        else:
            self._stamps.append(stamp)
            self._poses.append(T)
        keep_window(self._stamps, self._poses, stamp, self.window_ns)
        return not restarted

    def pose_at(self, stamp_ns: int) -> np.ndarray | None:
        """T_source_base at stamp_ns, interpolated between the poses around it (extrapolated past the newest by up to
        `tolerance`); None when the poses do not reach it."""
        n = len(self._stamps)
        if n == 0 or stamp_ns < self._stamps[0] - self.tolerance_ns or stamp_ns > self._stamps[-1] + self.tolerance_ns:
            return None
        if n == 1:  # no motion to extrapolate along
            return self._poses[0].copy() if stamp_ns == self._stamps[0] else None
        k = bisect.bisect_left(self._stamps, stamp_ns)
        if k < n and self._stamps[k] == stamp_ns:
            return self._poses[k].copy()
        i = min(max(k, 1), n - 1)  # segment [i-1, i]: around the stamp, or the nearest end one
        t0, t1 = self._stamps[i - 1], self._stamps[i]
        A, B = self._poses[i - 1], self._poses[i]
        alpha = (stamp_ns - t0) / (t1 - t0)
        T = np.eye(4)
        T[:3, :3] = A[:3, :3] @ Rotation.from_rotvec(alpha * rotation_vector(A[:3, :3].T @ B[:3, :3])).as_matrix()
        T[:3, 3] = A[:3, 3] + alpha * (B[:3, 3] - A[:3, 3])
        return T
