#!/usr/bin/env python3
"""Registration from a motion guess (a wheel odometry) next to the constant-velocity prediction and KISS-ICP.

    .venv/bin/python bench/motion_guess.py                        # KITTI 04/07 at 1, 1/36, 1/64; starts 0 and 2
    .venv/bin/python bench/motion_guess.py --scale 1.05 --yaw-noise 0.2 --starts 0 2 5 --no-kiss

`register_points(..., guess=T_prev_curr)` (the node: `guess.enabled`, topic `guess_odom`) registers each scan from
the other source's motion instead of the constant-velocity prediction. The guess here is the ground truth's motion as
a wheel odometry reports it: planar (x, y and yaw; no z, roll or pitch), the distance `--scale` times too long, the
heading off by Gaussian noise of `--yaw-noise` degrees a frame (seeded). Each run starts at a given scan with a
fresh Odometry, a fresh KISS-ICP (deskew off, on exactly the points line_odom keeps) and no velocity: a start
mid-drive. Printed: mean / max
frame-to-frame translation error (m) and mean rotation error (deg) of the guess itself, line_odom without it
(constant velocity), line_odom with it, and KISS-ICP; and how many of line_odom's frames held a direction at the
prediction (degenerate).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.append(str(Path(__file__).resolve().parents[1]))

import line_odom_core  # noqa: E402
from accuracy import kiss_odometry, overrides_and_kiss  # noqa: E402
from line_odom.datasets import kitti_sequence  # noqa: E402

LEVELS = {1: "full", 6: "1/36", 8: "1/64"}


def frame_errors(deltas, truths):
    t, r = [], []
    for D, G in zip(deltas, truths):
        E = np.linalg.inv(G) @ D
        t.append(np.linalg.norm(E[:3, 3]))
        r.append(np.degrees(np.linalg.norm(Rotation.from_matrix(E[:3, :3]).as_rotvec())))
    return np.array(t), np.array(r)


def wheel_guesses(truths, scale, yaw_noise_deg, seed):
    """Planar, as a wheel odometry reports it: the motion's x, y (scaled) and yaw (plus noise); no z, roll or pitch."""
    rng = np.random.default_rng(seed)
    out = []
    for G in truths:
        g = np.eye(4)
        yaw = np.arctan2(G[1, 0], G[0, 0]) + np.radians(rng.normal(0.0, yaw_noise_deg))
        g[:3, :3] = Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()
        g[:2, 3] = scale * G[:2, 3]
        out.append(g)
    return out


def run(seq, level, start, guesses_of, kiss, overrides):
    data = kitti_sequence(seq)
    idx = list(range(start, len(data)))
    truths = [np.linalg.inv(data.poses[i - 1]) @ data.poses[i] for i in idx[1:]]
    guesses = guesses_of(truths)
    config = line_odom_core.load_config("kitti_hdl64", {"downsample": level, **overrides})
    rows = {"guess": frame_errors(guesses, truths)}
    for name, use in (("constant velocity", False), ("with guess", True)):
        odom = line_odom_core.Odometry(config)
        deltas, held = [], 0
        for j, i in enumerate(idx):
            r = odom.register_points(data.xyz(i), float(data.times[i]), guess=guesses[j - 1] if use and j else None)
            if j:
                deltas.append(r.delta)
                held += bool(r.stats["degenerate"])
        rows[name] = (*frame_errors(deltas, truths), held)
    if kiss:
        odom = line_odom_core.Odometry(config)
        kiss_odom = kiss_odometry(100.0)
        poses = []
        for i in idx:
            xyz = data.xyz(i)
            pts = odom.downsampled_points(xyz) if level > 1 else xyz.astype(np.float64)
            kiss_odom.register_frame(pts, np.zeros(len(pts)))
            poses.append(kiss_odom.last_pose.copy())
        rows["KISS-ICP"] = frame_errors([np.linalg.inv(a) @ b for a, b in zip(poses, poses[1:])], truths)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", nargs="+", default=["04", "07"])
    parser.add_argument("--levels", nargs="+", type=int, default=[1, 6, 8])
    parser.add_argument("--starts", nargs="+", type=int, default=[0, 2])
    parser.add_argument("--scale", type=float, default=1.03, help="the guess's distance over the true one")
    parser.add_argument("--yaw-noise", type=float, default=0.05, help="deg a frame (Gaussian) on the guess's heading")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-kiss", action="store_true")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="engine override")
    args = parser.parse_args(argv)
    overrides, kiss = overrides_and_kiss(parser, args)
    print(f"guess: the ground truth's motion x {args.scale} in distance, heading noise {args.yaw_noise} deg a frame "
          f"(seed {args.seed}); t mean / max (m), r mean (deg); held = frames with a direction held at the prediction")
    head = (f"{'seq':3} {'res':5} {'start':>5} | {'guess alone':>19} | {'constant velocity':>25} | "
            f"{'with guess':>25} | {'KISS-ICP':>19}")
    print(head)
    print("-" * len(head))
    guesses_of = lambda truths: wheel_guesses(truths, args.scale, args.yaw_noise, args.seed)  # noqa: E731
    for seq in args.kitti:
        for level in args.levels:
            for start in args.starts:
                rows = run(seq, level, start, guesses_of, kiss, overrides)

                def cell(name, held=True):
                    if name not in rows:
                        return f"{'n/a':>19}" + (" " * 6 if held else "")
                    t, r, *h = rows[name]
                    text = f"{t.mean():.4f} / {t.max():.4f} {r.mean():.3f}"
                    return text + (f" h{h[0]:<2d}  " if held and h else "")
                print(f"{seq:3} {LEVELS.get(level, level):5} {start:5d} | {cell('guess', False)} | "
                      f"{cell('constant velocity')} | {cell('with guess')} | {cell('KISS-ICP', False)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
