"""Over real DDS: ~/scan, the scan the odometry registers (the engine's kept points, in the sensor frame, at the
frame's stamp), sent only while something subscribes."""
from __future__ import annotations

import time

import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from node_harness import use_large_message_profile
from test_node import STARTUP_S, kitti_unorganized, ns, publish_and_wait, run_node  # noqa: F401
from line_odom import convert
from line_odom.datasets import kitti_sequence

use_large_message_profile()


def test_registered_scan_while_subscribed(run_node):
    import line_odom_core

    seq = kitti_sequence("07", 3)
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6})
    pub = h.publisher(PointCloud2, node.topic("points"))
    h.wait_matched(pub, node, STARTUP_S)
    stamps = [80.0 + float(t) for t in seq.times]
    publish_and_wait(h, node, pub, kitti_unorganized(seq, 0, stamps[0]), stamps[0])  # nobody subscribed: no scan
    scans = []
    h.node.create_subscription(PointCloud2, node.topic("line_odom/scan"), scans.append,
                               QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    h.wait_for(lambda: h.node.count_publishers(node.topic("line_odom/scan")) > 0, 30, "the scan publisher", node)
    time.sleep(0.5)
    assert scans == []
    engine = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    for i in (1, 2):
        msg = kitti_unorganized(seq, i, stamps[i])
        publish_and_wait(h, node, pub, msg, stamps[i])
        scan = h.wait_for(lambda: next((s for s in scans if convert.stamp_to_ns(s.header.stamp) == ns(stamps[i])),
                                       None), 30, f"the scan at {stamps[i]}", node)
        assert scan.header.frame_id == "velodyne"
        cloud = convert.pointcloud2_to_arrays(msg)
        expected = engine.downsampled_points(cloud.xyz, ring=cloud.ring)
        got = convert.pointcloud2_to_arrays(scan).xyz
        assert 1000 < len(got) < len(cloud.xyz) / 20  # 1/36 of the points
        np.testing.assert_allclose(got, expected.astype(np.float32), atol=1e-6)


def test_registered_lines_while_subscribed(run_node):
    """~/lines: the H-lines and V-lines the engine registered each scan with, two LINE_LIST markers in the sensor
    frame at the frame's stamp, the same segments as the engine's own last_lines; nothing while nobody subscribes."""
    import line_odom_core
    from visualization_msgs.msg import Marker, MarkerArray

    seq = kitti_sequence("07", 3)
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6})
    pub = h.publisher(PointCloud2, node.topic("points"))
    h.wait_matched(pub, node, STARTUP_S)
    stamps = [90.0 + float(t) for t in seq.times]
    engine = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    publish_and_wait(h, node, pub, kitti_unorganized(seq, 0, stamps[0]), stamps[0])  # nobody subscribed
    cloud = convert.pointcloud2_to_arrays(kitti_unorganized(seq, 0, stamps[0]))
    engine.register_points(cloud.xyz, stamps[0], ring=cloud.ring)
    got = []
    h.node.create_subscription(MarkerArray, node.topic("line_odom/lines"), got.append,
                               QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
    h.wait_for(lambda: h.node.count_publishers(node.topic("line_odom/lines")) > 0, 30, "the lines publisher", node)
    time.sleep(0.5)
    assert got == []
    for i in (1, 2):
        msg = kitti_unorganized(seq, i, stamps[i])
        publish_and_wait(h, node, pub, msg, stamps[i])
        cloud = convert.pointcloud2_to_arrays(msg)
        engine.register_points(cloud.xyz, stamps[i], ring=cloud.ring)
        h_lines, v_lines = engine.last_lines()
        markers = h.wait_for(lambda: next((m for m in got if m.markers and
                                           convert.stamp_to_ns(m.markers[0].header.stamp) == ns(stamps[i])), None),
                             30, f"the lines at {stamps[i]}", node)
        assert [m.ns for m in markers.markers] == ["h_lines", "v_lines"]
        assert all(m.type == Marker.LINE_LIST and m.header.frame_id == "velodyne" for m in markers.markers)
        assert markers.markers[0].color.r != markers.markers[1].color.r  # H and V coloured apart
        for marker, segments in zip(markers.markers, (h_lines, v_lines)):
            ends = np.array([[p.x, p.y, p.z] for p in marker.points])
            assert len(segments) > 50 and ends.shape == (2 * len(segments), 3)
            np.testing.assert_allclose(ends, segments.reshape(-1, 3), atol=1e-9)
