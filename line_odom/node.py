"""rclpy node: ``ros2 run line_odom node`` (or ``python -m line_odom.node``).

Subscribes ``points`` (PointCloud2) or ``depth/image`` + ``depth/camera_info``; publishes ``odom``
(nav_msgs/Odometry), ``path`` (nav_msgs/Path), ``/tf`` (tf2_msgs/TFMessage) and ``/diagnostics``; serves
``~/reset`` (std_srvs/Trigger). Frames are processed on a worker thread (the engine releases the GIL): the
subscription callback only stores the newest message, so when processing falls behind the newest frame wins
and the replaced ones are counted as dropped. The work itself is line_odom.processor.OdometryProcessor.
"""
from __future__ import annotations

import sys
import threading
import time
import traceback

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, DurabilityPolicy, qos_profile_sensor_data
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2
from std_srvs.srv import Trigger

from line_odom.processor import NODE_PARAMETERS, NodeSettings, OdometryProcessor
from line_odom_core.config import CHOICES, config_schema, load_config

NODE_NAME = "line_odom"
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


class LatestSlot:
    """A one-element mailbox: put() replaces an unprocessed item (returns True then, i.e. one frame dropped)."""

    def __init__(self):
        self._cond = threading.Condition()
        self._item = None
        self._closed = False

    def put(self, item) -> bool:
        with self._cond:
            replaced = self._item is not None
            self._item = item
            self._cond.notify()
            return replaced

    def put_back(self, item) -> bool:
        """Return an item the consumer could not handle yet, unless a newer one arrived (then False)."""
        with self._cond:
            if self._item is not None:
                return False
            self._item = item
            return True

    def take(self, timeout: float):
        with self._cond:
            if self._item is None and not self._closed:
                self._cond.wait(timeout)
            item, self._item = self._item, None
            return item

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


def _descriptor(name: str, ptype: int, description: str, lo=None, hi=None, constraints: str = "",
                integer: bool = False) -> ParameterDescriptor:
    d = ParameterDescriptor(name=name, type=ptype, description=description, read_only=True,
                            additional_constraints=constraints)
    if lo is not None or hi is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo if lo is not None else INT64_MIN),
                                            to_value=int(hi if hi is not None else INT64_MAX), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo if lo is not None else -1e308),
                                                         to_value=float(hi if hi is not None else 1e308),
                                                         step=0.0)]
    return d


_PTYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
           float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
           list: ParameterType.PARAMETER_DOUBLE_ARRAY}


class ParameterSetupError(ValueError):
    """A parameter has a bad value or type; the message names it and says what is expected."""


class LineOdomNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._declare_and_load()
        s = self.settings
        try:
            self.processor = OdometryProcessor(self.config, s, logger=self.get_logger())
        except ValueError as err:  # the engine rejected a setting
            raise ParameterSetupError(f"the engine rejected the settings: {err}") from None
        self.processor.diagnostic_name = f"{self.get_fully_qualified_name()}: odometry"
        self._log_parameters()

        if s.qos_reliable:
            input_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=s.qos_depth,
                                   reliability=ReliabilityPolicy.RELIABLE)
        else:
            input_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=s.qos_depth,
                                   reliability=qos_profile_sensor_data.reliability,
                                   durability=qos_profile_sensor_data.durability)
        self.pub_odom = self.create_publisher(Odometry, "odom", 10)
        self.pub_path = self.create_publisher(Path, "path", QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                                       durability=DurabilityPolicy.VOLATILE))
        self.pub_tf = None
        if s.publish_tf:
            from tf2_msgs.msg import TFMessage

            self.pub_tf = self.create_publisher(TFMessage, "/tf", 100)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)

        self._slot = LatestSlot()
        self._camera_info_event = threading.Event()
        if s.input == "pointcloud":
            self.create_subscription(PointCloud2, "points", self._on_message, input_qos)
            inputs = [self.resolve_topic_name("points")]
        else:
            self.create_subscription(Image, "depth/image", self._on_message, input_qos)
            self.create_subscription(CameraInfo, "depth/camera_info", self._on_camera_info, input_qos)
            inputs = [self.resolve_topic_name("depth/image"), self.resolve_topic_name("depth/camera_info")]
        if s.guess_enabled:
            # best effort matches reliable and best-effort publishers; a lost pose only widens an interpolation
            guess_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                                   reliability=qos_profile_sensor_data.reliability)
            self.create_subscription(Odometry, "guess_odom", self.processor.add_guess, guess_qos)
            inputs.append(self.resolve_topic_name("guess_odom") + " (motion guess)")
        if s.imu_enabled:
            # 100-400 Hz: a deep best-effort queue, so a registration holding the GIL briefly loses no sample
            imu_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=400,
                                 reliability=qos_profile_sensor_data.reliability)
            self.create_subscription(Imu, "imu", self.processor.add_imu, imu_qos)
            inputs.append(self.resolve_topic_name("imu") + " (gyro rotation guess)")
        if s.base_to_sensor_from_tf:
            from tf2_msgs.msg import TFMessage

            # as tf2's static listener: reliable and transient local, so transforms latched before the start arrive
            static_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.create_subscription(TFMessage, "/tf_static", self.processor.add_static_tf, static_qos)
            inputs.append(f"/tf_static ({s.base_frame} -> the input's frame)")
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_timer(s.diagnostics_period, self._publish_diagnostics)
        self._last_path_stamp: float | None = None
        self._worker = threading.Thread(target=self._work, name="line_odom_worker", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"line_odom ready: input {s.input} on {', '.join(inputs)} "
            f"({'reliable' if s.qos_reliable else 'best effort (SensorDataQoS)'}), publishing "
            f"{self.resolve_topic_name('odom')}, {self.resolve_topic_name('path')}"
            f"{', /tf' if s.publish_tf else ''}, /diagnostics; {s.odom_frame} -> {s.base_frame}")

    # ------------------------------------------------------------------ parameters
    def _coerce_overrides(self, names_types: dict[str, type]) -> None:
        """ROS parameter files often write 2 for 2.0 (and [0, 0, 0] for doubles); accept those for double
        parameters instead of failing on the type."""
        overrides = getattr(self, "_parameter_overrides", None)
        if not isinstance(overrides, dict):
            return
        for name, want in names_types.items():
            p = overrides.get(name)
            if p is None:
                continue
            if want is float and p.type_ == Parameter.Type.INTEGER:
                overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(p.value))
            elif want is list and p.type_ == Parameter.Type.INTEGER_ARRAY:
                overrides[name] = Parameter(name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in p.value])

    def _declare(self, name, default, ptype, descriptor):
        try:
            return self.declare_parameter(name, default, descriptor).value
        except Exception as err:  # rclpy raises several exception types for bad overrides
            raise ParameterSetupError(f"parameter {name!r}: {err}") from None

    def _declare_and_load(self) -> None:
        preset = self._declare("preset", "kitti_hdl64", ParameterType.PARAMETER_STRING, _descriptor(
            "preset", ParameterType.PARAMETER_STRING,
            "engine + node defaults: a preset name (kitti_hdl64, tum_kinect, vlp16, ouster_os128) or a ROS 2 "
            "parameter YAML path; individual parameters override it"))
        try:
            base = load_config(preset)
        except (ValueError, FileNotFoundError, OSError) as err:
            raise ParameterSetupError(f"parameter 'preset': {err}") from None
        try:
            preset_node = NodeSettings.from_mapping(base.extra, strict=False).as_dict()
        except ValueError as err:
            raise ParameterSetupError(f"preset {base.source}: {err}") from None
        unknown = sorted(k for k in base.extra if k not in preset_node and k not in ("use_sim_time", "preset"))
        if unknown:
            self.get_logger().warning(f"preset {base.source}: ignoring unknown keys {unknown}")

        schema = config_schema()
        self._coerce_overrides({**{e.name: e.type for e in schema}, **{p.name: p.type for p in NODE_PARAMETERS}})

        node_values = {}
        for p in NODE_PARAMETERS:
            ptype = _PTYPES[p.type]
            constraints = ("one of " + ", ".join(p.choices)) if p.choices else ""
            desc = _descriptor(p.name, ptype, p.description, p.min, p.max, constraints, integer=p.type is int)
            default = preset_node[p.name]
            node_values[p.name] = self._declare(p.name, [float(v) for v in default] if p.type is list else default,
                                                ptype, desc)
        try:
            self.settings = NodeSettings.from_mapping(node_values)
        except ValueError as err:
            raise ParameterSetupError(str(err)) from None

        engine_values = {}
        for e in schema:
            ptype = _PTYPES[e.type]
            constraints = ("one of " + ", ".join(CHOICES[e.name])) if e.name in CHOICES else ""
            desc = _descriptor(e.name, ptype, e.description, e.min, e.max, constraints, integer=e.type is int)
            engine_values[e.name] = self._declare(e.name, base[e.name], ptype, desc)
        try:
            self.config = load_config(preset, engine_values)
        except ValueError as err:
            raise ParameterSetupError(str(err)) from None

        declared = {"preset", "use_sim_time"} | set(node_values) | set(engine_values)
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        stray = sorted(n for n in overrides if n not in declared and not n.startswith("qos_overrides."))
        if stray:
            self.get_logger().warning(f"ignoring unknown parameters {stray} (typo?)")

    def _log_parameters(self) -> None:
        lines = [f"  preset = {self.config.source}"]
        lines += [f"  {k} = {v}" for k, v in self.settings.as_dict().items()]
        lines += [f"  {k} = {v}" for k, v in self.config.as_dict().items()]
        lines.append(f"  use_sim_time = {self.get_parameter('use_sim_time').value}")
        self.get_logger().info("parameters:\n" + "\n".join(lines))

    # ------------------------------------------------------------------ callbacks
    def _on_message(self, msg) -> None:
        self.processor.note_received()
        if self._slot.put((msg, time.monotonic())):
            self.processor.note_dropped()

    def _on_camera_info(self, msg) -> None:
        if self.processor.set_camera_info(msg):
            self._camera_info_event.set()

    def _on_reset(self, request, response):
        self.processor.reset("~/reset service")
        response.success = True
        response.message = "odometry reset; the next frame starts at initial_pose"
        return response

    def _publish_diagnostics(self) -> None:
        self.pub_diag.publish(self.processor.diagnostics(self.get_clock().now().to_msg()))

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        depth = self.settings.input == "depth"
        while not self._slot.closed:
            item = self._slot.take(timeout=0.2)
            if item is None:
                continue
            msg, received = item
            try:
                if depth:
                    if not self.processor.has_camera_info:
                        # hold a valid image until its CameraInfo arrives (unless a newer image replaces it)
                        if not self.processor.check_depth_image(msg):
                            continue
                        if not self._slot.put_back(item):
                            self.processor.note_dropped()
                        self._camera_info_event.wait(0.2)
                        continue
                    out = self.processor.process_depth(msg, receive_time=received)
                else:
                    out = self.processor.process_pointcloud(msg, receive_time=received)
                if out is None:
                    continue
                if not rclpy.ok(context=self.context):
                    break
                self.pub_odom.publish(out.odometry)
                if self.pub_tf is not None and out.tf is not None:
                    self.pub_tf.publish(out.tf)
                if self.pub_path.get_subscription_count() > 0 and self._path_due(out.stamp):
                    self.pub_path.publish(out.path)  # ~3.7 ms for 1,000 poses: only when wanted
            except Exception as err:  # never let one frame kill the node
                if self._slot.closed:
                    break
                self.get_logger().error(f"frame failed: {err}\n{traceback.format_exc()}")
                self.processor.note_failure(f"{type(err).__name__}: {err}")

    def _path_due(self, stamp: float) -> bool:
        """path.period seconds of stamps since the last path sent (always after a stamp went backwards)."""
        last = self._last_path_stamp
        if last is not None and last <= stamp < last + self.processor.settings.path_period:
            return False
        self._last_path_stamp = stamp
        return True

    def shutdown(self) -> None:
        self._slot.close()
        self._camera_info_event.set()
        if self._worker.is_alive():
            self._worker.join(timeout=5.0)


def main(args=None) -> int:
    """Console script ``node``: start, log the parameters, spin; exit 0 on Ctrl-C / SIGTERM, 2 on a bad
    parameter (with the reason, no traceback)."""
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = LineOdomNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except ParameterSetupError as err:
        rclpy.logging.get_logger(NODE_NAME).fatal(f"bad parameter: {err}")
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        # Ctrl-C / SIGTERM: rclpy's signal handler shuts the context down from another thread, and an executor
        # building its wait set at that moment raises this instead of ExternalShutdownException (ros2/rclpy#398).
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.shutdown()
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - the context may already be gone at shutdown
                pass
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
