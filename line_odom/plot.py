"""trajectory.png: top view of the estimate against ground truth, and the frame-to-frame error over time.

Uses matplotlib's Agg backend (no display needed). The estimate is drawn start-aligned (its first pose put on
the ground truth's), so drift shows as it accumulates.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from line_odom import metrics
from line_odom.evaluation import Trajectory, associate

AXIS_NAMES = "xyz"


def _top_view_axes(positions: np.ndarray) -> tuple[int, int]:
    """Without ground truth (whose world has z up) the up axis is unknown: show the two axes with the largest
    spread (the view looks along the axis that varies least)."""
    if len(positions) < 2:
        return 0, 1
    spread = positions.max(axis=0) - positions.min(axis=0)
    a, b = sorted(np.argsort(spread)[1:])
    return int(a), int(b)


def plot_trajectory(path: str | Path, estimate: Trajectory, ground_truth: Trajectory | None = None,
                    title: str = "line_odom") -> Path:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    path = Path(path)
    est, gt = estimate, None
    if ground_truth is not None and len(ground_truth):
        est, gt = associate(estimate, ground_truth)
    fig, (ax_top, ax_err) = plt.subplots(1, 2, figsize=(12, 5.2))
    fig.suptitle(title)
    if gt is not None and len(est):
        start = gt.poses[0] @ np.linalg.inv(est.poses[0])
        est_xyz = (start @ est.poses)[:, :3, 3]
        gt_xyz = gt.poses[:, :3, 3]
        a, b = 0, 1  # the ground-truth worlds (KITTI LiDAR, TUM mocap, simulator) have z up: look down z
        ax_top.plot(gt_xyz[:, a], gt_xyz[:, b], "k--", lw=1.5, label="ground truth")
        ax_top.plot(est_xyz[:, a], est_xyz[:, b], "C0-", lw=1.5, label="estimate (start-aligned)")
        ax_top.plot(gt_xyz[:1, a], gt_xyz[:1, b], "ko", ms=5, label="start")
    else:
        est_xyz = est.poses[:, :3, 3]
        a, b = _top_view_axes(est_xyz)
        ax_top.plot(est_xyz[:, a], est_xyz[:, b], "C0-", lw=1.5, label="estimate")
        if len(est_xyz):
            ax_top.plot(est_xyz[:1, a], est_xyz[:1, b], "ko", ms=5, label="start")
    ax_top.set_xlabel(f"{AXIS_NAMES[a]} [m]")
    ax_top.set_ylabel(f"{AXIS_NAMES[b]} [m]")
    ax_top.set_title("top view")
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.grid(True, alpha=0.3)
    ax_top.legend(loc="best", fontsize=8)

    if gt is not None and len(est) >= 2:
        t_err, r_err = metrics.relative_pose_errors(est.poses, gt.poses)
        if est.stamps is not None:
            x = est.stamps[1:] - est.stamps[0]
            ax_err.set_xlabel("time [s]")
        else:
            x = np.arange(1, len(est))
            ax_err.set_xlabel("frame")
        ax_err.plot(x, t_err * 100.0, "C0-", lw=1.2, label="RPE translation [cm]")
        ax_err.set_ylabel("RPE translation [cm]", color="C0")
        ax_rot = ax_err.twinx()
        ax_rot.plot(x, r_err, "C3-", lw=1.0, alpha=0.8, label="RPE rotation [deg]")
        ax_rot.set_ylabel("RPE rotation [deg]", color="C3")
        ax_err.set_title("frame-to-frame error")
        ax_err.grid(True, alpha=0.3)
    else:
        ax_err.axis("off")
        ax_err.text(0.5, 0.5, "no ground truth", ha="center", va="center", fontsize=14, color="0.4")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _feature_settings(values: dict, preset: str) -> dict:
    from line_odom_core import feature_config

    return {name: values[name] for name in feature_config(preset) if name in values}


UNIFORM_COLS = 1024  # azimuth columns of a uniform model that leaves sensor.cols at 0


def _ring_image(xyz: np.ndarray, ring: np.ndarray, cols: int, lo: float, hi: float) -> np.ndarray:
    """(rings, cols, 3) range image: row = ring, column = azimuth bin, the nearest point of each cell, NaN holes."""
    rng = np.linalg.norm(xyz, axis=1)
    keep = np.isfinite(rng) & (rng >= lo) & (rng <= hi) & (ring >= 0)
    xyz, ring, rng = xyz[keep], ring[keep].astype(np.int64), rng[keep]
    rows = int(ring.max()) + 1 if len(ring) else 1
    col = ((np.arctan2(xyz[:, 1], xyz[:, 0]) + np.pi) / (2 * np.pi) * cols).astype(np.int64) % cols
    cell = ring * cols + col
    order = np.lexsort((rng, cell))
    first = order[np.r_[True, cell[order][1:] != cell[order][:-1]]] if len(order) else order
    image = np.full((rows * cols, 3), np.nan)
    image[cell[first]] = xyz[first]
    return image.reshape(rows, cols, 3)


def scan_features(frame, config, K: np.ndarray | None = None) -> tuple[np.ndarray, dict, str]:
    """(the points the engine keeps of `frame` (M, 3), line_odom_core.extract_features of its range image, a note)
    with `config`'s sensor model, ranges, downsampling and line settings. The engine returns no lines per registered
    frame, so they are fitted here again from the same range image; organize_points takes a preset sensor model only,
    so a uniform model's clouds with rings are binned here (row = ring, sensor.cols azimuth columns)."""
    import line_odom_core as core
    from line_odom_core import _core

    values = config.as_dict()
    step = int(values["downsample"])
    lo, hi = float(values["sensor.min_range"]), float(values["sensor.max_range"])
    note = ""
    if frame.depth is not None:
        if K is None:
            raise ValueError("K: a depth frame's lines need the camera intrinsics")
        image = core.organize_depth(np.ascontiguousarray(frame.depth, dtype=np.float32), np.asarray(K, float), lo, hi,
                                    step)["points"]
        preset = "tum"
    elif frame.xyz.ndim == 3:
        image = np.ascontiguousarray(frame.xyz[::step, ::step], dtype=np.float64)
        rng = np.linalg.norm(image, axis=2)
        image[~((rng >= lo) & (rng <= hi))] = np.nan
        preset = "kitti"
    else:
        ring = None if frame.ring is None else np.ascontiguousarray(frame.ring, dtype=np.int32)
        model = values["sensor.model"]
        xyz = np.ascontiguousarray(frame.xyz, dtype=np.float64)
        if model in _core.sensor_presets():
            image = core.organize_points(xyz, ring, model, lo, hi, step)["points"]
        elif ring is not None:
            cols = int(values["sensor.cols"]) or UNIFORM_COLS
            image = _ring_image(xyz, ring, cols, lo, hi)[::step, ::step]
            note = f"{model} sensor model: rows by ring, {cols} azimuth columns"
        else:
            image = core.organize_points(xyz, None, "hdl64", lo, hi, step)["points"]
            note = f"{model} sensor model without rings drawn in the HDL-64E model"
        preset = "kitti"
    features = core.extract_features(image, _feature_settings(values, preset), preset)
    points = image.reshape(-1, 3)
    return points[np.isfinite(points).all(axis=1)], features, note


def plot_features(path: str | Path, frame, config, K: np.ndarray | None = None, title: str = "line_odom") -> Path:
    """features.png: top view of one scan's kept points and the lines fitted along its rows (H) and columns (V)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    path = Path(path)
    points, features, note = scan_features(frame, config, K)
    # LiDAR frames have z up: look down z; a camera's optical frame has y down: look down -y (x right, z ahead)
    a, b = (0, 2) if frame.depth is not None else (0, 1)
    fig, ax = plt.subplots(figsize=(9, 8))
    ax.scatter(points[:, a], points[:, b], s=1.0, c="0.5", linewidths=0, label=f"points kept ({len(points)})")
    for key, colour, width, name in (("v_lines", "C3", 0.6, "V-lines (columns)"),
                                     ("h_lines", "C0", 1.0, "H-lines (rows)")):
        segments = np.asarray(features[key]["segments"]).reshape(-1, 2, 3)
        ax.add_collection(LineCollection(segments[:, :, [a, b]], colors=colour, linewidths=width,
                                         label=f"{name}: {len(segments)}"))
    if len(points):  # the scene around the sensor (at the origin), not its few farthest returns
        low = np.minimum(np.percentile(points[:, [a, b]], 3, axis=0), 0.0)
        high = np.maximum(np.percentile(points[:, [a, b]], 97, axis=0), 0.0)
        margin = 0.05 * float(np.max(high - low))
        ax.set_xlim(low[0] - margin, high[0] + margin)
        ax.set_ylim(low[1] - margin, high[1] + margin)
    ax.set_xlabel(f"{AXIS_NAMES[a]} [m]")
    ax.set_ylabel(f"{AXIS_NAMES[b]} [m]")
    ax.set_aspect("equal", adjustable="box")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8, markerscale=10)
    ax.set_title(title + (f"\n{note}" if note else ""), fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
