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


LINE_NAMES = {"h_lines": "H-lines (rows)", "v_lines": "V-lines (columns)"}


def _view_points(scan) -> np.ndarray:
    """(M, 3) of a ~/scan PointCloud2 (none when the engine kept no point)."""
    from line_odom import convert

    if scan is None or int(scan.width) * int(scan.height) == 0:
        return np.zeros((0, 3))
    xyz = convert.pointcloud2_to_arrays(scan).xyz.reshape(-1, 3)
    return xyz[np.isfinite(xyz).all(axis=1)]


def plot_registered_view(path: str | Path, scan, lines, *, depth: bool = False, title: str = "line_odom") -> Path:
    """features.png: a top view of what the node shows rviz for one frame: the points of its ~/scan (the points the
    engine kept) and the segments of its ~/lines markers (the H- and V-lines it registered, in the markers' colours).
    A LiDAR's frame has z up: looking down z; a camera's optical frame has y down: looking down -y."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    path = Path(path)
    points = _view_points(scan)
    a, b = (0, 2) if depth else (0, 1)
    fig, ax = plt.subplots(figsize=(9, 8))
    ax.scatter(points[:, a], points[:, b], s=1.0, c="0.5", linewidths=0, label=f"points kept ({len(points)})")
    markers = sorted(lines.markers if lines is not None else [], key=lambda m: m.ns != "v_lines")  # V under H
    for marker in markers:
        ends = np.array([[p.x, p.y, p.z] for p in marker.points], dtype=float).reshape(-1, 2, 3)
        colour = (marker.color.r, marker.color.g, marker.color.b)
        ax.add_collection(LineCollection(ends[:, :, [a, b]], colors=[colour], linewidths=0.6 if marker.ns == "v_lines"
                                         else 1.0, label=f"{LINE_NAMES.get(marker.ns, marker.ns)}: {len(ends)}"))
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
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
