"""Soak benchmark: thousands of simulated LiDAR frames through the node over DDS at sensor rate.

    .venv/bin/python bench/soak.py                      # 5,000 frames at 10 Hz (~8.5 min)
    .venv/bin/python bench/soak.py --frames 300         # a quick look
    .venv/bin/python bench/soak.py --distortion --imu   # motion-distorted sweeps with point times, and a gyro

The node runs in its own process (``python -m line_odom.node``, what ``ros2 run line_odom node`` starts) with the
shipped vlp16 preset as it is (``--set`` overrides a parameter); this process renders a
simulated street drive (VLP-16 beams, ``--columns`` azimuth steps) on a background thread, publishes it as
PointCloud2 (best effort, the shipped Fast DDS large-message profile) on a fixed 10 Hz schedule, and collects
``odom`` and ``/diagnostics``. It prints frames in / out / dropped, end-to-end latency percentiles (publish to
Odometry received), the node's RSS at start and end (and its trend), NaN poses, crashes and the frame-to-frame
error against the simulator's ground truth. Not a test: a table to paste into docs/RESULTS.md.

``--distortion`` casts each sweep while the sensor moves and publishes each point's ``time`` (float32 s after the
stamp) for the node to deskew. ``--imu`` runs the node with ``imu.enabled`` and publishes a gyro synthesized from the
ground truth on ``imu`` (200 Hz, 0.1 deg/s white noise, a bias the node is not told, in the LiDAR's frame), its samples
interleaved with the scans in stamp order at real time: a scan is sent once its sweep is complete (one period after
its stamp), after the gyro samples up to then. The summary adds the deskew and gyro counters and the learned bias.
"""
from __future__ import annotations

import argparse
import collections
import datetime
import os
import platform
import queue
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "test"))

from node_harness import NodeProcess, pose_matrix, use_large_message_profile  # noqa: E402

STAMP0 = 100.0  # the first frame's stamp (s); frame k is stamped STAMP0 + k / rate
NODE_SETTINGS = {
    "preset": "vlp16",
    "publish_tf": True,
    "diagnostics.period": 1.0,
}


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def relative_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(T_true) @ T_est
    angle = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(E[:3, 3])), float(angle)


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=5000)
    ap.add_argument("--rate", type=float, default=10.0, help="sensor rate (Hz)")
    ap.add_argument("--columns", type=int, default=600, help="VLP-16 azimuth steps per revolution")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domain", type=int, default=90 + os.getpid() % 10, help="ROS_DOMAIN_ID")
    ap.add_argument("--distortion", action="store_true",
                    help="sweeps cast while the sensor moves, with each point's time field (deskewing)")
    ap.add_argument("--imu", action="store_true", help="a synthesized gyro on 'imu' (imu.enabled: true)")
    ap.add_argument("--imu-rate", type=float, default=200.0, help="gyro sample rate (Hz)")
    ap.add_argument("--imu-noise", type=float, default=0.1, help="gyro white noise per sample (deg/s)")
    ap.add_argument("--imu-bias", type=float, nargs=3, default=(0.1, -0.2, 0.5), metavar=("X", "Y", "Z"),
                    help="gyro bias the node is not told (deg/s, LiDAR axes)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="extra node/engine parameter (repeatable), e.g. --set registration.passes=2")
    return ap.parse_args()


def node_params(args: argparse.Namespace) -> dict:
    params = dict(NODE_SETTINGS)
    if args.imu:
        params["imu.enabled"] = True
    for item in args.set:
        key, _, value = item.partition("=")
        params[key] = type(params[key])(value) if key in params and not isinstance(params[key], bool) else (
            value == "true" if value in ("true", "false") else float(value) if "." in value else int(value)
            if value.lstrip("-").isdigit() else value)
    return params


class Drive:
    """The simulated street drive: its frames, ground-truth poses and (with --imu) gyro samples, stamped from
    STAMP0 at the sensor rate."""

    def __init__(self, args: argparse.Namespace):
        from line_odom import sim
        from line_odom.sim.gyro import gyro_samples

        self.run = sim.make("street", frames=args.frames, seed=args.seed, rate_hz=args.rate,
                            sensor=sim.Lidar.vlp16(columns=args.columns, seed=args.seed, rate_hz=args.rate),
                            motion_distortion=args.distortion)
        self.truth = self.run.trajectory.poses
        self.gyro_stamps, self.gyro_rates = np.empty(0), np.empty((0, 3))
        if args.imu:  # up to the end of the last sweep, one period past the last stamp
            trajectory = self.run.trajectory
            end = trajectory.stamps[-1] + 1.0 / args.rate
            poses = np.concatenate([self.truth, trajectory.pose_at(end)[None]])
            self.gyro_stamps, self.gyro_rates = gyro_samples(
                poses, STAMP0 + np.r_[trajectory.stamps, end], rate_hz=args.imu_rate, offset=0.5 / args.imu_rate,
                noise_std=np.radians(args.imu_noise), bias=np.radians(args.imu_bias), seed=args.seed)

    def render_ahead(self, args: argparse.Namespace) -> queue.Queue:
        """The frames as PointCloud2 messages, rendered on a thread so the sensor-rate schedule does not wait for the
        ray caster: (index, message) items, then None."""
        from line_odom import convert

        frames_q: queue.Queue = queue.Queue(maxsize=50)

        def render():
            for i, frame in enumerate(self.run):
                msg = convert.pointcloud2_from_xyz(frame.data.points, ring=frame.data.ring, frame_id="velodyne",
                                                   time=frame.data.time if args.distortion else None,
                                                   stamp=STAMP0 + i / args.rate)
                frames_q.put((i, msg))
            frames_q.put(None)

        threading.Thread(target=render, daemon=True).start()
        return frames_q


class Listener:
    """The node's odom (by frame index: receive time, pose, every field finite) and its odometry diagnostics (the
    latest values, the levels seen)."""

    def __init__(self, part, node: NodeProcess, rate: float):
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from line_odom import convert

        self.convert = convert
        self.node, self.rate = node, rate
        self.lock = threading.Lock()
        self.received: dict[int, tuple[float, np.ndarray, bool]] = {}
        self.diag: dict[str, str] = {}
        self.levels = collections.Counter()
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        part.create_subscription(Odometry, f"{node.namespace}/odom", self.on_odom, reliable)
        part.create_subscription(DiagnosticArray, "/diagnostics", self.on_diag, reliable)

    def on_odom(self, msg) -> None:
        now = time.monotonic()
        k = int(round((self.convert.stamp_to_sec(msg.header.stamp) - STAMP0) * self.rate))
        values = np.r_[[msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z,
                        msg.pose.pose.orientation.x, msg.pose.pose.orientation.y, msg.pose.pose.orientation.z,
                        msg.pose.pose.orientation.w], msg.pose.covariance, msg.twist.covariance,
                       [msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.linear.z,
                        msg.twist.twist.angular.x, msg.twist.twist.angular.y, msg.twist.twist.angular.z]]
        finite = bool(np.isfinite(values).all())
        with self.lock:
            self.received[k] = (now, pose_matrix(msg.pose.pose) if finite else np.full((4, 4), np.nan), finite)

    def on_diag(self, msg) -> None:
        for status in msg.status:
            if status.name == f"{self.node.namespace}/line_odom: odometry":
                with self.lock:
                    self.diag.clear()
                    self.diag.update({kv.key: kv.value for kv in status.values})
                    self.levels[int.from_bytes(status.level, "little") if isinstance(status.level, bytes)
                                else int(status.level)] += 1

    def snapshot(self) -> tuple[dict, dict, dict]:
        with self.lock:
            return dict(self.received), dict(self.diag), dict(self.levels)


class Schedule:
    """Publishes the scans at the sensor rate, and (with --imu) the gyro samples at their own times before each scan
    whose sweep they cover; counts late ticks and samples, samples the node's RSS."""

    def __init__(self, args: argparse.Namespace, node: NodeProcess, pub, imu_pub, drive: Drive):
        from sensor_msgs.msg import Imu

        from line_odom import convert

        self.imu_type, self.convert = Imu, convert
        self.args, self.node, self.pub, self.imu_pub, self.drive = args, node, pub, imu_pub, drive
        self.period = 1.0 / args.rate
        self.published: dict[int, float] = {}
        self.rss_trend: list[tuple[int, float]] = []
        self.rss_start = float("nan")
        self.late_publishes = self.imu_sent = self.late_imu = 0
        self.crashed = False

    def send_imu_until(self, stamp: float, scan_due: float) -> None:
        """The gyro samples stamped up to `stamp`, each at its own time: scan_due (when the scan stamped one period
        before `stamp` goes out) less the sample's lead on `stamp`."""
        stamps, rates = self.drive.gyro_stamps, self.drive.gyro_rates
        while self.imu_sent < len(stamps) and stamps[self.imu_sent] <= stamp + 1e-9:
            due = scan_due - (stamp - stamps[self.imu_sent])
            now = time.monotonic()
            if now < due:
                time.sleep(due - now)
            elif now - due > self.period:
                self.late_imu += 1
            sample = self.imu_type()
            sample.header.stamp = self.convert.sec_to_stamp(float(stamps[self.imu_sent]))
            sample.header.frame_id = "velodyne"
            (sample.angular_velocity.x, sample.angular_velocity.y,
             sample.angular_velocity.z) = (float(v) for v in rates[self.imu_sent])
            sample.orientation_covariance[0] = -1.0  # a gyro: no orientation
            self.imu_pub.publish(sample)
            self.imu_sent += 1

    def run(self, frames_q: queue.Queue, listener: Listener) -> None:
        # with the gyro, the first scan goes out when its sweep is complete, its samples at their times before it
        t_next = time.monotonic() + (self.period if self.imu_pub is not None else 0.0)
        while (item := frames_q.get()) is not None:
            i, msg = item
            if self.imu_pub is not None:  # the sweep of scan i ends one period after its stamp: the gyro covered it
                self.send_imu_until(STAMP0 + (i + 1) / self.args.rate, t_next)
            now = time.monotonic()
            if now < t_next:
                time.sleep(t_next - now)
            elif now - t_next > self.period:
                self.late_publishes += 1
            t_next += self.period
            self.published[i] = time.monotonic()
            self.pub.publish(msg)
            if self.node.proc.poll() is not None:
                self.crashed = True
                break
            if i == 20:
                self.rss_start = rss_mb(self.node.proc.pid)
            if i % 250 == 0:
                self.rss_trend.append((i, rss_mb(self.node.proc.pid)))
                received, diag, _ = listener.snapshot()
                print(f"  frame {i:5d}: out {len(received):5d}, node RSS {self.rss_trend[-1][1]:.1f} MB, dropped "
                      f"{diag.get('frames_dropped', '?')}", flush=True)


def wait_for_node(node: NodeProcess, part, pub, imu_pub, frames_q: queue.Queue) -> None:
    """Until the node subscribes to the scans (and the gyro) and publishes odom, then a head start for the renderer."""
    deadline = time.monotonic() + 90
    while (pub.get_subscription_count() == 0 or part.count_publishers(f"{node.namespace}/odom") == 0
           or (imu_pub is not None and imu_pub.get_subscription_count() == 0)):
        if node.proc.poll() is not None or time.monotonic() > deadline:
            print(node.output())
            raise SystemExit("node did not come up")
        time.sleep(0.1)
    time.sleep(1.0)
    while frames_q.qsize() < 20:
        time.sleep(0.1)


def frame_to_frame_errors(got: dict, truth: np.ndarray) -> tuple[list[int], list[float], list[float]]:
    """Between consecutive received frames with finite poses: the frames, translation (m) and rotation (deg) errors
    against the ground truth."""
    ks = sorted(k for k in got if got[k][2])
    t_err, r_err = [], []
    for a, b in zip(ks, ks[1:]):
        e = relative_error(np.linalg.inv(got[a][1]) @ got[b][1], np.linalg.inv(truth[a]) @ truth[b])
        t_err.append(e[0])
        r_err.append(e[1])
    return ks, t_err, r_err


def print_summary(args: argparse.Namespace, schedule: Schedule, got: dict, final_diag: dict, levels: dict,
                  rss_end: float, crashed: bool, truth: np.ndarray) -> int:
    published = schedule.published
    latencies = np.array([(got[k][0] - published[k]) * 1e3 for k in got if k in published])
    nan_poses = sum(1 for v in got.values() if not v[2])
    ks, t_err, r_err = frame_to_frame_errors(got, truth)
    n_in, n_out = len(published), len(got)
    print()
    print(f"soak results ({datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.node()}, "
          f"{os.cpu_count()} cores, python {platform.python_version()})")
    print(f"  frames in (published)        {n_in}")
    print(f"  frames out (Odometry)        {n_out}")
    print(f"  lost (in - out)              {n_in - n_out}")
    print(f"  node frames_received         {final_diag.get('frames_received', '?')}")
    print(f"  node frames_processed        {final_diag.get('frames_processed', '?')}")
    print(f"  node frames_dropped          {final_diag.get('frames_dropped', '?')} (latest-wins replacements)")
    print(f"  node malformed/failed/dup    {final_diag.get('frames_malformed', '?')}/"
          f"{final_diag.get('frames_failed', '?')}/{final_diag.get('frames_duplicate', '?')}")
    print(f"  publisher late ticks         {schedule.late_publishes}")
    if latencies.size:
        print(f"  latency ms p50/p95/max       {np.percentile(latencies, 50):.1f} / {np.percentile(latencies, 95):.1f} / "
              f"{latencies.max():.1f}   (publish -> Odometry received, end to end)")
    print(f"  node latency ms mean/p95     {final_diag.get('latency_ms_mean', '?')} / "
          f"{final_diag.get('latency_ms_p95', '?')}   (receive -> processed, last 200 frames)")
    rss_start = schedule.rss_start
    print(f"  node RSS MB start/end        {rss_start:.1f} / {rss_end:.1f}  (growth {rss_end - rss_start:+.1f} MB; "
          f"start = after frame 20)")
    print("  node RSS trend MB            " + ", ".join(f"{i}:{m:.0f}" for i, m in schedule.rss_trend))
    print(f"  NaN poses                    {nan_poses}")
    print(f"  crashes                      {int(crashed)}")
    print(f"  diagnostics levels seen      {levels}  (0 OK, 1 WARN, 2 ERROR)")
    if args.distortion:
        expected_deskewed = n_in if args.imu else n_in - 2
        print(f"  node frames_deskewed         {final_diag.get('frames_deskewed', '?')} (expected {expected_deskewed}: "
              f"{'all, the first by the gyro' if args.imu else 'the first two (no velocity yet) as measured'})")
        print(f"  node point_times_ignored     {final_diag.get('point_times_ignored', '?')}")
    if args.imu:
        print(f"  gyro samples sent / late     {schedule.imu_sent} / {schedule.late_imu}")
        print(f"  node frames_imu              {final_diag.get('frames_imu', '?')} (every scan after the first)")
        print(f"  node frames_without_imu      {final_diag.get('frames_without_imu', '?')}")
        print(f"  node imu_rejected            {final_diag.get('imu_rejected', '?')}")
        print(f"  node sweeps_without_gyro     {final_diag.get('sweeps_without_gyro', '?')} (sweeps the gyro did not "
              f"cover{'' if args.distortion else '; no point times, so none asked'})")
        print(f"  node imu_samples (kept)      {final_diag.get('imu_samples', '?')}")
        print(f"  node gyro_bias deg/s         {final_diag.get('gyro_bias', '?')}  (true "
              f"{' '.join(f'{v:.4f}' for v in args.imu_bias)}, not told)")
        print(f"  node prediction (last)       {final_diag.get('prediction', '?')}")
    if final_diag.get("last_error"):
        print(f"  node last_error              {final_diag['last_error']}")
    if t_err:
        print(f"  frame-to-frame error         mean {np.mean(t_err):.4f} m / {np.mean(r_err):.3f} deg, "
              f"max {np.max(t_err):.3f} m / {np.max(r_err):.2f} deg")
        dist = sum(np.linalg.norm(truth[b][:3, 3] - truth[a][:3, 3]) for a, b in zip(ks, ks[1:]))
        T_end_err = np.linalg.inv(np.linalg.inv(truth[ks[0]]) @ truth[ks[-1]]) @ (
            np.linalg.inv(got[ks[0]][1]) @ got[ks[-1]][1])
        print(f"  end-point drift              {np.linalg.norm(T_end_err[:3, 3]):.2f} m over {dist:.0f} m")
    return nan_poses


def main() -> int:
    args = parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(args.domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ["PYTHONUNBUFFERED"] = "1"
    use_large_message_profile()

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, PointCloud2

    from line_odom.replay_realtime import spin_in_background

    params = node_params(args)
    drive = Drive(args)
    node = NodeProcess(dict(os.environ), params=params)
    ctx = Context()
    rclpy.init(context=ctx)
    part = rclpy.create_node("soak_" + str(os.getpid()), context=ctx)
    listener = Listener(part, node, args.rate)
    pub = part.create_publisher(PointCloud2, f"{node.namespace}/points",
                                QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
    imu_pub = (part.create_publisher(Imu, f"{node.namespace}/imu",
                                     QoSProfile(depth=400, reliability=ReliabilityPolicy.BEST_EFFORT))
               if args.imu else None)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(part)
    stop_spinning = spin_in_background(executor)
    frames_q = drive.render_ahead(args)

    inputs = (", motion-distorted sweeps with point times" if args.distortion else "") + (
        f", gyro {args.imu_rate:g} Hz noise {args.imu_noise:g} deg/s bias {tuple(args.imu_bias)} deg/s" if args.imu
        else "")
    print(f"soak: {args.frames} frames at {args.rate:g} Hz, VLP-16 x {args.columns} columns{inputs}, node "
          f"{node.namespace} (pid {node.proc.pid}), params {params}", flush=True)
    wait_for_node(node, part, pub, imu_pub, frames_q)
    schedule = Schedule(args, node, pub, imu_pub, drive)
    schedule.run(frames_q, listener)
    time.sleep(3.0)  # let the last frames through
    rss_end = rss_mb(node.proc.pid)
    got, final_diag, levels = listener.snapshot()
    crashed = schedule.crashed or node.proc.poll() is not None
    stop_spinning()
    log = ""
    try:
        log = node.stop()
    except AssertionError as err:
        crashed = True
        log = str(err)
    executor.shutdown()
    part.destroy_node()
    ctx.try_shutdown()

    nan_poses = print_summary(args, schedule, got, final_diag, levels, rss_end, crashed, drive.truth)
    if "Traceback" in log:
        print(log[-3000:])
    return 1 if crashed or nan_poses else 0


if __name__ == "__main__":
    sys.exit(main())
