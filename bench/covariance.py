#!/usr/bin/env python3
"""Is the reported covariance consistent with the real errors? NEES of every frame's motion.

    .venv/bin/python bench/covariance.py                # KITTI 00/04/07 at 1, 1/36, 1/64; TUM fr1/xyz 1, 1/100; sim
    .venv/bin/python bench/covariance.py --only tum --set registration.covariance_scale=1

For each frame, e = the error of the registered motion against the ground truth's (x y z rx ry rz, the chart of
the result's covariance C) and NEES = e^T C^-1 e. A consistent covariance has mean NEES / 6 = 1; > 1 means too
confident (an EKF fusing the odometry trusts it too much), < 1 too cautious. Also printed: the median, the share of
frames within the 95 % chi-square bound (12.59) and the rms of each axis's e_i / sqrt(C_ii) (1 = its marginal is
right). Frames held in full on the prediction report the fallback covariance; their count is shown.
Ground-truth errors count as estimate errors here: on KITTI 00, whose ground truth disagrees with the scans
(bench/gt_consistency.py), the NEES is that disagreement.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))

import line_odom_core  # noqa: E402
from line_odom.cli import parse_overrides  # noqa: E402
from line_odom.datasets import kitti_sequence, tum_sequence  # noqa: E402
from line_odom.metrics import motion_errors, nees  # noqa: E402

KITTI_LEVELS = {1: "full", 6: "1/36", 8: "1/64", 10: "1/100"}
CHI2_95_6DOF = 12.592


def frame_deltas(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[:-1]) @ poses[1:]


def summarize(name: str, res: int, results: list, gt_poses: np.ndarray, valid: np.ndarray | None = None) -> None:
    deltas = np.array([r.delta for r in results[1:]])
    covs = np.array([r.covariance for r in results[1:]])
    held = np.array([r.stats["held_directions"] for r in results[1:]])
    keep = np.ones(len(deltas), bool) if valid is None else valid[:-1] & valid[1:]
    e = motion_errors(deltas[keep], frame_deltas(gt_poses)[keep])
    n = nees(e, covs[keep])
    z = e / np.sqrt(np.einsum("nii->ni", covs[keep]))
    axes = " ".join(f"{v:5.2f}" for v in np.sqrt((z ** 2).mean(axis=0)))
    print(f"{name:13} {KITTI_LEVELS.get(res, f'1/{res * res}'):>5} {len(n):5d} {int((held[keep] == 6).sum()):4d} "
          f"{int(((held[keep] > 0) & (held[keep] < 6)).sum()):4d} | {n.mean() / 6:9.3f} {np.median(n) / 6:8.3f} "
          f"{(n <= CHI2_95_6DOF).mean():6.2f} | {axes}", flush=True)


def run_kitti(seqs, levels, overrides) -> None:
    for seq in seqs:
        data = kitti_sequence(seq, None)
        for level in levels:
            odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": level,
                                                                                      **overrides}))
            results = [odom.register_points(data.xyz(i), float(data.times[i]))
                       for i in range(len(data))]
            summarize(f"KITTI {seq}", level, results, data.poses)


def run_tum(levels, frames, overrides) -> None:
    data = tum_sequence(frames)
    for level in levels:
        odom = line_odom_core.Odometry(line_odom_core.load_config("tum_kinect", {"downsample": level, **overrides}))
        results = [odom.register_depth(data.depth(i), data.K, float(data.stamps[i])) for i in range(len(data))]
        summarize("TUM fr1/xyz", level, results, data.poses, data.pose_valid)


def run_sim(levels, frames, overrides) -> None:
    from line_odom import sim

    run = sim.make("street", frames=frames, seed=0, noise_std=0.01)
    gt = np.array(run.trajectory.poses)
    scans = [(f.data.points, f.data.ring.astype(np.int32), f.stamp) for f in run]
    for level in levels:
        odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": level, **overrides}))
        results = [odom.register_points(p, stamp, ring=ring) for p, ring, stamp in scans]
        summarize("sim street", level, results, gt)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--only", choices=("kitti", "tum", "sim"))
    parser.add_argument("--kitti", nargs="+", default=["00", "04", "07"])
    parser.add_argument("--kitti-levels", nargs="+", type=int, default=[1, 6, 8])
    parser.add_argument("--tum-levels", nargs="+", type=int, default=[1, 10])
    parser.add_argument("--tum-frames", type=int, default=300)
    parser.add_argument("--sim-levels", nargs="+", type=int, default=[1, 6])
    parser.add_argument("--sim-frames", type=int, default=300)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="engine overrides by dotted name (YAML values), applied to every run")
    args = parser.parse_args(argv)
    try:
        overrides = parse_overrides(args.set)
    except ValueError as err:
        parser.error(str(err))
    print(f"{'data':13} {'res':>5} {'pairs':>5} {'held':>4} {'part':>4} | {'NEES/6':>9} {'median':>8} {'<=95%':>6} | "
          f"rms of e_i / sigma_i: x y z rx ry rz (1 = consistent)")
    if args.only in (None, "kitti"):
        run_kitti(args.kitti, args.kitti_levels, overrides)
    if args.only in (None, "tum"):
        run_tum(args.tum_levels, args.tum_frames, overrides)
    if args.only in (None, "sim"):
        run_sim(args.sim_levels, args.sim_frames, overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
