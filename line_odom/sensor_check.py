"""Does a LiDAR's cloud fit the sensor model it is read with? The drop-in check of the node's `preset`.

An unorganized cloud is organized into the rows of a sensor model (its beams' elevations, or the cloud's `ring`
field). Read with another sensor's model, a cloud falls outside the model's beams or leaves most of its rows empty,
and its range image has no lines along the columns: the registration then holds the prediction frame after frame
(a VLP-16 cloud without `ring` read with `kitti_hdl64` fills 9 of 64 rows, 39 % of its points outside them). The
processor checks clouds until one fits and warns, naming the parameter to set and the preset that fits, until then.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping

LIDAR_PRESETS = ("kitti_hdl64", "vlp16", "ouster_os128")
MAX_OUTSIDE_SHARE = 0.10  # a fitting model leaves <= 3 % outside (the simulated HDL-64E in KITTI's measured table)
MIN_FILLED_SHARE = 0.6    # ... and fills >= 94 % of the rows between its top and bottom filled rows (open sky or a
                          # lone ground leaves rows above or below empty, not between; a VLP-16 cloud in the HDL-64E
                          # model fills 9 of 41)
MIN_POINTS = 100          # fewer valid points tell nothing


def problem(fit: Mapping[str, Any]) -> str | None:
    """What in `fit` (line_odom_core.Odometry.sensor_fit) does not fit the sensor model, or None when it fits or the
    cloud has too few points to tell."""
    model = (f"sensor model '{fit['model']}' ({fit['rows']} rows, {fit['max_elevation_deg']:+.1f} to "
             f"{fit['min_elevation_deg']:+.1f} deg)")
    spans = f"the cloud spans {fit['cloud_high_deg']:+.1f} to {fit['cloud_low_deg']:+.1f} deg"
    if fit["ring_rows"] > fit["rows"]:
        return f"the cloud's ring field counts {fit['ring_rows']} rings, more than {model} has"
    if fit["points"] < MIN_POINTS:
        return None
    outside = fit["outside_rows"] / fit["points"]
    if outside > MAX_OUTSIDE_SHARE:
        return f"{outside:.0%} of the cloud's points lie outside the beams of {model}; {spans}"
    if fit["filled_rows"] < MIN_FILLED_SHARE * fit["band_rows"]:
        rows_from = "its ring field" if fit["row_method"].startswith("ring") else "elevation"
        return (f"the cloud fills {fit['filled_rows']} of the {fit['band_rows']} rows between its top and bottom "
                f"rows in {model}, its rows by {rows_from}; {spans}")
    return None


def fits(fit: Mapping[str, Any]) -> bool:
    return fit["points"] >= MIN_POINTS and problem(fit) is None


def advice(fit_with: Callable[[str], Mapping[str, Any]]) -> str:
    """What to set: the LiDAR presets whose sensor model the cloud fits (`fit_with(preset)` gives the cloud's fit with
    that preset's model), else the sensor parameters."""
    fitting = [name for name in LIDAR_PRESETS if fits(fit_with(name))]
    params = "sensor.model, sensor.rows, sensor.max_elevation_deg, sensor.min_elevation_deg"
    if fitting:
        return f"set parameter 'preset' to {' or '.join(repr(n) for n in fitting)} (it fits), or {params}"
    return (f"set parameter 'preset' ({', '.join(LIDAR_PRESETS)}) or {params} to the sensor's (none of the presets "
            f"fits; is the cloud in the LiDAR's own frame, its origin at the sensor?)")
