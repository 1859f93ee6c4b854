"""The node's processing core without rclpy: sensor messages in, Odometry / Path / TFMessage / DiagnosticArray
out. The rclpy node (line_odom.node) wires it to topics; replay drives it in-process, frame by frame.

Frames (REP-105): the published pose is the base's, ``T_odom_base = T_init · T_base_sensor · T_s0_sk ·
inv(T_base_sensor)``, where ``T_s0_sk`` is the engine's sensor pose relative to its first frame and ``T_init``
(parameter ``initial_pose``) defines the odom frame by the base's pose at the first frame.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
import math
import threading
import time
from typing import Any, Callable, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom import convert, frames, sensor_check
from line_odom.imu_rotation import GyroRotation, in_sensor_frame
from line_odom.motion_guess import MotionGuess
from line_odom.static_tf import StaticTransforms, TransformError
from line_odom_core.config import Config, config_schema, load_config

INPUTS = ("pointcloud", "depth")
FIRST_POSE_VARIANCE = 1e-9  # the first pose is exact by definition; a floor keeps the covariance definite
UNKNOWN_TWIST_VARIANCE = 1e6  # first frame after a (re)start: no motion observed yet
LOG_REPEAT_S = 5.0
SENSOR_LOG_REPEAT_S = 30.0


@dataclasses.dataclass(frozen=True)
class NodeParameter:
    """One node (non-engine) parameter: dotted name, type, default, description, inclusive range or choices."""

    name: str
    type: type  # bool, int, float, str or list (of float)
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] | None = None
    vector: bool = False  # a list of 3 numbers (x y z), not a pose


NODE_PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("input", str, "pointcloud", "input kind: pointcloud (topic 'points', sensor_msgs/PointCloud2) or "
                  "depth (topics 'depth/image' + 'depth/camera_info')", choices=INPUTS),
    NodeParameter("odom_frame", str, "odom", "frame of the published pose (Odometry header.frame_id, TF parent)"),
    NodeParameter("base_frame", str, "base_link", "robot base frame (Odometry child_frame_id, TF child)"),
    NodeParameter("publish_tf", bool, True, "broadcast odom_frame -> base_frame on /tf"),
    NodeParameter("base_to_sensor", list, [0.0] * 6, "pose of the sensor in the base frame, T_base_sensor: "
                  "[x, y, z, roll, pitch, yaw] (m, rad) or [x, y, z, qx, qy, qz, qw]"),
    NodeParameter("base_to_sensor_from_tf", bool, False, "take T_base_sensor from /tf_static instead of base_to_sensor: "
                  "the transform base_frame -> the input's header.frame_id (robot_state_publisher, "
                  "static_transform_publisher), looked up at the first frame that has it; frames before it are "
                  "dropped and counted (frames_no_extrinsic)"),
    NodeParameter("initial_pose", list, [0.0] * 6, "pose of the base in the odom frame at the first frame and after "
                  "a reset: [x, y, z, roll, pitch, yaw] (m, rad) or [x, y, z, qx, qy, qz, qw]"),
    NodeParameter("path.max_poses", int, 1000, "poses kept in the published nav_msgs/Path (oldest dropped)", 1,
                  1_000_000),
    NodeParameter("path.period", float, 0.0, "seconds (of frame stamps) between published paths, 0 = every frame; "
                  "a path is sent only while something subscribes to it", 0.0, 3600.0),
    NodeParameter("qos.reliable", bool, False, "subscribe to the input with reliable QoS instead of SensorDataQoS "
                  "(best effort; REP-2003)"),
    NodeParameter("qos.depth", int, 5, "input subscription queue depth", 1, 1000),
    NodeParameter("max_points", int, 2_000_000, "reject clouds with more points than this (0 = no limit)", 0,
                  1_000_000_000),
    NodeParameter("diagnostics.period", float, 1.0, "seconds between /diagnostics messages", 0.05, 3600.0),
    NodeParameter("guess.enabled", bool, False, "register each scan from the base's motion reported by another "
                  "odometry source on topic 'guess_odom' (nav_msgs/Odometry, child_frame_id = base_frame: wheel "
                  "odometry, an IMU filter) instead of the constant-velocity prediction"),
    NodeParameter("guess.tolerance", float, 0.1, "seconds a scan's stamp may lie past the newest guess_odom pose "
                  "(extrapolated); a scan outside the poses is registered with the constant-velocity prediction "
                  "and counted (frames_unguessed)", 0.0, 10.0),
    NodeParameter("guess.window", float, 5.0, "seconds of guess_odom poses kept", 0.1, 86400.0),
    NodeParameter("imu.enabled", bool, False, "turn each scan's prediction by the rotation integrated from the gyro "
                  "on topic 'imu' (sensor_msgs/Imu angular_velocity) between the previous and this scan's stamp; the "
                  "translation stays the constant-velocity prediction's"),
    NodeParameter("imu.base_to_imu", list, [0.0] * 6, "pose of the IMU in the base frame, T_base_imu: "
                  "[x, y, z, roll, pitch, yaw] (m, rad) or [x, y, z, qx, qy, qz, qw]; with base_to_sensor_from_tf "
                  "it comes from /tf_static instead (base_frame -> the Imu messages' header.frame_id)"),
    NodeParameter("imu.gyro_bias", list, [0.0] * 3, "gyro bias (rad/s, IMU axes) subtracted from every "
                  "angular_velocity", vector=True),
    NodeParameter("imu.bias_gain", float, 0.05, "share of each scan interval's difference between the gyro's and the "
                  "registered rotation taken into the gyro bias (a frame registered in full, within 0.5 deg); 0 = the "
                  "bias stays imu.gyro_bias", 0.0, 1.0),
    NodeParameter("imu.wait", float, 0.03, "seconds a scan waits for the gyro samples that reach past its sweep (a scan "
                  "that arrives with its samples, or before them) before it is registered without them", 0.0, 1.0),
    NodeParameter("imu.max_gap", float, 0.05, "seconds without a gyro sample a scan interval may contain (also "
                  "between a scan's stamp and the nearest sample past it); a longer gap: the scan uses the "
                  "plain prediction and counts in frames_without_imu", 0.001, 10.0),
    NodeParameter("imu.window", float, 5.0, "seconds of gyro samples kept", 0.1, 86400.0),
)
NODE_PARAMETER_NAMES = {p.name for p in NODE_PARAMETERS}
IGNORED_KEYS = {"use_sim_time", "preset"}


def validate_node_value(name: str, value: Any) -> Any:
    """The value converted to the node parameter's type; ValueError naming the parameter and what it expects."""
    spec = next((p for p in NODE_PARAMETERS if p.name == name), None)
    if spec is None:
        raise ValueError(f"unknown node parameter {name!r}; known: {', '.join(sorted(NODE_PARAMETER_NAMES))}")
    if spec.type is list:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise ValueError(f"{name}: expected a list of numbers, got {value!r}")
        values = list(value)
        if spec.vector:
            try:
                vector = [float(v) for v in values]
            except (TypeError, ValueError):
                vector = []
            if len(vector) != 3 or not all(math.isfinite(v) for v in vector):
                raise ValueError(f"{name}: expected 3 finite numbers [x, y, z], got {values!r}")
            return vector
        frames.pose_from_params(values, name)  # validates length and values
        return [float(v) for v in values]
    bad = f"{name}: expected {spec.type.__name__}"
    if spec.choices:
        bad += " (one of " + ", ".join(spec.choices) + ")"
    elif spec.min is not None:
        bad += f" in [{spec.min}, {spec.max}]"
    bad += f", got {value!r}"
    if spec.type is bool:
        if not isinstance(value, bool):
            raise ValueError(bad)
        return value
    if spec.type is str:
        if not isinstance(value, str) or (spec.choices and value not in spec.choices) or (
                not spec.choices and not value):
            raise ValueError(bad)
        return value
    if isinstance(value, (bool, str, bytes)):
        raise ValueError(bad)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(bad) from None
    if not math.isfinite(number) or (spec.type is int and number != int(number)):
        raise ValueError(bad)
    number = int(number) if spec.type is int else number
    if (spec.min is not None and number < spec.min) or (spec.max is not None and number > spec.max):
        raise ValueError(bad)
    return number


@dataclasses.dataclass
class NodeSettings:
    """The node's own settings (the engine's are in line_odom_core.Config)."""

    input: str = "pointcloud"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    publish_tf: bool = True
    base_to_sensor: list = dataclasses.field(default_factory=lambda: [0.0] * 6)
    base_to_sensor_from_tf: bool = False
    initial_pose: list = dataclasses.field(default_factory=lambda: [0.0] * 6)
    path_max_poses: int = 1000
    path_period: float = 0.0
    qos_reliable: bool = False
    qos_depth: int = 5
    max_points: int = 2_000_000
    diagnostics_period: float = 1.0
    guess_enabled: bool = False
    guess_tolerance: float = 0.1
    guess_window: float = 5.0
    imu_enabled: bool = False
    imu_base_to_imu: list = dataclasses.field(default_factory=lambda: [0.0] * 6)
    imu_gyro_bias: list = dataclasses.field(default_factory=lambda: [0.0] * 3)
    imu_bias_gain: float = 0.05
    imu_wait: float = 0.03
    imu_max_gap: float = 0.05
    imu_window: float = 5.0

    @staticmethod
    def attribute(name: str) -> str:
        return name.replace(".", "_")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, strict: bool = True) -> "NodeSettings":
        """Settings from dotted parameter names (e.g. a Config's ``extra``). Unknown names raise ValueError when
        ``strict`` (engine names and use_sim_time/preset are not looked at)."""
        settings = cls()
        for name, value in values.items():
            if name in IGNORED_KEYS:
                continue
            if name not in NODE_PARAMETER_NAMES:
                if strict:
                    raise ValueError(f"unknown parameter {name!r}: neither an engine setting nor a node parameter "
                                     f"({', '.join(sorted(NODE_PARAMETER_NAMES))})")
                continue
            setattr(settings, cls.attribute(name), validate_node_value(name, value))
        # parse once so a bad pose fails here, not on the first frame
        frames.pose_from_params(settings.base_to_sensor, "base_to_sensor")
        frames.pose_from_params(settings.initial_pose, "initial_pose")
        frames.pose_from_params(settings.imu_base_to_imu, "imu.base_to_imu")
        return settings

    def as_dict(self) -> dict[str, Any]:
        return {p.name: getattr(self, self.attribute(p.name)) for p in NODE_PARAMETERS}


def settings_from_parameters(preset_or_path: str = "kitti_hdl64",
                             overrides: Mapping[str, Any] | None = None) -> tuple[Config, NodeSettings]:
    """The engine's and the node's settings from a preset name or ROS parameter YAML, with dotted overrides (engine
    or node names)."""
    overrides = dict(overrides or {})
    node_over = {k: v for k, v in overrides.items() if k in NODE_PARAMETER_NAMES or k in IGNORED_KEYS}
    engine_over = {k: v for k, v in overrides.items() if k not in node_over}
    config = load_config(preset_or_path, engine_over)
    return config, NodeSettings.from_mapping({**config.extra, **node_over})


@dataclasses.dataclass
class FrameOutput:
    """What one processed frame publishes, as messages and as numpy (for replay and tests)."""

    stamp: float
    T_odom_base: np.ndarray
    pose_covariance: np.ndarray  # 6x6, PoseWithCovariance convention (parent-frame axes)
    twist: np.ndarray  # (vx vy vz wx wy wz) in base_frame
    twist_covariance: np.ndarray
    stats: dict
    latency_ms: float
    odometry: Any
    path: Any
    tf: Any | None
    reset_reason: str | None = None


def _logger_call(logger, level: str) -> Callable[[str], None]:
    if logger is None:
        logger = logging.getLogger("line_odom")
    fn = getattr(logger, level, None) or getattr(logger, "warn", None) or print
    return fn


class OdometryProcessor:
    """Frame-by-frame odometry over sensor messages; thread-safe (one frame at a time; counters and reset may be
    called from other threads).

    config: engine settings (line_odom_core.Config); settings: NodeSettings (default: from ``config.extra``);
    engine: an object with register_points/register_organized/register_depth/reset (default:
    ``line_odom_core.Odometry(config)``); logger: anything with ``info``/``warning``/``error`` (rclpy or logging)."""

    def __init__(self, config: Config | None = None, settings: NodeSettings | None = None, *, engine=None,
                 logger=None):
        self.config = config if config is not None else load_config("kitti_hdl64")
        self.settings = settings if settings is not None else NodeSettings.from_mapping(self.config.extra)
        if self.settings.input not in INPUTS:
            raise ValueError(f"input: expected one of {INPUTS}, got {self.settings.input!r}")
        if engine is None:
            from line_odom_core import Odometry

            engine = Odometry(self.config)
        self.engine = engine
        self._info = _logger_call(logger, "info")
        self._warn = _logger_call(logger, "warning")
        self.T_base_sensor = frames.pose_from_params(self.settings.base_to_sensor, "base_to_sensor")
        self.T_sensor_base = frames.inverse(self.T_base_sensor)
        self.T_init = frames.pose_from_params(self.settings.initial_pose, "initial_pose")
        self._frame_lock = threading.RLock()
        self._count_lock = threading.Lock()
        self._guess_lock = threading.Lock()
        self._camera_info = None  # the last valid CameraInfo (its K checked; its size against each depth image)
        self.counters = collections.Counter(
            frames_received=0, frames_processed=0, frames_dropped=0, frames_malformed=0, frames_failed=0,
            frames_duplicate=0, resets=0, frames_deskewed=0, frames_deskewed_again=0, point_times_ignored=0,
            clouds_not_fitting_sensor=0)
        self.guess = (MotionGuess(self.settings.base_frame, tolerance=self.settings.guess_tolerance,
                                  window=self.settings.guess_window) if self.settings.guess_enabled else None)
        if self.guess is not None:
            self.counters.update(frames_guessed=0, frames_unguessed=0, guess_rejected=0)
        self._imu_lock = threading.Lock()
        self._imu_arrived = threading.Condition(self._imu_lock)  # notified by add_imu
        self.gyro = (GyroRotation(max_gap=self.settings.imu_max_gap, window=self.settings.imu_window,
                                  bias=self.settings.imu_gyro_bias) if self.settings.imu_enabled else None)
        # T_base_imu: the parameter's, or with base_to_sensor_from_tf looked up on /tf_static (None until then)
        self.T_base_imu: np.ndarray | None = (
            None if self.settings.base_to_sensor_from_tf
            else frames.pose_from_params(self.settings.imu_base_to_imu, "imu.base_to_imu"))
        if self.gyro is not None:
            self.counters.update(frames_imu=0, frames_without_imu=0, imu_rejected=0, sweeps_without_gyro=0)
        self.static_tf = StaticTransforms() if self.settings.base_to_sensor_from_tf else None
        self._tf_lock = threading.Lock()
        self.mounted_frame: str | None = None  # the sensor frame whose /tf_static mounting is T_base_sensor
        if self.static_tf is not None:
            self.counters.update(frames_no_extrinsic=0, tf_rejected=0)
        self.last_error: str | None = None
        # the sensor model checked against the clouds until one fits (sensor_check); the reason one did not
        self.sensor_fit = "not checked yet"
        self._sensor_checked = False
        self._sensor_advice: str | None = None
        self._sensor_logged = -math.inf  # time.monotonic() of the last sensor_fit warning
        self._last_logged: tuple[str, float] = ("", 0.0)
        self._suppressed = 0
        self._receive_times: collections.deque = collections.deque(maxlen=50)
        self._latencies: collections.deque = collections.deque(maxlen=200)
        self._last_stats: dict = {}
        self._window_start = dict(self.counters)
        self.sensor_frame = ""
        self.diagnostic_name = "line_odom: odometry"  # the node sets "<fully qualified node name>: odometry"
        self._clear_state()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_parameters(cls, preset_or_path: str = "kitti_hdl64", overrides: Mapping[str, Any] | None = None,
                        **kwargs) -> "OdometryProcessor":
        """From a preset name or ROS parameter YAML, with dotted overrides (engine or node names)."""
        return cls(*settings_from_parameters(preset_or_path, overrides), **kwargs)

    # ------------------------------------------------------------------ state
    def _clear_state(self) -> None:
        self._last_stamp_ns: int | None = None
        self._engine_origin_inv: np.ndarray | None = None
        self._T_prev: np.ndarray | None = None
        self._cov_left = np.eye(6) * FIRST_POSE_VARIANCE
        self._path_poses: collections.deque = collections.deque(maxlen=self.settings.path_max_poses)
        self._guess_prev: np.ndarray | None = None  # the guess source's T_source_base at the previous frame

    def reset(self, reason: str = "reset requested") -> None:
        """Forget the trajectory: the next frame is at ``initial_pose`` again."""
        with self._frame_lock:
            self.engine.reset()
            self._clear_state()
        with self._count_lock:
            self.counters["resets"] += 1
        self._info(f"odometry reset ({reason}); the next frame starts at initial_pose")

    # ------------------------------------------------------------------ counters
    def note_received(self, now: float | None = None) -> None:
        with self._count_lock:
            self.counters["frames_received"] += 1
            self._receive_times.append(time.monotonic() if now is None else now)

    def note_dropped(self, n: int = 1) -> None:
        with self._count_lock:
            self.counters["frames_dropped"] += n

    def _reject(self, kind: str, reason: str, what: str = "dropped frame") -> None:
        now = time.monotonic()
        with self._count_lock:
            self.counters[kind] += 1
            self.last_error = reason
            # the same reason again within LOG_REPEAT_S is counted, not logged again (no log flood at sensor rate)
            repeat = reason == self._last_logged[0] and now - self._last_logged[1] < LOG_REPEAT_S
            if not repeat:
                suppressed, self._suppressed = self._suppressed, 0
                self._last_logged = (reason, now)
            else:
                self._suppressed += 1
        if not repeat:
            more = f" (and {suppressed} more rejected frames since the last message)" if suppressed else ""
            self._warn(f"{what}: {reason}{more}")

    def note_failure(self, reason: str) -> None:
        """A frame that failed for a reason outside the processor (counted as failed)."""
        self._reject("frames_failed", reason)

    # ------------------------------------------------------------------ inputs
    def add_guess(self, msg) -> bool:
        """One nav_msgs/Odometry of the guess source (guess.enabled); an unusable one is logged and counted
        (guess_rejected)."""
        if self.guess is None:
            return False
        try:
            with self._guess_lock:  # (not the frame lock: the executor must not wait for a registration)
                if not self.guess.add(msg):
                    self._info("guess_odom stamp went backwards: its earlier poses are forgotten")
        except convert.ConversionError as err:
            self._reject("guess_rejected", str(err), "rejected guess_odom message")
            return False
        return True

    def add_imu(self, msg) -> bool:
        """One sensor_msgs/Imu (imu.enabled): its angular velocity is kept; an unusable message (no or non-finite
        rate, another frame_id, a stamp out of order) is logged and counted (imu_rejected)."""
        if self.gyro is None:
            return False
        try:
            with self._imu_lock:  # (not the frame lock: the executor must not wait for a registration)
                self._imu_arrived.notify_all()
                if not self.gyro.add(msg):
                    self._info("imu stamp went back by more than imu.window: its earlier samples are forgotten")
        except convert.ConversionError as err:
            self._reject("imu_rejected", str(err), "rejected imu message")
            return False
        return True

    def add_static_tf(self, msg) -> bool:
        """One tf2_msgs/TFMessage from /tf_static (base_to_sensor_from_tf); an unusable transform is logged and
        counted (tf_rejected), the message's others are kept."""
        if self.static_tf is None:
            return False
        try:
            with self._tf_lock:
                self.static_tf.add(msg)
        except TransformError as err:
            self._reject("tf_rejected", str(err), "rejected /tf_static transform")
            return False
        return True

    def _mount(self, frame_id: str) -> bool:
        """base_to_sensor_from_tf: T_base_sensor from /tf_static, looked up at the first frame that has it and kept
        (a static mounting); False, with the frame logged and counted, while it is unknown or for another sensor."""
        frame_id = frame_id.lstrip("/")
        if self.mounted_frame is not None:
            if frame_id == self.mounted_frame:
                return True
            self._reject("frames_malformed", f"header.frame_id {frame_id!r} is not the sensor frame "
                                             f"{self.mounted_frame!r} whose /tf_static mounting is in use")
            return False
        if not frame_id:
            self._reject("frames_malformed", "header.frame_id is empty: base_to_sensor_from_tf looks the sensor's "
                                             "mounting up on /tf_static by it")
            return False
        base = self.settings.base_frame
        with self._tf_lock:
            T = self.static_tf.lookup(base, frame_id)
            known = len(self.static_tf)
        if T is None:
            self._reject("frames_no_extrinsic", f"no transform {base} -> {frame_id} on /tf_static yet "
                                                f"(base_to_sensor_from_tf; {known} static transform(s) received)")
            return False
        self.T_base_sensor, self.T_sensor_base = T, frames.inverse(T)
        self.mounted_frame = frame_id
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
        self._info(f"base_to_sensor from /tf_static: {base} -> {frame_id} = "
                   f"{[round(float(v), 6) for v in (*T[:3, 3], *rpy)]} [x, y, z, roll, pitch, yaw]")
        return True

    def _guess_delta(self, stamp_ns: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(the sensor's motion since the previous frame by the guess source (T_prev_curr) or None, the source's
        T_source_base at this frame or None)."""
        if self.guess is None:
            return None, None
        with self._guess_lock:
            T = self.guess.pose_at(stamp_ns)
        if T is None or self._guess_prev is None:  # (None on the first frame after a start or reset)
            return None, T
        delta = self.T_sensor_base @ (frames.inverse(self._guess_prev) @ T) @ self.T_base_sensor
        # A jump the registration could not follow (a source reset to its origin, a glitch) is no guess: held, it
        # would move the pose by it.
        moved = float(np.linalg.norm(delta[:3, 3]))
        turned = math.degrees(float(np.linalg.norm(frames.rotation_vector(delta[:3, :3]))))
        max_t, max_r = self.config["registration.max_translation"], self.config["registration.max_rotation_deg"]
        if moved > max_t or turned > max_r:
            self._reject("guess_rejected", f"guess_odom moved the sensor {moved:.2f} m and {turned:.1f} deg between "
                                           f"two scans, beyond registration.max_translation {max_t:g} m / "
                                           f"registration.max_rotation_deg {max_r:g} deg", "ignored motion guess")
            return None, T
        return delta, T

    def _imu_rotation(self, stamp_ns: int) -> np.ndarray | None:
        """The sensor's rotation since the previous frame by the gyro (R_prev_curr), or None (first frame, the
        samples do not cover the interval, or the IMU's mounting is not known yet: counted in frames_without_imu)."""
        last = self._last_stamp_ns
        if self.gyro is None or last is None:
            return None
        with self._imu_lock:
            R_imu, why = self.gyro.rotation(last, stamp_ns)
            imu_frame = self.gyro.frame_id
        if R_imu is not None and self.T_base_imu is None:
            base = self.settings.base_frame
            T = None
            if imu_frame:
                with self._tf_lock:
                    T = self.static_tf.lookup(base, imu_frame)
            if T is None:
                why = (f"no transform {base} -> {imu_frame} on /tf_static yet (the IMU's mounting, "
                       "base_to_sensor_from_tf)" if imu_frame else
                       "the Imu messages' header.frame_id is empty: with base_to_sensor_from_tf the IMU's mounting "
                       "is looked up on /tf_static by it")
                R_imu = None
            else:
                self.T_base_imu = T
                rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
                self._info(f"IMU mounting from /tf_static: {base} -> {imu_frame} = "
                           f"{[round(float(v), 6) for v in (*T[:3, 3], *rpy)]} [x, y, z, roll, pitch, yaw]")
        if R_imu is None:
            self._reject("frames_without_imu", f"scan at {stamp_ns * 1e-9:.3f} s registered without the gyro: {why}",
                         "plain prediction")
            return None
        return in_sensor_frame(R_imu, self._T_sensor_imu())

    def _T_sensor_imu(self) -> np.ndarray:
        """The IMU's pose in the sensor frame (T_sensor_base T_base_imu; T_base_imu known)."""
        return self.T_sensor_base @ self.T_base_imu

    def _await_gyro(self, until_ns: int) -> None:
        """Waits up to imu.wait for a gyro sample at or past `until_ns` (the scan's stamp or its sweep's end): a scan's
        message can come before the samples of its sweep (a burst, a driver starting up)."""
        if self.gyro is None or self.settings.imu_wait <= 0.0:
            return
        with self._imu_arrived:
            self._imu_arrived.wait_for(lambda: (self.gyro.newest_ns or -1) >= until_ns, timeout=self.settings.imu_wait)

    def _sweep_rate(self, stamp_ns: int, times: np.ndarray) -> np.ndarray | None:
        """The sensor's mean angular velocity (rad/s, its axes) over a sweep's times by the gyro (imu.enabled), or
        None: no gyro, the mounting not known yet, or the samples do not cover the sweep (counted in
        sweeps_without_gyro; the sweep is then corrected at the prediction's turn)."""
        if self.gyro is None or self.T_base_imu is None:
            return None
        t0, t1 = stamp_ns + round(float(times.min()) * 1e9), stamp_ns + round(float(times.max()) * 1e9)
        if t1 <= t0:
            return None
        with self._imu_lock:
            R_imu, _ = self.gyro.rotation(t0, t1)
        if R_imu is None:
            with self._count_lock:
                self.counters["sweeps_without_gyro"] += 1
            return None
        rate_imu = Rotation.from_matrix(R_imu).as_rotvec() / ((t1 - t0) * 1e-9)
        return self._T_sensor_imu()[:3, :3] @ rate_imu

    def _learn_gyro_bias(self, rotation: np.ndarray, delta: np.ndarray, stats: dict, seconds: float) -> None:
        """imu.bias_gain of the difference between the gyro's turn and a frame's registered one into the bias, when
        the frame was registered in full (no direction held at the gyro's turn) and the two agree within 0.5 deg."""
        gain = self.settings.imu_bias_gain
        in_full = stats.get("registered") and not stats.get("degenerate") and stats.get("held_directions", 0) == 0
        if gain <= 0.0 or not in_full or stats.get("turn_recovered") or not seconds > 0.0:
            return
        residual = Rotation.from_matrix(rotation.T @ delta[:3, :3]).as_rotvec()
        if np.linalg.norm(residual) > np.radians(0.5):
            return
        R_imu_sensor = self._T_sensor_imu()[:3, :3].T
        with self._imu_lock:
            self.gyro.learn_bias(R_imu_sensor @ residual, seconds, gain)

    @property
    def has_camera_info(self) -> bool:
        return self._camera_info is not None

    def set_camera_info(self, msg) -> bool:
        """Validate and keep the intrinsics; a malformed CameraInfo is counted and the previous K is kept."""
        try:
            convert.camera_info_to_K(msg)
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return False
        self._camera_info = msg
        return True

    def check_depth_image(self, msg) -> bool:
        """Whether a depth Image converts (a malformed one is counted and logged) - for images that must wait
        for their CameraInfo."""
        try:
            convert.image_to_depth(msg)
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return False
        return True

    def process_pointcloud(self, msg, receive_time: float | None = None) -> FrameOutput | None:
        """One PointCloud2 -> outputs; None when the frame was dropped (logged and counted)."""
        t0 = time.perf_counter()
        try:
            cloud = convert.pointcloud2_to_arrays(msg, max_points=self.settings.max_points)
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return None
        if not cloud.organized:
            self._check_sensor(cloud)
        try:
            times = convert.sweep_times(cloud)
        except convert.ConversionError as err:  # registered as measured: the sweep is not corrected
            self._reject("point_times_ignored", str(err), "registering without deskewing")
            times = None
        # (the time keyword only when there are times: engines without it keep working)
        extra = {} if times is None else {"time": times}
        stamp_ns = convert.stamp_to_ns(msg.header.stamp)
        self._await_gyro(stamp_ns + (0 if times is None else max(0, round(float(times.max()) * 1e9))))
        rate = None if times is None else self._sweep_rate(stamp_ns, times)
        if rate is not None:
            extra["sweep_rate"] = rate
        if cloud.organized:
            run = lambda stamp, **guess: self.engine.register_organized(  # noqa: E731
                cloud.xyz, stamp, **extra, **guess)
        else:
            run = lambda stamp, **guess: self.engine.register_points(  # noqa: E731
                cloud.xyz, stamp, ring=cloud.ring, **extra, **guess)
        return self._register(run, stamp_ns, cloud.frame_id, t0, receive_time)

    def _check_sensor(self, cloud) -> None:
        """Until a cloud fits the engine's sensor model: a cloud that does not is counted (clouds_not_fitting_sensor)
        and logged every SENSOR_LOG_REPEAT_S with the preset that fits it; it is still registered."""
        if self._sensor_checked or not hasattr(self.engine, "sensor_fit"):
            return
        try:
            fit = self.engine.sensor_fit(cloud.xyz, ring=cloud.ring)
        except ValueError:  # the registration reports the input
            return
        problem = sensor_check.problem(fit)
        if problem is None:
            if fit["points"] >= sensor_check.MIN_POINTS:
                self._sensor_checked, self.sensor_fit = True, "ok"
            return
        if self._sensor_advice is None:
            from line_odom_core import Odometry

            self._sensor_advice = sensor_check.advice(
                lambda preset: Odometry(load_config(preset)).sensor_fit(cloud.xyz, ring=cloud.ring))
        self.sensor_fit = f"{problem}: {self._sensor_advice}"
        with self._count_lock:
            self.counters["clouds_not_fitting_sensor"] += 1
            self.last_error = self.sensor_fit
        if time.monotonic() - self._sensor_logged >= SENSOR_LOG_REPEAT_S:
            self._sensor_logged = time.monotonic()
            self._warn(f"the clouds do not fit the sensor model, registering them anyway: {self.sensor_fit}")

    def process_depth(self, image, camera_info=None, receive_time: float | None = None) -> FrameOutput | None:
        """One depth Image (+ its CameraInfo, or the last valid one) -> outputs; None when dropped."""
        t0 = time.perf_counter()
        if camera_info is not None:
            self.set_camera_info(camera_info)
        try:
            depth = convert.image_to_depth(image)
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return None
        if self._camera_info is None:
            self._reject("frames_dropped", "no valid CameraInfo received yet for the depth image")
            return None
        try:
            K = convert.camera_info_to_K(self._camera_info, depth.shape)
        except convert.ConversionError as err:  # another camera's CameraInfo (e.g. the colour camera's)
            self._reject("frames_malformed", f"{err} (is depth/camera_info the depth image's own?)")
            return None
        stamp_ns = convert.stamp_to_ns(image.header.stamp)
        self._await_gyro(stamp_ns)
        return self._register(lambda s, **guess: self.engine.register_depth(depth, K, s, **guess), stamp_ns,
                              str(image.header.frame_id), t0, receive_time)

    # ------------------------------------------------------------------ core
    def _register(self, run, stamp_ns: int, frame_id: str, t0: float, receive_time: float | None):
        stamp = stamp_ns * 1e-9
        with self._frame_lock:
            if self.static_tf is not None and not self._mount(frame_id):
                return None
            reset_reason = None
            last = self._last_stamp_ns
            if last is not None and stamp_ns == last:
                self._reject("frames_duplicate", f"stamp {stamp:.9f} repeats the previous frame's stamp")
                return None
            if last is not None and stamp_ns < last:
                reset_reason = (f"stamp went backwards from {last * 1e-9:.9f} to {stamp:.9f} s "
                                f"(looping bag or restarted clock?)")
                self._warn(reset_reason + "; resetting odometry")
                self.engine.reset()
                self._clear_state()
                with self._count_lock:
                    self.counters["resets"] += 1
            first = self._last_stamp_ns is None
            guess, guess_pose = self._guess_delta(stamp_ns)
            rotation = self._imu_rotation(stamp_ns)
            extra = {}  # (keywords only when there is a guess: engines without them keep working)
            if guess is not None and rotation is not None:  # the source's translation, the gyro's rotation
                guess = guess.copy()
                guess[:3, :3] = rotation
            if guess is not None:
                extra["guess"] = guess
            elif rotation is not None:
                extra["rotation_guess"] = rotation
            try:
                result = run(stamp, **extra)
            except ValueError as err:
                self._reject("frames_failed", f"registration rejected the frame: {err}")
                return None
            pose, delta, cov = (np.asarray(result.pose, float), np.asarray(result.delta, float),
                                np.asarray(result.covariance, float))
            if not (np.isfinite(pose).all() and np.isfinite(delta).all() and np.isfinite(cov).all()):
                self._reject("frames_failed", "registration returned a non-finite pose or covariance")
                return None
            out = self._outputs(stamp_ns, frame_id, pose, delta, cov, dict(result.stats))
            if out.stats.get("deskewed"):
                with self._count_lock:
                    self.counters["frames_deskewed"] += 1
                    if out.stats.get("deskewed_again"):
                        self.counters["frames_deskewed_again"] += 1
            out.reset_reason = reset_reason
            if self.guess is not None:
                self._guess_prev = guess_pose
                if not first:
                    with self._count_lock:
                        self.counters["frames_guessed" if guess is not None else "frames_unguessed"] += 1
            if rotation is not None:
                self._learn_gyro_bias(rotation, delta, out.stats, (stamp_ns - last) * 1e-9)
                with self._count_lock:
                    self.counters["frames_imu"] += 1
        end = time.perf_counter()
        out.latency_ms = 1e3 * ((time.monotonic() - receive_time) if receive_time is not None else (end - t0))
        with self._count_lock:
            self.counters["frames_processed"] += 1
            self._latencies.append(out.latency_ms)
            self._last_stats = out.stats
        self.sensor_frame = frame_id or self.sensor_frame
        return out

    def _outputs(self, stamp_ns, frame_id, pose, delta, cov_delta, stats) -> FrameOutput:
        stamp = stamp_ns * 1e-9
        X, X_inv = self.T_base_sensor, self.T_sensor_base
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
            dt = (stamp_ns - self._last_stamp_ns) * 1e-9  # integer nanoseconds: exact for epoch stamps
            xi = frames.log_se3(D)
            twist = xi / dt
            J = frames.left_jacobian_inverse(xi)  # perturbation of log(D) from the left perturbation of D
            twist_cov = frames.symmetrize(J @ cov_d @ J.T) / (dt * dt)
        pose_cov = frames.left_to_ros_pose_covariance(self._cov_left, T)
        self._T_prev = T
        self._last_stamp_ns = stamp_ns
        odom, pose_stamped, tf = self._messages(stamp_ns, T, pose_cov, twist, twist_cov)
        self._path_poses.append(pose_stamped)
        path = self._path_message(pose_stamped.header)
        return FrameOutput(stamp, T, pose_cov, twist, twist_cov, stats, 0.0, odom, path, tf)

    # ------------------------------------------------------------------ messages
    def _messages(self, stamp_ns, T, pose_cov, twist, twist_cov):
        from geometry_msgs.msg import PoseStamped, TransformStamped
        from nav_msgs.msg import Odometry

        stamp_msg = convert.ns_to_stamp(stamp_ns)
        q = frames.quaternion_xyzw(T[:3, :3])
        odom = Odometry()
        odom.header.stamp = stamp_msg
        odom.header.frame_id = self.settings.odom_frame
        odom.child_frame_id = self.settings.base_frame
        p = odom.pose.pose
        p.position.x, p.position.y, p.position.z = (float(v) for v in T[:3, 3])
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = (float(v) for v in q)
        odom.pose.covariance = pose_cov.reshape(-1).tolist()
        tw = odom.twist.twist
        tw.linear.x, tw.linear.y, tw.linear.z = (float(v) for v in twist[:3])
        tw.angular.x, tw.angular.y, tw.angular.z = (float(v) for v in twist[3:])
        odom.twist.covariance = twist_cov.reshape(-1).tolist()
        pose_stamped = PoseStamped()
        pose_stamped.header = odom.header
        pose_stamped.pose = p
        tf = None
        if self.settings.publish_tf:
            from tf2_msgs.msg import TFMessage

            ts = TransformStamped()
            ts.header = odom.header
            ts.child_frame_id = self.settings.base_frame
            ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = (
                float(v) for v in T[:3, 3])
            r = ts.transform.rotation
            r.x, r.y, r.z, r.w = (float(v) for v in q)
            tf = TFMessage(transforms=[ts])
        return odom, pose_stamped, tf

    def _path_message(self, header):
        from nav_msgs.msg import Path

        path = Path()
        path.header = header
        path.poses = list(self._path_poses)
        return path

    # ------------------------------------------------------------------ diagnostics
    def diagnostics_values(self) -> dict[str, Any]:
        with self._count_lock:
            counters = dict(self.counters)
            receive = list(self._receive_times)
            lat = np.array(self._latencies, dtype=float)
            stats = dict(self._last_stats)
            last_error = self.last_error
        rate = 0.0
        if len(receive) >= 2 and receive[-1] > receive[0]:
            rate = (len(receive) - 1) / (receive[-1] - receive[0])
        values: dict[str, Any] = {**counters, "input_rate_hz": rate}
        if self.guess is not None:
            with self._guess_lock:
                values["guess_poses"] = len(self.guess)  # kept from guess_odom (guess.window)
        if self.gyro is not None:
            with self._imu_lock:
                values["imu_samples"] = len(self.gyro)  # kept from imu (imu.window)
                values["gyro_bias"] = " ".join(f"{v:.4f}" for v in np.degrees(self.gyro.bias))  # deg/s, IMU axes
        if self.static_tf is not None:
            with self._tf_lock:
                known = len(self.static_tf)
            values["base_to_sensor"] = (f"/tf_static {self.settings.base_frame} -> {self.mounted_frame}"
                                        if self.mounted_frame else f"waiting for /tf_static ({known} transforms)")
        if lat.size:
            values.update(latency_ms_last=lat[-1], latency_ms_mean=float(lat.mean()),
                          latency_ms_p95=float(np.percentile(lat, 95)))
        for key in (
                "solver", "inliers", "degenerate", "held_directions", "candidates", "h_lines", "v_lines",
                "registered_lines", "planes", "prediction", "unmeasured_directions", "window_scans", "turn_searched",
                "turn_recovered", "deskewed", "previous_deskewed_again", "deskewed_again", "points_refined",
                "point_matches"):
            if key in stats:
                values[key] = stats[key]
        if "persistence" in stats:  # the share of the last motion the prediction carried, x y z rx ry rz
            values["persistence"] = " ".join(f"{a:.2f}" for a in stats["persistence"])
        for stage, ms in (stats.get("ms") or {}).items():
            values[f"ms.{stage}"] = ms
        if self.settings.input == "pointcloud":
            values["sensor_fit"] = self.sensor_fit
        values["last_error"] = last_error or ""
        return values

    def diagnostics(self, stamp_msg=None):
        """A DiagnosticArray (one status): OK, or WARN when the last frame was degenerate or frames were dropped,
        malformed or failed since the previous call."""
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        values = self.diagnostics_values()
        with self._count_lock:
            since = {k: self.counters[k] - self._window_start.get(k, 0) for k in self.counters}
            self._window_start = dict(self.counters)
        status = DiagnosticStatus()
        status.name = self.diagnostic_name
        status.hardware_id = self.sensor_frame or self.settings.input
        problems = []
        if values.get("degenerate"):
            held = values.get("held_directions", 6)
            problems.append("degenerate geometry: pose held by the motion model, covariance inflated" if held >= 6 else
                            f"degenerate geometry: {held} of 6 motion directions held by the motion model, "
                            "covariance inflated along them")
        if values.get("unmeasured_directions"):
            problems.append(f"velocity along {values['unmeasured_directions']} direction(s) not measured since the "
                            "start, reset or stamp gap (held at standing still), searched each frame")
        for key, text in (("frames_malformed", "frame(s) malformed"), ("frames_failed", "frame(s) failed"),
                          ("frames_dropped", "frame(s) dropped (processing behind or no CameraInfo)"),
                          ("frames_duplicate", "frame(s) with a repeated stamp"),
                          ("frames_unguessed", "frame(s) without a guess_odom pose (constant-velocity prediction)"),
                          ("guess_rejected", "guess_odom message(s) rejected"),
                          ("frames_without_imu", "frame(s) without the gyro's rotation (plain prediction)"),
                          ("imu_rejected", "imu message(s) rejected"),
                          ("frames_no_extrinsic", "frame(s) dropped: the sensor's mounting not on /tf_static yet"),
                          ("tf_rejected", "/tf_static transform(s) rejected"),
                          ("point_times_ignored", "frame(s) registered without deskewing (unusable point times)"),
                          ("clouds_not_fitting_sensor", "cloud(s) not fitting the sensor model (sensor_fit)")):
            if since.get(key):
                problems.append(f"{since[key]} {text}")
        if values["frames_processed"] == 0:
            status.level = DiagnosticStatus.WARN
            status.message = "waiting for input" if values["frames_received"] == 0 else "no frame processed yet"
            if problems:
                status.message += "; " + "; ".join(problems)
        elif problems:
            status.level = DiagnosticStatus.WARN
            status.message = "; ".join(problems)
        else:
            status.level = DiagnosticStatus.OK
            status.message = "tracking"
        for key, value in values.items():
            text = f"{value:.3f}" if isinstance(value, float) else str(value)
            status.values.append(KeyValue(key=key, value=text))
        array = DiagnosticArray()
        if stamp_msg is not None:
            array.header.stamp = stamp_msg
        array.status = [status]
        return array
