"""The scan the odometry registers, for rviz (``~/scan``): the points the engine registered, after organizing,
downsampling (``downsample``: every n-th row and column; ``sensor.min_range``/``max_range``) and deskewing, in the
sensor frame (the engine's own copy, Odometry.last_points). For an engine without that copy: the kept points as found
here, before deskewing."""
from __future__ import annotations

import numpy as np

from line_odom import convert


def kept_unorganized(engine, xyz: np.ndarray, ring: np.ndarray | None) -> np.ndarray | None:
    """(M, 3) of an unorganized cloud, by the engine's own binning (None: an engine without it)."""
    kept = getattr(engine, "downsampled_points", None)
    return None if kept is None else np.asarray(kept(xyz, ring=ring))


def _in_range(points: np.ndarray, config) -> np.ndarray:
    points = points.reshape(-1, 3)
    r = np.linalg.norm(points, axis=1)
    keep = np.isfinite(r) & (r > 0) & (r >= config["sensor.min_range"]) & (r <= config["sensor.max_range"])
    return points[keep]


def kept_organized(xyz: np.ndarray, config) -> np.ndarray:
    """(M, 3) of an organized cloud (H, W, 3): every downsample-th row and column from the first, as the engine."""
    step = int(config["downsample"])
    return _in_range(np.asarray(xyz, dtype=np.float64)[::step, ::step], config)


def kept_depth(depth: np.ndarray, K: np.ndarray, config) -> np.ndarray:
    """(M, 3) of a depth image back-projected by the engine's own organizing (camera optical frame)."""
    from line_odom_core._core import organize_depth

    image = organize_depth(depth, K, min_depth=config["sensor.min_range"], max_depth=config["sensor.max_range"],
                           downsample=int(config["downsample"]), downsample_while_organizing=True)
    return np.asarray(image["points"])[np.asarray(image["valid"], dtype=bool)]


def scan_message(points: np.ndarray, frame_id: str, stamp_ns: int):
    """PointCloud2 (x y z float32, unorganized) at the frame's own stamp and frame."""
    return convert.pointcloud2_from_xyz(np.asarray(points, dtype=np.float32).reshape(-1, 3), frame_id=frame_id,
                                        stamp=convert.ns_to_stamp(stamp_ns))
