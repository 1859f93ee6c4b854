"""Test harness for the node over real DDS: the node in its own process (``python -m line_odom.node``, the
console script's code) and an in-test rclpy participant that publishes inputs and collects the outputs.

Both use the shipped Fast DDS large-message profile (config/fastdds_large_messages.xml): without it,
best-effort KITTI-sized clouds are mostly lost between processes."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

from line_odom.replay_realtime import die_with_parent, spin_in_background

ROOT = Path(__file__).resolve().parents[1]
PROFILE = str(ROOT / "config" / "fastdds_large_messages.xml")
PROFILE_ENV = {"FASTDDS_DEFAULT_PROFILES_FILE": PROFILE, "FASTRTPS_DEFAULT_PROFILES_FILE": PROFILE,
               "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}


def use_large_message_profile() -> None:
    """Fast DDS reads the profile once per process, at its first participant: call before any rclpy.init."""
    os.environ.update(PROFILE_ENV)


def with_profile(env: dict, large_message_profile: bool = True) -> dict:
    """`env` with the large-message profile set, or with every profile variable removed (Fast DDS's defaults)."""
    if large_message_profile:
        return {**env, **PROFILE_ENV}
    return {k: v for k, v in env.items() if k not in ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")}


def _ros_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_ros_value(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)
    return str(value)


class NodeProcess:
    """``python -m line_odom.node --ros-args -r __ns:=/<ns> -p k:=v ...`` (``module``: line_odom.lifecycle_node for
    the managed node); stop() sends SIGINT and checks the node exits 0 without a traceback."""

    def __init__(self, env: dict, params: dict | None = None, namespace: str | None = None,
                 extra_args: list[str] | None = None, module: str = "line_odom.node", large_message_profile: bool = True):
        self.namespace = namespace or "/t" + uuid.uuid4().hex[:8]
        args = [sys.executable, "-m", module, "--ros-args", "-r", f"__ns:={self.namespace}"]
        for key, value in (params or {}).items():
            args += ["-p", f"{key}:={_ros_value(value)}"]
        args += extra_args or []
        self.log = tempfile.NamedTemporaryFile("w+", prefix="line_odom_node_", suffix=".log", delete=False)
        self.proc = subprocess.Popen(args, cwd=str(ROOT), env=with_profile(env, large_message_profile), stdout=self.log,
                                     stderr=subprocess.STDOUT, preexec_fn=die_with_parent)

    def output(self) -> str:
        self.log.flush()
        return Path(self.log.name).read_text(errors="replace")

    def topic(self, name: str) -> str:
        return f"{self.namespace}/{name}"

    def wait_exit(self, timeout: float) -> int:
        return self.proc.wait(timeout=timeout)

    def stop(self, timeout: float = 20.0) -> str:
        """SIGINT like Ctrl-C; returns the log. Asserts a clean exit."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise AssertionError("node did not exit within %.0f s of SIGINT:\n%s" % (timeout, self.output()))
        out = self.output()
        assert self.proc.returncode == 0, f"node exited with {self.proc.returncode}:\n{out}"
        assert "Traceback" not in out, out
        os.unlink(self.log.name)
        return out

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class Harness:
    """An rclpy participant in its own context with a background executor: publishers for the node's inputs,
    subscribers collecting its outputs (odom, path, /tf, /diagnostics)."""

    def __init__(self, node_ns: str):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry, Path as PathMsg
        from tf2_msgs.msg import TFMessage

        self.ns = node_ns
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("node_test_harness_" + uuid.uuid4().hex[:6], context=self.context)
        self.lock = threading.RLock()
        self.odom: list = []
        self.paths: list = []
        self.tf: list = []
        self.diagnostics: list = []
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(Odometry, f"{node_ns}/odom", self._collect(self.odom), reliable)
        self.node.create_subscription(PathMsg, f"{node_ns}/path", self._collect(self.paths), reliable)
        # /tf and /diagnostics are global: keep only this node's messages
        self.node.create_subscription(TFMessage, "/tf", self._collect(self.tf), reliable)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._collect(self.diagnostics), reliable)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop_spinning = spin_in_background(self.executor)

    def _collect(self, target: list):
        def callback(msg):
            with self.lock:
                target.append(msg)
        return callback

    def publisher(self, msg_type, topic: str, reliable: bool = False, depth: int = 10):
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE if reliable else
                         ReliabilityPolicy.BEST_EFFORT)
        return self.node.create_publisher(msg_type, topic, qos)

    def wait_for(self, predicate, timeout: float, what: str, node: NodeProcess | None = None):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                value = predicate()
            if value:
                return value
            if node is not None and node.proc.poll() is not None:
                raise AssertionError(f"node exited ({node.proc.returncode}) while waiting for {what}:\n"
                                     f"{node.output()}")
            time.sleep(0.02)
        log = node.output() if node is not None else ""
        raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}\n{log[-6000:]}")

    def wait_matched(self, publisher, node: NodeProcess, timeout: float = 60.0) -> None:
        """Until the node subscribes to `publisher` and our subscribers see its odom and path publishers."""
        self.wait_for(lambda: publisher.get_subscription_count() > 0, timeout,
                      f"the node to subscribe to {publisher.topic_name}", node)
        self.wait_for(lambda: self.node.count_publishers(f"{self.ns}/odom") > 0
                      and self.node.count_publishers(f"{self.ns}/path") > 0, timeout,
                      "the node's odom/path publishers", node)
        time.sleep(0.3)  # let the discovery of the reverse direction settle

    def odom_at(self, stamp_ns: int):
        from line_odom.convert import stamp_to_ns

        for msg in self.odom:
            if stamp_to_ns(msg.header.stamp) == stamp_ns:
                return msg
        return None

    def tf_at(self, stamp_ns: int):
        from line_odom.convert import stamp_to_ns

        for msg in self.tf:
            for t in msg.transforms:
                if stamp_to_ns(t.header.stamp) == stamp_ns:
                    return t
        return None

    def diagnostics_values(self):
        """This node's latest diagnostics status and its key -> value pairs."""
        with self.lock:
            msgs = list(self.diagnostics)
        for msg in reversed(msgs):
            for status in msg.status:
                if status.name == f"{self.ns}/line_odom: odometry":
                    return status, {kv.key: kv.value for kv in status.values}
        return None, {}

    def close(self) -> None:
        self._stop_spinning()
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def pose_matrix(pose) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    q = pose.orientation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return T


def transform_matrix(tf) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    q = tf.rotation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return T


def transform_stamped(parent: str, child: str, T: np.ndarray):
    """geometry_msgs/TransformStamped parent -> child of a 4x4 T_parent_child (for /tf_static)."""
    from geometry_msgs.msg import TransformStamped
    from scipy.spatial.transform import Rotation

    ts = TransformStamped()
    ts.header.frame_id, ts.child_frame_id = parent, child
    ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = (float(v) for v in T[:3, 3])
    r = ts.transform.rotation
    r.x, r.y, r.z, r.w = (float(v) for v in Rotation.from_matrix(T[:3, :3]).as_quat())
    return ts
