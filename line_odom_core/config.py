"""Engine configuration: one flat set of dotted settings ("ransac.max_iterations", "lines.min_points", ...),
the same names as the ROS parameters of the node, read from ROS 2 parameter files
(``line_odom: ros__parameters: {section: {key: value}}``) and checked against a schema with types and ranges.
"""
from __future__ import annotations

import functools
import math
import os
import re
import sys
from pathlib import Path
from typing import Any, Iterable, Mapping, NamedTuple

PRESETS = ("kitti_hdl64", "tum_kinect", "vlp16", "ouster_os128")
NODE_NAME = "line_odom"


class ConfigEntry(NamedTuple):
    """One engine setting: dotted name, Python type (bool, int, float or str), default, description, and the
    inclusive range [min, max] (None = unbounded; for str settings the allowed values are in CHOICES)."""

    name: str
    type: type
    default: Any
    description: str
    min: float | None
    max: float | None


_INF = None
_ENTRIES: list[ConfigEntry] = [
    ConfigEntry("downsample", int, 1, "keep every n-th row and column of the range image (1 = full resolution, "
                "6 = 1/36, 8 = 1/64, 10 = 1/100)", 1, 64),
    ConfigEntry("seed", int, 0, "random seed of every sampling step (runs are deterministic for a seed)", 0, 2**62),
    ConfigEntry("threads", int, 1, "threads of the line fit and the line-pair search (0 = one per hardware thread); "
                "the results do not depend on it", 0, 256),
    # --- organizing the input (paper §6.2) ---
    ConfigEntry("sensor.model", str, "hdl64", "how unorganized clouds map onto rows (beams) and columns (azimuth):"
                " hdl64 (= kitti), vlp16, os128, or uniform (sensor.rows beams evenly spaced between the "
                "elevation limits); organized clouds and depth images ignore it", None, None),
    ConfigEntry("sensor.rows", int, 0, "beams of a uniform sensor model (0 = the preset's)", 0, 1024),
    ConfigEntry("sensor.cols", int, 0, "azimuth bins of the range image (0 = the preset's)", 0, 65536),
    ConfigEntry("sensor.max_elevation_deg", float, 2.0, "uniform model: elevation of the top beam (deg)",
                -90.0, 90.0),
    ConfigEntry("sensor.min_elevation_deg", float, -24.9, "uniform model: elevation of the bottom beam (deg)",
                -90.0, 90.0),
    ConfigEntry("sensor.min_range", float, 0.0, "closer points are holes (m; depth cameras: depth z)", 0.0, 1e6),
    ConfigEntry("sensor.max_range", float, 1e9, "farther points are holes (m)", 0.0, 1e9),
    ConfigEntry("sensor.deskew", bool, True, "points given with their times (a PointCloud2's t/time/timestamp "
                "field) are moved into the sensor frame at the stamp at the predicted velocity (motion "
                "compensation of the sweep); false: used as measured", None, None),
    ConfigEntry("sensor.deskew_tolerance", float, 0.005, "the previous scan is deskewed again at the current "
                "velocity when the two corrections put a point 20 m away further apart than this (m), so both "
                "scans of a registration are corrected alike", 0.0, 10.0),
    ConfigEntry("sensor.deskew_trend", int, 3, "a sweep is corrected at the pair's velocity plus how much faster it "
                "moves than the previous sweep: the slope of the last n frames' registered velocities (frames; 0: "
                "off, both scans of a pair at one velocity; else 3 to 20)", 0, 20),
    ConfigEntry("sensor.deskew_iterations", int, 1, "once registered, a sweep whose registered velocity moves a point "
                "20 m away further than deskew_tolerance from where the prediction's did is deskewed again at it "
                "(its features and the previous scan's moved) and registered again from the estimate, at most "
                "this many times; 0: at the prediction only", 0, 10),
    # --- line fitting on rows (H-lines) and columns (V-lines), paper §6.2 ---
    ConfigEntry("lines.min_points_h", int, 5, "inlier points an H-line (row) needs", 2, 100000),
    ConfigEntry("lines.min_points_v", int, 3, "inlier points a V-line (column) needs (few rows when "
                "downsampled)", 2, 100000),
    ConfigEntry("lines.min_length", float, 0.3, "shortest line (m) between its end points", 0.0, 1000.0),
    ConfigEntry("lines.split_distance", float, 0.06, "largest point-to-line distance inside one line (m at "
                "range 0; grows with range)", 1e-5, 10.0),
    ConfigEntry("lines.max_rms", float, 0.03, "largest rms of a line fit (m at range 0; grows with range)",
                1e-5, 10.0),
    ConfigEntry("lines.threshold_per_m", float, 0.01, "line thresholds scale by 1 + a r + b r^2: a (1/m)",
                0.0, 10.0),
    ConfigEntry("lines.threshold_per_m2", float, 0.0, "line thresholds scale by 1 + a r + b r^2: b (1/m^2)",
                0.0, 100.0),
    ConfigEntry("lines.max_gap", int, 2, "missing cells bridged inside one line", 0, 1000),
    ConfigEntry("lines.min_incidence_deg", float, 4.0, "steps closer than this to the viewing ray are depth "
                "jumps (deg)", 0.0, 90.0),
    ConfigEntry("lines.trim_sigmas", float, 5.0, "line end points farther than this many rms from the line are "
                "trimmed", 0.0, 100.0),
    ConfigEntry("lines.max_outliers", int, 2, "stray points skipped between two collinear pieces", 0, 1000),
    # --- line normals from H/V crossings and their 3 clusters, paper §6.2-6.3 ---
    ConfigEntry("normals.min_crossing_angle_deg", float, 25.0, "flatter H/V crossings give no normal (deg)",
                0.0, 90.0),
    ConfigEntry("normals.max_deviation_deg", float, 15.0, "crossings farther than this from a line's mean "
                "normal are outliers (deg)", 0.0, 90.0),
    ConfigEntry("normals.min_crossings", int, 1, "agreeing crossings a line needs for a normal", 1, 100000),
    ConfigEntry("normals.min_agreement", float, 0.5, "fraction of a line's crossings that must agree", 0.0, 1.0),
    ConfigEntry("normals.vote_angle_deg", float, 10.0, "radius of a cluster-direction vote (deg)", 0.1, 90.0),
    ConfigEntry("normals.min_separation_deg", float, 45.0, "least angle between cluster directions (deg)",
                0.0, 90.0),
    ConfigEntry("normals.max_cluster_angle_deg", float, 90.0, "normals farther than this from every direction "
                "stay unclustered (deg)", 0.0, 90.0),
    ConfigEntry("normals.min_cluster_fraction", float, 0.02, "votes a direction needs, as a fraction of all "
                "normals", 0.0, 1.0),
    ConfigEntry("normals.end_crossing_weight", float, 0.25, "weight of an H/V crossing at a line's end (corners "
                "join lines of two surfaces there)", 0.0, 1.0),
    # --- plane fitting, paper §6.2 ---
    ConfigEntry("planes.enabled", bool, True, "fit planes (needed by the 3L1P and 1L2P solvers)", None, None),
    ConfigEntry("planes.max_distance", float, 0.10, "line end points within this of the plane join it (m at "
                "range 0)", 1e-5, 10.0),
    ConfigEntry("planes.max_normal_angle_deg", float, 10.0, "line normal vs plane normal (deg)", 0.0, 90.0),
    ConfigEntry("planes.min_points", int, 30, "range-image points a plane needs", 3, 10000000),
    ConfigEntry("planes.min_lines", int, 3, "H- and V-lines a plane needs", 2, 100000),
    ConfigEntry("planes.min_extent", float, 1.0, "shorter side of the plane's equal-moment rectangle (m)",
                0.0, 1000.0),
    ConfigEntry("planes.max_rms", float, 0.06, "point-to-plane rms (m)", 1e-5, 10.0),
    ConfigEntry("planes.max_planes", int, 20, "keep the largest this many planes", 0, 10000),
    # --- registration (paper §6.3) ---
    ConfigEntry("candidates.max_distance", float, 2.0, "line pairs whose segments come within this distance (m) "
                "under the motion guess are candidate intersections (paper: 2 m on KITTI)", 1e-3, 100.0),
    ConfigEntry("candidates.min_line_angle_deg", float, 10.0, "skip candidate pairs of lines closer to parallel "
                "than this (deg)", 0.0, 89.0),
    ConfigEntry("candidates.max_normal_angle_deg", float, 30.0, "when both lines have a surface normal, the "
                "normals must agree within this angle (deg); 90 disables", 0.0, 90.0),
    ConfigEntry("candidates.plane_max_angle_deg", float, 20.0, "candidate plane pairs: normals within this "
                "angle (deg) under the guess (paper: 20)", 0.0, 90.0),
    ConfigEntry("candidates.plane_max_distance", float, 2.0, "candidate plane pairs: centroid-to-other-plane "
                "distance (m) under the guess", 1e-3, 100.0),
    ConfigEntry("candidates.max_pairs_per_line", int, 0, "keep only the k closest partners of each line "
                "(0 = all)", 0, 100000),
    ConfigEntry("ransac.solver", str, "auto", "minimal solver: auto (hybrid over 7L, 3L1P, 1L2P), 7L, 3L1P "
                "or 1L2P", None, None),
    ConfigEntry("ransac.max_iterations", int, 1000, "RANSAC hypotheses per pass", 1, 1000000),
    ConfigEntry("ransac.min_iterations", int, 50, "RANSAC hypotheses per pass at least", 0, 1000000),
    ConfigEntry("ransac.confidence", float, 0.999, "stop when the best model is found with this probability",
                0.5, 0.999999),
    ConfigEntry("ransac.inlier_threshold", float, 0.02, "a candidate pair is an inlier when its lines pass "
                "within this distance (m) (paper: 2 cm KITTI, 5 mm TUM)", 1e-5, 10.0),
    ConfigEntry("ransac.plane_angle_threshold_deg", float, 3.0, "plane pair inlier: normal angle (deg)",
                0.0, 90.0),
    ConfigEntry("ransac.plane_distance_threshold", float, 0.05, "plane pair inlier: offset difference (m)",
                0.0, 10.0),
    ConfigEntry("ransac.refine_iterations", int, 10, "least-squares iterations on all inliers", 0, 1000),
    ConfigEntry("ransac.huber_delta", float, 0.0, "robust loss width of the refinement (m); 0 = inlier "
                "threshold", 0.0, 10.0),
    ConfigEntry("ransac.degeneracy_threshold", float, 1e-3, "the refinement is degenerate when its normal matrix "
                "(rotations scaled to metres) is worse conditioned than this", 0.0, 1.0),
    ConfigEntry("registration.passes", int, 3, "candidate + RANSAC passes per frame, each seeded with the best "
                "estimate so far (paper §6.3: 3)", 1, 10),
    ConfigEntry("registration.pass_distance_scale", float, 1.0, "candidate distance multiplier from one pass to "
                "the next (1 = the same threshold every pass)", 0.01, 1.0),
    ConfigEntry("registration.max_lines", int, 3000, "lines registered per scan: when more were fitted, only those "
                "of every s-th row and column give normals, planes and the registration, s the smallest step within "
                "this budget, and the next scan is fitted only on the rows and columns that step keeps (each line "
                "still fitted to every point of its row or column; neighbouring rows on one surface give nearly the "
                "same intersections). 0 = all", 0, 10000000),
    ConfigEntry("registration.window", int, 1, "previous scans each scan is registered against: their lines and "
                "planes moved into the last scan's frame by the estimated motions, kept only when the last scan alone "
                "observes every direction of the result (1 = the last scan only, paper §6.3)", 1, 10),
    ConfigEntry("registration.first_motion_pairs_per_line", int, 0, "while there is no motion guess (the first "
                "motion after start or reset, searched from standing still), keep the k closest partners of each line "
                "within candidates.max_distance (0 = all of them, as in the paper)", 0,
                100000),
    ConfigEntry("registration.min_inliers", int, 12, "fewer inlier pairs than this: registration failed, the "
                "motion model's prediction is held", 0, 1000000),
    ConfigEntry("registration.max_translation", float, 5.0, "an estimate further than this (m) from the "
                "prediction is rejected", 1e-3, 1000.0),
    ConfigEntry("registration.max_rotation_deg", float, 30.0, "an estimate rotated more than this (deg) from the "
                "prediction is rejected", 0.01, 180.0),
    ConfigEntry("registration.constant_velocity", bool, True, "predict each motion from the previous one "
                "(scaled by the stamp interval); false = identity", None, None),
    ConfigEntry("registration.persistence_window", int, 0, "frames over which the prediction measures, per axis, "
                "how much of one frame's estimated motion carries over to the next (the least-squares a in "
                "xi(k+1) ~ a xi(k), clamped to [0, 1]) and carries only that share: ~1 for a smoothly moving, "
                "precisely measured sensor; less where the estimates are noisy against the motion, so a wrong frame "
                "is not extrapolated into the next ones. Constant velocity until 10 pairs. 0 = the last motion as "
                "it was", 0, 100000),
    ConfigEntry("registration.max_axis_support", float, 0.97, "the estimate is degenerate (the prediction is "
                "held) when pushing it 20 inlier thresholds along one axis keeps this share of its inlier weight: "
                "that motion is unobservable, e.g. along an endless corridor (1 = off)", 0.0, 1.0),
    ConfigEntry("registration.max_axis_pair_support", float, 0.995, "... or when that push keeps this share of "
                "the inlier pairs, each pair counted once whatever its cluster weight (a few coincidental pairs at "
                "two planes' seam must not make the corridor's axis look observed; 1 = off)", 0.0, 1.0),
    ConfigEntry("registration.min_inlier_ratio", float, 0.3, "the estimate is degenerate (the prediction is held) "
                "unless the share of the last pass's candidate line pairs that meet within the inlier threshold is "
                "shown to exceed this (by 2 binomial standard deviations): otherwise the lines are too noisy to fix "
                "the motion (0 = off; docs/RESULTS.md, 'Preset choices')", 0.0, 1.0),
    ConfigEntry("registration.max_prediction_gap", float, 1.0, "a stamp gap longer than this (s) drops the "
                "velocity: the motion is found afresh as after a reset instead of extrapolated", 1e-3, 3600.0),
    ConfigEntry("registration.min_sample_pair_share", float, 0.95, "a RANSAC sample replaces the refined guess "
                "only if it also keeps this share of the guess's inlier pairs, counted unweighted (a wrong motion can "
                "out-weigh the guess on a few small, heavily weighted normal clusters while losing the others)",
                0.0, 1.0),
    ConfigEntry("registration.guess_preference", float, 0.0, "a RANSAC estimate replaces the refined guess "
                "(prediction or previous pass) only when its weighted inlier count is larger by this fraction",
                0.0, 1.0),
    ConfigEntry("registration.coarse_downsample", int, 6, "while there is no velocity (first motion after start "
                "or reset), register the scans downsampled by this step first and start from that estimate "
                "(0 or = downsample: off; finer than downsample helps where the sparse scans barely observe the "
                "motion, e.g. a highway at 1/64)", 0, 64),
    ConfigEntry("registration.covariance_scale", float, 1.0, "multiplies the refinement's covariance before it is "
                "reported and fused (the least-squares covariance ignores wrong candidate pairs)", 1e-6, 1e9),
    ConfigEntry("registration.covariance_per_inlier", bool, False, "covariance_scale multiplies the covariance "
                "once per inlier constraint, i.e. the frame's error does not shrink with the number of constraints, "
                "as measured on real sensors (their errors are shared: calibration, surfaces); false: the "
                "least-squares 1/n", None, None),
    ConfigEntry("registration.motion_prior_translation_sigma", float, 0.0, "1-sigma deviation (m per frame) from "
                "the constant-velocity prediction; > 0 fuses the estimate with the prediction so poorly observed "
                "directions follow the motion model (0 = off)", 0.0, 100.0),
    ConfigEntry("registration.motion_prior_rotation_sigma_deg", float, 0.5, "1-sigma deviation (deg per frame) "
                "from the constant-velocity prediction, used with motion_prior_translation_sigma", 1e-6, 180.0),
    ConfigEntry("registration.partial_updates", bool, True, "a degenerate registration keeps the directions the "
                "lines observe and holds only the others at the prediction (false: holds the whole prediction)",
                None, None),
    ConfigEntry("registration.fallback_translation_sigma", float, 0.5, "1-sigma translation uncertainty (m) "
                "reported when the prediction is held", 0.0, 1000.0),
    ConfigEntry("registration.fallback_rotation_sigma_deg", float, 5.0, "1-sigma rotation uncertainty (deg) "
                "reported when the prediction is held", 0.0, 180.0),
    # --- point-to-plane refinement (beyond the paper; docs/RESULTS.md, "Preset choices") ---
    ConfigEntry("points.weight", float, 0.0, "information (1/m^2) of one point-to-plane residual of this scan's "
                "voxel means against the previous scan's voxel planes, refined jointly with the lines' estimate (as a "
                "Gaussian of its covariance) after the registration; dense scans only: on sparse ones the voxels' "
                "planes are poor. 0 = off (the paper's method)", 0.0, 1e6),
    ConfigEntry("points.max_downsample", int, 1, "the refinement runs only while downsample is at most this step "
                "(the weight is measured at full resolution; sparser scans lose with it: docs/RESULTS.md)", 1, 1000),
    ConfigEntry("points.voxel", float, 1.0, "both scans are binned in cubes of this size (m): this scan's voxel "
                "means are matched to the planes of the previous scan's voxels they fall in", 0.01, 10.0),
    ConfigEntry("points.stride", int, 1, "every n-th row and column of the range image is binned", 1, 64),
    ConfigEntry("points.min_points", int, 6, "points a voxel needs: for its plane (previous scan) and for its mean "
                "(this scan)", 3, 1000000),
    ConfigEntry("points.min_planarity", float, 0.1, "a voxel is flat enough when (l1 - l0) / l2 of its points' "
                "scatter's eigenvalues reaches this", 0.0, 1.0),
    ConfigEntry("points.huber", float, 0.1, "robust loss width of the point-to-plane residuals (m)", 1e-4, 10.0),
    ConfigEntry("points.iterations", int, 10, "Gauss-Newton iterations, the partners found again in each", 1, 100),
    ConfigEntry("points.max_translation", float, 0.1, "a refinement moving the lines' estimate further than this (m) "
                "is not taken", 0.0, 10.0),
    ConfigEntry("points.max_rotation_deg", float, 0.5, "... or turning it more than this (deg)", 0.0, 180.0),
    # --- the point map where the lines leave a direction open, and the lines' observability (beyond the paper;
    # docs/NODE.md, "Validation") ---
    ConfigEntry("point_map.enabled", bool, True, "keep a local map of the last scans' points and align a scan to it "
                "where the lines do not pin its motion down (a first motion, a street along which every pair meets)",
                None, None),
    ConfigEntry("point_map.voxel", float, 0.0, "the map's cubes (m); 0: sensor.max_range / 100", 0.0, 100.0),
    ConfigEntry("point_map.max_points_per_voxel", int, 20, "points each cube keeps", 1, 1000),
    ConfigEntry("point_map.max_iterations", int, 50, "Gauss-Newton iterations of an alignment", 1, 1000),
    ConfigEntry("point_map.initial_threshold", float, 2.0, "the motion model's error assumed before one was measured "
                "(m): the alignment's first reach", 1e-3, 100.0),
    ConfigEntry("point_map.min_motion", float, 0.1, "frames moving less than this (m) do not measure the motion "
                "model's error", 0.0, 100.0),
    ConfigEntry("validation.enabled", bool, True, "test that the lines pin each motion down in every direction "
                "(McNemar's test of the pairs meeting under the motion against the motion pushed either way)",
                None, None),
    ConfigEntry("validation.tolerance", float, 0.3, "the push (m; rotations: as far at the lines' range): a motion "
                "is claimed right to this", 1e-3, 100.0),
    ConfigEntry("validation.motion_share", float, 0.3, "... or to this share of its translation, when larger", 0.0,
                1.0),
    ConfigEntry("validation.significance", float, 3.0, "z below which a push is not rejected: the direction is not "
                "pinned down (held at the point map's alignment, flagged)", 1e-3, 100.0),
]

CHOICES: dict[str, tuple[str, ...]] = {"ransac.solver": ("auto", "7L", "3L1P", "1L2P"),
                                       "sensor.model": ("hdl64", "kitti", "vlp16", "os128", "uniform")}


def _register(entries: Iterable[ConfigEntry]) -> None:
    _ENTRIES.extend(entries)


def config_schema() -> list[ConfigEntry]:
    """Every engine setting (name, type, default, description, min, max), in a stable order."""
    return list(_ENTRIES)


def _schema_map() -> dict[str, ConfigEntry]:
    return {e.name: e for e in _ENTRIES}


def _range_text(entry: ConfigEntry) -> str:
    if entry.name in CHOICES:
        return "one of " + ", ".join(CHOICES[entry.name])
    lo = "-inf" if entry.min is None else repr(entry.min)
    hi = "inf" if entry.max is None else repr(entry.max)
    return f"{entry.type.__name__} in [{lo}, {hi}]"


def validate_value(name: str, value: Any) -> Any:
    """The value converted to the setting's type; ValueError naming the key and the expected range."""
    schema = _schema_map()
    if name not in schema:
        raise ValueError(f"unknown engine setting {name!r}; known: {', '.join(sorted(schema))}")
    return validate_entry(schema[name], value, CHOICES.get(name))


def validate_entry(entry: ConfigEntry, value: Any, choices: tuple[str, ...] | None = None) -> Any:
    """validate_value for an entry of any schema (the node's own parameters use it too); ``choices`` for a str."""
    name = entry.name
    range_text = ("one of " + ", ".join(choices)) if choices else _range_text(entry)
    bad = ValueError(f"{name}: expected {range_text}, got {value!r}")
    if entry.type is bool:
        if isinstance(value, bool):
            return value
        raise bad
    if entry.type is str:
        if not isinstance(value, str):
            raise bad
        if choices is not None:
            match = [c for c in choices if c.lower() == value.lower()]
            if not match:
                raise bad
            value = match[0]
        return value
    if isinstance(value, (bool, str, bytes)):
        raise bad
    if entry.type is int:
        try:
            as_float = float(value)
        except (TypeError, ValueError):
            raise bad from None
        if not math.isfinite(as_float) or as_float != int(as_float):
            raise bad
        value = int(as_float)
    else:
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise bad from None
        if not math.isfinite(value):
            raise bad
    if (entry.min is not None and value < entry.min) or (entry.max is not None and value > entry.max):
        raise bad
    return value


class Config:
    """Engine settings by dotted name (``config["ransac.max_iterations"]``), plus ``extra``: the keys of the
    parameter file the engine does not know (the node's own parameters: frames, topics, qos, ...)."""

    def __init__(self, values: Mapping[str, Any] | None = None, extra: Mapping[str, Any] | None = None,
                 source: str | None = None):
        self._values = {e.name: e.default for e in _ENTRIES}
        for name, value in (values or {}).items():
            self._values[name] = validate_value(name, value)
        self.extra: dict[str, Any] = dict(extra or {})
        self.source = source
        self._check_consistency()

    def _check_consistency(self) -> None:
        if self._values["sensor.min_range"] >= self._values["sensor.max_range"]:
            raise ValueError(f"sensor.min_range: expected < sensor.max_range ({self._values['sensor.max_range']}), "
                             f"got {self._values['sensor.min_range']}")
        if self._values["sensor.model"] == "uniform" and (
                self._values["sensor.rows"] < 2
                or self._values["sensor.max_elevation_deg"] <= self._values["sensor.min_elevation_deg"]):
            raise ValueError("sensor.rows: a uniform sensor model needs sensor.rows >= 2 and "
                             "sensor.max_elevation_deg > sensor.min_elevation_deg")
        if self._values["ransac.min_iterations"] > self._values["ransac.max_iterations"]:
            raise ValueError(f"ransac.min_iterations: expected <= ransac.max_iterations "
                             f"({self._values['ransac.max_iterations']}), got {self._values['ransac.min_iterations']}")

    def __getitem__(self, name: str) -> Any:
        if name not in self._values:
            raise KeyError(name)
        return self._values[name]

    def __contains__(self, name: object) -> bool:
        return name in self._values

    def get(self, name: str, default: Any = None) -> Any:
        return self._values.get(name, default)

    def as_dict(self) -> dict[str, Any]:
        """All engine settings, dotted name -> value."""
        return dict(self._values)

    def with_overrides(self, overrides: Mapping[str, Any] | None) -> "Config":
        """A copy with some settings replaced; unknown names or out-of-range values raise ValueError."""
        values = dict(self._values)
        for name, value in (overrides or {}).items():
            values[name] = validate_value(name, value)
        return Config(values, self.extra, self.source)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Config) and self._values == other._values and self.extra == other.extra

    def __repr__(self) -> str:
        changed = {k: v for k, v in self._values.items() if v != _schema_map()[k].default}
        return f"Config(source={self.source!r}, changed={changed!r}, extra_keys={sorted(self.extra)!r})"


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested sections -> dotted names ({"ransac": {"max_iterations": 5}} -> {"ransac.max_iterations": 5})."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def config_search_dirs() -> list[Path]:
    """Where presets are looked for: the source tree, <sys.prefix>/share/line_odom/config, then every
    AMENT_PREFIX_PATH entry's share/line_odom/config."""
    dirs = [Path(__file__).resolve().parents[1] / "config", Path(sys.prefix) / "share" / "line_odom" / "config"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share" / "line_odom" / "config")
    return dirs


def preset_path(name: str) -> Path:
    """The YAML file of a preset (e.g. "kitti_hdl64"); FileNotFoundError listing where it was looked for."""
    if name not in PRESETS:
        raise ValueError(f"preset_or_path: expected one of {', '.join(PRESETS)} or a YAML file path, got {name!r}")
    searched = config_search_dirs()
    for directory in searched:
        candidate = directory / f"{name}.yaml"
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"preset {name!r}: {name}.yaml not found in " + ", ".join(str(d) for d in searched))


@functools.lru_cache(maxsize=None)
def _yaml_loader():
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    # YAML 1.1 (PyYAML) needs a dot in a float, so 1e-4 would be a string; ROS 2's parameter parser reads it as a
    # double, and so do we.
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$"),
                                 list("-+0123456789."))
    return Loader


def yaml_load(stream: Any) -> Any:
    """yaml.safe_load with exponent floats without a dot (1e-4) read as floats, as ROS 2 reads parameter files."""
    import yaml

    return yaml.load(stream, Loader=_yaml_loader())


def read_parameter_file(path: str | Path, node: str = NODE_NAME) -> dict[str, Any]:
    """The flattened ros__parameters of `node` (or of the wildcard "/**") in a ROS 2 parameter file."""
    path = Path(path)
    with open(path, encoding="utf-8") as f:
        doc = yaml_load(f)
    if not isinstance(doc, Mapping):
        raise ValueError(f"{path}: expected a ROS 2 parameter file (mapping '{node}: ros__parameters: ...')")
    params: dict[str, Any] = {}
    found = False
    for key in ("/**", node, "/" + node):
        section = doc.get(key)
        if isinstance(section, Mapping) and isinstance(section.get("ros__parameters"), Mapping):
            params.update(flatten(section["ros__parameters"]))
            found = True
    if not found:
        raise ValueError(f"{path}: no '{node}: ros__parameters:' (or '/**: ros__parameters:') section; "
                         f"top-level keys are {sorted(map(str, doc))}")
    return params


def load_config(preset_or_path: str | os.PathLike = "kitti_hdl64",
                overrides: Mapping[str, Any] | None = None) -> Config:
    """Engine settings from a preset name ("kitti_hdl64", "tum_kinect", "vlp16", "ouster_os128") or a ROS 2
    parameter YAML file, with `overrides` (dotted names as the ROS parameters) applied on top.

    Keys of the file the engine does not know are kept in ``config.extra``; unknown keys in `overrides` and
    out-of-range values raise ValueError naming the key and the expected range."""
    text = os.fspath(preset_or_path)
    looks_like_path = text.endswith((".yaml", ".yml")) or os.sep in text or Path(text).is_file()
    path = Path(text) if looks_like_path else preset_path(text)
    if not path.is_file():
        raise FileNotFoundError(f"preset_or_path: {path} does not exist")
    params = read_parameter_file(path)
    schema = _schema_map()
    known = {k: v for k, v in params.items() if k in schema}
    extra = {k: v for k, v in params.items() if k not in schema}
    try:
        config = Config(known, extra, str(path))
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    if overrides is not None:
        if not isinstance(overrides, Mapping):
            raise ValueError(f"overrides: expected a dict of dotted names, got {type(overrides).__name__}")
        config = config.with_overrides(overrides)
    return config
