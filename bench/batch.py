#!/usr/bin/env python3
"""Wall time of `line_odom batch` over one small archive with 1 and with 2 local worker processes, and the speed-up.

    .venv/bin/python bench/batch.py                              # the archive test/test_batch.py runs
    .venv/bin/python bench/batch.py --kitti-frames 10 --tum-frames 60 --set downsample=6

The archive is made from ../shared/data: KITTI sequences as bags written by kitti2bag and as KITTI folders, a TUM
RGB-D folder and one truncated (corrupt) bag. Each run starts with an empty output folder and includes starting and
stopping the local cluster, so with few frames per recording the fixed cost weighs in the ratio.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from line_odom import bags, datasets  # noqa: E402

KITTI = datasets.SHARED_DATA / "kitti_odometry_mini" / "sequences"
TUM = datasets.SHARED_DATA / "tum_rgbd_fr1_xyz"


def kitti_folder(src: Path, dst: Path, frames: int) -> Path:
    """A KITTI odometry sequence folder holding the first `frames` scans of `src` (scans linked, text files cut)."""
    (dst / "velodyne").mkdir(parents=True)
    scans = sorted((src / "velodyne").glob("*.bin"))[:frames]
    for scan in scans:
        os.symlink(scan.resolve(), dst / "velodyne" / scan.name)
    for name in ("times.txt", "poses_gt.txt", "poses.txt"):
        if (src / name).is_file():
            lines = (src / name).read_text().splitlines()[:len(scans)]
            (dst / name).write_text("\n".join(lines) + "\n")
    shutil.copy(src / "calib.txt", dst / "calib.txt")
    return dst


def tum_folder(src: Path, dst: Path, frames: int) -> Path:
    """A TUM RGB-D folder with the first `frames` depth images of `src` (images linked, ground truth copied)."""
    (dst / "depth").mkdir(parents=True)
    rows = [line for line in (src / "depth.txt").read_text().splitlines() if line and not line.startswith("#")]
    rows = rows[:frames]
    for row in rows:
        name = row.split()[1]
        os.symlink((src / name).resolve(), dst / name)
    (dst / "depth.txt").write_text("\n".join(rows) + "\n")
    shutil.copy(src / "groundtruth.txt", dst / "groundtruth.txt")
    return dst


def make_archive(root: str | Path, kitti_frames: int = 4, tum_frames: int = 5) -> dict[str, Path]:
    """The benchmark's (and test/test_batch.py's) archive under `root`; returns {label batch gives it: path}.
    KITTI 04 is there both as a bag and as a folder, so the two routes can be compared."""
    root = Path(root)
    out = {}
    out["kitti__04_bag"] = root / "kitti" / "04_bag"
    bags.kitti_to_bag(KITTI / "04", out["kitti__04_bag"], frames=kitti_frames)
    out["kitti__07_mcap"] = root / "kitti" / "07_mcap"
    bags.kitti_to_bag(KITTI / "07", out["kitti__07_mcap"], frames=kitti_frames, storage="mcap")
    out["kitti__04"] = kitti_folder(KITTI / "04", root / "kitti" / "04", kitti_frames)
    out["kitti__00"] = kitti_folder(KITTI / "00", root / "kitti" / "00", kitti_frames)
    out["tum__rgbd_dataset_freiburg1_xyz"] = tum_folder(TUM, root / "tum" / "rgbd_dataset_freiburg1_xyz", tum_frames)
    # a bag cut short, as a copy interrupted mid-file leaves it
    broken = root / "broken" / "truncated_bag"
    shutil.copytree(out["kitti__04_bag"], broken)
    (broken / "04_bag.db3").rename(broken / "truncated_bag.db3")
    meta = (broken / "metadata.yaml").read_text().replace("04_bag.db3", "truncated_bag.db3")
    (broken / "metadata.yaml").write_text(meta)
    with open(broken / "truncated_bag.db3", "r+b") as f:
        f.truncate(3000)
    out["broken__truncated_bag"] = broken
    (root / "notes").mkdir()
    (root / "notes" / "README.txt").write_text("not a recording\n")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kitti-frames", type=int, default=4)
    ap.add_argument("--tum-frames", type=int, default=5)
    ap.add_argument("--set", action="append", default=["downsample=6"], dest="overrides", metavar="NAME=VALUE",
                    help="overrides for every recording (default downsample=6)")
    ap.add_argument("--keep", action="store_true", help="keep the archive and outputs (printed)")
    args = ap.parse_args(argv)
    from line_odom import batch
    from line_odom.cli import parse_overrides

    work = Path(tempfile.mkdtemp(prefix="line_odom_bench_batch."))
    try:
        labels = make_archive(work / "archive", args.kitti_frames, args.tum_frames)
        overrides = parse_overrides(args.overrides)
        print(f"archive: {len(labels)} recordings (KITTI {args.kitti_frames} frames, TUM {args.tum_frames} frames, "
              f"one corrupt), overrides {overrides}, {os.cpu_count()} cores")
        walls = {}
        trajectories = {}
        for workers in (1, 2):
            out = work / f"out_{workers}"
            t0 = time.perf_counter()
            result = batch.run_batch(work / "archive", out, workers=workers, overrides=overrides, progress=False)
            walls[workers] = time.perf_counter() - t0
            ok = [r for r in result.rows if r["status"] == "ok"]
            trajectories[workers] = {r["label"]: (out / r["label"] / "trajectory_tum.txt").read_bytes() for r in ok}
            task_s = sum(r["seconds"] for r in ok)
            print(f"workers {workers}: wall {walls[workers]:6.2f} s  ({len(ok)} replayed, {len(result.failed)} failed, "
                  f"sum of task times {task_s:.2f} s)")
            print("  " + ", ".join(f"{r['label']} {r['seconds']:.2f} s" for r in ok))
            unexpected = [r for r in result.failed if r["label"] != "broken__truncated_bag"]
            if unexpected or len(ok) != len(labels) - 1:
                for r in unexpected:
                    print(f"  {r['label']} failed: {r['error']}")
                print("the archive's recordings should all replay but the corrupt one: no timing to compare")
                return 1
        print(f"speed-up 2 vs 1 workers: {walls[1] / walls[2]:.2f}x")
        same = trajectories[1] == trajectories[2]
        print(f"trajectories identical between 1 and 2 workers: {same}")
        if args.keep:
            print(f"kept {work}")
        return 0 if same else 1
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
