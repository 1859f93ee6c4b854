"""The node's processing core (line_odom.processor) without DDS: frame algebra (extrinsic, initial pose),
twist, covariance propagation, stamps, malformed input, path bound, messages and diagnostics.

The frame algebra is checked exactly with a scripted engine that replays known sensor poses (the real engine's
accuracy is checked end to end in test_node.py)."""
import dataclasses

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from scipy.spatial.transform import Rotation

from line_odom import convert, frames
from line_odom.processor import NodeSettings, OdometryProcessor, validate_node_value
from line_odom_core.config import load_config


def _T(xyz, rpy):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    T[:3, 3] = xyz
    return T


@dataclasses.dataclass
class _Result:
    pose: np.ndarray
    delta: np.ndarray
    covariance: np.ndarray
    stats: dict


class ScriptedEngine:
    """Replays given sensor poses T_world_sensor (as the engine would report them) with a fixed delta covariance."""

    def __init__(self, sensor_poses, cov):
        self.poses = list(sensor_poses)
        self.cov = cov
        self.k = 0
        self.prev = None
        self.resets = 0

    def _next(self, stamp):
        pose = self.poses[self.k]
        self.k += 1
        delta = np.eye(4) if self.prev is None else np.linalg.inv(self.prev) @ pose
        self.prev = pose
        return _Result(pose, delta, self.cov, {"solver": "3L1P", "inliers": 321, "degenerate": False,
                                               "persistence": (1.0, 1.0, 0.987, 0.5, 0.25, 0.0),
                                               "points_refined": True, "point_matches": 2345,
                                               "ms": {"total": 12.5, "points": 2.5}})

    def register_points(self, xyz, stamp, ring=None):
        assert xyz.shape[1] == 3
        return self._next(stamp)

    def register_organized(self, xyz, stamp):
        assert xyz.ndim == 3
        return self._next(stamp)

    def register_depth(self, depth, K, stamp):
        return self._next(stamp)

    def reset(self, pose=None):
        self.prev = None
        self.resets += 1


def _cloud(stamp, n=50):
    rng = np.random.default_rng(0)
    return convert.pointcloud2_from_xyz(rng.normal(size=(n, 3)), frame_id="lidar", stamp=stamp)


def _processor(sensor_poses, cov=None, **settings):
    cov = np.diag([1e-4, 2e-4, 3e-4, 1e-6, 2e-6, 3e-6]) if cov is None else cov
    engine = ScriptedEngine(sensor_poses, cov)
    config = load_config("kitti_hdl64")
    s = NodeSettings.from_mapping({**config.extra, **settings})
    return OdometryProcessor(config, s, engine=engine), engine


def test_base_pose_from_sensor_poses_with_extrinsic_and_initial_pose():
    X = _T([1.2, -0.3, 1.7], [0.1, -0.2, 1.3])  # T_base_sensor
    B0 = _T([10.0, 5.0, 0.5], [0.0, 0.0, 0.7])  # initial base pose in odom
    base = [B0 @ _T([k * 1.0, 0.1 * k * k, 0.0], [0.0, 0.01 * k, 0.05 * k]) for k in range(6)]
    world_offset = _T([3, 4, 5], [0.3, 0.2, 0.1])  # the engine's world is arbitrary: only relative poses count
    sensor = [world_offset @ np.linalg.inv(X) @ np.linalg.inv(B0) @ B @ X for B in base]
    proc, _ = _processor(sensor, base_to_sensor=[1.2, -0.3, 1.7, 0.1, -0.2, 1.3],
                         initial_pose=[10.0, 5.0, 0.5, 0.0, 0.0, 0.7])
    for k, B in enumerate(base):
        out = proc.process_pointcloud(_cloud(100.0 + 0.1 * k))
        np.testing.assert_allclose(out.T_odom_base, B, atol=1e-9)
        q = out.odometry.pose.pose.orientation
        np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(), B[:3, :3], atol=1e-9)
        p = out.odometry.pose.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], B[:3, 3], atol=1e-9)
        if k:
            # twist: the constant body twist that moves the base from the previous pose to this one in dt
            D = np.linalg.inv(base[k - 1]) @ B
            xi = out.twist * 0.1
            np.testing.assert_allclose(frames.log_se3(D), xi, atol=1e-9)
            from scipy.linalg import expm
            hat = np.zeros((4, 4))
            hat[:3, :3] = frames.skew(xi[3:])
            hat[:3, 3] = xi[:3]
            np.testing.assert_allclose(expm(hat), D, atol=1e-9)


def test_quaternion_initial_pose_equals_rpy():
    q = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_quat()
    a = frames.pose_from_params([1, 2, 3, *q], "initial_pose")
    b = frames.pose_from_params([1, 2, 3, 0.1, 0.2, 0.3], "initial_pose")
    np.testing.assert_allclose(a, b, atol=1e-12)
    with pytest.raises(ValueError, match="initial_pose: expected 6 values"):
        frames.pose_from_params([1, 2, 3], "initial_pose")
    with pytest.raises(ValueError, match="unit norm"):
        frames.pose_from_params([0, 0, 0, 0, 0, 0, 2.0], "initial_pose")


def test_twist_of_straight_motion_and_covariance_propagation():
    v = 10.0  # m/s along x, 10 Hz
    sensor = [_T([v * 0.1 * k, 0, 0], [0, 0, 0]) for k in range(5)]
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    proc, _ = _processor(sensor, cov)
    outs = [proc.process_pointcloud(_cloud(50.0 + 0.1 * k)) for k in range(5)]
    np.testing.assert_allclose(outs[0].twist, 0)
    for out in outs[1:]:
        np.testing.assert_allclose(out.twist, [v, 0, 0, 0, 0, 0], atol=1e-9)
        J = np.eye(6) - 0.5 * frames.ad(np.array([1.0, 0, 0, 0, 0, 0]))  # ad^2 = 0 for a pure translation
        np.testing.assert_allclose(out.twist_covariance, J @ cov @ J.T / 0.01, rtol=1e-9, atol=1e-15)
        assert out.twist_covariance[1, 1] == pytest.approx((1e-4 + 0.25e-6) / 0.01)
    for out in outs:
        C = np.asarray(out.odometry.pose.covariance).reshape(6, 6)
        np.testing.assert_allclose(C, C.T)
        assert np.all(np.linalg.eigvalsh(C) > 0)
    # position variance along y grows by the rotation uncertainty times the lever arm (x = 4 m after 4 steps)
    C4 = outs[4].pose_covariance
    assert C4[0, 0] == pytest.approx(4e-4 + 1e-9, rel=1e-6)
    assert C4[1, 1] > 4e-4  # 4e-4 from translation + yaw uncertainty swept over the travelled distance
    assert C4[5, 5] == pytest.approx(4e-6 + 1e-9, rel=1e-6)


def test_extrinsic_rotates_covariance_into_base_frame():
    # sensor mounted with yaw 90 deg: sensor x = base y
    sensor = [np.eye(4), np.eye(4)]
    cov = np.diag([9e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6])
    proc, _ = _processor(sensor, cov, base_to_sensor=[0, 0, 0, 0, 0, np.pi / 2])
    proc.process_pointcloud(_cloud(1.0))
    out = proc.process_pointcloud(_cloud(1.1))
    assert out.pose_covariance[1, 1] == pytest.approx(9e-4 + 1e-9, rel=1e-6)
    assert out.pose_covariance[0, 0] == pytest.approx(1e-4 + 1e-9, rel=1e-6)


def test_stamp_backwards_resets_and_duplicate_is_dropped():
    sensor = [_T([k, 0, 0], [0, 0, 0]) for k in range(10)]
    proc, engine = _processor(sensor, initial_pose=[5, 0, 0, 0, 0, 0])
    assert proc.process_pointcloud(_cloud(10.0)) is not None
    out = proc.process_pointcloud(_cloud(10.1))
    assert out.T_odom_base[0, 3] == pytest.approx(6.0)
    assert proc.process_pointcloud(_cloud(10.1)) is None  # duplicate stamp
    assert proc.counters["frames_duplicate"] == 1
    out = proc.process_pointcloud(_cloud(3.0))  # a looping bag
    assert out.reset_reason and "backwards" in out.reset_reason
    assert engine.resets == 1 and proc.counters["resets"] == 1
    np.testing.assert_allclose(out.T_odom_base[:3, 3], [5, 0, 0])  # back at initial_pose
    assert len(out.path.poses) == 1


def test_malformed_frames_are_counted_and_next_good_frame_processed():
    sensor = [_T([k, 0, 0], [0, 0, 0]) for k in range(3)]
    proc, _ = _processor(sensor)
    bad = _cloud(1.0)
    bad.fields = bad.fields[1:]  # no x
    assert proc.process_pointcloud(bad) is None
    assert proc.counters["frames_malformed"] == 1 and "no 'x' field" in proc.last_error
    assert proc.process_pointcloud(_cloud(1.0)) is not None
    diag = proc.diagnostics()
    values = {kv.key: kv.value for kv in diag.status[0].values}
    assert values["frames_malformed"] == "1" and values["frames_processed"] == "1"
    assert "no 'x' field" in values["last_error"]
    assert diag.status[0].level == DiagnosticStatus.WARN and "malformed" in diag.status[0].message  # WARN
    assert values["solver"] == "3L1P" and values["inliers"] == "321" and values["ms.total"] == "12.500"
    assert values["persistence"] == "1.00 1.00 0.99 0.50 0.25 0.00"  # x y z rx ry rz share of the last motion
    # the point-to-plane refinement (points.*): whether it moved the frame, on how many voxel means, at what cost
    assert values["points_refined"] == "True" and values["point_matches"] == "2345" and values["ms.points"] == "2.500"
    diag = proc.diagnostics()  # the next period has no new problem
    assert diag.status[0].level == DiagnosticStatus.OK


def test_depth_needs_camera_info_and_rejects_bad_one():
    proc, _ = _processor([np.eye(4)] * 3, input="depth")
    img = convert.depth_to_image(np.full((4, 5), 2.0), stamp=1.0)
    assert proc.process_depth(img) is None and proc.counters["frames_dropped"] == 1
    bad = convert.camera_info_from_K(np.diag([0.0, 0.0, 1.0]), 5, 4)
    assert not proc.set_camera_info(bad) and proc.counters["frames_malformed"] == 1
    assert "focal length" in proc.last_error
    assert proc.process_depth(img, convert.camera_info_from_K(np.diag([500.0, 500.0, 1.0]), 5, 4)) is not None
    # another camera's CameraInfo (a colour camera's 10 x 8 for a 5 x 4 depth image): refused, naming both sizes
    other = convert.camera_info_from_K(np.diag([500.0, 500.0, 1.0]), 10, 8)
    assert proc.process_depth(convert.depth_to_image(np.full((4, 5), 2.0), stamp=2.0), other) is None
    assert proc.counters["frames_malformed"] == 2 and "CameraInfo is 10 x 8 but the image is 5 x 4" in proc.last_error
    unsized = convert.camera_info_from_K(np.diag([500.0, 500.0, 1.0]), 0, 0)  # states no size: taken as it is
    assert proc.process_depth(convert.depth_to_image(np.full((4, 5), 2.0), stamp=3.0), unsized) is not None


def test_path_is_bounded_and_messages_carry_frames():
    proc, _ = _processor([_T([k, 0, 0], [0, 0, 0]) for k in range(8)], **{"path.max_poses": 3},
                         odom_frame="map_odom", base_frame="robot")
    for k in range(8):
        out = proc.process_pointcloud(_cloud(1.0 + 0.1 * k))
    assert len(out.path.poses) == 3
    assert [p.pose.position.x for p in out.path.poses] == [5.0, 6.0, 7.0]
    assert out.path.header.frame_id == "map_odom"
    assert (out.odometry.header.frame_id, out.odometry.child_frame_id) == ("map_odom", "robot")
    (tf,) = out.tf.transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ("map_odom", "robot")
    assert tf.transform.translation.x == 7.0
    assert (tf.header.stamp.sec, tf.header.stamp.nanosec) == (1, 700_000_000)


def test_publish_tf_false_gives_no_tf():
    proc, _ = _processor([np.eye(4)], publish_tf=False)
    assert proc.process_pointcloud(_cloud(1.0)).tf is None


@pytest.mark.parametrize("name, value, message", [
    ("input", "camera", "one of pointcloud, depth"),
    ("path.max_poses", 0, r"in \[1, 1000000\]"),
    ("publish_tf", "yes", "expected bool"),
    ("base_to_sensor", [1, 2], "expected 6 values"),
    ("odom_frame", "", "expected str"),
    ("no_such_key", 1, "unknown node parameter"),
])
def test_bad_node_values_have_clear_errors(name, value, message):
    with pytest.raises(ValueError, match=message) as err:
        validate_node_value(name, value)
    assert name in str(err.value)


def test_from_parameters_splits_engine_and_node_overrides():
    proc = OdometryProcessor.from_parameters("tum_kinect", {"downsample": 10, "base_frame": "cam_base"},
                                             engine=ScriptedEngine([np.eye(4)], np.eye(6)))
    assert proc.config["downsample"] == 10 and proc.settings.base_frame == "cam_base"
    assert proc.settings.input == "depth"
    with pytest.raises(ValueError, match="downsample"):
        OdometryProcessor.from_parameters("tum_kinect", {"downsample": 0}, engine=object())


def test_se3_log_and_left_jacobian_inverse_against_finite_differences():
    from scipy.linalg import expm

    def hat(xi):
        H = np.zeros((4, 4))
        H[:3, :3] = frames.skew(xi[3:])
        H[:3, 3] = xi[:3]
        return H

    xi = np.array([0.9, -0.2, 0.1, 0.05, -0.1, 0.3])
    D = expm(hat(xi))
    np.testing.assert_allclose(frames.log_se3(D), xi, atol=1e-12)
    J = frames.left_jacobian_inverse(xi)
    eps = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        numeric = (frames.log_se3(expm(hat(d)) @ D) - frames.log_se3(expm(hat(-d)) @ D)) / (2 * eps)
        np.testing.assert_allclose(numeric, J[:, i], atol=1e-6)
    # adjoint: T exp(xi) T^-1 = exp(Ad_T xi)
    T = _T([1, 2, 3], [0.3, -0.2, 0.5])
    np.testing.assert_allclose(T @ D @ np.linalg.inv(T), expm(hat(frames.adjoint(T) @ xi)), atol=1e-12)


def test_repeated_rejections_are_counted_and_logged_once_per_reason_with_a_count():
    """300 malformed clouds at 100 Hz, two defects alternating: one line per defect, then one line per defect telling
    how many more came in the window (a rate limit that compared with the last reason only logged all 300)."""
    from line_odom.diagnostics import RateLimitedLog

    messages = []
    log = type("Log", (), {"info": lambda self, m: None, "warning": lambda self, m: messages.append(m)})()
    config = load_config("kitti_hdl64")
    proc = OdometryProcessor(config, NodeSettings.from_mapping(config.extra), engine=ScriptedEngine([], np.eye(6)),
                             logger=log)
    now = [1000.0]
    proc.log_limiter = RateLimitedLog(proc._warn, clock=lambda: now[0])
    no_x = _cloud(1.0)
    no_x.fields = no_x.fields[1:]
    empty = _cloud(2.0)
    empty.width = 0
    for k in range(300):
        bad = no_x if k % 2 == 0 else empty
        bad.header.stamp = convert.sec_to_stamp(1.0 + 0.01 * k)  # a stamp in the text does not make a new reason
        assert proc.process_pointcloud(bad) is None
        now[0] += 0.01
    assert proc.counters["frames_malformed"] == 300
    assert len(messages) == 2, messages
    assert "no 'x' field" in messages[0] and "empty cloud" in messages[1]
    proc.diagnostics()  # within the window: nothing to tell yet
    assert len(messages) == 2
    now[0] += 10.0
    proc.diagnostics()  # the window is over: the counts
    assert len(messages) == 4, messages
    assert sorted(m.split("... ")[1] for m in messages[2:]) == ["149 more like this in the last 10 s"] * 2
    assert proc.process_pointcloud(no_x) is None  # a new window: logged again at once
    assert len(messages) == 5 and "more like this" not in messages[4]


@pytest.mark.parametrize("offsets, extra, field", [
    ((0, 2, 8), None, "PointCloud2.fields[y].offset"),        # y inside x
    ((0, 0, 0), None, "PointCloud2.fields[y].offset"),        # x = y = z
    ((0, 4, 8), ("intensity", 10), "PointCloud2.point_step"),  # a float32 at 10 runs past the 12-byte point
])
def test_overlapping_fields_and_fields_past_point_step_are_refused_as_malformed(offsets, extra, field):
    """Layouts a writer got wrong are not read as garbage and held: each cloud is counted malformed (the engine is
    never called), the reason logged once naming the field, and the next good cloud is registered."""
    from sensor_msgs.msg import PointField

    messages = []
    proc, engine = _processor([np.eye(4)] * 2)
    proc._warn = messages.append
    proc.log_limiter = type(proc.log_limiter)(messages.append)
    for k in range(30):
        bad = convert.pointcloud2_from_xyz(np.random.default_rng(k).normal(size=(50, 3)).astype(np.float32),
                                           frame_id="lidar", stamp=1.0 + 0.1 * k)
        bad.fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1)
                      for n, o in zip("xyz", offsets)]
        if extra is not None:
            bad.fields.append(PointField(name=extra[0], offset=extra[1], datatype=PointField.FLOAT32, count=1))
        assert bad.point_step == 12
        assert proc.process_pointcloud(bad) is None
    assert proc.counters["frames_malformed"] == 30 and proc.counters["frames_processed"] == 0
    assert engine.k == 0  # the engine never saw one
    assert len(messages) == 1 and field in messages[0] and "\n" not in messages[0], messages
    assert proc.process_pointcloud(_cloud(10.0)) is not None and proc.counters["frames_processed"] == 1


def test_oversized_depth_image_is_refused_before_conversion_and_memory_returns(monkeypatch):
    """An image over max_pixels, or contradicting its CameraInfo, is refused from its header: no conversion runs
    (checked by making it fail), each is counted and logged once naming the limit, and the process's RSS stays
    within a margin of where it was after the first refusal."""
    from line_odom import processor as processor_module
    from line_odom.diagnostics import RateLimitedLog

    messages = []
    log = type("Log", (), {"info": lambda self, m: None, "warning": lambda self, m: messages.append(m)})()
    config = load_config("tum_kinect")
    proc = OdometryProcessor(config, NodeSettings.from_mapping({**config.extra, "max_pixels": 640 * 480}),
                             engine=ScriptedEngine([np.eye(4)] * 4, np.eye(6) * 1e-4), logger=log)
    proc.log_limiter = RateLimitedLog(proc._warn, clock=lambda: 0.0)
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    assert proc.process_depth(convert.depth_to_image(np.full((480, 640), 2.0), stamp=1.0),
                              convert.camera_info_from_K(K, 640, 480)) is not None

    def no_conversion(*args, **kwargs):
        raise AssertionError("the image was converted")

    monkeypatch.setattr(processor_module.convert, "image_to_depth", no_conversion)
    big = convert.depth_to_image(np.full((2000, 3000), 2.0), stamp=2.0)  # 12 MB of 16UC1
    assert proc.process_depth(big) is None
    rss0 = _rss_mb()
    for k in range(20):
        msg = convert.depth_to_image(np.full((2000, 3000), 2.0), stamp=3.0 + k)
        assert proc.process_depth(msg) is None
        del msg
    assert proc.counters["frames_too_large"] == 21
    assert _rss_mb() - rss0 < RSS_MARGIN_MB
    too_large = [m for m in messages if "max_pixels" in m]
    assert len(too_large) == 1 and "3000 x 2000 = 6000000 pixels exceed the max_pixels limit of 307200" in \
        too_large[0]
    # a well-sized image of another size than its CameraInfo: refused unconverted too
    other = convert.depth_to_image(np.full((240, 320), 2.0), stamp=30.0)
    assert proc.process_depth(other) is None and proc.counters["frames_malformed"] == 1
    assert "CameraInfo is 640 x 480 but the image is 320 x 240" in proc.last_error
    assert proc.check_depth_image(other) is False and proc.counters["frames_malformed"] == 2
    status = proc.diagnostics().status[0]
    assert "21 frame(s) too large" in status.message


RSS_MARGIN_MB = 40.0  # 20 refused 12 MB images: holding even two of them would exceed it


def _rss_mb() -> float:
    import gc
    from pathlib import Path

    gc.collect()
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise KeyError("VmRSS")


@pytest.mark.parametrize("sec, nanosec, field", [(-5, 0, "header.stamp.sec"), (10, 1_000_000_000, "header.stamp.nanosec"),
                                                 (10, 2**32 - 1, "header.stamp.nanosec")])
def test_stamps_no_clock_gives_are_refused_as_malformed_in_one_line(sec, nanosec, field):
    messages = []
    log = type("Log", (), {"info": lambda self, m: None, "warning": lambda self, m: messages.append(m)})()
    proc, _ = _processor([np.eye(4)] * 2)
    proc._warn = log.warning
    proc.log_limiter = type(proc.log_limiter)(log.warning)
    bad = _cloud(1.0)
    bad.header.stamp.sec, bad.header.stamp.nanosec = sec, nanosec
    for _ in range(60):
        assert proc.process_pointcloud(bad) is None
    assert proc.counters["frames_malformed"] == 60 and proc.counters["frames_processed"] == 0
    assert len(messages) == 1 and f"PointCloud2.{field}" in messages[0] and "\n" not in messages[0]
    depth_proc, _ = _processor([np.eye(4)], input="depth")
    img = convert.depth_to_image(np.full((4, 5), 2.0), stamp=1.0)
    img.header.stamp.sec, img.header.stamp.nanosec = sec, nanosec
    assert depth_proc.process_depth(img, convert.camera_info_from_K(np.diag([500.0, 500.0, 1.0]), 5, 4)) is None
    assert depth_proc.counters["frames_malformed"] == 1 and f"Image.{field}" in depth_proc.last_error
    assert proc.process_pointcloud(_cloud(2.0)) is not None  # and the next good frame goes on


def test_node_parameter_table_and_settings_agree():
    """Each row of the table is a NodeSettings attribute with the row's default (the table is the one source)."""
    from line_odom.node_parameters import NODE_PARAMETERS

    fields = {f.name for f in dataclasses.fields(NodeSettings)}
    assert fields == {p.attribute for p in NODE_PARAMETERS}
    defaults = NodeSettings()
    for p in NODE_PARAMETERS:
        assert getattr(defaults, p.attribute) == p.default, p.name
        assert validate_node_value(p.name, p.default) == p.default


def test_registered_scan_is_built_only_when_wanted():
    """~/scan: nothing is built unless scan_wanted (the node sets it while the topic has a subscriber); an organized
    cloud's scan is every downsample-th row and column from the first, within the range limits, at the frame's
    stamp and frame."""
    proc, _ = _processor([np.eye(4)] * 3)
    proc.config = load_config("kitti_hdl64", {"downsample": 2, "sensor.min_range": 1.0})
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-20, 20, size=(10, 20, 3))
    xyz[0, 0] = np.nan
    xyz[2, 2] = (0.1, 0.1, 0.1)  # closer than sensor.min_range
    msg = convert.pointcloud2_from_xyz(xyz, frame_id="lidar", stamp=5.0)
    assert proc.process_pointcloud(msg).scan is None
    proc.scan_wanted = True
    msg.header.stamp = convert.sec_to_stamp(5.1)
    out = proc.process_pointcloud(msg)
    scan = convert.pointcloud2_to_arrays(out.scan)
    assert out.scan.header.frame_id == "lidar" and convert.stamp_to_ns(out.scan.header.stamp) == 5_100_000_000
    kept = xyz[::2, ::2].reshape(-1, 3)
    kept = kept[np.isfinite(kept).all(axis=1) & (np.linalg.norm(kept, axis=1) >= 1.0)]
    assert len(kept) == 5 * 10 - 2
    np.testing.assert_allclose(scan.xyz, kept.astype(np.float32))


def test_registered_scan_is_deskewed_as_registered():
    """~/scan of sweeps cast while the sensor moves (the simulated VLP-16 street at 10 m/s, point times in the cloud):
    the points as the engine registered them, each moved to where it was at the stamp, not where it was measured.
    Measured 3 mm median from the truth (the measured points: 0.55 m); bounds 0.02 and 0.3 m."""
    from scipy.spatial import cKDTree

    from line_odom import sim

    run = sim.make("street", frames=4, seed=0, sensor="vlp16", noise_std=0.01, motion_distortion=True)
    config = load_config("vlp16")
    proc = OdometryProcessor(config, NodeSettings.from_mapping(config.extra))
    proc.scan_wanted = True
    for sweep in run:
        cloud = convert.pointcloud2_from_xyz(sweep.data.points, ring=sweep.data.ring, time=sweep.data.time,
                                             frame_id="velodyne", stamp=convert.sec_to_stamp(1000.0 + sweep.stamp))
        out = proc.process_pointcloud(cloud)
    assert out.stats["deskewed"]
    scan = convert.pointcloud2_to_arrays(out.scan).xyz.astype(float)
    measured = np.asarray(proc.engine.downsampled_points(sweep.data.points, ring=sweep.data.ring))
    assert scan.shape == measured.shape
    distance, index = cKDTree(sweep.data.points).query(measured)
    assert distance.max() == 0.0
    at_stamp = np.linalg.inv(run.trajectory.pose_at(sweep.stamp))
    truth = []
    for point, time in zip(measured, sweep.data.time[index]):
        T = at_stamp @ run.trajectory.pose_at(sweep.stamp + float(time))
        truth.append(T[:3, :3] @ point + T[:3, 3])
    assert np.median(np.linalg.norm(scan - truth, axis=1)) < 0.02
    assert np.median(np.linalg.norm(measured - truth, axis=1)) > 0.3


def test_the_node_imports_no_offline_tooling():
    """The node's runtime path (node, lifecycle node, processor) imports no bag, dataset, replay or CLI code."""
    import subprocess
    import sys

    code = ("import sys, line_odom.node, line_odom.lifecycle_node; "
            "print(' '.join(m for m in sys.modules if m.split('.')[0] in ('line_odom', 'rosbags')))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    offline = ("line_odom.bags", "line_odom.datasets", "line_odom.replay", "line_odom.cli", "line_odom.readers",
               "line_odom.batch", "line_odom.evaluation", "line_odom.sim", "rosbags")
    assert "line_odom.processor" in loaded
    assert [m for m in loaded if m.startswith(offline)] == []


def test_a_ring_field_of_one_value_is_ignored_counted_and_logged():
    """Some converters fill the ring field with 0: the cloud would lie in one row, which the engine refuses. The node
    registers it with the rows from the points' elevations, as a cloud without the field, and counts it."""
    from line_odom.bags import kitti_rings
    from line_odom.datasets import kitti_sequence

    data = kitti_sequence("07", 3)
    overrides = {"sensor.model": "uniform", "sensor.rows": 16, "sensor.max_elevation_deg": 2.0,
                 "sensor.min_elevation_deg": -24.9}
    zeroed, plain = (OdometryProcessor.from_parameters("vlp16", overrides) for _ in range(2))
    for i in range(len(data)):
        points = data.points(i)
        keep = kitti_rings(points) % 4 == 0
        xyz = np.ascontiguousarray(points[keep, :3])
        stamp = 1.0 + float(data.times[i])
        with_zero_ring = convert.pointcloud2_from_xyz(xyz, ring=np.zeros(len(xyz), np.uint16), frame_id="lidar",
                                                      stamp=stamp)
        out = zeroed.process_pointcloud(with_zero_ring)
        reference = plain.process_pointcloud(convert.pointcloud2_from_xyz(xyz, frame_id="lidar", stamp=stamp))
        assert out is not None and out.stats["registered"]
        np.testing.assert_array_equal(out.T_odom_base, reference.T_odom_base)
    assert zeroed.counters["ring_fields_ignored"] == len(data) and zeroed.counters["frames_failed"] == 0
    assert "fields[ring]: one value (0)" in zeroed.last_error
    assert plain.counters["ring_fields_ignored"] == 0
