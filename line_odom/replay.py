"""Replay a recording through the odometry node and evaluate the result.

:func:`replay` takes every format line_odom.readers knows, guessed from the path: a rosbag2 goes through
:func:`replay_bag`, everything else through :func:`replay_source` (its frames turned into the PointCloud2 / Image
messages a driver would publish, with ring and time fields where the recording has them).

Default (deterministic): the node's processing core (:class:`line_odom.processor.OdometryProcessor`, the code the
rclpy node runs in its callbacks) in this process, every frame in recording order as fast as possible. A bag's
messages are deserialized with rclpy, so the core sees exactly the message objects the node gets from a subscription.

``realtime=True`` (rosbag2 only): the node in its own process (``python -m line_odom.node``), messages published over
DDS at the bag's rate with /clock and ``use_sim_time``; see :mod:`line_odom.replay_realtime`.

Writes trajectory_tum.txt, trajectory_kitti.txt (the estimated sensor poses), ground_truth_tum.txt (when the recording
has ground truth), metrics.json, trajectory.png, features.png (plot_features), and optionally an output bag with the
node's Odometry and Path.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from line_odom import bags, convert, evaluation, replay_realtime
from line_odom.progress import ProgressBar
from line_odom.replay_common import PRESET_FOR_INPUT, ReplayInput, ReplayRun, node_settings

ODOMETRY_TOPIC = "/odom"  # the node's output topics
PATH_TOPIC = "/path"
FEATURES_PNG = "features.png"

__all__ = ["PRESET_FOR_INPUT", "ReplayInput", "ReplayRun", "ReplayResult", "node_settings", "replay", "replay_bag",
           "replay_source", "select_input", "run_in_process", "run_source", "write_results", "write_output_bag"]


@dataclasses.dataclass
class ReplayResult:
    metrics: dict
    files: list[Path]
    run: ReplayRun
    ground_truth: evaluation.Trajectory | None
    input: dict = dataclasses.field(default_factory=dict)  # format, preset, why, ground truth, reader notes


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


def _rclpy_types(kind: str):
    from sensor_msgs.msg import CameraInfo, Image, PointCloud2

    return {"pointcloud": PointCloud2, "depth": Image, "info": CameraInfo}


class RegisteredView:
    """What the node sends rviz for one frame (the index-th input frame): its ~/scan and ~/lines messages, asked of the
    processor for that frame only (plot_features draws them)."""

    def __init__(self, processor, index: int):
        self.processor, self.index = processor, index
        self.scan = self.lines = None
        self.registered = False

    def before(self, n: int) -> None:
        self.processor.scan_wanted = self.processor.lines_wanted = n == self.index

    def after(self, n: int, out) -> None:
        if n == self.index and out is not None:
            self.scan, self.lines, self.registered = out.scan, out.lines, True

    def check(self, frames_in: int, what: str) -> None:
        if self.index >= frames_in:
            raise ValueError(f"--plot-features {self.index}: {what} has {frames_in} frame(s) (0 .. {frames_in - 1})")
        if not self.registered:
            raise ValueError(f"--plot-features {self.index}: that frame of {what} was not registered (dropped: "
                             f"see frames_dropped in metrics.json); choose another")


def run_in_process(reader: bags.BagReader, inp: ReplayInput, processor, *, frames: int | None = None,
                   progress: ProgressBar | None = None, guess_topic: str | None = None,
                   imu_topic: str | None = None, view: RegisteredView | None = None) -> ReplayRun:
    """Every frame of the input topic through the processor, in bag order (with the nav_msgs/Odometry messages of
    guess_topic as the motion guess, guess.enabled, and the sensor_msgs/Imu messages of imu_topic as the gyro,
    imu.enabled); view: keeps one frame's ~/scan and ~/lines."""
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
    fields = {"frames_with_ring": 0, "frames_with_time": 0}
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
        if inp.kind == "pointcloud":
            names = {str(f.name) for f in msg.fields}
            fields["frames_with_ring"] += "ring" in names
            fields["frames_with_time"] += bool(names & set(convert.TIME_FIELDS))
        if view is not None:
            view.before(n_in - 1)
        out = processor.process_pointcloud(msg) if inp.kind == "pointcloud" else processor.process_depth(msg)
        if view is not None:
            view.after(n_in - 1, out)
        if out is not None:
            stamps.append(out.stamp)
            poses.append(out.T_odom_base @ processor.T_base_sensor)
            odom_msgs.append((message.log_time_ns, out.odometry))
            latencies.append(out.latency_ms)
        if progress is not None:
            progress.update(n_in, total)
    estimate = evaluation.Trajectory(np.array(poses).reshape(-1, 4, 4), np.array(stamps, dtype=float))
    return ReplayRun(estimate, odom_msgs, latencies, n_in, {**processor.counters, **fields})


def write_output_bag(path: str | Path, run: ReplayRun, reader: bags.BagReader | None = None, storage: str = "sqlite3",
                     ground_truth: evaluation.Trajectory | None = None) -> Path:
    """The node's Odometry (every frame), the whole Path (once, at the last frame) and the ground truth (the input
    bag's messages, else `ground_truth`'s poses), so `evo_ape bag` / `evo_traj bag` can read it."""
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
        if reader is not None and reader.topics.get(bags.GROUND_TRUTH_TOPIC) == bags.ODOMETRY:
            for message in reader.messages([bags.GROUND_TRUTH_TOPIC]):
                writer.write_raw(bags.GROUND_TRUTH_TOPIC, bags.ODOMETRY, message.log_time_ns, message.raw)
        elif ground_truth is not None and ground_truth.stamps is not None:
            for stamp, T in zip(ground_truth.stamps, ground_truth.poses):
                ns = round(float(stamp) * 1e9)
                writer.write(bags.GROUND_TRUTH_TOPIC, bags.ODOMETRY, ns,
                             writer.msgs.odometry(ns, bags.GROUND_TRUTH_FRAME, "sensor", T))
    return path


def write_results(out_dir: str | Path, run: ReplayRun, ground_truth: evaluation.Trajectory | None,
                  title: str, extra: Mapping[str, Any] | None = None) -> tuple[dict, list[Path]]:
    """The trajectories, metrics.json (with `extra`'s keys added) and the plot in out_dir."""
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
    metrics.update(extra or {})
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
               guess_topic: str | None = None, imu_topic: str | None = None, ground_truth: str | Path | None = None,
               plot_features: int | None = None) -> ReplayResult:
    """Replay `bag` through the node and write the results to `out_dir` (see the module docstring). guess_topic: a
    nav_msgs/Odometry topic of the bag (wheel odometry) given to the node as its motion guess (guess.enabled);
    imu_topic: a sensor_msgs/Imu topic of the bag whose gyro turns the node's prediction (imu.enabled); ground_truth:
    a TUM / KITTI trajectory file instead of the bag's /ground_truth; plot_features: the frame whose lines
    features.png shows."""
    from line_odom_core.config import PRESETS

    if params is not None and not Path(params).is_file() and params not in PRESETS:
        raise FileNotFoundError(f"{params}: no such parameter file (or preset: {', '.join(sorted(PRESETS))})")
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
        sensor = _bag_sensor(reader, inp) if params is None else None
        if sensor is not None:
            params, overrides = sensor.preset, {**sensor.overrides, **(overrides or {})}
        config, settings = node_settings(inp.kind, params, overrides)
        if settings.base_to_sensor_from_tf and reader.topics.get(bags.TF_STATIC_TOPIC) != bags.TF_MESSAGE:
            raise ValueError(f"{reader.path}: base_to_sensor_from_tf is set but the bag has no {bags.TF_STATIC_TOPIC} "
                             f"({bags.TF_MESSAGE}) to take the sensor's mounting from")
        gt_data = bags.read_ground_truth(reader)
        gt = evaluation.Trajectory(gt_data[1], gt_data[0]) if gt_data is not None else None
        label = f"replay {Path(bag).name}"
        from line_odom.processor import OdometryProcessor

        view = None
        with ProgressBar(label, enabled=None if progress else False) as bar:
            if realtime:
                run = replay_realtime.run_realtime(reader, inp, params=params, overrides=overrides, frames=frames,
                                                   progress=bar, rate=rate, guess_topic=guess_topic,
                                                   imu_topic=imu_topic)
            else:
                processor = OdometryProcessor(config, settings)
                view = None if plot_features is None else RegisteredView(processor, plot_features)
                run = run_in_process(reader, inp, processor, frames=frames, progress=bar, guess_topic=guess_topic,
                                     imu_topic=imu_topic, view=view)
        if len(run.estimate) == 0:
            raise RuntimeError(f"{bag}: the node produced no pose from {run.frames_in} frame(s) on {inp.topic} "
                               f"(counters: {run.counters})")
        if ground_truth is not None:
            gt = _ground_truth_file(ground_truth, run)
        preset = params or PRESET_FOR_INPUT[inp.kind]
        info = {"format": "rosbag2", "path": str(bag), "topic": inp.topic, "preset": preset,
                "overrides": sensor.overrides if sensor is not None else {},
                "sensor": sensor.reason if sensor is not None else (
                    "--params" if params != PRESET_FOR_INPUT[inp.kind] else f"the {inp.kind} preset"),
                "ground_truth": str(ground_truth) if ground_truth is not None else (
                    bags.GROUND_TRUTH_TOPIC + " (nav_msgs/Odometry)" if gt is not None else None), "notes": []}
        metrics, files = write_results(out_dir, run, gt, title or f"{Path(bag).name} ({inp.topic})",
                                       _input_metrics(run, info))
        if plot_features is not None:
            from line_odom.plot import plot_registered_view

            if view is None:  # the node ran in its own process: the same frames through its processing core here
                processor = OdometryProcessor(config, settings)
                view = RegisteredView(processor, plot_features)
                run_in_process(reader, inp, processor, frames=min(plot_features + 1, run.frames_in),
                               guess_topic=guess_topic, imu_topic=imu_topic, view=view)
            view.check(run.frames_in, f"{Path(bag).name} {inp.topic}")
            files.append(plot_registered_view(Path(out_dir) / FEATURES_PNG, view.scan, view.lines,
                                              depth=inp.kind == "depth",
                                              title=f"{Path(bag).name} {inp.topic}, frame {plot_features}"))
        if out_bag is not None:
            files.append(write_output_bag(out_bag, run, reader, out_bag_storage))
    return ReplayResult(metrics, files, run, gt, info)


def _bag_sensor(reader: bags.BagReader, inp: ReplayInput):
    """The preset the bag's first cloud suggests (line_odom.readers.sensor_preset), None for depth or a first message
    that is no cloud (the processor reports it)."""
    if inp.kind != "pointcloud":
        return None
    from rclpy.serialization import deserialize_message

    from line_odom.readers import sensor_preset

    try:
        message = next(iter(reader.messages([inp.topic])))
        cloud = convert.pointcloud2_to_arrays(deserialize_message(message.raw, _rclpy_types(inp.kind)["pointcloud"]))
    except Exception:  # noqa: BLE001 - rclpy's decode errors and malformed clouds: counted when replayed
        return None
    return sensor_preset.for_points(cloud.xyz, cloud.ring, f"clouds on {inp.topic}")


# ------------------------------------------------------------------------------------------- other recordings


def frame_message(frame, frame_id: str):
    """A reader's Frame as the message a driver publishes: PointCloud2 (x, y, z, intensity, ring, time where the
    frame has them; organized when the frame is) or a 32FC1 depth Image (metres as read: no rounding to mm)."""
    stamp = convert.ns_to_stamp(frame.stamp_ns)
    if frame.depth is not None:
        return convert.depth_to_image(frame.depth, encoding="32FC1", frame_id=frame_id, stamp=stamp)
    return convert.pointcloud2_from_xyz(frame.xyz, intensity=frame.intensity, ring=frame.ring, time=frame.time,
                                        frame_id=frame_id, stamp=stamp)


def run_source(source, processor, *, progress: ProgressBar | None = None,
               view: RegisteredView | None = None) -> ReplayRun:
    """Every frame of a reader's source through the processor, in recording order; view: keeps one frame's ~/scan and
    ~/lines."""
    camera_info = height_width = None
    stamps, poses, odom_msgs, latencies = [], [], [], []
    counts = {"frames_with_ring": 0, "frames_with_time": 0}
    rows_from = None
    n_in = 0
    for frame in source.frames():
        if view is not None:
            view.before(n_in)
        n_in += 1
        processor.note_received()
        msg = frame_message(frame, source.frame_id)
        if source.kind == "depth":
            if camera_info is None or height_width != frame.depth.shape:
                height_width = frame.depth.shape
                camera_info = convert.camera_info_from_K(source.K, height_width[1], height_width[0],
                                                         frame_id=source.frame_id, stamp=msg.header.stamp)
            out = processor.process_depth(msg, camera_info)
        else:
            counts["frames_with_ring"] += frame.ring is not None
            counts["frames_with_time"] += frame.time is not None
            if rows_from is None:  # how the engine puts this recording's points into rows (its ring, if given)
                rows_from = "organized" if frame.xyz.ndim == 3 else processor.engine.sensor_fit(
                    np.ascontiguousarray(frame.xyz.reshape(-1, 3)),
                    ring=None if frame.ring is None else frame.ring.astype(np.int32))["row_method"]
            out = processor.process_pointcloud(msg)
        if view is not None:
            view.after(n_in - 1, out)
        if out is not None:
            stamps.append(out.stamp)
            poses.append(out.T_odom_base @ processor.T_base_sensor)
            odom_msgs.append((frame.stamp_ns, out.odometry))
            latencies.append(out.latency_ms)
        if progress is not None:
            progress.update(n_in, source.count)
    estimate = evaluation.Trajectory(np.array(poses).reshape(-1, 4, 4), np.array(stamps, dtype=float))
    counters = {**processor.counters, **counts}
    if rows_from is not None:
        counters["rows_from"] = rows_from
    return ReplayRun(estimate, odom_msgs, latencies, n_in, counters)


def _ground_truth_file(path: str | Path, run: ReplayRun) -> evaluation.Trajectory:
    """A TUM or KITTI trajectory file as ground truth; a KITTI file (no stamps) belongs to the frames by index."""
    gt = evaluation.read_trajectory(path)
    if gt.stamps is None:
        if len(gt) < run.frames_in:
            raise ValueError(f"{path}: {len(gt)} poses for {run.frames_in} frames (a KITTI file is matched to the "
                             f"frames by index)")
        if len(run.estimate) != run.frames_in:
            missing = run.frames_in - len(run.estimate)
            raise ValueError(f"{path}: a KITTI file is matched to the frames by index, but {missing} frame(s) have no "
                             f"pose; use a TUM file (with stamps)")
        gt = evaluation.Trajectory(gt.poses[: len(run.estimate)], run.estimate.stamps)
    return gt


def _input_metrics(run: ReplayRun, info: Mapping[str, Any]) -> dict:
    keys = ("frames_with_ring", "frames_with_time", "frames_deskewed", "point_times_ignored", "ring_fields_ignored",
            "rows_from")
    return {**{k: run.counters[k] for k in keys if k in run.counters}, "input": dict(info)}


def replay_source(source, out_dir: str | Path, *, params: str | None = None,
                  overrides: Mapping[str, Any] | None = None, progress: bool = True, title: str | None = None,
                  ground_truth: str | Path | None = None, plot_features: int | None = None,
                  out_bag: str | Path | None = None, out_bag_storage: str = "sqlite3") -> ReplayResult:
    """Replay an opened line_odom.readers Source through the node's processing core and write the results to
    out_dir. Parameters: `params` (a preset name or YAML file), else the preset the data suggests with its overrides;
    then `overrides`. ground_truth: a TUM / KITTI trajectory file instead of the recording's own."""
    from line_odom.processor import OdometryProcessor

    suggested = {} if params is not None else dict(source.sensor.overrides)
    config, settings = node_settings(source.kind, params or source.sensor.preset, {**suggested, **(overrides or {})})
    processor = OdometryProcessor(config, settings)
    view = None if plot_features is None else RegisteredView(processor, plot_features)
    label = f"replay {source.path.name}"
    with ProgressBar(label, enabled=None if progress else False) as bar:
        run = run_source(source, processor, progress=bar, view=view)
    if run.frames_in == 0:
        raise RuntimeError(f"{source.path}: no frame to replay")
    if len(run.estimate) == 0:
        raise RuntimeError(f"{source.path}: the node produced no pose from {run.frames_in} frame(s) "
                           f"(counters: {dict(run.counters)})")
    gt = _ground_truth_file(ground_truth, run) if ground_truth is not None else source.ground_truth
    info = {"format": source.format, "path": str(source.path), "preset": params or source.sensor.preset,
            "overrides": suggested, "sensor": source.sensor.reason,
            "ground_truth": str(ground_truth) if ground_truth is not None else (source.ground_truth_source or None),
            "notes": list(source.notes)}
    metrics, files = write_results(out_dir, run, gt, title or f"{source.path.name} ({source.format})",
                                   _input_metrics(run, info))
    if view is not None:
        from line_odom.plot import plot_registered_view

        view.check(run.frames_in, "the recording")
        files.append(plot_registered_view(Path(out_dir) / FEATURES_PNG, view.scan, view.lines,
                                          depth=source.kind == "depth",
                                          title=f"{source.path.name}, frame {plot_features}"))
    if out_bag is not None:
        files.append(write_output_bag(out_bag, run, None, out_bag_storage, gt))
    return ReplayResult(metrics, files, run, gt, info)


def replay(path: str | Path, out_dir: str | Path, *, format: str | None = None, params: str | None = None,
           overrides: Mapping[str, Any] | None = None, frames: int | None = None, topic: str | None = None,
           meta: str | Path | None = None, ground_truth: str | Path | None = None, plot_features: int | None = None,
           progress: bool = True, title: str | None = None, realtime: bool = False, rate: float = 1.0,
           out_bag: str | Path | None = None, out_bag_storage: str = "sqlite3", guess_topic: str | None = None,
           imu_topic: str | None = None) -> ReplayResult:
    """Replay any recording line_odom reads (format guessed from the path unless given: see
    line_odom.readers.FORMATS) and write trajectories, metrics.json and plots to out_dir; returns the metrics and
    files. guess_topic and imu_topic apply to rosbag2 bags only; realtime replays another format as a rosbag2 of the
    messages its frames become, written to a temporary folder first."""
    from line_odom import readers

    format = format or readers.guess_format(path)
    if format == "rosbag2":
        bag = readers.rosbag2_dir(Path(path)) or Path(path)
        result = replay_bag(bag, out_dir, params=params, overrides=overrides, realtime=realtime, out_bag=out_bag,
                            out_bag_storage=out_bag_storage, topic=topic, frames=frames, progress=progress,
                            title=title, rate=rate, guess_topic=guess_topic, imu_topic=imu_topic,
                            ground_truth=ground_truth, plot_features=plot_features)
        return result
    rosbag_only = [name for name, given in (("--guess-topic", guess_topic), ("--imu-topic", imu_topic)) if given]
    if rosbag_only:
        raise ValueError(f"{', '.join(rosbag_only)}: for rosbag2 bags only, {path} is {format}")
    with readers.open_source(path, format, frames=frames, topic=topic, meta=meta) as source:
        if not realtime:
            return replay_source(source, out_dir, params=params, overrides=overrides, progress=progress, title=title,
                                 ground_truth=ground_truth, plot_features=plot_features, out_bag=out_bag,
                                 out_bag_storage=out_bag_storage)
        import tempfile

        with tempfile.TemporaryDirectory(prefix="line_odom_replay_") as scratch:
            bag = source_to_bag(source, Path(scratch) / "bag")
            suggested = {} if params is not None else dict(source.sensor.overrides)
            result = replay_bag(bag, out_dir, params=params or source.sensor.preset,
                                overrides={**suggested, **(overrides or {})}, realtime=True, rate=rate,
                                out_bag=out_bag, out_bag_storage=out_bag_storage, progress=progress,
                                title=title or f"{source.path.name} ({source.format})", ground_truth=ground_truth,
                                plot_features=plot_features)
        result.input.update(format=source.format, path=str(source.path), preset=params or source.sensor.preset,
                            overrides=suggested, sensor=source.sensor.reason, notes=list(source.notes))
        if ground_truth is None:
            result.input["ground_truth"] = source.ground_truth_source or None
        result.metrics["input"] = result.input
        (Path(out_dir) / "metrics.json").write_text(json.dumps(result.metrics, indent=2) + "\n")
        return result


SOURCE_POINTS_TOPIC = "/points"  # the topics of source_to_bag's bags
SOURCE_DEPTH_TOPIC = "/depth/image"
SOURCE_INFO_TOPIC = "/depth/camera_info"


def source_to_bag(source, bag: str | Path, storage: str = "sqlite3") -> Path:
    """A reader's frames as a rosbag2: the messages frame_message makes (and a CameraInfo beside each depth image),
    logged at their stamps, and the source's ground truth on /ground_truth."""
    from rclpy.serialization import serialize_message

    bag = Path(bag)
    with bags.BagWriter(bag, storage) as writer:
        for frame in source.frames():
            msg = frame_message(frame, source.frame_id)
            if frame.depth is not None:
                info = convert.camera_info_from_K(source.K, frame.depth.shape[1], frame.depth.shape[0],
                                                  frame_id=source.frame_id, stamp=msg.header.stamp)
                writer.write_raw(SOURCE_INFO_TOPIC, bags.CAMERA_INFO, frame.stamp_ns, serialize_message(info))
                writer.write_raw(SOURCE_DEPTH_TOPIC, bags.IMAGE, frame.stamp_ns, serialize_message(msg))
            else:
                writer.write_raw(SOURCE_POINTS_TOPIC, bags.POINTCLOUD2, frame.stamp_ns, serialize_message(msg))
        if source.ground_truth is not None and source.ground_truth.stamps is not None:
            for stamp, T in zip(source.ground_truth.stamps, source.ground_truth.poses):
                ns = round(float(stamp) * 1e9)
                writer.write(bags.GROUND_TRUTH_TOPIC, bags.ODOMETRY, ns,
                             writer.msgs.odometry(ns, bags.GROUND_TRUTH_FRAME, source.frame_id, T))
    return bag
