"""The ROS-free step from the engine's sensor poses to the base's odometry (REP-105), with covariances.

Pose: ``T_odom_base = T_init · T_base_sensor · T_s0_sk · inv(T_base_sensor)``, where ``T_s0_sk`` is the engine's sensor
pose relative to its first frame and ``T_init`` (parameter ``initial_pose``) is the base's pose in odom at the first
frame.

Twist (REP-105: in the child frame, base_frame): the constant body velocity that moves the base from the previous
frame's pose to this one's over the stamp interval, ``xi = log(T_prev^-1 · T_curr) / dt`` with the SE(3) logarithm,
(vx vy vz wx wy wz). Integrating it, ``T_prev · exp(xi dt)``, gives the published pose back exactly.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from line_odom import frames
from line_odom_core.odometry import body_twist

FIRST_POSE_VARIANCE = 1e-9  # the first pose is exact by definition; a floor keeps the covariance definite
UNKNOWN_TWIST_VARIANCE = 1e6  # first frame after a (re)start: no motion observed yet


@dataclasses.dataclass
class EngineFrame:
    """One converted frame, ready for the engine: which register_* call, its arguments before the stamp, its keywords
    (ring, per-point time, sweep rate: given only when known, so engines without them keep working)."""

    call: str  # "register_points", "register_organized" or "register_depth"
    args: tuple
    keywords: dict = dataclasses.field(default_factory=dict)

    def register(self, engine, stamp: float, guess: dict):
        """The engine's FrameResult; `guess`: the fusion's guess keywords (guess / rotation_guess)."""
        return getattr(engine, self.call)(*self.args, stamp, **self.keywords, **guess)

    def kept_points(self, engine, config) -> np.ndarray | None:
        """The points the engine registered this frame with, in the sensor frame: its own copy (deskewed) when it kept
        one (keep_points), else the kept points as line_odom.scan_view finds them."""
        from line_odom import scan_view

        kept = getattr(engine, "last_points", None)
        if kept is not None:
            points = np.asarray(kept())
            if len(points):
                return points
        if self.call == "register_points":
            return scan_view.kept_unorganized(engine, self.args[0], self.keywords.get("ring"))
        if self.call == "register_organized":
            return scan_view.kept_organized(self.args[0], config)
        return scan_view.kept_depth(*self.args, config)


@dataclasses.dataclass
class BaseState:
    """One frame's odometry of the base: pose in odom, its covariance (PoseWithCovariance convention, parent-frame
    axes), twist in the base frame and its covariance."""

    T_odom_base: np.ndarray
    pose_covariance: np.ndarray
    twist: np.ndarray
    twist_covariance: np.ndarray


class BaseTrajectory:
    """The base's trajectory from the engine's sensor poses; ``clear()`` starts it again at T_init."""

    def __init__(self, T_init: np.ndarray):
        self.T_init = T_init
        self.clear()

    def clear(self) -> None:
        self.last_stamp_ns: int | None = None
        self._engine_origin_inv: np.ndarray | None = None
        self._T_prev: np.ndarray | None = None
        self._cov_left = np.eye(6) * FIRST_POSE_VARIANCE

    def step(self, stamp_ns: int, pose: np.ndarray, delta: np.ndarray, cov_delta: np.ndarray,
             T_base_sensor: np.ndarray, T_sensor_base: np.ndarray) -> BaseState:
        """pose: the engine's T_world_sensor; delta: T_prev_curr of the sensor; cov_delta: delta's 6x6 covariance
        (left perturbation)."""
        X, X_inv = T_base_sensor, T_sensor_base
        first = self._engine_origin_inv is None
        if first:
            self._engine_origin_inv = frames.inverse(pose)
        T = self.T_init @ X @ (self._engine_origin_inv @ pose) @ X_inv
        if first:
            twist = np.zeros(6)
            twist_cov = np.eye(6) * UNKNOWN_TWIST_VARIANCE
        else:
            D = X @ delta @ X_inv  # base motion prev -> curr
            cov_d = frames.conjugate_covariance(cov_delta, X)  # left perturbation in the previous base frame
            self._cov_left = frames.symmetrize(self._cov_left + frames.conjugate_covariance(cov_d, self._T_prev))
            dt = (stamp_ns - self.last_stamp_ns) * 1e-9  # integer nanoseconds: exact for epoch stamps
            twist = body_twist(D, dt)
            J = frames.left_jacobian_inverse(twist * dt)  # perturbation of log(D) from the left perturbation of D
            twist_cov = frames.symmetrize(J @ cov_d @ J.T) / (dt * dt)
        pose_cov = frames.left_to_ros_pose_covariance(self._cov_left, T)
        self._T_prev = T
        self.last_stamp_ns = stamp_ns
        return BaseState(T, pose_cov, twist, twist_cov)
