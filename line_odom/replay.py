"""Replay a rosbag2 through the odometry node and evaluate the result.

Default (deterministic): the node's processing core (:class:`line_odom.processor.OdometryProcessor`, the code the
rclpy node runs in its callbacks) in this process, every frame in bag order as fast as possible. Messages are
deserialized with rclpy, so the core sees exactly the message objects the node gets from a subscription.

``realtime=True``: the node in its own process (``python -m line_odom.node``), messages published over DDS at
the bag's rate with /clock and ``use_sim_time``; see :mod:`line_odom.replay_realtime`.

Writes trajectory_tum.txt, trajectory_kitti.txt (the estimated sensor poses), ground_truth_tum.txt (when the bag
has ground truth), metrics.json, trajectory.png, and optionally an output bag with the node's Odometry and Path.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from line_odom import bags, convert, evaluation
from line_odom.progress import ProgressBar

PRESET_FOR_INPUT = {"pointcloud": "kitti_hdl64", "depth": "tum_kinect"}
ODOMETRY_TOPIC = "/odom"  # the node's output topics
PATH_TOPIC = "/path"


@dataclasses.dataclass
class ReplayInput:
    kind: str  # "pointcloud" or "depth"
    topic: str
    info_topic: str | None = None  # CameraInfo topic for depth


@dataclasses.dataclass
class ReplayRun:
    """What the node produced for a bag."""

    estimate: evaluation.Trajectory  # sensor poses at the frame stamps
    odometry_msgs: list  # (stamp_ns, nav_msgs/Odometry) as the node published them
    latencies_ms: list[float]
    frames_in: int
    counters: dict[str, int]


@dataclasses.dataclass
class ReplayResult:
    metrics: dict
    files: list[Path]
    run: ReplayRun
    ground_truth: evaluation.Trajectory | None


def select_input(reader: bags.BagReader, topic: str | None = None) -> ReplayInput:
    """The bag's sensor topic: the given one, else its only PointCloud2 topic, else its only depth Image topic."""
    listing = ", ".join(f"{t} ({m})" for t, m in sorted(reader.topics.items())) or "none"
    if topic is not None:
        msgtype = reader.topics.get(topic)
        if msgtype is None:
            raise ValueError(f"{reader.path}: no topic {topic} (topics: {listing})")
        if msgtype not in (bags.POINTCLOUD2, bags.IMAGE):
            raise ValueError(f"{reader.path}: topic {topic} is {msgtype}, expected {bags.POINTCLOUD2} or {bags.IMAGE}")
        candidates = [topic]
    else:
        candidates = reader.topics_of_type(bags.POINTCLOUD2) or reader.topics_of_type(bags.IMAGE)
        if not candidates:
            raise ValueError(f"{reader.path}: no PointCloud2 or depth Image topic to replay (topics: {listing})")
        if len(candidates) > 1:
            raise ValueError(f"{reader.path}: several sensor topics ({', '.join(candidates)}); choose one with --topic")
    chosen = candidates[0]
    if reader.counts.get(chosen, 0) == 0:
        raise ValueError(f"{reader.path}: topic {chosen} has no messages")
    if reader.topics[chosen] == bags.POINTCLOUD2:
        return ReplayInput("pointcloud", chosen)
    infos = reader.topics_of_type(bags.CAMERA_INFO)
    if not infos:
        raise ValueError(f"{reader.path}: depth topic {chosen} but no CameraInfo topic (topics: {listing})")
    # prefer the CameraInfo beside the image (same namespace)
    namespace = chosen.rsplit("/", 1)[0]
    info = next((t for t in infos if t.rsplit("/", 1)[0] == namespace), infos[0])
    return ReplayInput("depth", chosen, info)


def node_settings(kind: str, params: str | None = None, overrides: Mapping[str, Any] | None = None):
    """(engine Config, NodeSettings) for this input kind: the --params file, else the preset for the input kind."""
    from line_odom.processor import settings_from_parameters

    return settings_from_parameters(params or PRESET_FOR_INPUT[kind], {**(overrides or {}), "input": kind})


def _rclpy_types(kind: str):
    from sensor_msgs.msg import CameraInfo, Image, PointCloud2

    return {"pointcloud": PointCloud2, "depth": Image, "info": CameraInfo}


def run_in_process(reader: bags.BagReader, inp: ReplayInput, processor, *, frames: int | None = None,
                   progress: ProgressBar | None = None, guess_topic: str | None = None,
                   imu_topic: str | None = None) -> ReplayRun:
    """Every frame of the input topic through the processor, in bag order (with the nav_msgs/Odometry messages of
    guess_topic as the motion guess, guess.enabled, and the sensor_msgs/Imu messages of imu_topic as the gyro,
    imu.enabled)."""
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Imu

    types = _rclpy_types(inp.kind)
    total = reader.counts.get(inp.topic, 0)
    if frames is not None:
        total = min(total, frames)
    topics = [inp.topic] + ([inp.info_topic] if inp.info_topic else [])
    if inp.info_topic:  # the intrinsics before the first image, whatever the order in the bag
        for message in reader.messages([inp.info_topic]):
            processor.set_camera_info(deserialize_message(message.raw, types["info"]))
            break
    if processor.static_tf is not None:  # base_to_sensor_from_tf: the bag's static transforms, latched as in DDS
        from tf2_msgs.msg import TFMessage

        for message in reader.messages([bags.TF_STATIC_TOPIC]):
            processor.add_static_tf(deserialize_message(message.raw, TFMessage))
    if guess_topic:  # offline, every pose of the guess source is known: each frame's is interpolated, never
        for message in reader.messages([guess_topic]):  # extrapolated (guess.window: replay_bag keeps them all)
            processor.add_guess(deserialize_message(message.raw, Odometry))
    if imu_topic:  # so is every gyro sample (imu.window: replay_bag keeps them all)
        for message in reader.messages([imu_topic]):
            processor.add_imu(deserialize_message(message.raw, Imu))
    stamps, poses, odom_msgs, latencies = [], [], [], []
    n_in = 0
    for message in reader.messages(topics):
        if n_in >= total:
            break
        try:
            if message.topic == inp.info_topic:
                processor.set_camera_info(deserialize_message(message.raw, types["info"]))
                continue
            msg = deserialize_message(message.raw, types[inp.kind])
        except Exception as exc:  # rclpy raises its own error types for bad CDR
            raise bags.BagError(f"{reader.path}: cannot decode a {message.msgtype} message on {message.topic} "
                                f"at {message.log_time_ns} ns ({type(exc).__name__}: {exc})") from None
        n_in += 1
        processor.note_received()
        out = processor.process_pointcloud(msg) if inp.kind == "pointcloud" else processor.process_depth(msg)
        if out is not None:
            stamps.append(out.stamp)
            poses.append(out.T_odom_base @ processor.T_base_sensor)
            odom_msgs.append((message.log_time_ns, out.odometry))
            latencies.append(out.latency_ms)
        if progress is not None:
            progress.update(n_in, total)
    estimate = evaluation.Trajectory(np.array(poses).reshape(-1, 4, 4), np.array(stamps, dtype=float))
    return ReplayRun(estimate, odom_msgs, latencies, n_in, dict(processor.counters))


def write_output_bag(path: str | Path, run: ReplayRun, reader: bags.BagReader, storage: str = "sqlite3") -> Path:
    """The node's Odometry (every frame), the whole Path (once, at the last frame) and the input bag's ground
    truth, so `evo_ape bag` / `evo_traj bag` can read it."""
    from rclpy.serialization import serialize_message

    path = Path(path)
    with bags.BagWriter(path, storage, overwrite=True) as writer:
        for stamp_ns, msg in run.odometry_msgs:
            writer.write_raw(ODOMETRY_TOPIC, bags.ODOMETRY, stamp_ns, serialize_message(msg))
        if run.odometry_msgs:
            last_ns, last = run.odometry_msgs[-1]
            stamps = [convert.stamp_to_ns(msg.header.stamp) for _, msg in run.odometry_msgs]
            poses = [bags.odometry_to_pose(msg)[1] for _, msg in run.odometry_msgs]
            writer.write(PATH_TOPIC, bags.PATH, last_ns, writer.msgs.path(last_ns, last.header.frame_id, stamps, poses))
        if reader.topics.get(bags.GROUND_TRUTH_TOPIC) == bags.ODOMETRY:
            for message in reader.messages([bags.GROUND_TRUTH_TOPIC]):
                writer.write_raw(bags.GROUND_TRUTH_TOPIC, bags.ODOMETRY, message.log_time_ns, message.raw)
    return path


def write_results(out_dir: str | Path, run: ReplayRun, ground_truth: evaluation.Trajectory | None,
                  title: str) -> tuple[dict, list[Path]]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    evaluation.write_tum(out / "trajectory_tum.txt", run.estimate)
    evaluation.write_kitti(out / "trajectory_kitti.txt", run.estimate)
    files += [out / "trajectory_tum.txt", out / "trajectory_kitti.txt"]
    if ground_truth is not None:
        evaluation.write_tum(out / "ground_truth_tum.txt", ground_truth)
        files.append(out / "ground_truth_tum.txt")
    metrics = evaluation.compute_metrics(run.estimate, ground_truth, frames_dropped=run.frames_in - len(run.estimate),
                                         latencies_ms=run.latencies_ms)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    files.append(out / "metrics.json")
    if len(run.estimate):
        from line_odom.plot import plot_trajectory

        files.append(plot_trajectory(out / "trajectory.png", run.estimate, ground_truth, title=title))
    return metrics, files


def replay_bag(bag: str | Path, out_dir: str | Path, *, params: str | None = None,
               overrides: Mapping[str, Any] | None = None, realtime: bool = False, out_bag: str | Path | None = None,
               out_bag_storage: str = "sqlite3", topic: str | None = None, frames: int | None = None,
               progress: bool = True, title: str | None = None, rate: float = 1.0,
               guess_topic: str | None = None, imu_topic: str | None = None) -> ReplayResult:
    """Replay `bag` through the node and write the results to `out_dir` (see the module docstring). guess_topic: a
    nav_msgs/Odometry topic of the bag (wheel odometry) given to the node as its motion guess (guess.enabled);
    imu_topic: a sensor_msgs/Imu topic of the bag whose gyro turns the node's prediction (imu.enabled)."""
    if params is not None and not Path(params).is_file():
        raise FileNotFoundError(f"{params}: no such parameter file")
    with bags.BagReader(bag) as reader:
        inp = select_input(reader, topic)
        if guess_topic is not None:
            if reader.topics.get(guess_topic) != bags.ODOMETRY:
                found = reader.topics.get(guess_topic)
                raise ValueError(f"{reader.path}: guess topic {guess_topic} is "
                                 f"{found + ', expected ' + bags.ODOMETRY if found else 'not in the bag'}")
            # (in-process every pose is read before the first frame and kept; in real time they arrive as published)
            overrides = {**({} if realtime else {"guess.window": 86400.0}), **(overrides or {}), "guess.enabled": True}
        if imu_topic is not None:
            if reader.topics.get(imu_topic) != bags.IMU:
                found = reader.topics.get(imu_topic)
                raise ValueError(f"{reader.path}: imu topic {imu_topic} is "
                                 f"{found + ', expected ' + bags.IMU if found else 'not in the bag'}")
            overrides = {**({} if realtime else {"imu.window": 86400.0}), **(overrides or {}), "imu.enabled": True}
        config, settings = node_settings(inp.kind, params, overrides)
        if settings.base_to_sensor_from_tf and reader.topics.get(bags.TF_STATIC_TOPIC) != bags.TF_MESSAGE:
            raise ValueError(f"{reader.path}: base_to_sensor_from_tf is set but the bag has no {bags.TF_STATIC_TOPIC} "
                             f"({bags.TF_MESSAGE}) to take the sensor's mounting from")
        gt_data = bags.read_ground_truth(reader)
        ground_truth = evaluation.Trajectory(gt_data[1], gt_data[0]) if gt_data is not None else None
        label = f"replay {Path(bag).name}"
        with ProgressBar(label, enabled=None if progress else False) as bar:
            if realtime:
                from line_odom import replay_realtime

                run = replay_realtime.run_realtime(reader, inp, params=params, overrides=overrides, frames=frames,
                                                   progress=bar, rate=rate, guess_topic=guess_topic,
                                                   imu_topic=imu_topic)
            else:
                from line_odom.processor import OdometryProcessor

                run = run_in_process(reader, inp, OdometryProcessor(config, settings), frames=frames, progress=bar,
                                     guess_topic=guess_topic, imu_topic=imu_topic)
        if len(run.estimate) == 0:
            raise RuntimeError(f"{bag}: the node produced no pose from {run.frames_in} frame(s) on {inp.topic} "
                               f"(counters: {run.counters})")
        metrics, files = write_results(out_dir, run, ground_truth, title or f"{Path(bag).name} ({inp.topic})")
        if out_bag is not None:
            files.append(write_output_bag(out_bag, run, reader, out_bag_storage))
    return ReplayResult(metrics, files, run, ground_truth)
