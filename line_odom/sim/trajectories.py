"""Smooth sensor trajectories with ground truth poses ``T_world_sensor`` (4x4, ``x_world = T @ x_sensor``).

``frame`` says which sensor frame the poses are for: ``"body"`` (x forward, y left, z up: LiDAR) or ``"optical"``
(z forward, x right, y down: camera). ``T_BODY_OPTICAL`` maps one to the other: ``T_optical = T_body @ T_BODY_OPTICAL``.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom.sim.scene import Scene

# x_body = T_BODY_OPTICAL @ x_optical: optical z = body x, optical x = -body y, optical y = -body z.
T_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0],
                           [-1.0, 0.0, 0.0, 0.0],
                           [0.0, -1.0, 0.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]])


def rpy_matrix(roll, pitch, yaw) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), vectorised over equal-shaped inputs -> (..., 3, 3)."""
    roll, pitch, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    R = np.empty(roll.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = -sp, cp * sr, cp * cr
    return R


def _poses(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, p, 1.0
    return T


def _check_frames(frames, rate_hz) -> tuple[int, float]:
    if int(frames) != frames or frames < 1:
        raise ValueError(f"frames must be a positive integer, got {frames!r}")
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
    return int(frames), float(rate_hz)


@dataclasses.dataclass
class Trajectory:
    """Ground truth: ``stamps`` (N,) seconds and ``poses`` (N, 4, 4) T_world_sensor for ``frame``."""

    stamps: np.ndarray
    poses: np.ndarray
    frame: str = "body"

    def __len__(self) -> int:
        return len(self.stamps)

    def __getitem__(self, i):
        return self.stamps[i], self.poses[i]

    def __iter__(self):
        return iter(zip(self.stamps, self.poses))

    @property
    def positions(self) -> np.ndarray:
        return self.poses[:, :3, 3]

    @property
    def length_m(self) -> float:
        """Path length: the sum of frame-to-frame translations."""
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum()) if len(self) > 1 else 0.0

    def in_frame(self, frame: str) -> "Trajectory":
        """The same motion expressed for the other sensor frame convention ("body" or "optical")."""
        if frame not in ("body", "optical"):
            raise ValueError(f"frame must be 'body' or 'optical', got {frame!r}")
        if frame == self.frame:
            return self
        X = T_BODY_OPTICAL if frame == "optical" else np.linalg.inv(T_BODY_OPTICAL)
        return Trajectory(self.stamps.copy(), self.poses @ X, frame)

    def pose_at(self, t: float) -> np.ndarray:
        """Pose at time ``t``: interpolated between samples (slerp + linear), extrapolated at constant velocity
        beyond the first/last sample."""
        if len(self) == 1:
            return self.poses[0].copy()
        i = int(np.clip(np.searchsorted(self.stamps, t) - 1, 0, len(self) - 2))
        T0, T1 = self.poses[i], self.poses[i + 1]
        f = (float(t) - self.stamps[i]) / (self.stamps[i + 1] - self.stamps[i])
        out = np.eye(4)
        rotvec = Rotation.from_matrix(T0[:3, :3].T @ T1[:3, :3]).as_rotvec()
        out[:3, :3] = T0[:3, :3] @ Rotation.from_rotvec(f * rotvec).as_matrix()
        out[:3, 3] = (1 - f) * T0[:3, 3] + f * T1[:3, 3]
        return out

    def relative(self) -> np.ndarray:
        """Frame-to-frame motions T_(k-1)k, (N-1, 4, 4)."""
        return np.linalg.inv(self.poses[:-1]) @ self.poses[1:]


def street_drive(scene: Scene, frames: int | None = None, rate_hz: float = 10.0, speed: float = 10.0,
                 seed: int = 0, *, height: float = 1.73, lane_offset: float = -1.75, start_s: float = 0.0,
                 speed_variation: float = 0.1, speed_period: float | None = None) -> Trajectory:
    """A car driving along a :func:`street_scene` centreline in the right lane at about ``speed`` m/s (a speed
    varying sinusoidally by +-``speed_variation`` of it over ``speed_period`` s, by default +-10 % over 15-40 s;
    a lane offset that drifts +-0.3 m, pitch and roll of a few tenths of a degree, 1 cm
    of bounce, all fading out below 5 m/s), LiDAR ``height`` metres above the ground, poses for the LiDAR ("body" frame) at ``rate_hz``.
    ``frames=None`` drives the whole street. The speed is the real speed of the sensor along its path, so
    ``frames`` frames cover ``(frames - 1) / rate_hz * speed`` metres on average."""
    line = scene.meta.get("centerline")
    if line is None:
        raise ValueError(f"street_drive needs a street scene (with a centreline), got scene {scene.name!r}")
    if not speed >= 0:
        raise ValueError(f"speed must be >= 0, got {speed}")
    length = float(scene.meta.get("length_m", line.s1))
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
    if not 0.0 <= speed_variation < 1.0:
        raise ValueError(f"speed_variation must be in [0, 1), got {speed_variation!r}")
    if speed_period is not None and not speed_period > 0:
        raise ValueError(f"speed_period must be positive (s), got {speed_period!r}")
    rng = np.random.default_rng(seed)
    # Distance travelled: integral of speed * (1 + a sin(w t + phi)).
    w_v, phi_v = 2 * np.pi / rng.uniform(15, 40), rng.uniform(0, 2 * np.pi)
    if speed_period is not None:
        w_v = 2 * np.pi / speed_period

    def travelled(t):
        return speed * (t - speed_variation / w_v * (np.cos(w_v * t + phi_v) - np.cos(phi_v)))

    if frames is None:      # the first frame count whose drive covers the street from start_s
        goal = max(length - start_s, 0.0) + 0.5 if length > start_s else 0.0
        frames = 1
        if speed > 0 and goal > 0:
            n = int(np.ceil(goal / (0.85 * max(1.0 - speed_variation, 0.05) * speed) * rate_hz)) + 2
            frames = int(np.argmax(travelled(np.arange(n) / rate_hz) >= goal)) + 1
    frames, rate_hz = _check_frames(frames, rate_hz)
    t = np.arange(frames) / rate_hz
    dist = travelled(t)
    # Lateral offset as a function of arc length along the centreline, and the arc length of the offset path.
    w_o, phi_o = 2 * np.pi / rng.uniform(60, 200), rng.uniform(0, 2 * np.pi)
    s_grid = np.arange(start_s, line.s1, 0.05)
    off = lane_offset + 0.3 * np.sin(w_o * s_grid + phi_o)
    doff = 0.3 * w_o * np.cos(w_o * s_grid + phi_o)
    speed_ratio = np.hypot(1.0 - off * line.curvature(s_grid), doff)        # |d p / d s| of the offset path
    sigma = np.concatenate([[0.0], np.cumsum((speed_ratio[1:] + speed_ratio[:-1]) / 2 * np.diff(s_grid))])
    if dist[-1] > sigma[-1] - 100.0:
        need = dist[-1] + start_s + 100.0 - (line.s1 - length)
        raise ValueError(f"frames={frames}: a drive of {dist[-1]:.0f} m does not fit this street of {length:.0f} m "
                         f"(build street_scene(length_m>={need:.0f}))")
    s = np.interp(dist, sigma, s_grid)
    o = lane_offset + 0.3 * np.sin(w_o * s + phi_o)
    do = 0.3 * w_o * np.cos(w_o * s + phi_o)
    p, psi = line.frame(s, o)
    # Heading of the offset path: tangent * (1 - o kappa) + normal * o'.
    yaw = psi + np.arctan2(do, 1.0 - o * line.curvature(s))
    a = rng.uniform(0, 2 * np.pi, 4)
    body = min(1.0, speed / 5.0)            # body motion fades out as the car slows down: a parked car is still
    pitch = body * (np.radians(0.3) * np.sin(2 * np.pi * 0.23 * t + a[0]) + np.radians(0.15) * np.sin(2 * np.pi * 0.61 * t + a[1]))
    roll = body * np.radians(0.3) * np.sin(2 * np.pi * 0.17 * t + a[2])
    z = height + body * 0.01 * np.sin(2 * np.pi * 0.9 * t + a[3])
    pos = np.column_stack([p, z])
    return Trajectory(t, _poses(rpy_matrix(roll, pitch, yaw), pos), "body")


def straight_drive(frames: int, rate_hz: float = 10.0, speed: float = 10.0, *, height: float = 1.73,
                   start=(0.0, 0.0), heading: float = 0.0) -> Trajectory:
    """Constant-velocity straight motion along ``heading`` (0 = world +x) at ``height``: the motion for the
    degenerate scenes. ``speed=0`` keeps the sensor still (identical noise-free frames)."""
    frames, rate_hz = _check_frames(frames, rate_hz)
    t = np.arange(frames) / rate_hz
    d = speed * t
    pos = np.column_stack([start[0] + d * np.cos(heading), start[1] + d * np.sin(heading), np.full_like(t, height)])
    return Trajectory(t, _poses(rpy_matrix(0 * t, 0 * t, np.full_like(t, heading)), pos), "body")


def look_at(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation(s) of an optical frame (z forward, x right, y down) at ``position`` looking at ``target``."""
    z = np.asarray(target, dtype=float) - np.asarray(position, dtype=float)
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, np.broadcast_to(np.asarray(up, dtype=float), z.shape))
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def handheld_path(scene: Scene, frames: int = 300, rate_hz: float = 30.0, seed: int = 0, *,
                  amplitude: float = 0.15, angle_deg: float = 4.0) -> Trajectory:
    """A handheld camera in a :func:`room_scene` swaying around ``meta['viewpoint']`` (sums of sinusoids of
    0.1-0.6 Hz, ``amplitude`` metres per axis, like TUM fr1/xyz: a few millimetres per frame at 30 Hz) while
    looking at ``meta['target']`` with ``angle_deg`` of extra yaw/pitch/roll wobble. Poses of the optical frame."""
    frames, rate_hz = _check_frames(frames, rate_hz)
    view, target = scene.meta.get("viewpoint"), scene.meta.get("target")
    if view is None or target is None:
        raise ValueError(f"handheld_path needs a scene with meta 'viewpoint' and 'target' (room_scene), got {scene.name!r}")
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / rate_hz

    def sway(scale, n=2):
        f = rng.uniform(0.1, 0.6, (n, 1))
        ph = rng.uniform(0, 2 * np.pi, (n, 1))
        amp = scale * rng.uniform(0.4, 1.0, (n, 1)) / n
        return np.sum(amp * (np.sin(2 * np.pi * f * t + ph) - np.sin(ph)), axis=0)

    pos = np.asarray(view, dtype=float) + np.column_stack([sway(amplitude) for _ in range(3)])
    R = look_at(pos, target)
    wobble = rpy_matrix(*(np.radians(angle_deg) * sway(1.0) for _ in range(3)))
    return Trajectory(t, _poses(R @ wobble, pos), "optical")
