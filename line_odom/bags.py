"""rosbag2 conversion and reading through the `rosbags` library (sqlite3 and mcap storage, no ROS needed).

- :func:`kitti_to_bag`: KITTI odometry sequence -> PointCloud2 (x, y, z, intensity float32, ring uint16) on
  ``/kitti/points`` in frame ``velodyne``; ground truth (LiDAR frame) as nav_msgs/Odometry on
  ``/ground_truth``; the calibration velodyne -> camera_0 on ``/tf_static``.
- :func:`tum_to_bag`: TUM RGB-D depth PNGs -> 16UC1 Image (millimetres, REP 118) + CameraInfo; ground truth
  on ``/ground_truth``.
- :class:`BagReader`: messages of a bag in log-time order, every failure a :class:`BagError` with the bag's
  name and the reason.
"""
from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom import datasets

KITTI_POINTS_TOPIC = "/kitti/points"
KITTI_FRAME = "velodyne"
KITTI_CAMERA_FRAME = "camera_0"
TUM_DEPTH_TOPIC = "/camera/depth/image"
TUM_INFO_TOPIC = "/camera/depth/camera_info"
TUM_FRAME = "camera_depth_optical_frame"
GROUND_TRUTH_TOPIC = "/ground_truth"
GROUND_TRUTH_FRAME = "world"
TF_STATIC_TOPIC = "/tf_static"
STORAGES = ("sqlite3", "mcap")

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
IMU = "sensor_msgs/msg/Imu"
PATH = "nav_msgs/msg/Path"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

# PointField datatypes
_FLOAT32, _UINT16 = 7, 4
KITTI_POINT_DTYPE = np.dtype({"names": ["x", "y", "z", "intensity", "ring"],
                              "formats": ["<f4", "<f4", "<f4", "<f4", "<u2"],
                              "offsets": [0, 4, 8, 12, 16], "itemsize": 18})


class BagError(RuntimeError):
    """A bag that cannot be written or read: the message names the bag and the reason."""


def typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _storage_plugin(storage: str):
    from rosbags.rosbag2 import StoragePlugin

    if storage not in STORAGES:
        raise ValueError(f"storage: expected one of {', '.join(STORAGES)}, got {storage!r}")
    return StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3


def kitti_rings(points: np.ndarray, min_ring_points: int = 100) -> np.ndarray:
    """Scan line (ring) of each point of a KITTI scan, 0 = first line in the file (the top beam).

    KITTI stores the HDL-64E points line by line, each line sweeping the azimuth counter-clockwise from the
    front; a new line starts where the azimuth wraps from just below 0 back to just above it. Wraps closer
    than `min_ring_points` to the previous one are jitter, not a new line."""
    az = np.arctan2(points[:, 1], points[:, 0])
    wraps = np.nonzero((az[:-1] < 0) & (az[1:] >= 0) & (az[:-1] > -np.pi / 2))[0] + 1
    starts = []
    last = 0
    for w in wraps:
        if w - last >= min_ring_points:
            starts.append(w)
            last = w
    ring = np.zeros(len(points), dtype=np.int64)
    ring[np.asarray(starts, dtype=np.int64)] = 1
    return np.minimum(np.cumsum(ring), np.iinfo(np.uint16).max).astype(np.uint16)


# ------------------------------------------------------------------------------------------------ messages


class _Messages:
    """Message builders on the rosbags Jazzy typestore."""

    def __init__(self):
        self.store = typestore()
        self.T = self.store.types

    def serialize(self, msg, msgtype: str) -> bytes:
        return self.store.serialize_cdr(msg, msgtype)

    def header(self, stamp_ns: int, frame_id: str):
        Time = self.T["builtin_interfaces/msg/Time"]
        return self.T["std_msgs/msg/Header"](stamp=Time(sec=int(stamp_ns // 1_000_000_000),
                                                        nanosec=int(stamp_ns % 1_000_000_000)), frame_id=frame_id)

    def pointcloud2(self, stamp_ns: int, frame_id: str, points: np.ndarray):
        PointField = self.T["sensor_msgs/msg/PointField"]
        fields = [PointField(name=name, offset=int(points.dtype.fields[name][1]),
                             datatype=_UINT16 if name == "ring" else _FLOAT32, count=1)
                  for name in points.dtype.names]
        data = np.frombuffer(np.ascontiguousarray(points).tobytes(), dtype=np.uint8)
        return self.T[POINTCLOUD2](header=self.header(stamp_ns, frame_id), height=1, width=len(points),
                                   fields=fields, is_bigendian=False, point_step=points.dtype.itemsize,
                                   row_step=points.dtype.itemsize * len(points), data=data,
                                   is_dense=bool(np.isfinite(points["x"]).all()))

    def image16(self, stamp_ns: int, frame_id: str, pixels: np.ndarray):
        pixels = np.ascontiguousarray(pixels, dtype="<u2")
        return self.T[IMAGE](header=self.header(stamp_ns, frame_id), height=pixels.shape[0], width=pixels.shape[1],
                             encoding="16UC1", is_bigendian=0, step=2 * pixels.shape[1],
                             data=np.frombuffer(pixels.tobytes(), dtype=np.uint8))

    def camera_info(self, stamp_ns: int, frame_id: str, K: np.ndarray, width: int, height: int):
        RegionOfInterest = self.T["sensor_msgs/msg/RegionOfInterest"]
        P = np.hstack([K, np.zeros((3, 1))])
        return self.T[CAMERA_INFO](header=self.header(stamp_ns, frame_id), height=height, width=width,
                                   distortion_model="plumb_bob", d=np.zeros(5), k=K.reshape(-1).astype(float),
                                   r=np.eye(3).reshape(-1), p=P.reshape(-1).astype(float), binning_x=0, binning_y=0,
                                   roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))

    def pose(self, T: np.ndarray):
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        return self.T["geometry_msgs/msg/Pose"](
            position=self.T["geometry_msgs/msg/Point"](x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            orientation=self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                               w=float(q[3])))

    def odometry(self, stamp_ns: int, frame_id: str, child_frame_id: str, T: np.ndarray):
        Vector3 = self.T["geometry_msgs/msg/Vector3"]
        twist = self.T["geometry_msgs/msg/Twist"](linear=Vector3(x=0.0, y=0.0, z=0.0),
                                                  angular=Vector3(x=0.0, y=0.0, z=0.0))
        return self.T[ODOMETRY](
            header=self.header(stamp_ns, frame_id), child_frame_id=child_frame_id,
            pose=self.T["geometry_msgs/msg/PoseWithCovariance"](pose=self.pose(T), covariance=np.zeros(36)),
            twist=self.T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))

    def imu(self, stamp_ns: int, frame_id: str, angular_velocity):
        """A sensor_msgs/Imu carrying only a gyro's rate (rad/s): no orientation, no linear acceleration (their
        covariance element 0 is -1, the message convention for 'not provided')."""
        Vector3 = self.T["geometry_msgs/msg/Vector3"]
        w = [float(v) for v in angular_velocity]
        unknown = np.zeros(9)
        unknown[0] = -1.0
        return self.T[IMU](header=self.header(stamp_ns, frame_id),
                           orientation=self.T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                           orientation_covariance=unknown.copy(), angular_velocity=Vector3(x=w[0], y=w[1], z=w[2]),
                           angular_velocity_covariance=np.zeros(9),
                           linear_acceleration=Vector3(x=0.0, y=0.0, z=0.0),
                           linear_acceleration_covariance=unknown.copy())

    def path(self, stamp_ns: int, frame_id: str, stamps_ns, poses):
        PoseStamped = self.T["geometry_msgs/msg/PoseStamped"]
        return self.T[PATH](header=self.header(stamp_ns, frame_id),
                            poses=[PoseStamped(header=self.header(s, frame_id), pose=self.pose(T))
                                   for s, T in zip(stamps_ns, poses)])

    def tf_static(self, stamp_ns: int, parent: str, child: str, T: np.ndarray):
        Vector3 = self.T["geometry_msgs/msg/Vector3"]
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        transform = self.T["geometry_msgs/msg/Transform"](
            translation=Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            rotation=self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                            w=float(q[3])))
        stamped = self.T["geometry_msgs/msg/TransformStamped"](header=self.header(stamp_ns, parent),
                                                               child_frame_id=child, transform=transform)
        return self.T[TF_MESSAGE](transforms=[stamped])


def _tf_static_qos():
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(sec=0, nsec=0)
    return [Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
                durability=QosDurability.TRANSIENT_LOCAL, deadline=never, lifespan=never,
                liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=never,
                avoid_ros_namespace_conventions=False)]


class BagWriter:
    """rosbag2 writer (version 9) for the line_odom topics; use as a context manager."""

    def __init__(self, path: str | Path, storage: str = "sqlite3", overwrite: bool = False):
        from rosbags.rosbag2 import Writer

        self.path = Path(path)
        plugin = _storage_plugin(storage)
        if self.path.exists():
            if not overwrite:
                raise FileExistsError(f"{self.path}: exists; choose another output path or pass --overwrite")
            shutil.rmtree(self.path) if self.path.is_dir() else self.path.unlink()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.msgs = _Messages()
        self._writer = Writer(self.path, version=9, storage_plugin=plugin)
        self._connections: dict[str, object] = {}
        self.count = 0

    def __enter__(self) -> "BagWriter":
        self._writer.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._writer.close()
        if exc_type is not None and self.path.exists():
            shutil.rmtree(self.path, ignore_errors=True)  # no half-written bag left behind

    def write(self, topic: str, msgtype: str, stamp_ns: int, msg) -> None:
        """A message object (rosbags typestore) serialized to CDR."""
        self.write_raw(topic, msgtype, stamp_ns, self.msgs.serialize(msg, msgtype))

    def write_raw(self, topic: str, msgtype: str, stamp_ns: int, raw: bytes) -> None:
        """An already CDR-serialized message (e.g. from rclpy.serialization or another bag)."""
        if topic not in self._connections:
            qos = _tf_static_qos() if topic == TF_STATIC_TOPIC else ()
            self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=self.msgs.store,
                                                                   offered_qos_profiles=qos)
        self._writer.write(self._connections[topic], int(stamp_ns), raw)
        self.count += 1


def _ns(seconds: float) -> int:
    return int(round(float(seconds) * 1e9))


Progress = Callable[[int, int], None]


def kitti_to_bag(seq_dir: str | Path, out_bag: str | Path, *, storage: str = "sqlite3", frames: int | None = None,
                 overwrite: bool = False, progress: Progress | None = None) -> int:
    """Write a KITTI odometry sequence as a bag; returns the number of scans written."""
    seq = datasets.KittiSequence.open(seq_dir, frames)
    with BagWriter(out_bag, storage, overwrite) as bag:
        m = bag.msgs
        stamp0 = _ns(seq.times[0]) if len(seq.times) else 0
        # Tr maps velodyne points into camera 0: it is T_camera_velodyne, so camera_0 in velodyne is inv(Tr).
        bag.write(TF_STATIC_TOPIC, TF_MESSAGE, stamp0,
                  m.tf_static(stamp0, KITTI_FRAME, KITTI_CAMERA_FRAME, np.linalg.inv(seq.Tr)))
        for i in range(len(seq)):
            stamp = _ns(seq.times[i])
            raw = seq.points(i)
            points = np.empty(len(raw), dtype=KITTI_POINT_DTYPE)
            for k, name in enumerate(("x", "y", "z", "intensity")):
                points[name] = raw[:, k]
            points["ring"] = kitti_rings(raw)
            bag.write(KITTI_POINTS_TOPIC, POINTCLOUD2, stamp, m.pointcloud2(stamp, KITTI_FRAME, points))
            if seq.poses is not None:
                bag.write(GROUND_TRUTH_TOPIC, ODOMETRY, stamp,
                          m.odometry(stamp, GROUND_TRUTH_FRAME, KITTI_FRAME, seq.poses[i]))
            if progress:
                progress(i + 1, len(seq))
    return len(seq)


def parse_intrinsics(camera: str) -> tuple[str, np.ndarray]:
    """'fr1' / 'fr2' / 'fr3' / 'ros_default', or 'fx,fy,cx,cy' -> (name, K)."""
    if camera in datasets.TUM_INTRINSICS:
        fx, fy, cx, cy = datasets.TUM_INTRINSICS[camera]
        name = camera
    else:
        try:
            fx, fy, cx, cy = (float(v) for v in camera.split(","))
        except ValueError:
            raise ValueError(f"camera: expected one of {', '.join(sorted(datasets.TUM_INTRINSICS))} or "
                             f"'fx,fy,cx,cy', got {camera!r}") from None
        if not all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
            raise ValueError(f"camera: focal lengths must be positive and all values finite, got {camera!r}")
        name = "custom"
    return name, np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def tum_camera_from_path(root: Path) -> str:
    """fr1/fr2/fr3 from a TUM sequence directory name (rgbd_dataset_freiburg2_xyz, tum_rgbd_fr1_xyz ...)."""
    name = root.resolve().name.lower()
    for k in ("1", "2", "3"):
        if f"freiburg{k}" in name or f"fr{k}" in name:
            return f"fr{k}"
    return "fr1"


def tum_to_bag(tum_dir: str | Path, out_bag: str | Path, *, storage: str = "sqlite3", frames: int | None = None,
               camera: str | None = None, overwrite: bool = False, progress: Progress | None = None) -> int:
    """Write TUM RGB-D depth frames as a bag (16UC1 millimetres + CameraInfo, ground truth where the
    interpolation is valid); returns the number of depth frames written."""
    root = Path(tum_dir)
    camera = camera or tum_camera_from_path(root)
    _, K = parse_intrinsics(camera)
    seq = datasets.TumSequence.open(root, frames, "fr1")
    with BagWriter(out_bag, storage, overwrite) as bag:
        m = bag.msgs
        for i in range(len(seq)):
            stamp = _ns(seq.stamps[i])
            try:
                raw = seq.depth_raw(i)
            except (OSError, ValueError) as exc:
                raise ValueError(f"{seq.depth_paths[i]}: cannot read the depth PNG ({exc})") from None
            if raw.ndim != 2:
                raise ValueError(f"{seq.depth_paths[i]}: expected a single-channel 16-bit depth PNG, got shape {raw.shape}")
            # TUM stores metres * 5000; 16UC1 depth is millimetres (REP 118).
            mm = np.round(raw.astype(np.float64) * (1000.0 / datasets.TUM_DEPTH_FACTOR)).astype(np.uint16)
            bag.write(TUM_INFO_TOPIC, CAMERA_INFO, stamp, m.camera_info(stamp, TUM_FRAME, K, raw.shape[1], raw.shape[0]))
            bag.write(TUM_DEPTH_TOPIC, IMAGE, stamp, m.image16(stamp, TUM_FRAME, mm))
            if seq.poses is not None and seq.pose_valid[i]:
                bag.write(GROUND_TRUTH_TOPIC, ODOMETRY, stamp, m.odometry(stamp, GROUND_TRUTH_FRAME, TUM_FRAME,
                                                                          seq.poses[i]))
            if progress:
                progress(i + 1, len(seq))
    return len(seq)


def lidar_frames_to_bag(out_bag: str | Path, frames, *, topic: str = "/points", frame_id: str = "lidar",
                        storage: str = "sqlite3", overwrite: bool = False, progress: Progress | None = None,
                        total: int | None = None) -> int:
    """(stamp s, xyz (N, 3), ring (N,) or None, intensity (N,) or None, T_world_sensor or None) per frame ->
    PointCloud2 (x, y, z, intensity, ring; 0 where not given) on `topic` and ground truth on /ground_truth;
    returns the number of frames."""
    n = 0
    with BagWriter(out_bag, storage, overwrite) as bag:
        for stamp_s, xyz, ring, intensity, pose in frames:
            stamp = _ns(stamp_s)
            points = np.zeros(len(xyz), dtype=KITTI_POINT_DTYPE)
            points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            if ring is not None:
                points["ring"] = ring
            if intensity is not None:
                points["intensity"] = intensity
            bag.write(topic, POINTCLOUD2, stamp, bag.msgs.pointcloud2(stamp, frame_id, points))
            if pose is not None:
                bag.write(GROUND_TRUTH_TOPIC, ODOMETRY, stamp, bag.msgs.odometry(stamp, GROUND_TRUTH_FRAME, frame_id, pose))
            n += 1
            if progress:
                progress(n, total)
    return n


def depth_frames_to_bag(out_bag: str | Path, frames, K: np.ndarray, *, topic: str = TUM_DEPTH_TOPIC,
                        info_topic: str = TUM_INFO_TOPIC, frame_id: str = TUM_FRAME, storage: str = "sqlite3",
                        overwrite: bool = False, progress: Progress | None = None, total: int | None = None) -> int:
    """(stamp s, depth (H, W) metres with 0 = none, T_world_sensor or None) per frame -> 16UC1 Image
    (millimetres) + CameraInfo, ground truth on /ground_truth; returns the number of frames."""
    n = 0
    K = np.asarray(K, dtype=float)
    with BagWriter(out_bag, storage, overwrite) as bag:
        for stamp_s, depth, pose in frames:
            stamp = _ns(stamp_s)
            depth = np.asarray(depth, dtype=np.float64)
            valid = np.isfinite(depth) & (depth > 0)
            mm = np.where(valid, np.round(depth * 1000.0), 0.0)
            if (mm > 65535).any():
                raise ValueError("depth: beyond 65.535 m cannot be stored as 16UC1 millimetres")
            bag.write(info_topic, CAMERA_INFO, stamp, bag.msgs.camera_info(stamp, frame_id, K, depth.shape[1], depth.shape[0]))
            bag.write(topic, IMAGE, stamp, bag.msgs.image16(stamp, frame_id, mm.astype(np.uint16)))
            if pose is not None:
                bag.write(GROUND_TRUTH_TOPIC, ODOMETRY, stamp, bag.msgs.odometry(stamp, GROUND_TRUTH_FRAME, frame_id, pose))
            n += 1
            if progress:
                progress(n, total)
    return n


# ------------------------------------------------------------------------------------------------ reading


@dataclasses.dataclass
class BagMessage:
    topic: str
    msgtype: str
    log_time_ns: int
    raw: bytes

    def decode(self, store):
        return store.deserialize_cdr(self.raw, self.msgtype)


class BagReader:
    """Reads a rosbag2 (directory with metadata.yaml, sqlite3 or mcap); every failure is a BagError."""

    def __init__(self, path: str | Path):
        from rosbags.rosbag2 import Reader

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as exc:  # rosbags raises several types for broken metadata/storage
            raise BagError(f"{self.path}: cannot open the bag: corrupt, truncated or not a rosbag2 "
                           f"({type(exc).__name__}: {exc})") from None
        self.store = typestore()
        try:
            self.topics = {c.topic: c.msgtype for c in self._reader.connections}
            self.counts = {}
            for c in self._reader.connections:
                self.counts[c.topic] = self.counts.get(c.topic, 0) + int(c.msgcount)
        except Exception as exc:
            self.close()
            raise BagError(f"{self.path}: unreadable topic list ({type(exc).__name__}: {exc})") from None

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:
            pass

    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def topics_of_type(self, msgtype: str) -> list[str]:
        return sorted(t for t, m in self.topics.items() if m == msgtype)

    def messages(self, topics: list[str] | None = None) -> Iterator[BagMessage]:
        """Messages of the given topics (all when None) in log-time order."""
        conns = [c for c in self._reader.connections if topics is None or c.topic in topics]
        try:
            for conn, stamp, raw in self._reader.messages(connections=conns):
                yield BagMessage(conn.topic, conn.msgtype, int(stamp), bytes(raw))
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"{self.path}: corrupt or truncated bag while reading messages "
                           f"({type(exc).__name__}: {exc})") from None

    def decode(self, message: BagMessage):
        try:
            return message.decode(self.store)
        except Exception as exc:
            raise BagError(f"{self.path}: cannot decode a {message.msgtype} message on {message.topic} at "
                           f"{message.log_time_ns} ns ({type(exc).__name__}: {exc})") from None


def odometry_to_pose(msg) -> tuple[float, np.ndarray]:
    """nav_msgs/Odometry (any implementation) -> (stamp s, 4x4 pose)."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    T = np.eye(4)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
    if not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-9:
        raise ValueError(f"Odometry.pose.pose.orientation: expected a finite non-zero quaternion, got {quat}")
    T[:3, :3] = Rotation.from_quat(quat).as_matrix()
    T[:3, 3] = (p.x, p.y, p.z)
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, T


def read_ground_truth(reader: BagReader, topic: str = GROUND_TRUTH_TOPIC):
    """(stamps (N,), poses (N, 4, 4)) from the bag's ground-truth Odometry topic, or None when it has none."""
    if reader.topics.get(topic) != ODOMETRY:
        return None
    stamps, poses = [], []
    for message in reader.messages([topic]):
        stamp, T = odometry_to_pose(reader.decode(message))
        stamps.append(stamp)
        poses.append(T)
    if not stamps:
        return None
    return np.array(stamps), np.stack(poses)
