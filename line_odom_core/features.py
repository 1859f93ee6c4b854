"""Scan features (lines, normals, planes) of one organized cloud with a sensor preset's feature settings: the presets'
lines.*, normals.*, planes.* from config/*.yaml over the engine's defaults."""
from __future__ import annotations

from typing import Any, Mapping

from line_odom_core import _core
from line_odom_core.config import PRESETS, preset_path, read_parameter_file

# Short names of the presets (and the sensor model names they go with).
PRESET_ALIASES = {"kitti": "kitti_hdl64", "hdl64": "kitti_hdl64", "tum": "tum_kinect", "os128": "ouster_os128"}


def feature_config(preset: str = "kitti") -> dict[str, Any]:
    """The feature settings (lines.*, normals.*, planes.*) of a preset ("kitti", "tum", or a preset name of
    line_odom_core.config.PRESETS), by dotted name."""
    name = PRESET_ALIASES.get(preset, preset)
    if name not in PRESETS:
        raise ValueError(f"preset: expected one of {', '.join([*PRESET_ALIASES, *PRESETS])}, got {preset!r}")
    values = _core.feature_config()
    values.update({k: v for k, v in read_parameter_file(preset_path(name)).items() if k in values})
    return values


def extract_features(range_image, config: Mapping[str, Any] | None = None, preset: str = "kitti", *,
                     threads: int = 1) -> dict:
    """Organized cloud (H, W, 3) (NaN/zero = hole) -> dict of H/V lines, planes, cluster directions, stats, with the
    preset's feature settings and `config`'s on top (dotted names); `threads`: the line fit's (the same features)."""
    if config is not None and not isinstance(config, Mapping):
        raise ValueError("config: expected a dict of dotted names")
    return _core.extract_features(range_image, {**feature_config(preset), **(config or {})}, threads=threads)
