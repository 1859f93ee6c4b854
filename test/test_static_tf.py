"""The sensor's mounting from /tf_static (base_to_sensor_from_tf): the static transform tree, and the processor
taking T_base_sensor from it, dropping and counting the frames before it is known."""
from __future__ import annotations

import numpy as np
import pytest
from node_harness import transform_stamped
from scipy.spatial.transform import Rotation
from tf2_msgs.msg import TFMessage

from line_odom import convert, frames
from line_odom.datasets import kitti_sequence
from line_odom.processor import OdometryProcessor
from line_odom.static_tf import StaticTransforms, TransformError

MOUNT = [0.3, -0.1, 1.2, 0.0, 0.05, 0.4]  # base -> mount [x, y, z, roll, pitch, yaw]
LIDAR = [0.0, 0.2, 0.5, 0.02, 0.0, -0.3]  # mount -> lidar
CAMERA = [0.4, 0.0, 0.9, -np.pi / 2, 0.0, -np.pi / 2]  # base -> camera


def stamped(parent: str, child: str, pose):
    return transform_stamped(parent, child, P(pose))


def P(pose) -> np.ndarray:
    return frames.pose_from_params(pose, "pose")


def robot_tree() -> StaticTransforms:
    tree = StaticTransforms()
    tree.add(TFMessage(transforms=[stamped("base_link", "mount", MOUNT), stamped("mount", "lidar", LIDAR)]))
    tree.add(TFMessage(transforms=[stamped("base_link", "camera", CAMERA)]))
    return tree


def test_lookup_through_a_chain_its_inverse_and_between_siblings():
    tree = robot_tree()
    np.testing.assert_allclose(tree.lookup("base_link", "lidar"), P(MOUNT) @ P(LIDAR), atol=1e-12)
    np.testing.assert_allclose(tree.lookup("lidar", "base_link"), np.linalg.inv(P(MOUNT) @ P(LIDAR)), atol=1e-12)
    np.testing.assert_allclose(tree.lookup("camera", "lidar"), np.linalg.inv(P(CAMERA)) @ P(MOUNT) @ P(LIDAR),
                               atol=1e-12)
    np.testing.assert_allclose(tree.lookup("mount", "mount"), np.eye(4))
    np.testing.assert_allclose(tree.lookup("/base_link", "/lidar"), tree.lookup("base_link", "lidar"))  # tf1 names
    assert tree.lookup("base_link", "gps") is None
    assert tree.lookup("map", "lidar") is None
    assert len(tree) == 3


def test_a_republished_transform_replaces_the_old_one():
    tree = robot_tree()
    moved = [0.0, 0.0, 2.0, 0.0, 0.0, 0.0]
    tree.add(TFMessage(transforms=[stamped("base_link", "mount", moved)]))
    np.testing.assert_allclose(tree.lookup("base_link", "lidar"), P(moved) @ P(LIDAR), atol=1e-12)


def test_bad_transforms_name_the_field_and_the_good_ones_are_kept():
    tree = StaticTransforms()
    bad_q = stamped("base_link", "imu", [0, 0, 0, 0, 0, 0])
    bad_q.transform.rotation.w = 2.0
    nan_t = stamped("base_link", "gps", [0, 0, 0, 0, 0, 0])
    nan_t.transform.translation.y = float("nan")
    no_child = stamped("base_link", "", [0, 0, 0, 0, 0, 0])
    cases = [(bad_q, r"TFMessage\.transforms\[1\]\.transform\.rotation: expected a unit quaternion"),
             (nan_t, r"TFMessage\.transforms\[1\]\.transform\.translation: expected finite values"),
             (no_child, r"TFMessage\.transforms\[1\]\.child_frame_id: expected a frame name")]
    for bad, message in cases:
        with pytest.raises(TransformError, match=message):
            tree.add(TFMessage(transforms=[stamped("base_link", "lidar", LIDAR), bad]))
    np.testing.assert_allclose(tree.lookup("base_link", "lidar"), P(LIDAR), atol=1e-12)
    assert len(tree) == 1
    with pytest.raises(TransformError, match=r"transforms\[0\]\.child_frame_id: 'base_link' under 'lidar' would "
                                             r"close a loop"):
        tree.add(TFMessage(transforms=[stamped("lidar", "base_link", LIDAR)]))
    assert tree.lookup("base_link", "lidar") is not None  # and lookups still end


# ------------------------------------------------------------------------------------------------ processor

def clouds(n: int, frame_id: str = "lidar"):
    seq = kitti_sequence("07", n)
    return [convert.pointcloud2_from_xyz(seq.xyz(i), frame_id=frame_id, stamp=100.0 + float(seq.times[i]))
            for i in range(n)]


def processor(**node):
    return OdometryProcessor.from_parameters("kitti_hdl64", {"downsample": 6, **node})


def test_mounting_from_tf_static_gives_the_same_odometry_as_the_parameter():
    msgs = clouds(4)
    X = P(MOUNT) @ P(LIDAR)
    by_parameter = processor(base_to_sensor=[*X[:3, 3], *Rotation.from_matrix(X[:3, :3]).as_quat()])
    by_tf = processor(base_to_sensor_from_tf=True)

    assert by_tf.process_pointcloud(msgs[0]) is None  # no /tf_static yet: dropped and counted, no pose
    assert by_tf.counters["frames_no_extrinsic"] == 1 and by_tf.counters["frames_processed"] == 0
    assert "no transform base_link -> lidar on /tf_static yet" in by_tf.last_error
    _, values = diagnostics(by_tf)
    assert values["base_to_sensor"] == "waiting for /tf_static (0 transforms)"

    by_tf.add_static_tf(TFMessage(transforms=[stamped("base_link", "mount", MOUNT)]))
    assert by_tf.process_pointcloud(msgs[0]) is None  # mount -> lidar still missing
    assert by_tf.counters["frames_no_extrinsic"] == 2
    by_tf.add_static_tf(TFMessage(transforms=[stamped("mount", "lidar", LIDAR)]))

    for msg in msgs:
        a, b = by_parameter.process_pointcloud(msg), by_tf.process_pointcloud(msg)
        np.testing.assert_allclose(b.T_odom_base, a.T_odom_base, atol=1e-9)
        np.testing.assert_allclose(b.pose_covariance, a.pose_covariance, rtol=1e-6, atol=1e-15)
        np.testing.assert_allclose(b.twist, a.twist, atol=1e-8)
    np.testing.assert_allclose(by_tf.T_base_sensor, X, atol=1e-12)
    status, values = diagnostics(by_tf)
    assert values["base_to_sensor"] == "/tf_static base_link -> lidar"
    assert status.level == status.WARN and "the sensor's mounting not on /tf_static yet" in status.message
    assert by_tf.counters["frames_processed"] == len(msgs)

    # the extrinsic is held for the run: a later change on /tf_static (or a reset) does not move it
    by_tf.add_static_tf(TFMessage(transforms=[stamped("base_link", "mount", [0, 0, 5.0, 0, 0, 0])]))
    by_tf.reset()
    by_tf.process_pointcloud(msgs[0])
    np.testing.assert_allclose(by_tf.T_base_sensor, X, atol=1e-12)


def test_frames_of_another_sensor_or_without_a_frame_are_rejected():
    by_tf = processor(base_to_sensor_from_tf=True)
    by_tf.add_static_tf(TFMessage(transforms=[stamped("base_link", "lidar", LIDAR),
                                              stamped("base_link", "other_lidar", MOUNT)]))
    (nameless,) = clouds(1, frame_id="")
    assert by_tf.process_pointcloud(nameless) is None
    assert "header.frame_id is empty" in by_tf.last_error
    first, second = clouds(2)
    assert by_tf.process_pointcloud(first) is not None
    (other,) = clouds(1, frame_id="other_lidar")
    other.header.stamp = second.header.stamp
    assert by_tf.process_pointcloud(other) is None
    assert "header.frame_id 'other_lidar' is not the sensor frame 'lidar'" in by_tf.last_error
    assert by_tf.counters["frames_malformed"] == 2
    assert by_tf.process_pointcloud(second) is not None  # the sensor's next frame goes on


def test_a_bad_static_transform_is_counted_and_the_node_goes_on():
    by_tf = processor(base_to_sensor_from_tf=True)
    bad = stamped("base_link", "lidar", LIDAR)
    bad.transform.rotation.x = 0.9
    assert not by_tf.add_static_tf(TFMessage(transforms=[bad]))
    assert by_tf.counters["tf_rejected"] == 1
    assert "TFMessage.transforms[0].transform.rotation" in by_tf.last_error
    assert by_tf.add_static_tf(TFMessage(transforms=[stamped("base_link", "lidar", LIDAR)]))
    assert by_tf.process_pointcloud(clouds(1)[0]) is not None


def test_without_the_setting_no_tf_is_needed():
    plain = processor()
    assert plain.static_tf is None and not plain.add_static_tf(TFMessage())
    assert plain.process_pointcloud(clouds(1)[0]) is not None
    assert "frames_no_extrinsic" not in plain.counters and "base_to_sensor" not in plain.diagnostics_values()


def diagnostics(proc):
    status = proc.diagnostics().status[0]
    return status, {kv.key: kv.value for kv in status.values}
