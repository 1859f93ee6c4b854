"""rclpy node: ``ros2 run line_odom node`` (or ``python -m line_odom.node``); the managed variant is
line_odom.lifecycle_node.

Subscribes ``points`` (PointCloud2) or ``depth/image`` + ``depth/camera_info``, and ``initialpose``; publishes ``odom``
(nav_msgs/Odometry), ``path`` (nav_msgs/Path), ``/tf`` (tf2_msgs/TFMessage), ``/diagnostics`` and, while subscribed,
``~/scan`` (the registered scan, PointCloud2); serves ``~/reset``
(std_srvs/Trigger). A frame goes: subscription callback -> LatestSlot (the newest message wins; a replaced one is
counted as dropped) -> the worker thread -> OdometryProcessor (convert, fuse, register, base pose, messages; the
engine releases the GIL) -> publish.
"""
from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
import time

import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks, UnsupportedEventTypeError
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2
from std_srvs.srv import Trigger

from line_odom.node_parameters import NODE_PARAMETERS, NodeSettings
from line_odom.processor import OdometryProcessor
from line_odom_core.config import CHOICES, config_schema, load_config

NODE_NAME = "line_odom"
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
# Requests a service holds before answering: a burst of callers (a launch file resetting several nodes, a test rig)
# beyond the default depth of 10 would lose requests. Every caller gets its answer up to this many at once.
SERVICE_QUEUE_DEPTH = 100
EXIT_BAD_PARAMETER = 2


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
            self._item = None
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


class UndeclaredParameterError(ParameterNotDeclaredException):
    """rclpy's own message for this lists no name; this one names them."""

    def __init__(self, names: list[str]):
        Exception.__init__(self, f"no parameter {', '.join(repr(n) for n in names)} on this node (line_odom declares "
                                 f"its parameters at start-up; list them with ros2 param list)")


def _one_line(text: str) -> str:
    return re.sub(r"\s*\n\s*", "; ", str(text).strip())


class OdometryNodeBase:
    """What the plain and the managed node share, on top of an rclpy Node: parameters (declared once, read-only
    afterwards), and the interfaces of a running odometry (started by ``start_odometry``, torn down by
    ``stop_odometry``)."""

    processor: OdometryProcessor | None = None
    _worker: threading.Thread | None = None

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

    def _declare(self, name, default, descriptor):
        if self.has_parameter(name):  # a managed node configured again reads the values it declared
            return self.get_parameter(name).value
        try:
            return self.declare_parameter(name, default, descriptor).value
        except Exception as err:  # rclpy raises several exception types for bad overrides
            raise ParameterSetupError(f"parameter {name!r}: {_one_line(err)}") from None

    def declare_and_load(self) -> None:
        """Declares every parameter (the preset gives the defaults), reads them into ``self.settings`` and
        ``self.config``; ParameterSetupError naming the parameter or file when one is bad."""
        preset = self._declare("preset", "kitti_hdl64", _descriptor(
            "preset", ParameterType.PARAMETER_STRING,
            "engine + node defaults: a preset name (kitti_hdl64, tum_kinect, vlp16, ouster_os128) or a ROS 2 "
            "parameter YAML path; individual parameters override it"))
        try:
            base = load_config(preset)
        except Exception as err:  # noqa: BLE001 - YAML syntax, encoding, I/O and schema errors alike: one line
            raise ParameterSetupError(f"parameter 'preset' ({preset!r}): {_one_line(err)}") from None
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
                                                desc)
        try:
            self.settings = NodeSettings.from_mapping(node_values)
        except ValueError as err:
            raise ParameterSetupError(str(err)) from None

        engine_values = {}
        for e in schema:
            ptype = _PTYPES[e.type]
            constraints = ("one of " + ", ".join(CHOICES[e.name])) if e.name in CHOICES else ""
            desc = _descriptor(e.name, ptype, e.description, e.min, e.max, constraints, integer=e.type is int)
            engine_values[e.name] = self._declare(e.name, base[e.name], desc)
        try:
            self.config = load_config(preset, engine_values)
        except ValueError as err:
            raise ParameterSetupError(str(err)) from None

        declared = {"preset", "use_sim_time"} | set(node_values) | set(engine_values)
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        stray = sorted(n for n in overrides if n not in declared and not n.startswith("qos_overrides."))
        if stray:
            self.get_logger().warning(f"ignoring unknown parameters {stray} (typo?)")
        if not getattr(self, "_parameter_guards", False):
            self.add_pre_set_parameters_callback(self._refuse_undeclared)
            self.add_on_set_parameters_callback(self._refuse_change)
            self._parameter_guards = True

    def _refuse_undeclared(self, parameters: list[Parameter]) -> list[Parameter]:
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            raise UndeclaredParameterError(unknown)
        return parameters

    def _refuse_change(self, parameters: list[Parameter]) -> SetParametersResult:
        """No parameter is applied live (the engine, the subscriptions and the clock are built from them once):
        a change at runtime, use_sim_time included, is refused naming it rather than accepted and ignored."""
        names = ", ".join(p.name for p in parameters)
        return SetParametersResult(successful=False, reason=(
            f"{names}: read-only while the node runs (line_odom reads its parameters once, at start-up; restart it "
            f"with the new value, e.g. -p {parameters[0].name}:=...)" if parameters else "no parameter given"))

    def log_parameters(self) -> None:
        lines = [f"  preset = {self.config.source}"]
        lines += [f"  {k} = {v}" for k, v in self.settings.as_dict().items()]
        lines += [f"  {k} = {v}" for k, v in self.config.as_dict().items()]
        lines.append(f"  use_sim_time = {self.get_parameter('use_sim_time').value}")
        self.get_logger().info("parameters:\n" + "\n".join(lines))

    # ------------------------------------------------------------------ running
    def make_processor(self) -> OdometryProcessor:
        try:
            processor = OdometryProcessor(self.config, self.settings, logger=self.get_logger())
        except ValueError as err:  # the engine rejected a setting
            raise ParameterSetupError(f"the engine rejected the settings: {err}") from None
        processor.diagnostic_name = f"{self.get_fully_qualified_name()}: odometry"
        return processor

    def start_odometry(self, publisher_factory=None) -> list[str]:
        """Creates the publishers, subscriptions, service and timer, starts the worker; returns what it subscribed."""
        s = self.settings
        create_pub = publisher_factory or self.create_publisher
        if s.qos_reliable:
            input_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=s.qos_depth,
                                   reliability=ReliabilityPolicy.RELIABLE)
        else:
            input_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=s.qos_depth,
                                   reliability=qos_profile_sensor_data.reliability,
                                   durability=qos_profile_sensor_data.durability)
        self._entities = []
        self.pub_odom = create_pub(Odometry, "odom", 10)
        self.pub_path = create_pub(Path, "path", QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                            durability=DurabilityPolicy.VOLATILE))
        self.pub_tf = None
        if s.publish_tf:
            from tf2_msgs.msg import TFMessage

            self.pub_tf = create_pub(TFMessage, "/tf", 100)
        self.pub_diag = create_pub(DiagnosticArray, "/diagnostics", 10)
        self.pub_scan = create_pub(PointCloud2, "~/scan", QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self._publishers_made = [p for p in (self.pub_odom, self.pub_path, self.pub_tf, self.pub_diag, self.pub_scan)
                                 if p]

        self._slot = LatestSlot()
        self._camera_info_event = threading.Event()
        subscribe = self._subscribe
        processor = self.processor
        if s.input == "pointcloud":
            self._subscribe_input(PointCloud2, "points", self._on_message, input_qos)
            inputs = [self.resolve_topic_name("points")]
        else:
            self._subscribe_input(Image, "depth/image", self._on_message, input_qos)
            self._subscribe_input(CameraInfo, "depth/camera_info", self._on_camera_info, input_qos)
            inputs = [self.resolve_topic_name("depth/image"), self.resolve_topic_name("depth/camera_info")]
        if s.guess_enabled:
            # best effort matches reliable and best-effort publishers; a lost pose only widens an interpolation
            guess_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                                   reliability=qos_profile_sensor_data.reliability)
            subscribe(Odometry, "guess_odom", processor.add_guess, guess_qos)
            inputs.append(self.resolve_topic_name("guess_odom") + " (motion guess)")
        if s.imu_enabled:
            # 100-400 Hz: a deep best-effort queue, so a registration holding the GIL briefly loses no sample
            imu_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=400,
                                 reliability=qos_profile_sensor_data.reliability)
            subscribe(Imu, "imu", processor.add_imu, imu_qos)
            inputs.append(self.resolve_topic_name("imu") + " (gyro rotation guess)")
        if s.base_to_sensor_from_tf:
            from tf2_msgs.msg import TFMessage

            # as tf2's static listener: reliable and transient local, so transforms latched before the start arrive
            static_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                                    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            subscribe(TFMessage, "/tf_static", processor.add_static_tf, static_qos)
            inputs.append(f"/tf_static ({s.base_frame} -> the input's frame)")
        # rviz's 2D Pose Estimate (reliable, like Nav2's initial pose publishers)
        subscribe(PoseWithCovarianceStamped, "initialpose", processor.set_initial_pose,
                  QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE))
        services = MutuallyExclusiveCallbackGroup()  # a service call never waits behind a subscription's callback
        self._entities.append(self.create_service(
            Trigger, "~/reset", self._on_reset, qos_profile=QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=SERVICE_QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.VOLATILE), callback_group=services))
        # the steady clock: under use_sim_time the ROS clock stands still until /clock ticks, and diagnostics must go on
        self._entities.append(self.create_timer(s.diagnostics_period, self._publish_diagnostics,
                                                clock=Clock(clock_type=ClockType.STEADY_TIME)))
        self._last_path_stamp: float | None = None
        self._worker = threading.Thread(target=self._work, name="line_odom_worker", daemon=True)
        self._worker.start()
        return inputs

    def _subscribe(self, msg_type, topic, callback, qos):
        self._entities.append(self.create_subscription(msg_type, topic, callback, qos))

    def _subscribe_input(self, msg_type, topic, callback, qos):
        """A sensor input, with DDS's reports of messages lost on the way counted (frames_lost_in_transport)."""
        name = self.resolve_topic_name(topic)
        events = SubscriptionEventCallbacks(
            message_lost=lambda info: self.processor.note_lost(int(info.total_count_change), name))
        try:
            self._entities.append(self.create_subscription(msg_type, topic, callback, qos, event_callbacks=events))
        except UnsupportedEventTypeError:  # an RMW that does not report lost messages: they stay uncounted
            self._subscribe(msg_type, topic, callback, qos)

    def log_ready(self, inputs: list[str]) -> None:
        s = self.settings
        self.get_logger().info(
            f"line_odom ready: input {s.input} on {', '.join(inputs)} "
            f"({'reliable' if s.qos_reliable else 'best effort (SensorDataQoS)'}), publishing "
            f"{self.resolve_topic_name('odom')}, {self.resolve_topic_name('path')}"
            f"{', /tf' if s.publish_tf else ''}, /diagnostics; {s.odom_frame} -> {s.base_frame}")

    def stop_odometry(self, destroy_publisher=None) -> None:
        """Stops the worker and destroys what start_odometry created."""
        slot = getattr(self, "_slot", None)
        if slot is not None:
            slot.close()
            self._camera_info_event.set()
        if self._worker is not None and self._worker.is_alive():
            self._worker.join(timeout=5.0)
        self._worker = None
        for entity in getattr(self, "_entities", []):
            kind = type(entity).__name__
            destroy = {"Subscription": self.destroy_subscription, "Service": self.destroy_service,
                       "Timer": self.destroy_timer}.get(kind)
            if destroy is not None:
                destroy(entity)
        self._entities = []
        for pub in getattr(self, "_publishers_made", []):
            (destroy_publisher or self.destroy_publisher)(pub)
        self._publishers_made = []

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
        slot, processor = self._slot, self.processor
        while not slot.closed:
            item = slot.take(timeout=0.2)
            if item is None:
                continue
            msg, received = item
            try:
                processor.scan_wanted = self.pub_scan.get_subscription_count() > 0
                if depth:
                    if not processor.has_camera_info:
                        # hold a valid image until its CameraInfo arrives (unless a newer image replaces it)
                        if not processor.check_depth_image(msg):
                            continue
                        if not slot.put_back(item):
                            processor.note_dropped()
                        self._camera_info_event.wait(0.2)
                        continue
                    out = processor.process_depth(msg, receive_time=received)
                else:
                    out = processor.process_pointcloud(msg, receive_time=received)
                del msg, item  # a large message is freed now, not when the next one replaces it
                if out is None:
                    continue
                if not rclpy.ok(context=self.context) or slot.closed:
                    break
                self.pub_odom.publish(out.odometry)
                if self.pub_tf is not None and out.tf is not None:
                    self.pub_tf.publish(out.tf)
                if self.pub_path.get_subscription_count() > 0 and self._path_due(out.stamp):
                    self.pub_path.publish(out.path)  # a long path costs milliseconds: only when wanted
                if out.scan is not None:
                    self.pub_scan.publish(out.scan)
            except Exception as err:  # a bug: never let one frame kill the node, and show where it is
                if slot.closed:
                    break
                import traceback

                self.get_logger().error(f"frame failed: {err}\n{traceback.format_exc()}")
                processor.note_failure(f"{type(err).__name__}: {err}")

    def _path_due(self, stamp: float) -> bool:
        """path.period seconds of stamps since the last path sent (always after a stamp went backwards)."""
        last = self._last_path_stamp
        if last is not None and last <= stamp < last + self.settings.path_period:
            return False
        self._last_path_stamp = stamp
        return True


class LineOdomNode(OdometryNodeBase, Node):
    def __init__(self, **kwargs):
        Node.__init__(self, NODE_NAME, **kwargs)
        self.declare_and_load()
        self.processor = self.make_processor()
        self.log_parameters()
        self.log_ready(self.start_odometry())

    def shutdown(self) -> None:
        self.stop_odometry()


# ---------------------------------------------------------------------------------------------- start-up


def _ros_arguments(argv: list[str]) -> list[str]:
    """The arguments between --ros-args and --/the end (every --ros-args section)."""
    out, inside = [], False
    for arg in argv:
        if arg == "--ros-args":
            inside = True
        elif arg == "--" and inside:
            inside = False
        elif inside:
            out.append(arg)
    return out


def check_parameter_files(argv: list[str]) -> None:
    """Each --params-file is a readable YAML mapping; ParameterSetupError naming the file otherwise (rcl's own
    error would name it too, but after a log line of its own and without saying what is wrong in plain words)."""
    args = _ros_arguments(argv)
    for i, arg in enumerate(args):
        if arg != "--params-file":
            continue
        if i + 1 >= len(args):
            raise ParameterSetupError("bad parameter file: --params-file without a file")
        path = args[i + 1]
        if not os.path.isfile(path):
            raise ParameterSetupError(f"bad parameter file: --params-file {path}: no such file")
        try:
            from line_odom_core.config import yaml_load

            with open(path, encoding="utf-8") as f:
                doc = yaml_load(f)
        except Exception as err:  # noqa: BLE001 - I/O, encoding and YAML errors alike: one line
            raise ParameterSetupError(f"bad parameter file: --params-file {path}: not a YAML file ({_one_line(err)})") from None
        if not isinstance(doc, dict):
            raise ParameterSetupError(f"bad parameter file: --params-file {path}: expected a ROS 2 parameter file (a mapping "
                                      f"'<node>: ros__parameters: ...'), got {type(doc).__name__}")


def init_rclpy(argv: list[str]) -> None:
    """rclpy.init with rcl's own error log line held back: a bad command line becomes one ParameterSetupError line
    naming the argument (a bad remapping, parameter rule or params file)."""
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            rclpy.init(args=argv)
            error = None
        except _rclpy.RCLError as err:
            error = err
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if error is None:
            captured.seek(0)
            sys.stderr.buffer.write(captured.read())  # rcl's warnings of a good start stay visible
            sys.stderr.flush()
            return
    text = re.sub(r"^failed to initialize rcl: ", "", str(error))
    text = re.sub(r"(, at /\S+:\d+)+", "", text)
    raise ParameterSetupError(f"bad command line: {_one_line(text)}")


def run(node_factory, args=None) -> int:
    """Start, spin; exit 0 on Ctrl-C / SIGTERM, 2 on a bad parameter, parameter file or remapping (one line, no
    traceback)."""
    argv = list(sys.argv if args is None else args)
    node = None
    code = 0
    try:
        check_parameter_files(argv)
        init_rclpy(argv)
        node = node_factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except ParameterSetupError as err:
        text = str(err) if str(err).startswith("bad ") else f"bad parameter: {err}"
        print(f"[FATAL] [{NODE_NAME}]: {text}", file=sys.stderr, flush=True)
        code = EXIT_BAD_PARAMETER
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


def main(args=None) -> int:
    """Console script ``node``."""
    return run(LineOdomNode, args)


if __name__ == "__main__":
    sys.exit(main())
