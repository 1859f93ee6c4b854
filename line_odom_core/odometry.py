"""Python face of the odometry pipeline: numpy in, a FrameResult out, state kept across frames.

    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    result = odom.register_points(xyz, stamp)          # result.pose is T_world_sensor (4x4)

Every heavy call runs in C++ with the GIL released.
"""
from __future__ import annotations

import dataclasses
import math
import os
from typing import Any

import numpy as np

from line_odom_core import _core
from line_odom_core.config import Config, load_config


@dataclasses.dataclass
class FrameResult:
    """One registered frame.

    pose: T_world_sensor (4x4); delta: T_prev_curr (4x4), the motion since the previous frame;
    covariance: 6x6 of delta, order (x y z rx ry rz), perturbation on the left; twist: (vx vy vz wx wy wz),
    ``body_twist(delta, dt)``: the constant velocity in the sensor frame that moves it by delta over the stamp interval
    (zeros on the first frame);
    stats: see ``_core.pyi`` (solver, candidates, inliers, h_lines, v_lines, planes, ms, degenerate, ...)."""

    stamp: float
    pose: np.ndarray
    delta: np.ndarray
    covariance: np.ndarray
    twist: np.ndarray
    stats: dict[str, Any]

    @property
    def degenerate(self) -> bool:
        return bool(self.stats["degenerate"])


def log_se3(T: np.ndarray) -> np.ndarray:
    """xi = (rho, phi) with exp(xi) = T: the constant body twist that moves by T in unit time."""
    phi = _core.rotation_vector(np.ascontiguousarray(T[:3, :3], dtype=float))
    px, py, pz = (float(v) for v in phi)
    tx, ty, tz = (float(v) for v in T[:3, 3])
    theta2 = px * px + py * py + pz * pz
    if theta2 < 1e-12:
        coeff = 1.0 / 12.0
    else:
        half = 0.5 * math.sqrt(theta2)
        coeff = (1.0 - half * math.cos(half) / math.sin(half)) / theta2
    # rho = V^-1 t = t - phi x t / 2 + coeff phi x (phi x t), in scalars: a frame's twist costs microseconds, not the
    # tens a 3x3 matrix of numpy calls takes.
    wx, wy, wz = py * tz - pz * ty, pz * tx - px * tz, px * ty - py * tx
    vx, vy, vz = py * wz - pz * wy, pz * wx - px * wz, px * wy - py * wx
    return np.array([tx - 0.5 * wx + coeff * vx, ty - 0.5 * wy + coeff * vy, tz - 0.5 * wz + coeff * vz, px, py, pz])


def body_twist(motion: np.ndarray, seconds: float) -> np.ndarray:
    """The twist (vx vy vz wx wy wz) of a motion T_prev_curr over `seconds`, in the moving frame's axes (REP-105's
    twist in the child frame): log(motion) / seconds, so that T_prev exp(twist seconds) = T_curr exactly. The node
    publishes the same for the base."""
    return log_se3(motion) / seconds


def _stamp(stamp: Any) -> float:
    try:
        value = float(stamp)
    except (TypeError, ValueError):
        raise ValueError(f"stamp: expected a finite number of seconds, got {stamp!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"stamp: expected a finite number of seconds, got {stamp!r}")
    return value


def _float_array(name: str, value: Any, ndim: int, last: int | None, what: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "fiu" or arr.ndim != ndim or (last is not None and arr.shape[-1] != last):
        raise ValueError(f"{name}: expected {what}, got array of shape {arr.shape} and dtype {arr.dtype}")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float64)
    return arr if last == 3 and _core.reads_in_place(arr) else np.require(arr, requirements=["C", "A"])


def _pose(name: str, value: Any) -> np.ndarray:
    T = np.asarray(value, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: expected a finite 4x4 homogeneous transform, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0 or not np.allclose(
            T[3], [0, 0, 0, 1]):
        raise ValueError(f"{name}: expected a rigid transform (orthonormal rotation, last row 0 0 0 1)")
    return T


def _times(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf" or arr.shape != shape:
        raise ValueError(f"time: expected {what} of shape {shape} (seconds from the stamp), got shape {arr.shape} "
                         f"and dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    outside = ~(np.abs(arr) <= 10.0)
    if outside.any():
        raise ValueError(f"time: expected finite seconds within 10 s of the stamp (a sweep's times), got "
                         f"{int(outside.sum())} values outside, e.g. {arr[outside].flat[0]!r}")
    return arr


def _sweep_rate(value: Any, times: np.ndarray | None) -> np.ndarray | None:
    if value is None:
        return None
    if times is None:
        raise ValueError("sweep_rate: expected it with time (the rate turns each point by its time)")
    try:
        rate = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        rate = np.array([np.nan])
    if rate.shape != (3,) or not np.isfinite(rate).all() or np.linalg.norm(rate) >= 100.0:
        raise ValueError(f"sweep_rate: expected a finite angular velocity (3,) in rad/s (under 100), got {value!r}")
    return rate


def _ring(value: Any, count: int) -> np.ndarray | None:
    if value is None:
        return None
    ring = np.asarray(value)
    if ring.dtype.kind not in "iu" or ring.shape != (count,):
        raise ValueError(f"ring: expected an integer array of shape ({count},), got shape {ring.shape} and dtype "
                         f"{ring.dtype}")
    return np.ascontiguousarray(ring, dtype=np.int32)


def _guess(value: Any) -> np.ndarray | None:
    return None if value is None else _pose("guess", value)


def _rotation_guess(value: Any, guess: Any) -> np.ndarray | None:
    if value is None:
        return None
    if guess is not None:
        raise ValueError("rotation_guess: expected no guess beside it (guess replaces the whole prediction, "
                         "rotation_guess only its rotation); pass one of them")
    R = np.asarray(value, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"rotation_guess: expected a finite 3x3 rotation matrix R_prev_curr, got shape {R.shape}"
                         + ("" if R.shape != (3, 3) else " with non-finite values"))
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("rotation_guess: expected a rotation matrix R_prev_curr (orthonormal, determinant +1)")
    return np.ascontiguousarray(R)


class Odometry:
    """Frame-to-frame line-intersection odometry (paper §6.3) with a constant-velocity motion model.

    config: a Config (from load_config), a preset name or YAML path, or None for the kitti_hdl64 preset."""

    def __init__(self, config: Config | str | os.PathLike | None = None):
        if config is None:
            config = load_config("kitti_hdl64")
        elif isinstance(config, (str, os.PathLike)):
            config = load_config(config)
        elif not isinstance(config, Config):
            raise ValueError(f"config: expected a line_odom_core.Config, preset name or YAML path, got "
                             f"{type(config).__name__}")
        self.config = config
        self._engine = _core.Odometry(config.as_dict())
        self._last_stamp: float | None = None

    # ---- registration ----
    def register_points(self, xyz: np.ndarray, stamp: float, *, ring: np.ndarray | None = None,
                        guess: np.ndarray | None = None, rotation_guess: np.ndarray | None = None,
                        time: np.ndarray | None = None, sweep_rate: np.ndarray | None = None) -> FrameResult:
        """Unorganized points (N, 3) in metres (NaN/inf = dropped); `ring` (N,) integer beam index per point, or
        None to organize by elevation with the configured sensor model.

        time (register_points, register_organized): when each point was measured, in seconds from `stamp` (negative:
        before it), or None. With `sensor.deskew` (on in the LiDAR presets) the sweep is corrected for the sensor's
        motion during it at the predicted velocity, into the sensor frame at `stamp`; the previous scan is corrected
        again when it was corrected at a velocity that differs by more than `sensor.deskew_tolerance`, so that both
        scans of a registration are corrected alike (stats["deskewed"], stats["previous_deskewed_again"]), this one
        also by how much faster it moves than the previous sweep, the trend of the last `sensor.deskew_trend`
        registered velocities. Points before
        the stamp (a sweep stamped at its end) moved at this frame's motion: once registered, both scans are corrected
        again at the registered velocity and the frame registered again from the estimate, up to
        `sensor.deskew_iterations` times (stats["deskewed_again"]). sweep_rate (with time): the sensor's angular
        velocity during this sweep (3,) rad/s in its axes, a gyro's over the sweep's times: the correction turns at it
        (this scan's own, kept when the scan is corrected again) instead of at the predicted rotation.

        guess (every register_* method): the sensor's motion since the previous frame from another source (wheel
        odometry, an IMU), T_prev_curr (4x4) in the sensor frame, or None. It replaces the constant-velocity
        prediction: the registration starts from it, the motion prior is centred on it, and directions the scan
        does not observe are held at it (stats["prediction"] == "guess"). Ignored on the first frame.

        rotation_guess (every register_* method; not with guess): the sensor's rotation since the previous frame,
        R_prev_curr (3x3) in the sensor frame, e.g. integrated from a gyro (line_odom.imu_rotation). It replaces the
        rotation of the prediction; the translation stays the engine's own (constant velocity, or standing still
        before the first motion), turned with the rotation (stats["prediction"] ends in "+imu"). The registration
        starts from it, the motion prior is centred on it and held directions are held at it."""
        pts = _float_array("xyz", xyz, 2, 3, "an (N, 3) array of points")
        ring_arr = _ring(ring, pts.shape[0])
        times = _times(time, (pts.shape[0],), "one time per point")
        return self._wrap(self._engine.register_points(pts, _stamp(stamp), ring_arr, _guess(guess),
                                                       _rotation_guess(rotation_guess, guess), times,
                                                       _sweep_rate(sweep_rate, times)))

    def register_organized(self, xyz: np.ndarray, stamp: float, *, guess: np.ndarray | None = None,
                           rotation_guess: np.ndarray | None = None, time: np.ndarray | None = None,
                           sweep_rate: np.ndarray | None = None) -> FrameResult:
        """Organized points (H, W, 3): rows = rings or pixel rows; NaN/inf/zero points are holes; `time` (H, W)."""
        pts = _float_array("xyz", xyz, 3, 3, "an (H, W, 3) organized point array")
        times = _times(time, pts.shape[:2], "one time per point")
        return self._wrap(self._engine.register_organized(pts, _stamp(stamp), _guess(guess),
                                                          _rotation_guess(rotation_guess, guess), times,
                                                          _sweep_rate(sweep_rate, times)))

    def register_depth(self, depth: np.ndarray, K: np.ndarray, stamp: float, *,
                       guess: np.ndarray | None = None, rotation_guess: np.ndarray | None = None) -> FrameResult:
        """Depth image (H, W) in metres (0/NaN = no measurement) and pinhole intrinsics K (3, 3)."""
        d = _float_array("depth", depth, 2, None, "an (H, W) depth image in metres")
        K_arr = np.asarray(K, dtype=float)
        if K_arr.shape != (3, 3) or not np.all(np.isfinite(K_arr)) or K_arr[0, 0] <= 0 or K_arr[1, 1] <= 0:
            raise ValueError(f"K: expected finite 3x3 intrinsics with fx, fy > 0, got {K_arr.tolist()}")
        with np.errstate(over="ignore"):  # depths beyond float32 become inf: holes, like any out-of-range depth
            d32 = np.ascontiguousarray(d, dtype=np.float32)
        return self._wrap(self._engine.register_depth(d32, K_arr, _stamp(stamp), _guess(guess),
                                                      _rotation_guess(rotation_guess, guess)))

    def reset(self, pose: np.ndarray | None = None) -> None:
        """Forget the previous scan and the velocity; the next frame gets `pose` (default identity)."""
        T = np.eye(4) if pose is None else _pose("pose", pose)
        self._engine.reset(T)
        self._last_stamp = None

    # ---- helpers ----
    def downsampled_points(self, xyz: np.ndarray, *, ring: np.ndarray | None = None) -> np.ndarray:
        """The valid points the pipeline keeps from an unorganized cloud after organizing and downsampling (M, 3)
        (e.g. to feed another method exactly the same sparse scan)."""
        pts = _float_array("xyz", xyz, 2, 3, "an (N, 3) array of points")
        return self._engine.downsampled_points(pts, _ring(ring, pts.shape[0]))

    def sensor_fit(self, xyz: np.ndarray, *, ring: np.ndarray | None = None) -> dict:
        """How an unorganized cloud fits the configured sensor model (every row and column): the model (name, rows,
        elevations), how its rows were found, the valid points, those outside the model's beams, the rows holding
        points in >= 1 % of the columns and the rows from the first of those to the last, 1 + the largest ring value,
        the cloud's 0.5 / 99.5 % elevations (deg). line_odom.sensor_check reads it."""
        pts = _float_array("xyz", xyz, 2, 3, "an (N, 3) array of points")
        return self._engine.sensor_fit(pts, _ring(ring, pts.shape[0]))

    @property
    def pose(self) -> np.ndarray:
        return self._engine.pose()

    def last_lines(self) -> tuple[np.ndarray, np.ndarray]:
        """The H-lines and V-lines the last scan was registered with: segments (n, 2, 3), their two ends in that
        scan's sensor frame (deskewed, as registered)."""
        h, v = self._engine.last_lines()
        return np.asarray(h), np.asarray(v)

    def keep_points(self, keep: bool) -> None:
        """While on, each frame keeps the points it was registered with, for last_points() (off by default: a copy per
        frame only a view needs)."""
        self._engine.keep_points(bool(keep))

    def last_points(self) -> np.ndarray:
        """The points the last frame was registered with: after organizing, downsampling and deskewing, (n, 3) in its
        sensor frame; empty unless keep_points(True) was set before that frame."""
        return np.asarray(self._engine.last_points())

    @property
    def frames(self) -> int:
        return self._engine.frames()

    def _wrap(self, raw: Any) -> FrameResult:
        stamp = raw.stamp
        delta = raw.delta
        twist = np.zeros(6)
        if self._last_stamp is not None and stamp > self._last_stamp:
            dt = stamp - self._last_stamp
            twist = body_twist(delta, dt)
        self._last_stamp = stamp
        return FrameResult(stamp, raw.pose, delta, raw.covariance, twist, raw.stats)

