"""Engine configuration: one flat set of dotted settings ("ransac.max_iterations", "lines.min_points", ...),
the same names as the ROS parameters of the node, read from ROS 2 parameter files
(``line_odom: ros__parameters: {section: {key: value}}``). The schema (types, defaults, ranges, units, descriptions)
and the checks are the engine's own settings table, read through the bindings: nothing here repeats them.
"""
from __future__ import annotations

import dataclasses
import functools
import os
import re
import sys
from pathlib import Path
from typing import Any, Mapping

from line_odom_core import _core

PRESETS = ("kitti_hdl64", "tum_kinect", "vlp16", "ouster_os128")
NODE_NAME = "line_odom"


@dataclasses.dataclass(frozen=True)
class ConfigEntry:
    """One setting: dotted name, Python type (bool, int, float or str), default, one-line description, the range
    [min, max] (None: unbounded; min_open / max_open exclude the bound; zero_is_off: 0 accepted besides, switching the
    feature off), choices of a str setting, unit, and whether a running node may change it. The engine's come from
    its C++ table (line_odom_core/cpp/odometry/engine_settings.cpp); the node's own parameters use the same rows
    (line_odom.node_parameters)."""

    name: str
    type: type
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    max_open: bool = False
    zero_is_off: bool = False
    choices: tuple[str, ...] = ()
    unit: str = ""
    runtime: bool = False

    @property
    def expected(self) -> str:
        """What the setting accepts, as its errors say it: "float in (0.0, 10.0] m", "one of auto, 7L, ..."."""
        return expected_text(self)


def _bound_text(entry: ConfigEntry, x: float) -> str:
    return str(int(x)) if entry.type is int else repr(float(x))


def expected_text(entry: ConfigEntry) -> str:
    """The words the engine's errors use for what a setting accepts (its C++ table's SettingInfo::expected)."""
    if entry.type is bool:
        return "bool"
    if entry.type is str:
        return "one of " + ", ".join(entry.choices) if entry.choices else "str"
    lo, hi = entry.min, entry.max
    if lo is not None and hi is not None:
        text = (f"in {'(' if entry.min_open else '['}{_bound_text(entry, lo)}, {_bound_text(entry, hi)}"
                f"{')' if entry.max_open else ']'}")
    elif lo is not None:
        text = f"{'>' if entry.min_open else '>='} {_bound_text(entry, lo)}"
    elif hi is not None:
        text = f"{'<' if entry.max_open else '<='} {_bound_text(entry, hi)}"
    else:
        text = ""
    if entry.zero_is_off:
        text = "0 (off) or " + text
    words = ("integer" if entry.type is int else "float") + (" " + text if text else "")
    return words + (" " + entry.unit if entry.unit else "")


_TYPES = {"bool": bool, "int": int, "float": float, "str": str}


def entry_from_schema(row: Mapping[str, Any]) -> ConfigEntry:
    """A ConfigEntry from one row of the engine's exported schema (_core.settings_schema())."""
    return ConfigEntry(row["name"], _TYPES[row["type"]], row["default"], row["description"], row["min"], row["max"],
                       row["min_open"], row["max_open"], row["zero_is_off"], tuple(row["choices"]), row["unit"],
                       row["runtime"])


@functools.lru_cache(maxsize=None)
def _entries() -> tuple[ConfigEntry, ...]:
    return tuple(entry_from_schema(row) for row in _core.settings_schema())


def config_schema() -> list[ConfigEntry]:
    """Every engine setting, in the engine's order (its settings table)."""
    return list(_entries())


@functools.lru_cache(maxsize=None)
def _schema_by_name() -> dict[str, ConfigEntry]:
    return {e.name: e for e in _entries()}


def _schema_map() -> dict[str, ConfigEntry]:
    return dict(_schema_by_name())


def validate_value(name: str, value: Any) -> Any:
    """The value as the engine setting takes it (an int for a float setting becomes a float, a choice its spelling in
    the schema); ValueError naming the setting and what it accepts. The engine's own check."""
    return _core.check_setting(name, value)


CHOICES: dict[str, tuple[str, ...]] = {e.name: e.choices for e in _entries() if e.choices}


class Config:
    """Engine settings by dotted name (``config["ransac.max_iterations"]``), plus ``extra``: the keys of the
    parameter file the engine does not know (the node's own parameters: frames, topics, qos, ...)."""

    def __init__(self, values: Mapping[str, Any] | None = None, extra: Mapping[str, Any] | None = None,
                 source: str | None = None):
        self._values = {e.name: e.default for e in _entries()}
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
        changed = {k: v for k, v in self._values.items() if v != _schema_by_name()[k].default}
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
    schema = _schema_by_name()
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
