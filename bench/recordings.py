#!/usr/bin/env python3
"""Sparse against dense on recordings without ground truth: each recording (a sensor's own format, read as `replay`
reads it, with the preset it suggests) at full resolution and thinned, line_odom's frame motions against its own at
full resolution, and KISS-ICP's on the same points against line_odom's and its own at full resolution.

    .venv/bin/python bench/recordings.py                       # every recording in ../shared/data/sensor_recordings
    .venv/bin/python bench/recordings.py my_drive.pcap --levels 1 2 3 6

Where a recording has no ground truth, the full-resolution registration of the same frames is the nearest reference
there is: a sparse level that moves away from it shows what thinning costs on that sensor and scene (the dense
registration's own error is not seen). Per row: the frames, line_odom's mean/max translation (m) and rotation (deg)
error against its full resolution, the frames flagged (degenerate or not registered), the frames reported as good
that are off by more than max(0.3 m, 30 % of the frame's motion) (as bench/accuracy.py counts gross frames) and the
largest rotation error among the frames reported as good; KISS-ICP 1.3.0 (a benchmark-only dependency) on exactly
the points line_odom registered (after organizing, thinning and deskewing; deskew off, max range 100 m, one thread)
against line_odom's full resolution and against its own. Steady ms: the median per frame after the first
registration, as bench/accuracy.py.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))
sys.path.append(str(Path(__file__).resolve().parent))

import line_odom_core  # noqa: E402
from accuracy import flagged_and_gross, frame_errors, kiss_available, kiss_odometry, steady_ms  # noqa: E402
from line_odom.datasets import SHARED_DATA  # noqa: E402
from line_odom.readers import ReaderError, open_source  # noqa: E402
from line_odom.replay_common import node_settings  # noqa: E402

RECORDINGS = SHARED_DATA / "sensor_recordings"
SUFFIXES = (".pcap", ".osf", ".bag")


def default_recordings() -> list[Path]:
    return sorted(p for p in RECORDINGS.glob("*") if p.suffix in SUFFIXES)


def read(path: Path, frames: int | None):
    with open_source(path, frames=frames) as source:
        return source, list(source.frames())


def register(frames, config) -> tuple[np.ndarray, list[dict], list[np.ndarray], list[float]]:
    """line_odom over the frames: poses, stats, the points each frame was registered with, ms per frame."""
    odom = line_odom_core.Odometry(config)
    odom.keep_points(True)
    poses, stats, points, ms = [], [], [], []
    for f in frames:
        ring = None if f.ring is None else np.ascontiguousarray(f.ring, dtype=np.int32)
        t0 = time.perf_counter()
        if f.xyz.ndim == 3:
            result = odom.register_organized(f.xyz, f.stamp_ns * 1e-9, time=f.time)
        else:
            result = odom.register_points(f.xyz, f.stamp_ns * 1e-9, ring=ring, time=f.time)
        ms.append((time.perf_counter() - t0) * 1e3)
        poses.append(result.pose)
        stats.append(result.stats)
        points.append(np.asarray(odom.last_points(), dtype=np.float64))
    return np.array(poses), stats, points, ms


def kiss(points: list[np.ndarray]) -> tuple[np.ndarray, list[float]]:
    odom = kiss_odometry(100.0)
    poses, ms = [], []
    for p in points:
        t0 = time.perf_counter()
        odom.register_frame(p, np.zeros(len(p)))
        ms.append((time.perf_counter() - t0) * 1e3)
        poses.append(odom.last_pose.copy())
    return np.array(poses), ms


def judged(poses: np.ndarray, stats: list[dict], reference: np.ndarray) -> dict:
    t, r = frame_errors(poses, reference)
    flagged, gross = flagged_and_gross(stats, t, reference)
    good = np.array([s["registered"] and not s["degenerate"] for s in stats[1:]])
    return {"t": t, "r": r, "flagged": flagged, "gross": gross,
            "r_good_max": float(r[good].max()) if good.any() else float("nan")}


def rows_of(path: Path, levels: list[int], frames: int | None, with_kiss: bool) -> list[str]:
    source, read_frames = read(path, frames)
    if len(read_frames) < 2:
        return [f"{path.name}: {len(read_frames)} frame, nothing to register (at least 2 needed)"]
    preset, overrides = source.sensor.preset, dict(source.sensor.overrides)
    out = [f"{path.name}: {len(read_frames)} frames, preset {preset} {overrides or ''}"]
    full = None
    kiss_full = None
    for level in levels:
        config, _ = node_settings(source.kind, preset, {**overrides, "downsample": level})
        poses, stats, points, ms = register(read_frames, config)
        if full is None:
            full = poses
        row = judged(poses, stats, full)
        line = (f"  1/{level * level:<4d} {np.mean([len(p) for p in points]):7.0f} pts | line_odom t "
                f"{row['t'].mean():.4f}/{row['t'].max():.4f} r {row['r'].mean():.3f}/{row['r'].max():.3f} "
                f"{steady_ms(ms):6.1f} ms  flg {row['flagged']:3d} grs {row['gross']:2d} r(good) max "
                f"{row['r_good_max']:.3f}")
        if with_kiss:
            kiss_poses, kiss_ms = kiss(points)
            if kiss_full is None:
                kiss_full = kiss_poses
            kt, kr = frame_errors(kiss_poses, full)
            own_t, own_r = frame_errors(kiss_poses, kiss_full)
            line += (f" | KISS-ICP t {kt.mean():.4f}/{kt.max():.4f} r {kr.mean():.3f}/{kr.max():.3f} "
                     f"{steady_ms(kiss_ms):6.1f} ms; against its own full t {own_t.mean():.4f} r {own_r.mean():.3f}")
        out.append(line)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("recordings", nargs="*", type=Path, help="recordings (default: every one in "
                        f"{RECORDINGS})")
    parser.add_argument("--levels", nargs="+", type=int, default=[1, 2, 3, 4, 6],
                        help="downsampling steps, the first the reference (default: 1 2 3 4 6)")
    parser.add_argument("--frames", type=int, default=None, help="frames per recording (default all)")
    parser.add_argument("--no-kiss", action="store_true", help="line_odom only")
    args = parser.parse_args(argv)
    if any(level < 1 for level in args.levels):
        parser.error(f"--levels: expected downsampling steps >= 1, got {args.levels}")
    with_kiss = not args.no_kiss and kiss_available()
    if not args.no_kiss and not with_kiss:
        print("KISS-ICP not installed (.venv/bin/pip install kiss-icp): line_odom only")
    for path in args.recordings or default_recordings():
        try:
            lines = rows_of(path, args.levels, args.frames, with_kiss)
        except (ReaderError, FileNotFoundError) as err:
            print(f"{path}: {err}", file=sys.stderr)
            return 1
        print("\n".join(lines), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
