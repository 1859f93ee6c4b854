"""Which parameter preset fits a LiDAR's data: from its beam count (rings) or metadata, else from how the cloud fits
each preset's sensor model (line_odom.sensor_check)."""
from __future__ import annotations

import numpy as np

from line_odom import sensor_check
from line_odom.readers.base import Sensor

# beams -> (preset, the beams' elevation span in deg that preset's model has)
BEAM_PRESETS = {16: ("vlp16", (-15.0, 15.0)), 64: ("kitti_hdl64", (-24.9, 2.0)), 128: ("ouster_os128", (-22.5, 22.5))}
SPAN_TOLERANCE_DEG = 4.0  # a model that far off its beams still puts each ring on its own row


def ring_elevations(xyz: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Median elevation (deg) of each ring 0 .. max(ring) (NaN for a ring without points)."""
    el = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    out = np.full(int(ring.max()) + 1, np.nan)
    for r in np.unique(ring):
        out[int(r)] = float(np.median(el[ring == r]))
    return out


def for_rings(xyz: np.ndarray, ring: np.ndarray, what: str) -> Sensor:
    """The preset for a cloud whose points carry their beam (ring): the preset of that many beams when its model's
    elevations are the cloud's, else a uniform model of the cloud's beams between its top and bottom beam (on the
    vlp16 preset: a spinning LiDAR without KITTI's tuning)."""
    finite = np.isfinite(xyz).all(axis=1)
    xyz, ring = xyz[finite], ring[finite]
    elevations = ring_elevations(xyz, ring)
    beams = len(elevations)
    top, bottom = float(np.nanmax(elevations)), float(np.nanmin(elevations))
    if beams in BEAM_PRESETS:
        preset, (low, high) = BEAM_PRESETS[beams]
        if abs(top - high) <= SPAN_TOLERANCE_DEG and abs(bottom - low) <= SPAN_TOLERANCE_DEG:
            return Sensor(preset, {}, f"{what}: {beams} beams from {top:+.1f} to {bottom:+.1f} deg")
    return Sensor("vlp16", {"sensor.model": "uniform", "sensor.rows": beams, "sensor.max_elevation_deg": round(top, 3),
                            "sensor.min_elevation_deg": round(bottom, 3)},
                  f"{what}: {beams} beams from {top:+.1f} to {bottom:+.1f} deg (no preset of that sensor: a uniform "
                  f"model of its beams)")


def for_organized(rows: int, what: str) -> Sensor:
    """The preset for organized clouds (rows = beams, so no sensor model is needed): ouster_os128, every row kept under
    its 128."""
    overrides = {} if rows >= 128 else {"downsample": 1}
    return Sensor("ouster_os128", overrides, f"{what}: organized clouds of {rows} rows"
                  + ("" if not overrides else "; every row kept (downsample 1)"))


def for_points(xyz: np.ndarray, ring: np.ndarray | None, what: str) -> Sensor:
    """The preset for one cloud as a reader gives it: (N, 3) with or without rings, or organized (H, W, 3)."""
    if xyz.ndim == 3:
        return for_organized(xyz.shape[0], what)
    if ring is not None:
        return for_rings(xyz, np.asarray(ring).astype(np.int64), what)
    return for_cloud(xyz, what)


def for_cloud(xyz: np.ndarray, what: str) -> Sensor:
    """The preset for a cloud without rings: the first LiDAR preset whose sensor model the cloud fits, else
    kitti_hdl64 (the processor then warns with what to set)."""
    from line_odom_core import Odometry, load_config

    xyz = np.ascontiguousarray(np.asarray(xyz, dtype=np.float64).reshape(-1, 3))
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    for preset in sensor_check.LIDAR_PRESETS:
        if sensor_check.fits(Odometry(load_config(preset)).sensor_fit(xyz)):
            return Sensor(preset, {}, f"{what}: no ring field; the cloud fits the sensor model of {preset}")
    presets = ", ".join(sensor_check.LIDAR_PRESETS)
    return Sensor("kitti_hdl64", {}, f"{what}: no ring field and the cloud fits none of the LiDAR presets' sensor "
                                     f"models ({presets}); set --params or --set sensor.*")
