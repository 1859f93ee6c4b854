"""ROS messages of one frame's odometry: nav_msgs/Odometry, the PoseStamped of the Path, tf2_msgs/TFMessage.
The message packages are imported on first use, so the processing code runs without them until it publishes."""
from __future__ import annotations

from typing import Iterable

import numpy as np

from line_odom import convert, frames


def odometry_messages(stamp_ns: int, T: np.ndarray, pose_cov: np.ndarray, twist: np.ndarray, twist_cov: np.ndarray,
                      odom_frame: str, base_frame: str, publish_tf: bool):
    """(Odometry, PoseStamped, TFMessage or None) at `stamp_ns` for the base pose T (odom_frame -> base_frame)."""
    from geometry_msgs.msg import PoseStamped, TransformStamped
    from nav_msgs.msg import Odometry

    stamp_msg = convert.ns_to_stamp(stamp_ns)
    q = frames.quaternion_xyzw(T[:3, :3])
    odom = Odometry()
    odom.header.stamp = stamp_msg
    odom.header.frame_id = odom_frame
    odom.child_frame_id = base_frame
    p = odom.pose.pose
    p.position.x, p.position.y, p.position.z = (float(v) for v in T[:3, 3])
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = (float(v) for v in q)
    odom.pose.covariance = pose_cov.reshape(-1).tolist()
    tw = odom.twist.twist
    tw.linear.x, tw.linear.y, tw.linear.z = (float(v) for v in twist[:3])
    tw.angular.x, tw.angular.y, tw.angular.z = (float(v) for v in twist[3:])
    odom.twist.covariance = twist_cov.reshape(-1).tolist()
    pose_stamped = PoseStamped()
    pose_stamped.header = odom.header
    pose_stamped.pose = p
    tf = None
    if publish_tf:
        from tf2_msgs.msg import TFMessage

        ts = TransformStamped()
        ts.header = odom.header
        ts.child_frame_id = base_frame
        ts.transform.translation.x, ts.transform.translation.y, ts.transform.translation.z = (
            float(v) for v in T[:3, 3])
        r = ts.transform.rotation
        r.x, r.y, r.z, r.w = (float(v) for v in q)
        tf = TFMessage(transforms=[ts])
    return odom, pose_stamped, tf


def path_message(header, poses: Iterable):
    from nav_msgs.msg import Path

    path = Path()
    path.header = header
    path.poses = list(poses)
    return path
