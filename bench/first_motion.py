#!/usr/bin/env python3
"""The first motion after a fresh start, at every frame pair, next to KISS-ICP's.

    .venv/bin/python bench/first_motion.py                    # KITTI 00/04/07 at 1, 1/36, 1/64
    .venv/bin/python bench/first_motion.py --kitti 04 --levels 1
    .venv/bin/python bench/first_motion.py --strides 1 2 3    # also every 2nd / 3rd scan (2.6 / 3.9 m a scan on 04)
    .venv/bin/python bench/first_motion.py --no-kiss --set registration.coarse_downsample=0

A replay from the middle of a drive, a node restart or a stamp gap beyond registration.max_prediction_gap starts
the registration without a velocity: the motion is searched from standing still. bench/accuracy.py runs every
sequence from frame 0 only, so here each frame pair k -> k+1 gets its own fresh Odometry (and a fresh KISS-ICP on
exactly the points line_odom keeps, deskew off). With --strides s the pairs are k -> k+s: every s-th scan, a faster
drive or a slower sensor (04 at 13 m/s: 2.6 m a scan at s = 2, beyond the candidates' 2 m). Printed per sequence,
resolution and stride: the mean / max translation error (m) of those first motions, how many were more than 0.1 m
off ("wrong"), and of those how many line_odom flagged (registration failed or held: "flagged") instead of
reporting them as registered motions; and the mean / max rotation error (deg).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))

import line_odom_core  # noqa: E402
from accuracy import kiss_odometry, overrides_and_kiss  # noqa: E402
from line_odom.datasets import kitti_sequence  # noqa: E402
from line_odom.metrics import rotation_angle_deg  # noqa: E402

WRONG = 0.1  # m: a first motion further than this from the ground truth's is wrong (KITTI moves 0.1-1.3 m/frame)
LEVELS = {1: "full", 6: "1/36", 8: "1/64"}


def translation_error(delta: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm((np.linalg.inv(truth) @ delta)[:3, 3]))


def rotation_error(delta: np.ndarray, truth: np.ndarray) -> float:
    """The angle (deg) of the rotation between the two motions."""
    return float(rotation_angle_deg((np.linalg.inv(truth) @ delta)[:3, :3]))


def first_motions(seq: str, level: int, kiss: bool, overrides: dict, stride: int = 1):
    """Per frame pair k -> k + stride: ((line_odom t, r error), flagged, (KISS-ICP t, r error) or None)."""
    data = kitti_sequence(seq)
    config = line_odom_core.load_config("kitti_hdl64", {"downsample": level, **overrides})
    out = []
    for k in range(len(data) - stride):
        odom = line_odom_core.Odometry(config)
        odom.register_points(data.xyz(k), float(data.times[k]))
        result = odom.register_points(data.xyz(k + stride), float(data.times[k + stride]))
        truth = np.linalg.inv(data.poses[k]) @ data.poses[k + stride]
        flagged = not result.stats["registered"] or result.stats["degenerate"]
        kiss_error = None
        if kiss:
            kiss_odom = kiss_odometry(100.0)
            poses = []
            for i in (k, k + stride):
                xyz = data.xyz(i)
                pts = odom.downsampled_points(xyz) if level > 1 else xyz.astype(np.float64)
                kiss_odom.register_frame(pts, np.zeros(len(pts)))
                poses.append(kiss_odom.last_pose.copy())
            kiss_delta = np.linalg.inv(poses[0]) @ poses[1]
            kiss_error = (translation_error(kiss_delta, truth), rotation_error(kiss_delta, truth))
        out.append(((translation_error(result.delta, truth), rotation_error(result.delta, truth)), flagged, kiss_error))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", nargs="+", default=["00", "04", "07"], help="KITTI sequences")
    parser.add_argument("--levels", nargs="+", type=int, default=[1, 6, 8], help="downsampling steps")
    parser.add_argument("--strides", nargs="+", type=int, default=[1], help="register scan k with scan k + s")
    parser.add_argument("--no-kiss", action="store_true", help="line_odom only")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="engine setting overrides (dotted names)")
    args = parser.parse_args(argv)
    overrides, kiss = overrides_and_kiss(parser, args)
    if any(s < 1 for s in args.strides):
        parser.error("--strides: expected integers >= 1")
    print(f"line_odom_core {line_odom_core.__version__}; overrides {overrides or 'none'}; KISS-ICP "
          f"{'on' if kiss else 'off'}; a fresh start at every frame pair (step: of scans); wrong: > {WRONG} m off")
    print(f"{'seq':4} {'res':5} {'step':>4} {'n':>2} | {'line_odom mean/max t [m]':>24} {'wrong':>5} {'flagged':>7} "
          f"{'r [deg]':>13} | {'KISS-ICP mean/max t [m]':>23} {'wrong':>5} {'r [deg]':>13}")
    for level, stride, seq in ((lv, st, sq) for lv in args.levels for st in args.strides for sq in args.kitti):
        rows = first_motions(seq, level, kiss, overrides, stride)
        lo = np.array([r[0] for r in rows])  # columns: translation, rotation
        wrong = lo[:, 0] > WRONG
        flagged = sum(1 for r, w in zip(rows, wrong) if w and r[1])
        line = (f"{seq:4} {LEVELS.get(level, f'1/{level * level}'):5} {stride:4} {len(rows):2} | "
                f"{lo[:, 0].mean():12.4f}/{lo[:, 0].max():.4f} {int(wrong.sum()):5} {flagged:7} "
                f"{lo[:, 1].mean():7.3f}/{lo[:, 1].max():.3f} | ")
        if kiss:
            ks = np.array([r[2] for r in rows])
            line += (f"{ks[:, 0].mean():11.4f}/{ks[:, 0].max():.4f} {int((ks[:, 0] > WRONG).sum()):5} "
                     f"{ks[:, 1].mean():7.3f}/{ks[:, 1].max():.3f}")
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
