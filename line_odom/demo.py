"""`line_odom demo`: the built-in input, end to end, without a download.

1. The simulator (line_odom.sim) renders a LiDAR street drive (HDL-64E, 10 Hz) and a depth camera moved by hand
   through an office room (Kinect intrinsics, 30 Hz), with exact ground truth.
2. Both are written as rosbag2 (the same layout kitti2bag / tum2bag produce).
3. Each bag is replayed through the node's processing core in-process (``line_odom replay``), which writes the
   trajectories, metrics.json and trajectory.png.
4. The metrics are printed side by side.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

from line_odom import bags, evaluation, replay
from line_odom.progress import ProgressBar


@dataclasses.dataclass
class Scenario:
    name: str
    title: str
    kind: str  # line_odom.sim kind
    frames: int
    sensor: str
    noise_std: float
    overrides: dict[str, Any]


SCENARIOS = (
    Scenario("street", "LiDAR street drive: simulated HDL-64E, 10 Hz, 1/36 of the points", "street", 120, "hdl64",
             0.01, {"downsample": 6}),
    Scenario("room", "depth camera in a room: simulated Kinect 640x480, 30 Hz, 1/100 of the pixels", "room", 90,
             "kinect", 0.0014, {"downsample": 10}),
)


def write_scenario_bag(sc: Scenario, bag_path: Path, storage: str, progress: bool, seed: int = 0) -> Path:
    from line_odom import sim

    run = sim.make(sc.kind, frames=sc.frames, seed=seed, sensor=sc.sensor, noise_std=sc.noise_std)
    with ProgressBar(f"simulate {sc.name}", sc.frames, enabled=None if progress else False) as bar:
        if isinstance(run.sensor, sim.Lidar):
            frames = ((f.stamp, f.data.points, f.data.ring, f.data.intensity, f.pose) for f in run)
            bags.lidar_frames_to_bag(bag_path, frames, storage=storage, overwrite=True, progress=bar, total=sc.frames)
        else:
            frames = ((f.stamp, f.data, f.pose) for f in run)
            bags.depth_frames_to_bag(bag_path, frames, run.sensor.K, storage=storage, overwrite=True, progress=bar,
                                     total=sc.frames)
    return bag_path


def comparison_table(results: dict[str, dict]) -> str:
    """Metrics of several runs side by side (one column per run)."""
    keys = ["frames", "frames_dropped", "path_length_m"] + [k for k in evaluation.METRIC_KEYS
                                                             if k not in ("frames", "frames_dropped")]
    names = list(results)
    rows = []
    for key in keys:
        if not any(key in r for r in results.values()):
            continue
        label, fmt = evaluation._LABELS[key]
        rows.append([label] + [fmt.format(results[n][key]) if key in results[n] else "-" for n in names])
    widths = [max(len(r[i]) for r in rows + [["metric"] + names]) for i in range(len(names) + 1)]
    line = "-" * (sum(widths) + 3 * len(names))
    out = [line, "   ".join(["metric".ljust(widths[0])] + [n.rjust(w) for n, w in zip(names, widths[1:])]), line]
    out += ["   ".join([r[0].ljust(widths[0])] + [v.rjust(w) for v, w in zip(r[1:], widths[1:])]) for r in rows]
    out.append(line)
    return "\n".join(out)


def run_demo(out_dir: str | Path = "demo_out", *, storage: str = "sqlite3", progress: bool = True,
             scenarios=SCENARIOS, stream=None) -> dict[str, dict]:
    stream = stream or sys.stdout
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict] = {}
    t_start = time.monotonic()
    for sc in scenarios:
        print(f"== {sc.name}: {sc.title}", file=stream, flush=True)
        t0 = time.monotonic()
        bag = write_scenario_bag(sc, out / sc.name / "input_bag", storage, progress)
        t1 = time.monotonic()
        res = replay.replay_bag(bag, out / sc.name, overrides=sc.overrides, progress=progress,
                                title=f"line_odom demo: {sc.title}")
        t2 = time.monotonic()
        results[sc.name] = res.metrics
        print(evaluation.format_table(res.metrics), file=stream)
        print(f"   bag:  {bag} (simulated and written in {t1 - t0:.1f} s)\n"
              f"   plot: {out / sc.name / 'trajectory.png'} (replayed and evaluated in {t2 - t1:.1f} s)",
              file=stream, flush=True)
    print(f"== summary ({time.monotonic() - t_start:.1f} s)", file=stream)
    print(comparison_table(results), file=stream, flush=True)
    return results
