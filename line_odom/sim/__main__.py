"""``python -m line_odom.sim [--frames N]``: time the simulator's sensors on its own scenes and print a table."""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from line_odom import sim


def _time(fn, items) -> np.ndarray:
    out = []
    for item in items:
        t = time.perf_counter()
        fn(item)
        out.append(time.perf_counter() - t)
    return np.array(out) * 1000.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m line_odom.sim", description=__doc__)
    ap.add_argument("--frames", type=int, default=100, help="frames timed per sensor (spread over a 1 km drive)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.frames < 1:
        ap.error("--frames must be >= 1")
    t = time.perf_counter()
    street = sim.street_scene(1000, seed=args.seed)
    t_street = (time.perf_counter() - t) * 1000
    drive = sim.street_drive(street, seed=args.seed)
    idx = np.linspace(0, len(drive) - 2, min(args.frames, len(drive) - 1)).round().astype(int)
    room = sim.room_scene(seed=args.seed)
    path = sim.handheld_path(room, frames=args.frames, seed=args.seed)
    rows = []
    for name, lidar in [("HDL-64E 64x2083", sim.Lidar.hdl64(noise_std=0.01)), ("VLP-16 16x1800", sim.Lidar.vlp16()),
                        ("OS-128 128x1024", sim.Lidar.os128()), ("OS-128 128x2048", sim.Lidar.os128(columns=2048))]:
        n = []
        ms = _time(lambda i: n.append(len(lidar.scan(street, drive.poses[i]))), idx)
        rows.append((f"{name}, street", ms, np.mean(n)))
    lidar = sim.Lidar.hdl64()
    ms = _time(lambda i: lidar.scan(street, drive.poses[i], T_end=drive.poses[i + 1]), idx)
    rows.append(("HDL-64E, street, motion during sweep", ms, float("nan")))
    for name, cam in [("depth 320x240, room", sim.DepthCamera()), ("depth Kinect 640x480, room", sim.DepthCamera.kinect())]:
        n = []
        ms = _time(lambda T: n.append(np.count_nonzero(cam.render(room, T))), path.poses)
        rows.append((name, ms, np.mean(n)))
    print(f"line_odom.sim timing ({platform.node()}, {platform.processor() or platform.machine()}; "
          f"{len(idx)} frames each; street_scene(1000) built in {t_street:.0f} ms with {len(street)} primitives; "
          f"drive {drive.length_m:.0f} m in {len(drive)} frames)")
    print(f"{'sensor, scene':40s} {'median ms':>10s} {'p95 ms':>8s} {'max ms':>8s} {'points':>8s}")
    for name, ms, pts in rows:
        print(f"{name:40s} {np.median(ms):10.1f} {np.percentile(ms, 95):8.1f} {ms.max():8.1f} {pts:8.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
