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

import sys
import threading
import time

import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks, UnsupportedEventTypeError
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2
from visualization_msgs.msg import MarkerArray
from std_srvs.srv import Trigger

from line_odom.node_startup import EXIT_BAD_PARAMETER, NODE_NAME, run  # noqa: F401
from line_odom.processor import OdometryProcessor
from line_odom.ros_parameters import ParameterMixin, ParameterSetupError  # noqa: F401
# Requests a service holds before answering: a burst of callers (a launch file resetting several nodes, a test rig)
# beyond the default depth of 10 would lose requests. Every caller gets its answer up to this many at once.
SERVICE_QUEUE_DEPTH = 100


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


class OdometryNodeBase(ParameterMixin):
    """What the plain and the managed node share, on top of an rclpy Node: parameters (declared once, read-only
    afterwards), and the interfaces of a running odometry (started by ``start_odometry``, torn down by
    ``stop_odometry``)."""

    processor: OdometryProcessor | None = None
    _worker: threading.Thread | None = None

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
        self.pub_lines = create_pub(MarkerArray, "~/lines", QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self._publishers_made = [p for p in (self.pub_odom, self.pub_path, self.pub_tf, self.pub_diag, self.pub_scan,
                                             self.pub_lines) if p]

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
                processor.lines_wanted = self.pub_lines.get_subscription_count() > 0
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
                if out.lines is not None:
                    self.pub_lines.publish(out.lines)
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


def main(args=None) -> int:
    """Console script ``node``."""
    return run(LineOdomNode, args)


if __name__ == "__main__":
    sys.exit(main())
