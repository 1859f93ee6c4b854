"""The node's processing core without rclpy: sensor messages in, Odometry / Path / TFMessage / DiagnosticArray
out. The rclpy node (line_odom.node) wires it to topics; replay drives it in-process, frame by frame.

Per frame: convert (line_odom.convert) -> fuse the guesses (line_odom.fusion) -> register (the engine) -> the base's
pose and twist (line_odom.pipeline) -> messages (line_odom.messages). Parameters are in line_odom.node_parameters,
reporting in line_odom.diagnostics.
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

from line_odom import convert, frames, lines_view, messages, scan_view, sensor_check
from line_odom.diagnostics import RateLimitedLog, diagnostic_array, frame_values
from line_odom.fusion import Fusion
from line_odom.node_parameters import (INPUTS, NODE_PARAMETER_NAMES, NODE_PARAMETERS, NodeSettings,  # noqa: F401
                                       settings_from_parameters, validate_node_value)
from line_odom.pipeline import BaseTrajectory, EngineFrame
from line_odom_core.config import Config, load_config

SENSOR_LOG_REPEAT_S = 30.0


@dataclasses.dataclass
class FrameOutput:
    """What one processed frame publishes, as messages and as numpy (for replay and tests)."""

    stamp: float
    T_odom_base: np.ndarray
    pose_covariance: np.ndarray  # 6x6, PoseWithCovariance convention (parent-frame axes)
    twist: np.ndarray  # (vx vy vz wx wy wz) in base_frame (line_odom.pipeline)
    twist_covariance: np.ndarray
    stats: dict
    latency_ms: float
    odometry: Any
    path: Any
    tf: Any | None
    reset_reason: str | None = None
    scan: Any | None = None  # the registered scan as PointCloud2, only when scan_wanted
    lines: Any | None = None  # the registered lines as MarkerArray, only when lines_wanted


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
        self.log_limiter = RateLimitedLog(self._warn)
        self._frame_lock = threading.RLock()
        self._count_lock = threading.Lock()
        self._camera_info = None  # the last valid CameraInfo (its K checked; its size against each depth image)
        self.counters = collections.Counter(
            frames_received=0, frames_processed=0, frames_dropped=0, frames_malformed=0, frames_too_large=0,
            frames_failed=0, frames_duplicate=0, resets=0, frames_deskewed=0, frames_deskewed_again=0,
            point_times_ignored=0, ring_fields_ignored=0, clouds_not_fitting_sensor=0, initial_poses_rejected=0,
            frames_lost_in_transport=0)
        self.fusion = Fusion(self.settings, self.config["registration.max_translation"],
                             self.config["registration.max_rotation_deg"], reject=self._reject, count=self._count,
                             info=self._info)
        self.counters.update(self.fusion.counters())
        self.T_init_parameter = frames.pose_from_params(self.settings.initial_pose, "initial_pose")
        self.trajectory = BaseTrajectory(self.T_init_parameter)
        self.last_error: str | None = None
        # the sensor model checked against the clouds until one fits (sensor_check); the reason one did not
        self.sensor_fit = "not checked yet"
        self._sensor_checked = False
        self._sensor_advice: str | None = None
        self._sensor_logged = -math.inf  # time.monotonic() of the last sensor_fit warning
        self._receive_times: collections.deque = collections.deque(maxlen=50)
        self._latencies: collections.deque = collections.deque(maxlen=200)
        self._last_stats: dict = {}
        self._window_start = dict(self.counters)
        self.sensor_frame = ""
        self.diagnostic_name = "line_odom: odometry"  # the node sets "<fully qualified node name>: odometry"
        self._path_poses: collections.deque = collections.deque(maxlen=self.settings.path_max_poses)
        # set while something subscribes to the node's ~/scan: building it costs a second pass over the points
        self.scan_wanted = False
        self.lines_wanted = False

    @classmethod
    def from_parameters(cls, preset_or_path: str = "kitti_hdl64", overrides: Mapping[str, Any] | None = None,
                        **kwargs) -> "OdometryProcessor":
        """From a preset name or ROS parameter YAML, with dotted overrides (engine or node names)."""
        return cls(*settings_from_parameters(preset_or_path, overrides), **kwargs)

    # ------------------------------------------------------------------ the fused inputs
    @property
    def T_base_sensor(self) -> np.ndarray:
        return self.fusion.T_base_sensor

    @property
    def T_init(self) -> np.ndarray:
        """The base's pose in odom at the first frame since the start or the last reset."""
        return self.trajectory.T_init

    @property
    def gyro(self):
        return self.fusion.gyro

    @property
    def guess(self):
        return self.fusion.guess

    @property
    def static_tf(self):
        return self.fusion.static_tf

    @property
    def mounted_frame(self) -> str | None:
        return self.fusion.mounted_frame

    def add_guess(self, msg) -> bool:
        """One nav_msgs/Odometry of the guess source (guess.enabled); an unusable one is logged and counted
        (guess_rejected)."""
        return self.fusion.add_guess(msg)

    def add_imu(self, msg) -> bool:
        """One sensor_msgs/Imu (imu.enabled): its angular velocity is kept; an unusable message (no or non-finite
        rate, another frame_id, a stamp out of order) is logged and counted (imu_rejected)."""
        return self.fusion.add_imu(msg)

    def add_static_tf(self, msg) -> bool:
        """One tf2_msgs/TFMessage from /tf_static (base_to_sensor_from_tf); an unusable transform is logged and
        counted (tf_rejected), the message's others are kept."""
        return self.fusion.add_static_tf(msg)

    # ------------------------------------------------------------------ state
    def _clear_state(self) -> None:
        self.trajectory.clear()
        self._path_poses.clear()
        self.fusion.clear()

    def reset(self, reason: str = "reset requested", initial_pose: np.ndarray | None = None) -> None:
        """Forget the trajectory: the next frame is at ``initial_pose`` (a 4x4 T_odom_base; default: the parameter
        initial_pose) again."""
        with self._frame_lock:
            self.engine.reset()
            self._clear_state()
            self.trajectory.T_init = self.T_init_parameter if initial_pose is None else np.array(initial_pose, float)
        self._count("resets")
        where = "initial_pose" if initial_pose is None else "the given pose"
        self._info(f"odometry reset ({reason}); the next frame starts at {where}")

    def set_initial_pose(self, msg) -> bool:
        """geometry_msgs/PoseWithCovarianceStamped (rviz's 2D Pose Estimate): the base's pose in odom_frame; the
        trajectory restarts there at the next frame (as after ~/reset, which goes back to the parameter
        initial_pose). A pose in another frame or not a pose (non-finite, not a unit quaternion) is refused, logged
        and counted (initial_poses_rejected)."""
        odom = self.settings.odom_frame
        frame = str(msg.header.frame_id).lstrip("/")
        what = "refused initialpose"
        if frame != odom:
            self._reject("initial_poses_rejected", f"PoseWithCovarianceStamped.header.frame_id: expected odom_frame "
                                                   f"{odom!r} (the base's pose in it), got {frame!r}; no transform "
                                                   f"between them is looked up (set rviz's fixed frame to {odom!r})",
                         what)
            return False
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        position = np.array([p.x, p.y, p.z], dtype=float)
        quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
        norm = float(np.linalg.norm(quat))
        if not np.isfinite(position).all():
            self._reject("initial_poses_rejected", f"PoseWithCovarianceStamped.pose.pose.position: expected finite "
                                                   f"values, got {position.tolist()}", what)
            return False
        if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
            self._reject("initial_poses_rejected", f"PoseWithCovarianceStamped.pose.pose.orientation: expected a unit "
                                                   f"quaternion, got {quat.tolist()} (norm {norm:g})", what)
            return False
        T = frames.pose_from_params([*position, *(quat / norm)], "initialpose")
        self.reset(f"initialpose in {odom}", T)
        return True

    # ------------------------------------------------------------------ counters and logs
    def _count(self, kind: str, n: int = 1) -> None:
        with self._count_lock:
            self.counters[kind] += n

    def note_received(self, now: float | None = None) -> None:
        with self._count_lock:
            self.counters["frames_received"] += 1
            self._receive_times.append(time.monotonic() if now is None else now)

    def note_dropped(self, n: int = 1) -> None:
        self._count("frames_dropped", n)

    def _reject(self, kind: str, reason: str, what: str = "dropped frame") -> None:
        """Counts a rejected input in `kind` and logs it: one line per reason in LOG_WINDOW_S, repeats counted."""
        with self._count_lock:
            self.counters[kind] += 1
            self.last_error = reason
        self.log_limiter(f"{what}: {reason}")

    def note_lost(self, n: int, topic: str) -> None:
        """`n` input messages DDS reports lost before they reached the node (counted in frames_lost_in_transport)."""
        if n > 0:
            self._count("frames_lost_in_transport", n - 1)
            self._reject("frames_lost_in_transport", f"{topic}: DDS lost {n} message(s) before they reached the node "
                                                     "(best effort loses a message with any of its fragments: one "
                                                     "larger than the transport carries? docs/NODE.md, \"Clouds "
                                                     "larger than the transport carries\")", "lost input")

    def note_failure(self, reason: str) -> None:
        """A frame that failed for a reason outside the processor (counted as failed)."""
        self._reject("frames_failed", reason)

    def note_rejected(self, kind: str, reason: str, what: str) -> None:
        """An input the node refused before it reached the processor (counted in `kind`, logged rate-limited)."""
        self._reject(kind, reason, what)

    def flush_log(self) -> None:
        """Logs the counts of repeated rejections whose window is over."""
        self.log_limiter.flush()

    # ------------------------------------------------------------------ depth
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

    def _depth_size_refused(self, image) -> bool:
        """Checks what the header alone tells, before any pixel is touched: the size against max_pixels (counted in
        frames_too_large) and against the CameraInfo (frames_malformed). True when refused."""
        try:
            height = convert.image_dimension(image, "height")
            width = convert.image_dimension(image, "width")
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return True
        limit = self.settings.max_pixels
        if limit and width * height > limit:
            self._reject("frames_too_large", f"Image.width: {width} x {height} = {width * height} pixels exceed the "
                                             f"max_pixels limit of {limit} (parameter max_pixels)")
            return True
        info = self._camera_info
        if info is not None and int(info.width) and int(info.height) and (
                (int(info.height), int(info.width)) != (height, width)):
            self._reject("frames_malformed", f"CameraInfo.width: CameraInfo is {info.width} x {info.height} but the "
                                             f"image is {width} x {height} (is depth/camera_info the depth "
                                             f"image's own?)")
            return True
        return False

    def check_depth_image(self, msg) -> bool:
        """Whether a depth Image converts (a malformed one is counted and logged) - for images that must wait
        for their CameraInfo."""
        if self._depth_size_refused(msg):
            return False
        try:
            convert.header_stamp_ns(msg.header.stamp, "Image")
            convert.image_to_depth(msg)
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return False
        return True

    def process_depth(self, image, camera_info=None, receive_time: float | None = None) -> FrameOutput | None:
        """One depth Image (+ its CameraInfo, or the last valid one) -> outputs; None when dropped."""
        t0 = time.perf_counter()
        if camera_info is not None:
            self.set_camera_info(camera_info)
        if self._depth_size_refused(image):
            return None
        try:
            stamp_ns = convert.header_stamp_ns(image.header.stamp, "Image")
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
        self.fusion.await_gyro(stamp_ns)
        return self._register(EngineFrame("register_depth", (depth, K)), stamp_ns, str(image.header.frame_id), t0,
                              receive_time)

    # ------------------------------------------------------------------ point clouds
    def process_pointcloud(self, msg, receive_time: float | None = None) -> FrameOutput | None:
        """One PointCloud2 -> outputs; None when the frame was dropped (logged and counted)."""
        t0 = time.perf_counter()
        try:
            stamp_ns = convert.header_stamp_ns(msg.header.stamp, "PointCloud2")
            cloud = convert.pointcloud2_to_arrays(msg, max_points=self.settings.max_points)
        except convert.TooLargeError as err:
            self._reject("frames_too_large", f"{err} (parameter max_points)")
            return None
        except convert.ConversionError as err:
            self._reject("frames_malformed", str(err))
            return None
        one_ring = cloud.ring is not None and cloud.ring.size > 1 and cloud.ring.min() == cloud.ring.max()
        if one_ring and not cloud.organized:
            # A ring field of one value (a converter filling it with 0) would put the whole cloud in one row, which the
            # engine refuses: the rows come from the points' elevations instead.
            self._reject("ring_fields_ignored", f"PointCloud2.fields[ring]: one value ({int(cloud.ring.flat[0])}) for "
                                                f"all {cloud.ring.size} points", "rows from the points' elevations")
            cloud = dataclasses.replace(cloud, ring=None)
        if not cloud.organized:
            self._check_sensor(cloud)
        try:
            times = convert.sweep_times(cloud)
        except convert.ConversionError as err:  # registered as measured: the sweep is not corrected
            self._reject("point_times_ignored", str(err), "registering without deskewing")
            times = None
        extra = {} if times is None else {"time": times}
        self.fusion.await_gyro(stamp_ns + (0 if times is None else max(0, round(float(times.max()) * 1e9))))
        rate = None if times is None else self.fusion.sweep_rate(stamp_ns, times)
        if rate is not None:
            extra["sweep_rate"] = rate
        if cloud.organized:
            frame = EngineFrame("register_organized", (cloud.xyz,), extra)
        else:
            frame = EngineFrame("register_points", (cloud.xyz,), {"ring": cloud.ring, **extra})
        return self._register(frame, stamp_ns, cloud.frame_id, t0, receive_time)

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

    # ------------------------------------------------------------------ registration
    def _register(self, frame: EngineFrame, stamp_ns: int, frame_id: str, t0: float, receive_time: float | None):
        stamp = stamp_ns * 1e-9
        with self._frame_lock:
            if not self.fusion.mount(frame_id):
                return None
            reset_reason = None
            last = self.trajectory.last_stamp_ns
            if last is not None and stamp_ns == last:
                self._reject("frames_duplicate", f"stamp {stamp:.9f} repeats the previous frame's stamp")
                return None
            if last is not None and stamp_ns < last:
                reset_reason = (f"stamp went backwards from {last * 1e-9:.9f} to {stamp:.9f} s "
                                f"(looping bag or restarted clock?)")
                self._warn(reset_reason + "; resetting odometry")
                self.engine.reset()
                self._clear_state()
                self._count("resets")
            last = self.trajectory.last_stamp_ns
            guess, guess_pose = self.fusion.guess_delta(stamp_ns)
            rotation = self.fusion.imu_rotation(last, stamp_ns)
            try:
                if hasattr(self.engine, "keep_points"):  # ~/scan shows the points as registered (deskewed)
                    self.engine.keep_points(self.scan_wanted)
                result = frame.register(self.engine, stamp, self.fusion.engine_guess(guess, rotation))
            except ValueError as err:
                self._reject("frames_failed", f"registration rejected the frame: {err}")
                return None
            pose, delta, cov = (np.asarray(result.pose, float), np.asarray(result.delta, float),
                                np.asarray(result.covariance, float))
            if not (np.isfinite(pose).all() and np.isfinite(delta).all() and np.isfinite(cov).all()):
                self._reject("frames_failed", "registration returned a non-finite pose or covariance")
                return None
            out = self._outputs(stamp_ns, pose, delta, cov, dict(result.stats))
            if out.stats.get("deskewed"):
                self._count("frames_deskewed")
                if out.stats.get("deskewed_again"):
                    self._count("frames_deskewed_again")
            out.reset_reason = reset_reason
            seconds = (stamp_ns - last) * 1e-9 if last is not None else 0.0
            self.fusion.registered(last is None, guess, guess_pose, rotation, delta, out.stats, seconds)
        end = time.perf_counter()
        out.latency_ms = 1e3 * ((time.monotonic() - receive_time) if receive_time is not None else (end - t0))
        if self.scan_wanted:  # after the latency is taken: the view is not the odometry's cost
            points = frame.kept_points(self.engine, self.config)
            if points is not None:
                out.scan = scan_view.scan_message(points, frame_id, stamp_ns)
        if self.lines_wanted and hasattr(self.engine, "last_lines"):
            out.lines = lines_view.lines_message(*self.engine.last_lines(), frame_id, stamp_ns)
        with self._count_lock:
            self.counters["frames_processed"] += 1
            self._latencies.append(out.latency_ms)
            self._last_stats = out.stats
        self.sensor_frame = frame_id or self.sensor_frame
        return out

    def _outputs(self, stamp_ns, pose, delta, cov_delta, stats) -> FrameOutput:
        state = self.trajectory.step(stamp_ns, pose, delta, cov_delta, self.fusion.T_base_sensor,
                                     self.fusion.T_sensor_base)
        s = self.settings
        odom, pose_stamped, tf = messages.odometry_messages(
            stamp_ns, state.T_odom_base, state.pose_covariance, state.twist, state.twist_covariance, s.odom_frame,
            s.base_frame, s.publish_tf)
        self._path_poses.append(pose_stamped)
        path = messages.path_message(pose_stamped.header, self._path_poses)
        return FrameOutput(stamp_ns * 1e-9, state.T_odom_base, state.pose_covariance, state.twist,
                           state.twist_covariance, stats, 0.0, odom, path, tf)

    # ------------------------------------------------------------------ diagnostics
    def diagnostics_values(self) -> dict[str, Any]:
        with self._count_lock:
            counters = dict(self.counters)
            receive = list(self._receive_times)
            latencies = list(self._latencies)
            stats = dict(self._last_stats)
            last_error = self.last_error
        values = frame_values(counters, receive, latencies, stats)
        values.update(self.fusion.diagnostics_values())
        if self.settings.input == "pointcloud":
            values["sensor_fit"] = self.sensor_fit
        values["last_error"] = last_error or ""
        return values

    def diagnostics(self, stamp_msg=None):
        """A DiagnosticArray (one status): OK, or WARN when the last frame was degenerate or frames were dropped,
        malformed or failed since the previous call. Also tells the counts of repeated log lines."""
        self.flush_log()
        values = self.diagnostics_values()
        with self._count_lock:
            since = {k: self.counters[k] - self._window_start.get(k, 0) for k in self.counters}
            self._window_start = dict(self.counters)
        return diagnostic_array(self.diagnostic_name, self.sensor_frame or self.settings.input, values, since,
                                stamp_msg)
