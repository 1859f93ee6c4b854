#!/usr/bin/env python3
"""Do the shared KITTI scans agree with their ground truth? Scan-to-scan alignment under GT vs the estimates.

    .venv/bin/python bench/gt_consistency.py              # KITTI 00/04/07, line_odom and KISS-ICP at full resolution
    .venv/bin/python bench/gt_consistency.py --no-kiss

For every frame pair the non-ground points of scan i-1 (5-40 m horizontal range, z > -1.3 m in the LiDAR frame)
are moved into scan i by a relative motion and matched to their nearest neighbour in scan i (all points). A motion
that describes the scans leaves them close: the table prints the median nearest-neighbour distance and the share
within 5 cm and 10 cm, per sequence, for the ground-truth motion and for each method's estimate, and the forward
motion per frame. Where both methods align the scans much more tightly than the ground truth does, the RPE of
that sequence measures the ground truth's disagreement with the scans, not the methods' accuracy (bench/accuracy.py
goals on KITTI 00, docs/RESULTS.md).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.append(str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import line_odom_core  # noqa: E402
from accuracy import KISS_HINT, kiss_available, kiss_odometry  # noqa: E402
from line_odom.datasets import kitti_sequence  # noqa: E402


def structure_points(xyz: np.ndarray) -> np.ndarray:
    horizontal = np.linalg.norm(xyz[:, :2], axis=1)
    return xyz[(horizontal > 5.0) & (horizontal < 40.0) & (xyz[:, 2] > -1.3)]


def alignment(prev: np.ndarray, tree: cKDTree, T_prev_cur: np.ndarray) -> tuple[float, float, float]:
    """Median NN distance and shares within 5 / 10 cm of `prev` (frame i-1) moved into frame i."""
    T = np.linalg.inv(T_prev_cur)
    d, _ = tree.query(prev @ T[:3, :3].T + T[:3, 3])
    return float(np.median(d)), float(np.mean(d < 0.05)), float(np.mean(d < 0.10))


def relative(poses: list[np.ndarray], i: int) -> np.ndarray:
    return np.linalg.inv(poses[i - 1]) @ poses[i]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", nargs="+", default=["00", "04", "07"])
    parser.add_argument("--no-kiss", action="store_true")
    args = parser.parse_args()
    use_kiss = not args.no_kiss and kiss_available()
    if not args.no_kiss and not use_kiss:
        print(KISS_HINT)

    print("KITTI scans aligned by each relative motion (mean over frame pairs); forward = motion along x per frame")
    head = f"{'seq':4} {'motion':10} | {'median NN [m]':>13} {'<5 cm':>6} {'<10 cm':>7} | {'forward [m]':>11}"
    print(head)
    print("-" * len(head))
    for seq in args.kitti:
        data = kitti_sequence(seq)
        scans = [np.ascontiguousarray(data.points(i)[:, :3], dtype=np.float64) for i in range(len(data))]
        motions = {"GT": list(data.poses)}
        odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {}))
        motions["line_odom"] = [odom.register_points(s, float(t)).pose for s, t in zip(scans, data.times)]
        if use_kiss:
            kiss = kiss_odometry(100.0)
            motions["KISS-ICP"] = []
            for s in scans:
                kiss.register_frame(s, np.zeros(len(s)))
                motions["KISS-ICP"].append(kiss.last_pose.copy())
        trees = [cKDTree(s) for s in scans]
        for name, poses in motions.items():
            rows = np.array([alignment(structure_points(scans[i - 1]), trees[i], relative(poses, i))
                             for i in range(1, len(scans))])
            forward = np.mean([relative(poses, i)[0, 3] for i in range(1, len(scans))])
            print(f"{seq:4} {name:10} | {rows[:, 0].mean():13.4f} {rows[:, 1].mean():6.3f} {rows[:, 2].mean():7.3f} | "
                  f"{forward:11.3f}")


if __name__ == "__main__":
    main()
