"""ROS 1 bags through rosbags (no ROS needed): the bag's only PointCloud2 topic (or --topic), else its only depth
Image topic with the CameraInfo beside it; ground truth from a nav_msgs/Odometry topic /ground_truth."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from line_odom import convert
from line_odom.readers import sensor_preset
from line_odom.readers.base import Frame, ReaderError, Sensor, Source

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
GROUND_TRUTH_TOPIC = "/ground_truth"


class Ros1Bag(Source):
    format = "ros1"

    def __init__(self, path: str | Path, topic: str | None = None, frames: int | None = None):
        super().__init__(path)
        from rosbags.rosbag1 import Reader
        from rosbags.typesys import Stores, get_typestore

        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as exc:  # rosbags raises its ReaderError and others for broken bags
            raise ReaderError(f"{self.path}: cannot open the ROS 1 bag ({type(exc).__name__}: {exc})") from None
        self.store = get_typestore(Stores.ROS1_NOETIC)
        topics = {c.topic: c.msgtype for c in self._reader.connections}
        counts: dict[str, int] = {}
        for c in self._reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
        listing = ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())) or "none"
        if topic is not None:
            if topics.get(topic) not in (POINTCLOUD2, IMAGE):
                self.close()
                raise ReaderError(f"{self.path}: topic {topic} is {topics.get(topic, 'not in the bag')}, expected "
                                  f"{POINTCLOUD2} or {IMAGE} (topics: {listing})")
            candidates = [topic]
        else:
            candidates = sorted(t for t, m in topics.items() if m == POINTCLOUD2) or \
                sorted(t for t, m in topics.items() if m == IMAGE)
        if len(candidates) != 1:
            self.close()
            raise ReaderError(f"{self.path}: " + ("no PointCloud2 or depth Image topic to replay" if not candidates else
                                                  f"several sensor topics ({', '.join(candidates)}); choose one with "
                                                  f"--topic") + f" (topics: {listing})")
        self.topic = candidates[0]
        self.kind = "pointcloud" if topics[self.topic] == POINTCLOUD2 else "depth"
        self.info_topic = None
        if self.kind == "depth":
            infos = sorted(t for t, m in topics.items() if m == CAMERA_INFO)
            namespace = self.topic.rsplit("/", 1)[0]
            self.info_topic = next((t for t in infos if t.rsplit("/", 1)[0] == namespace), infos[0] if infos else None)
            if self.info_topic is None:
                self.close()
                raise ReaderError(f"{self.path}: depth topic {self.topic} but no CameraInfo topic (topics: {listing})")
            self.K = self._first_K()
            self.sensor = Sensor("tum_kinect", {}, f"depth images on {self.topic}")
        self.limit = frames
        self.count = counts.get(self.topic, 0) if frames is None else min(frames, counts.get(self.topic, 0))
        if self.count == 0:
            self.close()
            raise ReaderError(f"{self.path}: topic {self.topic} has no messages")
        if self.kind == "pointcloud":
            first = self._cloud(next(self._messages([self.topic]))[1])
            self.frame_id = first.frame_id or "sensor"
            self.sensor = sensor_preset.for_points(first.xyz, first.ring, f"clouds on {self.topic}")
        if topics.get(GROUND_TRUTH_TOPIC) == ODOMETRY:
            self.ground_truth = self._ground_truth()
            self.ground_truth_source = f"{GROUND_TRUTH_TOPIC} (nav_msgs/Odometry)"

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:  # noqa: BLE001 - closing a bag that failed to open
            pass

    def _messages(self, topics: list[str]):
        conns = [c for c in self._reader.connections if c.topic in topics]
        try:
            for conn, _, raw in self._reader.messages(connections=conns):
                yield conn.topic, self.store.deserialize_ros1(raw, conn.msgtype)
        except ReaderError:
            raise
        except Exception as exc:
            raise ReaderError(f"{self.path}: corrupt ROS 1 bag or a message its type does not describe "
                              f"({type(exc).__name__}: {exc})") from None

    def _first_K(self) -> np.ndarray:
        for _, info in self._messages([self.info_topic]):
            return self._K(info)
        raise ReaderError(f"{self.path}: {self.info_topic} has no messages")

    def _K(self, info) -> np.ndarray:
        K = np.asarray(info.K, dtype=float).reshape(3, 3)  # ROS 1 names it K (ROS 2: k)
        if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
            raise ReaderError(f"{self.path}: {self.info_topic}: CameraInfo.K has no valid focal lengths: {K.tolist()}")
        return K

    def _cloud(self, msg) -> convert.CloudArrays:
        try:
            return convert.pointcloud2_to_arrays(msg)
        except convert.ConversionError as err:
            raise ReaderError(f"{self.path}: {self.topic}: {err}") from None

    def _ground_truth(self):
        from line_odom.bags import odometry_to_pose
        from line_odom.evaluation import Trajectory

        stamps, poses = [], []
        for _, msg in self._messages([GROUND_TRUTH_TOPIC]):
            stamp, T = odometry_to_pose(msg)
            stamps.append(stamp)
            poses.append(T)
        return Trajectory(np.stack(poses), np.array(stamps)) if poses else None

    def frames(self) -> Iterator[Frame]:
        n = 0
        for topic, msg in self._messages([self.topic] + ([self.info_topic] if self.info_topic else [])):
            if topic == self.info_topic:
                self.K = self._K(msg)
                continue
            stamp_ns = convert.stamp_to_ns(msg.header.stamp)
            if self.kind == "depth":
                try:
                    depth = convert.image_to_depth(msg)
                except convert.ConversionError as err:
                    raise ReaderError(f"{self.path}: {self.topic}: {err}") from None
                yield Frame(stamp_ns, depth=depth)
            else:
                cloud = self._cloud(msg)
                try:
                    times = convert.sweep_times(cloud)
                except convert.ConversionError as err:  # registered as measured, as the node does
                    times = None
                    if not self.notes:
                        self.notes.append(f"{self.topic}: point times unusable, not deskewed ({err})")
                ring = None if cloud.ring is None else cloud.ring.astype(np.uint16)
                yield Frame(stamp_ns, cloud.xyz, ring, times, cloud.intensity)
            n += 1
            if self.limit is not None and n >= self.limit:
                return
