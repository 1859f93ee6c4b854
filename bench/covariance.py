#!/usr/bin/env python3
"""Is the reported covariance consistent with the real errors? NEES of every frame's motion.

    .venv/bin/python bench/covariance.py                # every real run at 1, 1/36, 1/64, 16 and 32 lasers; TUM; sim
    .venv/bin/python bench/covariance.py --only kitti --kitti 07 --kitti-levels 6 --kitti-beams
    .venv/bin/python bench/covariance.py --only kitti --kitti-stride 2 --kitti-levels 6 8 --kitti-beams 16
    .venv/bin/python bench/covariance.py --only tum --set registration.covariance_scale=1

For each frame, e = the error of the registered motion against the reference's (x y z rx ry rz, the chart of the
result's covariance C) and NEES = e^T C^-1 e. The KITTI runs are those of bench/accuracy.py, read, played
(--kitti-stride, --kitti-backwards, --kitti-view, ...) and thinned as it reads them, judged against their ground
truth; KITTI 00 and 08 (whose ground truth disagrees with their scans) and the stop-and-go drive (whose reference poses
are KISS-ICP's own at full resolution, its cold start in their first frames: docs/RESULTS.md, "Accuracy") against the
dense registration of their scans, on all six axes.

Frames reported as good (registered, not degenerate) and flagged frames are summarized apart. Good frames: mean NEES / 6
(1 = consistent; > 1 too confident: an EKF fusing the odometry trusts it too much; < 1 too cautious), the median, the
share within the 95 % chi-square bound (12.59), the frames beyond the 99.9 % bound (22.46: a frame that far outside
its covariance is wrong with confidence) and the rms of each axis's e_i / sqrt(C_ii) (1 = its marginal is right).
Flagged frames: their largest NEES (a flagged frame's covariance is inflated so that a filter gives it no weight).
Reference errors count as estimate errors here.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))
sys.path.append(str(Path(__file__).resolve().parent))

import line_odom_core  # noqa: E402
from line_odom.cli import parse_overrides  # noqa: E402
from line_odom.datasets import tum_sequence  # noqa: E402
from line_odom.metrics import motion_errors, nees  # noqa: E402

import accuracy  # noqa: E402  (bench/accuracy.py: the same runs, read and thinned as it reads them)

KITTI_LEVELS = {1: "full", 6: "1/36", 8: "1/64", 10: "1/100"}
CHI2_95_6DOF = 12.592
CHI2_999_6DOF = 22.458
# Runs judged against the dense registration of their own scans: KITTI 00 and 08 (their ground truth disagrees with
# their scans) and the stop-and-go drive (its reference poses are KISS-ICP's, with its cold start: docs/RESULTS.md).
DENSE_REFERENCE = accuracy.GT_DISAGREES + (accuracy.STOP_AND_GO,)


def level_name(level: int) -> str:
    return KITTI_LEVELS.get(level, f"1/{level * level}")


def frame_deltas(poses: np.ndarray) -> np.ndarray:
    return np.linalg.inv(poses[:-1]) @ poses[1:]


def summarize(name: str, level: str, results: list, reference: np.ndarray, valid: np.ndarray | None = None) -> None:
    deltas = np.array([r.delta for r in results[1:]])
    covs = np.array([r.covariance for r in results[1:]])
    flagged = accuracy.flagged_frames([r.stats for r in results[1:]])
    keep = np.ones(len(deltas), bool) if valid is None else valid[:-1] & valid[1:]
    n = np.full(len(deltas), np.nan)
    e = motion_errors(deltas[keep], frame_deltas(reference)[keep])
    n[keep] = nees(e, covs[keep])
    good = keep & ~flagged
    g = n[good]
    z = e[~flagged[keep]] / np.sqrt(np.einsum("nii->ni", covs[good]))
    axes = " ".join(f"{v:5.2f}" for v in np.sqrt((z ** 2).mean(axis=0))) if len(g) else "-"
    stats = (f"{g.mean() / 6:9.3f} {np.median(g) / 6:8.3f} {(g <= CHI2_95_6DOF).mean():6.2f} "
             f"{int((g > CHI2_999_6DOF).sum()):6d}" if len(g) else f"{'-':>9} {'-':>8} {'-':>6} {'-':>6}")
    bad = n[keep & flagged]
    bad_max = f"{bad.max() / 6:9.3f}" if len(bad) else f"{'-':>9}"
    print(f"{name:18} {level:>5} {int(keep.sum()):5d} {len(g):5d} {len(bad):5d} | {stats} | {bad_max} | {axes}",
          flush=True)


def run_kitti(runs, levels, beams, overrides, playback: accuracy.Playback = accuracy.Playback()) -> None:
    """Each run as bench/accuracy.py reads it, plays it and thins it (levels of kitti_hdl64, `beams` of its lasers with
    vlp16)."""
    for name in runs:
        data = playback.apply(accuracy.open_run(name, None))
        label = f"KITTI {accuracy.run_name(name)}{playback.suffix()}"
        reference = playback.mounted(accuracy.dense_reference(label, data)
                                     if accuracy.run_name(name) in DENSE_REFERENCE else data.poses)
        for level, lasers in [(level, 0) for level in levels] + [(1, b) for b in beams]:
            odom = line_odom_core.Odometry(accuracy.kitti_config(level, lasers, overrides))
            results = []
            for i in range(len(data)):
                xyz, ring = playback.scan(data, i, lasers)
                results.append(odom.register_points(xyz, float(data.times[i]), ring=ring))
            summarize(label, f"{lasers}b" if lasers else level_name(level), results, reference)


def run_tum(levels, frames, clock_offsets, overrides) -> None:
    """Also with the ground truth read at the depth stamps + each offset (s): fr1's depth images are stamped after the
    scene the motion capture saw them in (bench/accuracy.py's clock table)."""
    data = tum_sequence(frames)
    for level in levels:
        odom = line_odom_core.Odometry(line_odom_core.load_config("tum_kinect", {"downsample": level, **overrides}))
        results = [odom.register_depth(data.depth(i), data.K, float(data.stamps[i])) for i in range(len(data))]
        summarize("TUM fr1/xyz", level_name(level), results, data.poses, data.pose_valid)
        for offset in clock_offsets:
            poses, valid = data.poses_at_offset(offset)
            summarize(f"TUM {offset * 1e3:+.0f} ms", level_name(level), results, poses, valid)


def run_sim(levels, frames, overrides) -> None:
    from line_odom import sim

    run = sim.make("street", frames=frames, seed=0, noise_std=0.01)
    gt = np.array(run.trajectory.poses)
    scans = [(f.data.points, f.data.ring.astype(np.int32), f.stamp) for f in run]
    for level in levels:
        odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": level, **overrides}))
        results = [odom.register_points(p, stamp, ring=ring) for p, ring, stamp in scans]
        summarize("sim street", level_name(level), results, gt)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--only", choices=("kitti", "tum", "sim"))
    parser.add_argument("--kitti", nargs="+", default=None, metavar="RUN",
                        help="runs as bench/accuracy.py names them, or KITTI-layout directories (default: every run in "
                             "../shared/data)")
    parser.add_argument("--kitti-levels", nargs="*", type=int, default=[1, 6, 8])
    parser.add_argument("--kitti-beams", nargs="*", type=int, default=[16, 32], choices=(16, 32),
                        help="also each run kept to 16 / 32 of its 64 lasers")
    accuracy.add_playback_arguments(parser)
    parser.add_argument("--tum-levels", nargs="+", type=int, default=[1, 10])
    parser.add_argument("--tum-frames", type=int, default=300)
    parser.add_argument("--tum-clock-offsets", nargs="*", type=float, default=[-0.04], metavar="S",
                        help="TUM rows again with the ground truth at the depth stamps + S seconds")
    parser.add_argument("--sim-levels", nargs="+", type=int, default=[1, 6])
    parser.add_argument("--sim-frames", type=int, default=300)
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="engine overrides by dotted name (YAML values), applied to every run")
    args = parser.parse_args(argv)
    try:
        overrides = parse_overrides(args.set)
    except ValueError as err:
        parser.error(str(err))
    print(f"{'data':18} {'res':>5} {'pairs':>5} {'good':>5} {'flag':>5} | good: {'NEES/6':>9} {'median':>8} "
          f"{'<=95%':>6} {'>99.9%':>6} | flagged: {'max/6':>9} | good, rms of e_i / sigma_i: x y z rx ry rz "
          f"(1 = consistent)")
    if args.only in (None, "kitti"):
        run_kitti(args.kitti or accuracy.default_runs(), args.kitti_levels, args.kitti_beams, overrides,
                  accuracy.playback_from(parser, args))
    if args.only in (None, "tum"):
        run_tum(args.tum_levels, args.tum_frames, args.tum_clock_offsets, overrides)
    if args.only in (None, "sim"):
        run_sim(args.sim_levels, args.sim_frames, overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
