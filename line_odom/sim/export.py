"""Write simulated runs in the layouts of the real datasets, so every dataset reader, converter and peer tool
(KISS-ICP, evo, the KITTI devkit) can run on them unchanged.

- :func:`write_kitti`: ``velodyne/000000.bin`` (x, y, z, reflectance float32), ``times.txt``, ``calib.txt``
  (``Tr``, identity unless given: the LiDAR is camera 0) and ``poses.txt`` (KITTI convention: the camera-0 poses
  relative to the first frame, ``Tr @ inv(T_0) @ T_k @ inv(Tr)``, 12 numbers per line).
- :func:`write_tum`: ``depth/<stamp>.png`` (16-bit, metres * 5000, 0 = none), ``depth.txt``, ``groundtruth.txt``
  (``stamp tx ty tz qx qy qz qw`` of the optical frame) and ``intrinsics.txt`` (``fx fy cx cy width height``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom.sim.runner import Simulation
from line_odom.sim.sensors import DepthCamera, Lidar

TUM_DEPTH_FACTOR = 5000.0
_STAMP0 = 1_000_000_000.0     # TUM-style absolute stamps (seconds)


def _kitti_row(T: np.ndarray) -> str:
    return " ".join(f"{v:.9e}" for v in T[:3, :4].reshape(-1))


def write_kitti(run: Simulation, out_dir: str | Path, Tr: np.ndarray | None = None) -> Path:
    """Write a LiDAR run as a KITTI odometry sequence directory; returns the directory."""
    if not isinstance(run.sensor, Lidar):
        raise ValueError(f"write_kitti needs a LiDAR run, got a {type(run.sensor).__name__}")
    Tr = np.eye(4) if Tr is None else np.asarray(Tr, dtype=float)
    if Tr.shape != (4, 4):
        raise ValueError(f"Tr must be a 4x4 pose (velodyne -> camera 0), got shape {Tr.shape}")
    out = Path(out_dir)
    (out / "velodyne").mkdir(parents=True, exist_ok=True)
    stamps, rows = [], []
    Tr_inv = np.linalg.inv(Tr)
    T0_inv = None
    for i, frame in enumerate(run):
        scan = frame.data
        np.column_stack([scan.points, scan.intensity]).astype(np.float32).tofile(out / "velodyne" / f"{i:06d}.bin")
        if T0_inv is None:
            T0_inv = np.linalg.inv(frame.pose)
        stamps.append(frame.stamp)
        rows.append(_kitti_row(Tr @ T0_inv @ frame.pose @ Tr_inv))
    (out / "times.txt").write_text("".join(f"{t:.6e}\n" for t in stamps))
    (out / "poses.txt").write_text("\n".join(rows) + "\n")
    (out / "calib.txt").write_text(f"Tr: {_kitti_row(Tr)}\n")
    return out


def write_tum(run: Simulation, out_dir: str | Path) -> Path:
    """Write a depth-camera run as a TUM RGB-D sequence directory (depth only); returns the directory."""
    if not isinstance(run.sensor, DepthCamera):
        raise ValueError(f"write_tum needs a depth-camera run, got a {type(run.sensor).__name__}")
    from PIL import Image

    out = Path(out_dir)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    listing, gt = ["# depth maps (simulated by line_odom.sim)\n# timestamp filename\n"], \
        ["# ground truth (simulated by line_odom.sim)\n# timestamp tx ty tz qx qy qz qw\n"]
    for frame in run:
        stamp = f"{_STAMP0 + frame.stamp:.6f}"
        raw = np.clip(np.round(frame.data * TUM_DEPTH_FACTOR), 0, 65535).astype(np.uint16)
        Image.fromarray(raw).save(out / "depth" / f"{stamp}.png")
        listing.append(f"{stamp} depth/{stamp}.png\n")
        q = Rotation.from_matrix(frame.pose[:3, :3]).as_quat()
        t = frame.pose[:3, 3]
        gt.append(f"{stamp} {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
    (out / "depth.txt").write_text("".join(listing))
    (out / "groundtruth.txt").write_text("".join(gt))
    cam = run.sensor
    (out / "intrinsics.txt").write_text(f"{cam.fx} {cam.fy} {cam.cx} {cam.cy} {cam.width} {cam.height}\n")
    return out
