#!/usr/bin/env python3
"""What the node adds to a registration: per-frame milliseconds of its processor (message in -> Odometry, TF and
Path messages out) beyond the engine's own total, and what publishing the path costs.

    .venv/bin/python bench/node_overhead.py

KITTI scans go in as PointCloud2 (x, y, z, intensity float32, as a Velodyne driver sends them), TUM depth as
16UC1 Image + CameraInfo; the processor is the node's (line_odom.processor), without DDS. "conversion" is
PointCloud2/Image -> numpy alone. The path row publishes a nav_msgs/Path of 10 and of path.max_poses = 1000 poses
through rclpy (the node sends one per frame while something subscribes, every path.period seconds).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))

from line_odom import convert  # noqa: E402
from line_odom.datasets import kitti_sequence, tum_sequence  # noqa: E402
from line_odom.processor import OdometryProcessor  # noqa: E402


def kitti_messages(seq):
    data = kitti_sequence(seq)
    msgs = []
    for i in range(len(data)):
        p = data.points(i)
        cloud = np.zeros(len(p), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
        for k, name in enumerate(("x", "y", "z", "intensity")):
            cloud[name] = p[:, k]
        msgs.append(convert.pointcloud2_from_array(cloud, frame_id="velodyne", stamp=1000.0 + float(data.times[i])))
    return msgs


def measure(make_processor, process, convert_only, msgs, repeat):
    """Median per-frame ms: processor beyond the engine total, conversion alone, engine total."""
    beyond, conversion, engine = [], [], []
    for _ in range(repeat):
        proc = make_processor()
        for k, msg in enumerate(msgs):
            t0 = time.perf_counter()
            convert_only(msg)
            conversion.append((time.perf_counter() - t0) * 1e3)
            out = process(proc, msg)
            if k == 0:
                continue
            engine.append(out.stats["ms"]["total"])
            beyond.append(out.latency_ms - out.stats["ms"]["total"])
    return float(np.median(beyond)), float(np.median(conversion)), float(np.median(engine))


def path_publish_ms(poses):
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path as PathMsg

    rclpy.init()
    try:
        node = rclpy.create_node("line_odom_path_cost")
        pub = node.create_publisher(PathMsg, "path", 1)
        msg = PathMsg()
        msg.poses = [PoseStamped() for _ in range(poses)]
        pub.publish(msg)
        t0 = time.perf_counter()
        for _ in range(50):
            pub.publish(msg)
        cost = (time.perf_counter() - t0) * 1e3 / 50
        node.destroy_node()
        return cost
    finally:
        rclpy.shutdown()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", default="07")
    parser.add_argument("--kitti-levels", nargs="+", type=int, default=[1, 6])
    parser.add_argument("--tum-frames", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)

    print("median ms per frame (first frame of each run left out)")
    print(f"{'input':34} | {'beyond engine':>13} {'conversion':>10} | {'engine total':>12}")
    msgs = kitti_messages(args.kitti)
    for level in args.kitti_levels:
        row = measure(lambda: OdometryProcessor.from_parameters("kitti_hdl64", {"downsample": level}),
                      lambda proc, m: proc.process_pointcloud(m), convert.pointcloud2_to_arrays, msgs, args.repeat)
        name = f"KITTI {args.kitti} PointCloud2, 1/{level * level}" if level > 1 else f"KITTI {args.kitti} PointCloud2, full"
        print(f"{name:34} | {row[0]:13.2f} {row[1]:10.2f} | {row[2]:12.2f}")
    data = tum_sequence(args.tum_frames)
    images = [convert.depth_to_image(data.depth(i), encoding="16UC1", frame_id="camera", stamp=float(data.stamps[i]))
              for i in range(len(data))]
    info = convert.camera_info_from_K(data.K, 640, 480, frame_id="camera", stamp=float(data.stamps[0]))

    def depth_processor():
        proc = OdometryProcessor.from_parameters("tum_kinect", {"downsample": 10, "input": "depth"})
        proc.set_camera_info(info)
        return proc

    row = measure(depth_processor, lambda proc, m: proc.process_depth(m), convert.image_to_depth, images, args.repeat)
    print(f"{'TUM fr1/xyz 16UC1 Image, 1/100':34} | {row[0]:13.2f} {row[1]:10.2f} | {row[2]:12.2f}")
    print(f"publishing nav_msgs/Path (rclpy): 10 poses {path_publish_ms(10):.2f} ms, "
          f"1000 poses {path_publish_ms(1000):.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
