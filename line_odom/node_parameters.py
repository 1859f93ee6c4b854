"""The node's own (non-engine) parameters: one table in the engine settings' style (name, type, default, range or
choices, unit, description, whether a running node may change it), the settings read from it, and their checks. No
rclpy here: replay and tests use it without ROS. No parameter is applied live: the node reads them once, at start-up,
and refuses changes at runtime.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

from line_odom import frames
from line_odom_core.config import Config, ConfigEntry, load_config

INPUTS = ("pointcloud", "depth")
# Names rclpy or the launch side owns; a parameter file may carry them beside ours.
IGNORED_KEYS = {"use_sim_time", "preset"}


@dataclasses.dataclass(frozen=True)
class NodeParameter(ConfigEntry):
    """One node parameter: an engine setting's row (line_odom_core.ConfigEntry) whose type may also be list: a pose
    (6 or 7 numbers) or, with vector, 3 numbers (x y z); a str without choices is a frame name (not empty)."""

    vector: bool = False

    @property
    def attribute(self) -> str:
        return self.name.replace(".", "_")

    @property
    def expected(self) -> str:
        if self.type is list:
            unit = f" ({self.unit})" if self.unit else ""
            return (f"3 finite numbers [x, y, z]{unit}" if self.vector else
                    f"6 values [x, y, z, roll, pitch, yaw]{unit} or 7 [x, y, z, qx, qy, qz, qw]")
        if self.type is str and not self.choices:
            return "str (a non-empty name)"
        return super().expected


NODE_PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("input", str, "pointcloud", "input kind: pointcloud (topic 'points', sensor_msgs/PointCloud2) or "
                  "depth (topics 'depth/image' + 'depth/camera_info')", choices=INPUTS),
    NodeParameter("odom_frame", str, "odom", "frame of the published pose (Odometry header.frame_id, TF parent)"),
    NodeParameter("base_frame", str, "base_link", "robot base frame (Odometry child_frame_id, TF child)"),
    NodeParameter("publish_tf", bool, True, "broadcast odom_frame -> base_frame on /tf"),
    NodeParameter("base_to_sensor", list, [0.0] * 6, "pose of the sensor in the base frame, T_base_sensor",
                  unit="m, rad"),
    NodeParameter("base_to_sensor_from_tf", bool, False, "take T_base_sensor from /tf_static instead of base_to_sensor: "
                  "the transform base_frame -> the input's header.frame_id (robot_state_publisher, "
                  "static_transform_publisher), looked up at the first frame that has it; frames before it are "
                  "dropped and counted (frames_no_extrinsic)"),
    NodeParameter("initial_pose", list, [0.0] * 6, "pose of the base in the odom frame at the first frame and after "
                  "a reset", unit="m, rad"),
    NodeParameter("path.max_poses", int, 1000, "poses kept in the published nav_msgs/Path (oldest dropped)", 1,
                  1_000_000),
    NodeParameter("path.period", float, 0.0, "time (of frame stamps) between published paths, 0 = every frame; a "
                  "path is sent only while something subscribes to it. A long path costs more to publish than a "
                  "sparse registration: set e.g. 1.0 when RViz shows it on a small computer", 0.0, 3600.0, unit="s"),
    NodeParameter("qos.reliable", bool, False, "subscribe to the input with reliable QoS instead of SensorDataQoS "
                  "(best effort; REP-2003)"),
    NodeParameter("qos.depth", int, 5, "input subscription queue depth", 1, 1000),
    NodeParameter("max_points", int, 2_000_000, "reject clouds with more points than this, before converting them "
                  "(0 = no limit)", 0, 1_000_000_000),
    NodeParameter("max_pixels", int, 4_000_000, "reject depth images with more pixels (width x height) than this, "
                  "before converting them (0 = no limit); the default holds the common depth cameras up to "
                  "2208 x 1242, a 4K depth image (3840 x 2160) needs 8294400", 0, 1_000_000_000),
    NodeParameter("diagnostics.period", float, 1.0, "time (wall clock, also under use_sim_time) between "
                  "/diagnostics messages", 0.05, 3600.0, unit="s"),
    NodeParameter("guess.enabled", bool, False, "register each scan from the base's motion reported by another "
                  "odometry source on topic 'guess_odom' (nav_msgs/Odometry, child_frame_id = base_frame: wheel "
                  "odometry, an IMU filter) instead of the constant-velocity prediction"),
    NodeParameter("guess.tolerance", float, 0.1, "how far a scan's stamp may lie past the newest guess_odom pose "
                  "(extrapolated along the last two); a scan outside the poses is registered with the "
                  "constant-velocity prediction and counted (frames_unguessed)", 0.0, 10.0, unit="s"),
    NodeParameter("guess.window", float, 5.0, "guess_odom poses kept", 0.1, 86400.0, unit="s"),
    NodeParameter("imu.enabled", bool, False, "turn each scan's prediction by the rotation integrated from the gyro "
                  "on topic 'imu' (sensor_msgs/Imu angular_velocity) between the previous and this scan's stamp; the "
                  "translation stays the constant-velocity prediction's"),
    NodeParameter("imu.base_to_imu", list, [0.0] * 6, "pose of the IMU in the base frame, T_base_imu; with "
                  "base_to_sensor_from_tf it comes from /tf_static instead (base_frame -> the Imu messages' "
                  "header.frame_id)", unit="m, rad"),
    NodeParameter("imu.gyro_bias", list, [0.0] * 3, "gyro bias (IMU axes) subtracted from every angular_velocity, "
                  "where the learned bias starts", unit="rad/s", vector=True),
    NodeParameter("imu.bias_gain", float, 0.05, "share of each scan interval's difference between the gyro's and the "
                  "registered rotation taken into the gyro bias (a frame registered in full, within 0.5 deg); 0 = the "
                  "bias stays imu.gyro_bias", 0.0, 1.0),
    NodeParameter("imu.wait", float, 0.03, "how long a scan waits for the gyro samples that reach past its sweep (a "
                  "scan's message can come before the samples of its sweep: a burst at a driver's start-up, a late "
                  "IMU) before it is registered without them; 0: never waits", 0.0, 1.0, unit="s"),
    NodeParameter("imu.max_gap", float, 0.05, "time without a gyro sample a scan interval may contain (also between a "
                  "scan's stamp and the nearest sample past it); a longer gap: the scan uses the plain prediction "
                  "and counts in frames_without_imu", 0.001, 10.0, unit="s"),
    NodeParameter("imu.window", float, 5.0, "gyro samples kept", 0.1, 86400.0, unit="s"),
)
NODE_PARAMETER_NAMES = {p.name for p in NODE_PARAMETERS}
_BY_NAME = {p.name: p for p in NODE_PARAMETERS}
POSE_PARAMETERS = tuple(p.name for p in NODE_PARAMETERS if p.type is list and not p.vector)


def validate_node_value(name: str, value: Any) -> Any:
    """The value converted to the node parameter's type; ValueError naming the parameter and what it expects."""
    spec = _BY_NAME.get(name)
    if spec is None:
        raise ValueError(f"unknown node parameter {name!r}; known: {', '.join(sorted(NODE_PARAMETER_NAMES))}")
    bad = ValueError(f"{name}: expected {spec.expected}, got {value!r}")
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
                raise bad
            return vector
        frames.pose_from_params(values, name)  # validates length and values
        return [float(v) for v in values]
    if spec.type is bool:
        if isinstance(value, bool):
            return value
        raise bad
    if spec.type is str:
        if not isinstance(value, str) or not value:
            raise bad
        if spec.choices:
            match = [c for c in spec.choices if c.lower() == value.lower()]
            if not match:
                raise bad
            value = match[0]
        return value
    if isinstance(value, (bool, str, bytes)):
        raise bad
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise bad from None
    if not math.isfinite(number) or (spec.type is int and number != int(number)):
        raise bad
    if not _in_range(spec, number):
        raise bad
    return int(number) if spec.type is int else number


def _in_range(spec: NodeParameter, x: float) -> bool:
    if spec.zero_is_off and x == 0:
        return True
    above = spec.min is None or (x > spec.min if spec.min_open else x >= spec.min)
    below = spec.max is None or (x < spec.max if spec.max_open else x <= spec.max)
    return above and below


class _SettingsMethods:
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
        return settings

    def as_dict(self) -> dict[str, Any]:
        return {p.name: getattr(self, p.attribute) for p in NODE_PARAMETERS}


def _field(spec: NodeParameter):
    if isinstance(spec.default, list):
        return dataclasses.field(default_factory=lambda d=spec.default: list(d))
    return dataclasses.field(default=spec.default)


# The node's own settings (the engine's are in line_odom_core.Config): one attribute per NODE_PARAMETERS row, named
# by its dotted name with underscores (qos.depth -> qos_depth), its default the row's: the table is the one source.
NodeSettings = dataclasses.make_dataclass(
    "NodeSettings", [(p.attribute, p.type, _field(p)) for p in NODE_PARAMETERS], bases=(_SettingsMethods,),
    namespace={"__module__": __name__})  # (make_dataclass's own module= is Python 3.12+)


def settings_from_parameters(preset_or_path: str = "kitti_hdl64",
                             overrides: Mapping[str, Any] | None = None) -> tuple[Config, NodeSettings]:
    """The engine's and the node's settings from a preset name or ROS parameter YAML, with dotted overrides (engine
    or node names)."""
    overrides = dict(overrides or {})
    node_over = {k: v for k, v in overrides.items() if k in NODE_PARAMETER_NAMES or k in IGNORED_KEYS}
    engine_over = {k: v for k, v in overrides.items() if k not in node_over}
    config = load_config(preset_or_path, engine_over)
    return config, NodeSettings.from_mapping({**config.extra, **node_over})
