"""`line_odom replay --realtime`: the node in its own process, the bag published over DDS at its own rate.

The node (``python -m line_odom.node``) runs with ``use_sim_time``; this process publishes /clock and the bag's
sensor messages (already serialized: no decode/encode on the way) at the pace of their log times, and records
the node's Odometry. Latency per frame = arrival of the Odometry - publication of its input (wall clock).
Frames the node skips because it fell behind show up as ``frames_dropped``.
"""
from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from line_odom import bags, evaluation, frames as frames_mod
from line_odom.replay_common import PRESET_FOR_INPUT, ReplayRun, node_settings

NODE_OUTPUT_TOPIC = "/odom"
STARTUP_TIMEOUT_S = 60.0
DRAIN_TIMEOUT_S = 10.0


def _fastdds_profile() -> str | None:
    from line_odom_core.config import config_search_dirs

    for d in config_search_dirs():
        candidate = Path(d) / "fastdds_large_messages.xml"
        if candidate.is_file():
            return str(candidate)
    return None


def _ros_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_ros_value(v) for v in value) + "]"
    return str(value)


def node_command(inp, preset_or_params: str, overrides: Mapping[str, Any], guess_topic: str | None = None,
                 imu_topic: str | None = None) -> list[str]:
    cmd = [sys.executable, "-m", "line_odom.node", "--ros-args", "-p", f"preset:={preset_or_params}",
           "-p", "use_sim_time:=true", "-p", f"input:={inp.kind}", "-p", "publish_tf:=false"]
    for name, value in overrides.items():
        cmd += ["-p", f"{name}:={_ros_value(value)}"]
    if inp.kind == "pointcloud":
        cmd += ["-r", f"points:={inp.topic}"]
    else:
        cmd += ["-r", f"depth/image:={inp.topic}", "-r", f"depth/camera_info:={inp.info_topic}"]
    if guess_topic:
        cmd += ["-r", f"guess_odom:={guess_topic}"]
    if imu_topic:
        cmd += ["-r", f"imu:={imu_topic}"]
    cmd += ["-r", f"odom:={NODE_OUTPUT_TOPIC}"]
    return cmd


def _sensor_in_base(reader: bags.BagReader, inp, settings) -> tuple[np.ndarray, list[bytes]]:
    """(T_base_sensor the node will use, the bag's /tf_static messages to publish when it takes it from there)."""
    if not settings.base_to_sensor_from_tf:
        return frames_mod.pose_from_params(settings.base_to_sensor, "base_to_sensor"), []
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image, PointCloud2
    from tf2_msgs.msg import TFMessage

    from line_odom.static_tf import StaticTransforms

    tree, static = StaticTransforms(), []
    for message in reader.messages([bags.TF_STATIC_TOPIC]):
        static.append(message.raw)
        tree.add(deserialize_message(message.raw, TFMessage))
    first = next(iter(reader.messages([inp.topic])))
    frame_id = deserialize_message(first.raw, PointCloud2 if inp.kind == "pointcloud" else Image).header.frame_id
    T = tree.lookup(settings.base_frame, frame_id)
    if T is None:
        raise ValueError(f"{reader.path}: base_to_sensor_from_tf is set but {bags.TF_STATIC_TOPIC} has no transform "
                         f"{settings.base_frame} -> {frame_id} (the frame of {inp.topic})")
    return T, static


def header_stamp_ns(raw: bytes) -> int:
    """header.stamp of a serialized message that starts with a std_msgs/Header (PointCloud2, Image): the CDR
    encapsulation (4 bytes, byte 1 = 1 for little endian) is followed by int32 sec and uint32 nanosec."""
    order = "<" if raw[1] == 1 else ">"
    sec, nanosec = struct.unpack_from(order + "iI", raw, 4)
    return sec * 1_000_000_000 + nanosec


def die_with_parent() -> None:
    """In a child before exec: SIGTERM it when the process that started it dies (a killed replay or test leaves
    no node behind)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def spin_in_background(executor):
    """Spins `executor` on a daemon thread (spin_once, 50 ms waits) until the returned stop() is called. stop() joins
    the thread, so nothing waits on the executor's nodes when they are torn down: rclpy's executor.shutdown()
    returns while executor.spin() may still be inside such a wait."""
    spinning = threading.Event()
    spinning.set()

    def spin():
        while spinning.is_set():
            try:
                executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - the context shut down under the wait
                if spinning.is_set():
                    raise

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()

    def stop() -> None:
        spinning.clear()
        thread.join(timeout=5.0)

    return stop


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _tail(path: Path, lines: int = 5) -> str:
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return " | ".join(text[-lines:])


def _start_node(inp, preset: str, overrides: Mapping[str, Any], guess_topic: str | None,
                imu_topic: str | None) -> tuple[subprocess.Popen, Path]:
    """The node in its own process (its output into a temporary log file, read for errors)."""
    profile = _fastdds_profile()
    if profile and "FASTDDS_DEFAULT_PROFILES_FILE" not in os.environ:
        os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = profile
        os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", profile)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    log_file = Path(tempfile.mkstemp(prefix="line_odom_node_", suffix=".log")[1])
    with open(log_file, "wb") as log:
        proc = subprocess.Popen(node_command(inp, preset, overrides, guess_topic, imu_topic), env=env, stdout=log,
                                stderr=subprocess.STDOUT, preexec_fn=die_with_parent)
    return proc, log_file


class _BagPublishers:
    """The replaying node's publishers of what the bag holds for the node: /clock, the sensor topic (and its camera
    info), the guess and IMU topics; /tf_static latched, as robot_state_publisher does."""

    def __init__(self, node, inp, guess_topic: str | None, imu_topic: str | None, static_tf: list[bytes]):
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import CameraInfo, Image, Imu, PointCloud2

        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.clock_type = Clock
        self.clock = node.create_publisher(Clock, "/clock", 10)
        self.data = node.create_publisher(PointCloud2 if inp.kind == "pointcloud" else Image, inp.topic, reliable)
        self.by_topic = {inp.topic: self.data}
        if inp.info_topic:
            self.by_topic[inp.info_topic] = node.create_publisher(CameraInfo, inp.info_topic, reliable)
        if guess_topic:
            self.by_topic[guess_topic] = node.create_publisher(
                Odometry, guess_topic, QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        if imu_topic:
            self.by_topic[imu_topic] = node.create_publisher(
                Imu, imu_topic, QoSProfile(depth=400, reliability=ReliabilityPolicy.RELIABLE))
        self.inputs = [(self.data, inp.topic)] + [(self.by_topic[t], t) for t in (guess_topic, imu_topic) if t]
        if static_tf:
            from rclpy.qos import DurabilityPolicy
            from tf2_msgs.msg import TFMessage

            static_pub = node.create_publisher(TFMessage, bags.TF_STATIC_TOPIC, QoSProfile(
                depth=len(static_tf), reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL))
            for raw in static_tf:
                static_pub.publish(raw)

    def topics(self) -> list[str]:
        return list(self.by_topic)

    def publish_clock(self, log_time_ns: int) -> None:
        clock = self.clock_type()
        clock.clock.sec, clock.clock.nanosec = divmod(int(log_time_ns), 1_000_000_000)
        self.clock.publish(clock)


def _wait_until_connected(proc: subprocess.Popen, log_file: Path, pubs: _BagPublishers, sub) -> None:
    """Until the node subscribes to every input and publishes its output; an error naming what is missing when it
    exits first or does not connect within STARTUP_TIMEOUT_S."""
    def not_connected() -> list[str]:
        missing = [f"no subscription to {topic}" for pub, topic in pubs.inputs if pub.get_subscription_count() < 1]
        return missing + ([f"no publisher of {NODE_OUTPUT_TOPIC}"] if sub.get_publisher_count() < 1 else [])

    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while missing := not_connected():
        if proc.poll() is not None:
            raise RuntimeError(f"the node exited with code {proc.returncode} before subscribing: {_tail(log_file)}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"the node is not connected within {STARTUP_TIMEOUT_S:.0f} s "
                               f"({', '.join(missing)}): {_tail(log_file)}")
        time.sleep(0.05)
    time.sleep(0.5)  # let discovery settle in both directions


def _play(reader: bags.BagReader, inp, pubs: _BagPublishers, total: int, rate: float, proc: subprocess.Popen,
          log_file: Path, progress) -> tuple[dict[int, float], int]:
    """The bag's messages for the node published at `rate` x their log times' pace, /clock before each: the wall
    time each sensor message went out, by its header stamp, and how many went out."""
    published: dict[int, float] = {}
    n_in = 0
    wall0 = bag0 = None
    for message in reader.messages(pubs.topics()):
        if n_in >= total:
            break
        if wall0 is None:
            wall0, bag0 = time.monotonic(), message.log_time_ns
        delay = wall0 + (message.log_time_ns - bag0) * 1e-9 / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if proc.poll() is not None:
            raise RuntimeError(f"the node exited with code {proc.returncode} during the replay: {_tail(log_file)}")
        pubs.publish_clock(message.log_time_ns)
        if message.topic != inp.topic:
            pubs.by_topic[message.topic].publish(message.raw)
            continue
        published[header_stamp_ns(message.raw)] = time.monotonic()
        pubs.data.publish(message.raw)
        n_in += 1
        if progress is not None:
            progress.update(n_in, total)
    return published, n_in


def run_realtime(reader: bags.BagReader, inp, *, params: str | None = None,
                 overrides: Mapping[str, Any] | None = None, frames: int | None = None, progress=None,
                 rate: float = 1.0, guess_topic: str | None = None, imu_topic: str | None = None):
    """Publish the bag at `rate` x its own pace (like `ros2 bag play --rate`) to the node in its own process
    (guess_topic: a nav_msgs/Odometry topic published with it, the node's guess_odom; imu_topic: a sensor_msgs/Imu
    topic published with it, the node's imu)."""
    if not (rate > 0.0 and rate < float("inf")):
        raise ValueError(f"rate: expected a positive factor, got {rate}")
    import rclpy
    from nav_msgs.msg import Odometry
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile

    from line_odom import convert

    preset = params or PRESET_FOR_INPUT[inp.kind]
    overrides = dict(overrides or {})
    T_base_sensor, static_tf = _sensor_in_base(reader, inp, node_settings(inp.kind, params, overrides)[1])
    total = reader.counts.get(inp.topic, 0)
    if frames is not None:
        total = min(total, frames)
    proc, log_file = _start_node(inp, preset, overrides, guess_topic, imu_topic)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("line_odom_replay", context=context)
    executor = SingleThreadedExecutor(context=context)
    received: dict[int, tuple[float, Any]] = {}
    lock = threading.Lock()

    def on_odom(msg):
        now = time.monotonic()
        with lock:
            received[convert.stamp_to_ns(msg.header.stamp)] = (now, msg)

    pubs = _BagPublishers(node, inp, guess_topic, imu_topic, static_tf)
    sub = node.create_subscription(Odometry, NODE_OUTPUT_TOPIC, on_odom, QoSProfile(depth=1000))
    executor.add_node(node)
    stop_spinning = spin_in_background(executor)
    published: dict[int, float] = {}
    n_in = 0
    try:
        _wait_until_connected(proc, log_file, pubs, sub)
        published, n_in = _play(reader, inp, pubs, total, rate, proc, log_file, progress)
        drain_until = time.monotonic() + DRAIN_TIMEOUT_S
        while time.monotonic() < drain_until:
            with lock:
                if len(received) >= n_in:
                    break
            time.sleep(0.05)
    finally:
        stop_spinning()
        _stop(proc)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.shutdown(context=context)
    log_file.unlink(missing_ok=True)
    with lock:
        items = sorted(received.items())
    return _replay_run(items, published, n_in, T_base_sensor)


def _replay_run(items, published: dict[int, float], n_in: int, T_base_sensor: np.ndarray) -> ReplayRun:
    """The node's Odometry messages (by stamp: arrival wall time, message) as the base's trajectory and the latency of
    each frame (arrival - publication of its input)."""
    stamps, poses, msgs, latencies = [], [], [], []
    for stamp_ns, (arrival, msg) in items:
        _, T = bags.odometry_to_pose(msg)
        stamps.append(stamp_ns * 1e-9)
        poses.append(T @ T_base_sensor)
        msgs.append((stamp_ns, msg))
        if stamp_ns in published:
            latencies.append(1e3 * (arrival - published[stamp_ns]))
    estimate = evaluation.Trajectory(np.array(poses).reshape(-1, 4, 4), np.array(stamps, dtype=float))
    return ReplayRun(estimate, msgs, latencies, n_in, {"frames_published": n_in, "frames_received": len(items)})
