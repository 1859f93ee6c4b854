"""The real ROS 2 Jazzy runtime works here: a publisher process and a subscriber exchange
nav_msgs/Odometry and tf2_msgs/TFMessage over DDS (rclpy on Fast DDS), and every field arrives intact."""
from __future__ import annotations

import math
import subprocess
import sys
import time
import uuid

import pytest
import rclpy
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

# Values the publisher sends; floats are chosen so that any truncation (float32, rounding) shows.
STAMP = (1_700_000_123, 456_789_012)
POSITION = (1.25, -2.5e3, 3.141592653589793)
YAW = 0.3
QUATERNION = (0.0, 0.0, math.sin(YAW / 2), math.cos(YAW / 2))
COVARIANCE = [0.001 * (i + 1) + 1e-12 * i for i in range(36)]
LINEAR = (0.5, -0.25, 1e-9)
ANGULAR = (0.0, 0.01, -0.1)
TRANSFORMS = [("odom", "base_link", (1.0, 2.0, 3.0)), ("base_link", "velodyne", (0.27, 0.0, 1.73))]

PUBLISHER = r"""
import math, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from nav_msgs.msg import Odometry
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage

odom_topic, tf_topic = sys.argv[1], sys.argv[2]
STAMP, POSITION, QUATERNION, COVARIANCE, LINEAR, ANGULAR, TRANSFORMS = eval(sys.argv[3])

rclpy.init()
node = rclpy.create_node("runtime_test_publisher")
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
odom_pub = node.create_publisher(Odometry, odom_topic, qos)
tf_pub = node.create_publisher(TFMessage, tf_topic, qos)

odom = Odometry()
odom.header.stamp.sec, odom.header.stamp.nanosec = STAMP
odom.header.frame_id = "odom"
odom.child_frame_id = "base_link"
p = odom.pose.pose.position
p.x, p.y, p.z = POSITION
q = odom.pose.pose.orientation
q.x, q.y, q.z, q.w = QUATERNION
odom.pose.covariance = COVARIANCE
odom.twist.covariance = list(reversed(COVARIANCE))
odom.twist.twist.linear.x, odom.twist.twist.linear.y, odom.twist.twist.linear.z = LINEAR
odom.twist.twist.angular.x, odom.twist.twist.angular.y, odom.twist.twist.angular.z = ANGULAR

tf = TFMessage()
for parent, child, xyz in TRANSFORMS:
    t = TransformStamped()
    t.header.stamp = odom.header.stamp
    t.header.frame_id, t.child_frame_id = parent, child
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
    t.transform.rotation.w = 1.0
    tf.transforms.append(t)

print("publisher ready", flush=True)
deadline = time.monotonic() + 30.0
while time.monotonic() < deadline:  # until the test has what it needs and terminates us
    odom_pub.publish(odom)
    tf_pub.publish(tf)
    time.sleep(0.05)
node.destroy_node()
rclpy.shutdown()
"""


def test_odometry_and_tf_cross_process_over_dds(ros_env):
    suffix = uuid.uuid4().hex[:12]
    odom_topic, tf_topic = f"/runtime_test_{suffix}/odom", f"/runtime_test_{suffix}/tf"
    values = repr((STAMP, POSITION, QUATERNION, COVARIANCE, LINEAR, ANGULAR, TRANSFORMS))

    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    publisher = None
    try:
        assert rclpy.utilities.get_rmw_implementation_identifier() == "rmw_fastrtps_cpp"
        node = rclpy.create_node("runtime_test_subscriber", context=context)
        received: dict[str, list] = {"odom": [], "tf": []}
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(Odometry, odom_topic, received["odom"].append, qos)
        node.create_subscription(TFMessage, tf_topic, received["tf"].append, qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER, odom_topic, tf_topic, values],
                                     env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 25.0
        while time.monotonic() < deadline and not (received["odom"] and received["tf"]):
            executor.spin_once(timeout_sec=0.1)
            if publisher.poll() is not None:
                break
        if not (received["odom"] and received["tf"]):
            publisher.kill()
            output = publisher.communicate()[0]
            pytest.fail(f"nothing received over DDS within 25 s (publisher exit {publisher.returncode}):\n{output}")
    finally:
        if publisher is not None and publisher.poll() is None:
            publisher.terminate()
            publisher.wait(timeout=10)
        rclpy.shutdown(context=context)

    odom = received["odom"][0]
    assert (odom.header.stamp.sec, odom.header.stamp.nanosec) == STAMP
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")
    p, q = odom.pose.pose.position, odom.pose.pose.orientation
    assert (p.x, p.y, p.z) == POSITION
    assert (q.x, q.y, q.z, q.w) == QUATERNION
    assert list(odom.pose.covariance) == COVARIANCE
    assert list(odom.twist.covariance) == list(reversed(COVARIANCE))
    lin, ang = odom.twist.twist.linear, odom.twist.twist.angular
    assert (lin.x, lin.y, lin.z) == LINEAR
    assert (ang.x, ang.y, ang.z) == ANGULAR

    tf = received["tf"][0]
    got = [(t.header.frame_id, t.child_frame_id,
            (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z))
           for t in tf.transforms]
    assert got == TRANSFORMS
    assert all((t.header.stamp.sec, t.header.stamp.nanosec) == STAMP for t in tf.transforms)
    assert all(t.transform.rotation.w == 1.0 for t in tf.transforms)
