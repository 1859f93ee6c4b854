#!/usr/bin/env python3
"""Per-frame latency of line_odom, stage by stage, next to KISS-ICP's on the same frames in one run.

    .venv/bin/python bench/latency.py                   # KITTI 00/04/07 at 1, 1/36, 1/64; TUM fr1/xyz (300 frames) at 1, 1/100
    .venv/bin/python bench/latency.py --repeat 3 --kiss-threads 1
    .venv/bin/python bench/latency.py --threads 2       # line_odom's line fit and line-pair search on two threads
    .venv/bin/python bench/latency.py --set registration.window=3   # any engine setting
    .venv/bin/python bench/latency.py --only kitti --kitti-levels --kitti-beams 16 32   # KITTI with 16 / 32 lasers

Stage times come from the engine's own stopwatch (stats["ms"]); "call" is the wall time of the Python call
(numpy in, result out). The first frame of each run is left out (nothing to register against). KISS-ICP runs
single-threaded by default (the comparison is per core), and so does line_odom (--threads sets its `threads`:
the line fit and the line-pair search on that many threads, feature stage times then in wall time instead of thread
CPU time). KISS-ICP on several threads (--kiss-threads) leaves its TBB workers spinning between frames, which slows
line_odom in the same process: time line_odom's threads without it. Timings on a shared machine are noisy: compare
the ratio within one run.

At full resolution the presets fit and register the lines of every 4th row and column of a KITTI scan
(registration.max_lines), each fitted to every point of its row or column. The row "all" runs the same frames with
registration.max_lines = 0: every row and column fitted and registered. Its line-fitting time is that of every
line of a full KITTI frame (what the paper's "line fitting" time covers). The "16b" row keeps every 4th of KITTI's 64
lasers with all their azimuth steps, through the vlp16 preset, as bench/accuracy.py's rows of that name (a 16-beam
LiDAR as this package is for): KISS-ICP gets the same points.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import line_odom_core  # noqa: E402
from accuracy import beams_config, depth_points, kiss_odometry, kitti_beams, overrides_and_kiss  # noqa: E402
from line_odom.datasets import kitti_sequence, tum_sequence  # noqa: E402

ALL_LINES = 0  # the "level" of the full-resolution run with registration.max_lines = 0
STAGES = ("organize", "downsample", "features", "lines", "candidates", "ransac", "points", "total")  # lines: part of features


def kitti_frames(seqs):
    for seq in seqs:
        data = kitti_sequence(seq)
        yield seq, [(data.xyz(i), float(data.times[i])) for i in range(len(data))]


def time_frames(register, kiss_odom, kiss_points, inputs, stage_ms, call_ms, kiss_ms):
    """Times register(item) and, with kiss_odom, KISS-ICP on kiss_points(item) for every item; the first frame of
    the run is left out (nothing to register against). stage_ms["steady"] gets the totals of the frames after the
    first registration (those with a motion prediction: the node's cost per frame once running), stage_ms["first"]
    that of the first registration (the first motion's search, once per run)."""
    for k, item in enumerate(inputs):
        t0 = time.perf_counter()
        result = register(item)
        call = (time.perf_counter() - t0) * 1e3
        if kiss_odom is not None:
            pts = kiss_points(item)
            t0 = time.perf_counter()
            kiss_odom.register_frame(pts, np.zeros(len(pts)))
            kiss_call = (time.perf_counter() - t0) * 1e3
        if k == 0:
            continue
        call_ms.append(call)
        for s in STAGES:
            stage_ms[s].append(result.stats["ms"][s])
        stage_ms["steady" if k >= 2 else "first"].append(result.stats["ms"]["total"])
        stage_ms["fitted"].append(result.stats["h_lines"] + result.stats["v_lines"])  # on every fit_step-th row
        stage_ms["registered"].append(result.stats["registered_lines"])
        if kiss_odom is not None:
            kiss_ms.append(kiss_call)


def time_lidar(frames_by_seq, level, kiss, kiss_threads, repeat, overrides=None):
    stage_ms = {s: [] for s in (*STAGES, "steady", "first", "fitted", "registered")}
    call_ms, kiss_ms = [], []
    for _ in range(repeat):
        for _seq, frames in frames_by_seq:
            odom = line_odom_core.Odometry(
                line_odom_core.load_config("kitti_hdl64", {"downsample": level, **(overrides or {})}))
            kiss_odom = kiss_odometry(100.0, kiss_threads) if kiss else None
            time_frames(lambda f: odom.register_points(f[0], f[1]), kiss_odom,
                        lambda f: odom.downsampled_points(f[0]) if level > 1 else f[0].astype(np.float64),
                        frames, stage_ms, call_ms, kiss_ms)
    return stage_ms, call_ms, kiss_ms


def time_beams(seqs, beams, kiss, kiss_threads, repeat, overrides=None):
    """KITTI kept to `beams` of its lasers (kitti_beams), registered with the vlp16 preset (beams_config)."""
    stage_ms = {s: [] for s in (*STAGES, "steady", "first", "fitted", "registered")}
    call_ms, kiss_ms = [], []
    frames_by_seq = []
    for seq in seqs:
        data = kitti_sequence(seq)
        frames_by_seq.append([(*kitti_beams(data, i, beams), float(data.times[i])) for i in range(len(data))])
    for _ in range(repeat):
        for frames in frames_by_seq:
            odom = line_odom_core.Odometry(beams_config(beams, overrides or {}))
            kiss_odom = kiss_odometry(100.0, kiss_threads) if kiss else None
            time_frames(lambda f: odom.register_points(f[0], f[2], ring=f[1]), kiss_odom,
                        lambda f: f[0], frames, stage_ms, call_ms, kiss_ms)
    return stage_ms, call_ms, kiss_ms


def time_depth(level, frames, kiss, kiss_threads, repeat, overrides=None):
    data = tum_sequence(frames)
    depths = [(data.depth(i), float(data.stamps[i])) for i in range(len(data))]
    stage_ms = {s: [] for s in (*STAGES, "steady", "first", "fitted", "registered")}
    call_ms, kiss_ms = [], []
    for _ in range(repeat):
        odom = line_odom_core.Odometry(
            line_odom_core.load_config("tum_kinect", {"downsample": level, **(overrides or {})}))
        kiss_odom = kiss_odometry(5.0, kiss_threads) if kiss else None

        def kiss_points(f):
            pts = depth_points(f[0], data.K, level)
            return pts[(pts[:, 2] >= odom.config["sensor.min_range"]) & (pts[:, 2] <= odom.config["sensor.max_range"])]

        time_frames(lambda f: odom.register_depth(f[0], data.K, f[1]), kiss_odom, kiss_points, depths,
                    stage_ms, call_ms, kiss_ms)
    return stage_ms, call_ms, kiss_ms


def steady_ms(stage_ms) -> float:
    """Mean ms of the frames with a motion prediction (all of them when a run has only its first registration)."""
    return float(np.mean(stage_ms["steady"] or stage_ms["total"]))


def goal_text(name, level, stage_ms, kiss_ms):
    steady = steady_ms(stage_ms)
    parts = []
    if name == "kitti" and level == 1:
        if kiss_ms:
            parts.append(f"steady <= KISS/2: {'MET' if steady <= 0.5 * np.mean(kiss_ms) else 'MISSED'}")
        parts.append(f">= 20 Hz: {'MET' if steady <= 50.0 else 'MISSED'}")
    elif name == "kitti" and level == ALL_LINES:
        parts.append(f"line fitting <= 10 ms: {'MET' if np.mean(stage_ms['lines']) <= 10.0 else 'MISSED'}")
    elif name == "kitti" and level == 6:
        parts.append(f"steady <= 5 ms: {'MET' if steady <= 5.0 else 'MISSED'}")
    elif name == "tum" and level == 10:
        parts.append(f"steady <= 3 ms: {'MET' if steady <= 3.0 else 'MISSED'}")
    return "; ".join(parts) or "-"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", nargs="+", default=["00", "04", "07"])
    parser.add_argument("--kitti-levels", nargs="*", type=int, default=[1, 6, 8])
    parser.add_argument("--kitti-beams", nargs="*", type=int, default=[16], choices=(8, 16, 32),
                        help="also KITTI kept to this many of its 64 lasers, through the vlp16 preset (none: skip)")
    parser.add_argument("--tum-levels", nargs="+", type=int, default=[1, 10])
    parser.add_argument("--tum-frames", type=int, default=300)  # all of fr1/xyz, as bench/accuracy.py
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--kiss-threads", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1, help="line_odom's `threads` (0: one per hardware thread)")
    parser.add_argument("--no-kiss", action="store_true")
    parser.add_argument("--only", choices=("kitti", "tum"))
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="engine setting overrides (dotted names), e.g. registration.window=2")
    args = parser.parse_args(argv)

    overrides, kiss = overrides_and_kiss(parser, args)
    threads = {**overrides, "threads": args.threads}
    print(f"line_odom_core {line_odom_core.__version__} ({line_odom_core.build_info()['flags']}), "
          f"threads {args.threads}; overrides {overrides or 'none'}; KISS-ICP "
          f"{'on, ' + str(args.kiss_threads) + ' thread(s)' if kiss else 'off'}; mean ms per frame (p50 and p95 of total;"
          " steady = mean total without each run's first registration, which searches the first motion once a run"
          " (first: its mean); ratio = steady / KISS-ICP's mean; the goals are for steady frames;"
          " lines = fitted / registered per frame, registration.max_lines; res all = full resolution with"
          " registration.max_lines 0, every row and column fitted and registered)")
    head = (f"{'data':5} {'res':5} {'n':>4} | " + " ".join(f"{s:>10}" for s in STAGES) +
            f" {'p50':>7} {'p95':>7} {'steady':>7} {'first':>7} {'call':>7} {'lines':>11} | {'KISS-ICP':>8} {'ratio':>6} | goal")
    print(head)
    print("-" * len(head))
    cases = []
    if args.only in (None, "kitti"):
        frames = list(kitti_frames(args.kitti))
        for level in args.kitti_levels:
            cases.append(("kitti", level, time_lidar(frames, level, kiss, args.kiss_threads, args.repeat, threads)))
            print_row(*cases[-1])
            if level == 1:
                all_lines = time_lidar(frames, 1, False, args.kiss_threads, args.repeat,
                                       {**threads, "registration.max_lines": 0})
                cases.append(("kitti", ALL_LINES, all_lines))
                print_row(*cases[-1])
        for beams in args.kitti_beams:
            measured = time_beams(args.kitti, beams, kiss, args.kiss_threads, args.repeat, threads)
            cases.append(("kitti", -beams, measured))
            print_row(*cases[-1])
    if args.only in (None, "tum"):
        for level in args.tum_levels:
            cases.append(("tum", level, time_depth(level, args.tum_frames, kiss, args.kiss_threads, args.repeat,
                                                   threads)))
            print_row(*cases[-1])
    return 0


def print_row(name, level, measured):
    stage_ms, call_ms, kiss_ms = measured
    res = ("all" if level == ALL_LINES else f"{-level}b" if level < 0 else "full" if level == 1 else
           f"1/{level * level}")  # level -n: n of the lasers
    cells = " ".join(f"{np.mean(stage_ms[s]):10.2f}" for s in STAGES)
    p50, p95 = np.percentile(stage_ms["total"], [50, 95])
    kiss = f"{np.mean(kiss_ms):8.1f} {steady_ms(stage_ms) / np.mean(kiss_ms):6.2f}" if kiss_ms else \
        f"{'n/a':>8} {'':>6}"
    steady = f"{np.mean(stage_ms['steady']):7.2f}" if stage_ms["steady"] else f"{'-':>7}"
    first = f"{np.mean(stage_ms['first']):7.2f}" if stage_ms["first"] else f"{'-':>7}"
    lines = f"{np.mean(stage_ms['fitted']):.0f}/{np.mean(stage_ms['registered']):.0f}"
    print(f"{name:5} {res:5} {len(call_ms):4d} | {cells} {p50:7.2f} {p95:7.2f} {steady} {first} {np.mean(call_ms):7.2f} {lines:>11} | {kiss} | "
          f"{goal_text(name, level, stage_ms, kiss_ms)}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
