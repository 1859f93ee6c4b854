#!/usr/bin/env python3
"""Registration from a gyro's rotation (imu.enabled) next to the constant-velocity prediction and KISS-ICP.

    .venv/bin/python bench/imu_guess.py                  # KITTI 00/04/07 at full, 1/36, 1/64; simulated yaw flips
    .venv/bin/python bench/imu_guess.py --only flips --gyro-noise 0.5 --gyro-bias 0 0 2 --no-kiss

`register_points(..., rotation_guess=R_prev_curr)` (the node: `imu.enabled`, topic `imu`) turns the engine's own
prediction by the gyro's rotation between the two scans. The gyro here is synthesized from the ground truth
(line_odom.sim.gyro): the body rate that turns each pose into the next over the stamp interval, sampled at
`--gyro-rate` Hz (half a sample off the scan stamps), plus white noise of `--gyro-noise` deg/s per sample and a
constant bias `--gyro-bias` (deg/s, x y z) the node is not told about; it is mounted in the LiDAR's frame and its
samples go through the node's integrator (line_odom.imu_rotation.GyroRotation). Every run starts with a fresh
Odometry and no velocity. KITTI: the 10-frame clips (rotation changes little there: the gyro must not cost
accuracy). Flips: the simulated street of test/test_turns.py, 0.5 m a frame, the yaw rate flipping sign every 3
frames (60 scans, 1 cm range noise), where the constant-velocity prediction's heading is off by the whole change.
KISS-ICP (deskew off) runs on exactly the points line_odom keeps. Printed per case: the gyro's own rotation error
a frame, then line_odom without and with it and KISS-ICP: mean translation error (m), mean / max rotation error
(deg), frames holding a direction (h) and frames whose heading was searched (s), and line_odom's ms per frame.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.append(str(ROOT))
sys.path.append(str(ROOT / "test"))

import line_odom_core  # noqa: E402
from accuracy import kiss_odometry  # noqa: E402
from line_odom.datasets import kitti_sequence  # noqa: E402
from line_odom.imu_rotation import GyroRotation  # noqa: E402
from line_odom.sim.gyro import gyro_samples  # noqa: E402
from motion_guess import frame_errors  # noqa: E402

LEVELS = {1: "full", 6: "1/36", 8: "1/64"}


def gyro_rotations(poses, stamps, rate_hz, noise_deg, bias_deg, seed):
    """R_prev_curr of each scan interval from a synthesized gyro, integrated as the node does."""
    samples, rates = gyro_samples(poses, stamps, rate_hz=rate_hz, offset=0.5 / rate_hz,
                                  noise_std=np.radians(noise_deg), bias=np.radians(bias_deg), seed=seed)
    from sensor_msgs.msg import Imu

    gyro = GyroRotation(window=1e6)
    for t, w in zip(samples, rates):
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 1_000_000_000)
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(v) for v in w)
        gyro.add(msg)
    out = []
    for a, b in zip(stamps, stamps[1:]):
        R, why = gyro.rotation(int(round(a * 1e9)), int(round(b * 1e9)))
        if R is None:
            raise RuntimeError(why)
        out.append(R)
    return out


def run_case(scans, poses, stamps, preset, overrides, rotations, kiss):
    """scans: (xyz, ring or None) per frame. Rows name -> (t errors, r errors, held, searched, ms)."""
    truths = [np.linalg.inv(a) @ b for a, b in zip(poses, poses[1:])]
    rows = {}
    for name, use in (("without", False), ("with IMU", True)):
        odom = line_odom_core.Odometry(line_odom_core.load_config(preset, overrides))
        deltas, held, searched, ms = [], 0, 0, []
        for k, ((xyz, ring), stamp) in enumerate(zip(scans, stamps)):
            t0 = time.perf_counter()
            res = odom.register_points(xyz, float(stamp), ring=ring,
                                       rotation_guess=rotations[k - 1] if use and k else None)
            if k:
                ms.append(1e3 * (time.perf_counter() - t0))
                deltas.append(res.delta)
                held += bool(res.stats["degenerate"])
                searched += bool(res.stats["turn_searched"])
        rows[name] = (*frame_errors(deltas, truths), held, searched, float(np.mean(ms)))
    if kiss:
        odom = line_odom_core.Odometry(line_odom_core.load_config(preset, overrides))
        kiss_odom = kiss_odometry(100.0)
        kiss_poses = []
        for xyz, ring in scans:
            pts = odom.downsampled_points(xyz, ring=ring)
            kiss_odom.register_frame(pts, np.zeros(len(pts)))
            kiss_poses.append(kiss_odom.last_pose.copy())
        rows["KISS-ICP"] = frame_errors([np.linalg.inv(a) @ b for a, b in zip(kiss_poses, kiss_poses[1:])], truths)
    gyro_r = frame_errors([np.pad(R, ((0, 1), (0, 1))) + np.diag([0, 0, 0, 1.0]) for R in rotations],
                          [np.pad(T[:3, :3], ((0, 1), (0, 1))) + np.diag([0, 0, 0, 1.0]) for T in truths])[1]
    return gyro_r, rows


def kitti_cases(seqs, levels):
    for seq in seqs:
        data = kitti_sequence(seq)
        scans = [(data.xyz(i), None) for i in range(len(data))]
        for level in levels:
            yield (f"KITTI {seq} {LEVELS.get(level, level)}", scans, np.array(data.poses),
                   np.array(data.times, dtype=float), "kitti_hdl64", {"downsample": level})


def flip_cases(rates):
    import test_turns

    for rate in rates:
        for sensor, preset, overrides, label in (("hdl64", "kitti_hdl64", {"downsample": 6}, "HDL-64E 1/36"),
                                                 ("vlp16", "vlp16", {}, "VLP-16 (window 3)"),
                                                 ("vlp16", "vlp16", {"registration.window": 1}, "VLP-16 window 1")):
            drive = list(test_turns._turning_scans(sensor, rate))
            scans = [(scan.points, scan.ring.astype(np.int32)) for _, scan, _ in drive]
            yield (f"flips {rate:g} deg/frame, {label}", scans, np.array([T for T, _, _ in drive]),
                   np.array([s for _, _, s in drive]), preset, overrides)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", choices=("kitti", "flips"), default=None)
    parser.add_argument("--kitti", nargs="+", default=["00", "04", "07"])
    parser.add_argument("--levels", nargs="+", type=int, default=[1, 6, 8])
    parser.add_argument("--flip-rates", nargs="+", type=float, default=[10.0, 20.0], help="deg a frame")
    parser.add_argument("--gyro-rate", type=float, default=200.0, help="Hz")
    parser.add_argument("--gyro-noise", type=float, default=0.1, help="deg/s white noise per sample")
    parser.add_argument("--gyro-bias", nargs=3, type=float, default=[0.1, -0.2, 0.5], help="deg/s, x y z (unknown)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-kiss", action="store_true")
    args = parser.parse_args(argv)
    print(f"gyro: {args.gyro_rate:g} Hz, noise {args.gyro_noise:g} deg/s a sample, bias {args.gyro_bias} deg/s "
          f"(not corrected), seed {args.seed}; t mean (m), r mean / max (deg), h = frames holding a direction, "
          f"s = frames whose heading was searched")
    head = (f"{'case':38} | {'gyro r':>13} | {'without IMU':>30} | {'with IMU':>30} | {'KISS-ICP':>22} | ms w/o / w")
    print(head)
    print("-" * len(head))
    cases = []
    if args.only in (None, "kitti"):
        cases += list(kitti_cases(args.kitti, args.levels))
    if args.only in (None, "flips"):
        cases += list(flip_cases(args.flip_rates))
    for label, scans, poses, stamps, preset, overrides in cases:
        rotations = gyro_rotations(poses, stamps, args.gyro_rate, args.gyro_noise, np.array(args.gyro_bias),
                                   args.seed)
        gyro_r, rows = run_case(scans, poses, stamps, preset, overrides, rotations, not args.no_kiss)

        def cell(name):
            t, r, held, searched, _ = rows[name]
            return f"{t.mean():.4f} {r.mean():6.3f} / {r.max():6.2f} h{held:<2d} s{searched:<2d}"
        kiss = rows.get("KISS-ICP")
        kiss_cell = f"{kiss[0].mean():.4f} {kiss[1].mean():6.3f} / {kiss[1].max():5.2f}" if kiss else f"{'n/a':>22}"
        print(f"{label:38} | {gyro_r.mean():5.3f} / {gyro_r.max():5.3f} | {cell('without')} | {cell('with IMU')} | "
              f"{kiss_cell} | {rows['without'][4]:.1f} / {rows['with IMU'][4]:.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
