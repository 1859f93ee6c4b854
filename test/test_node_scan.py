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
