"""One source for every setting: the engine's C++ table (line_odom_core/cpp/odometry/engine_settings.cpp). The Python
schema, the checks, estimate_motion's options, the ROS parameter descriptors, the presets' keys and the parameter
tables of docs/NODE.md agree with it (the node's own parameters with their table, line_odom/node_parameters.py)."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

import line_odom_core
from line_odom import docs_tables
from line_odom.node_parameters import NODE_PARAMETER_NAMES, NODE_PARAMETERS, validate_node_value
from line_odom_core import _core, _testing
from line_odom_core import config as cfg

ENGINE_ROWS = _core.settings_schema()
NUMERIC = [row for row in ENGINE_ROWS if row["type"] in ("int", "float")]


def test_the_python_schema_is_the_engine_table():
    schema = line_odom_core.config_schema()
    assert [e.name for e in schema] == [row["name"] for row in ENGINE_ROWS]
    for entry, row in zip(schema, ENGINE_ROWS):
        assert entry.type.__name__ == row["type"], entry.name
        assert (entry.default, entry.min, entry.max, entry.min_open, entry.max_open, entry.zero_is_off,
                list(entry.choices), entry.unit, entry.description, entry.runtime) == (
            row["default"], row["min"], row["max"], row["min_open"], row["max_open"], row["zero_is_off"],
            row["choices"], row["unit"], row["description"], row["runtime"]), entry.name
        assert entry.expected == row["expected"], entry.name  # the docs' and descriptors' words are the errors'
        assert type(entry.default) is entry.type, entry.name
        assert row["description"] and "\n" not in row["description"], entry.name
    assert _testing.odometry_config_defaults() == {e.name: e.default for e in schema}


def test_an_engine_dumps_the_settings_it_was_given():
    config = line_odom_core.load_config("tum_kinect", {"downsample": 10})
    assert line_odom_core.Odometry(config)._engine.settings() == config.as_dict()


@pytest.mark.parametrize("row", ENGINE_ROWS, ids=[row["name"] for row in ENGINE_ROWS])
def test_each_setting_takes_its_default_and_range_and_refuses_the_rest_naming_it(row):
    name, check = row["name"], _core.check_setting
    assert check(name, row["default"]) == row["default"]
    refused = "^" + re.escape(f"{name}: expected {row['expected']}, got ")
    if row["type"] == "bool":
        assert check(name, False) is False
        for bad in (1, "true", 0.0):
            with pytest.raises(ValueError, match=refused):
                check(name, bad)
        return
    if row["type"] == "str":
        for choice in row["choices"]:
            assert check(name, choice) == choice and check(name, choice.lower()) == choice
        with pytest.raises(ValueError, match=refused):
            check(name, "no_such_choice")
        with pytest.raises(ValueError, match=refused):
            check(name, 1)
        return
    lo, hi = row["min"], row["max"]
    step = 1 if row["type"] == "int" else None
    for bound, is_open, outward in ((lo, row["min_open"], -math.inf), (hi, row["max_open"], math.inf)):
        if bound is None:
            continue
        beyond = bound + (1 if outward > 0 else -1) if step else math.nextafter(bound, outward)
        if is_open:
            beyond = bound
        else:
            assert check(name, bound) == bound
        if not (row["zero_is_off"] and beyond == 0):
            with pytest.raises(ValueError, match=refused):
                check(name, beyond)
    with pytest.raises(ValueError, match=refused):
        check(name, float("nan"))
    if row["zero_is_off"]:
        assert check(name, 0) == 0


def test_an_unknown_setting_is_refused_naming_it():
    with pytest.raises(ValueError, match="^ransac.no_such: unknown engine setting"):
        _core.check_setting("ransac.no_such", 1)
    with pytest.raises(ValueError, match="^lines.no_such: unknown feature parameter"):
        _core.extract_features(np.full((4, 4, 3), np.nan), {"lines.no_such": 1})


def test_estimate_motion_options_share_the_ransac_rows():
    """estimate_motion takes the odometry's ransac.* rows as they are, and the options the odometry sets per pass."""
    ransac = {row["name"].split(".", 1)[1]: row for row in ENGINE_ROWS if row["name"].startswith("ransac.")}
    options = {row["name"]: row for row in _core.estimate_motion_options()}
    assert set(ransac) <= set(options)
    for name, row in ransac.items():
        assert {**options[name], "name": row["name"]} == row, name
    assert set(options) - set(ransac) == {"seed", "min_inliers", "local_optimisation", "pretest",
                                          "min_inlier_contrast", "solve_7l_method", "solve_7l_max_iterations"}


def test_feature_settings_are_the_engine_rows_of_lines_normals_planes():
    engine = {row["name"]: row["default"] for row in ENGINE_ROWS}
    features = _core.feature_config()
    assert set(features) == {n for n in engine if n.split(".")[0] in ("lines", "normals", "planes")}
    assert all(features[n] == engine[n] for n in features)


def test_ros_descriptors_are_built_from_the_rows():
    pytest.importorskip("rclpy")
    from rcl_interfaces.msg import ParameterType

    from line_odom.ros_parameters import parameter_descriptor

    types = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
             float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
             list: ParameterType.PARAMETER_DOUBLE_ARRAY}
    for entry in [*line_odom_core.config_schema(), *NODE_PARAMETERS]:
        d = parameter_descriptor(entry)
        assert (d.name, d.type, d.description, d.read_only) == (entry.name, types[entry.type], entry.description,
                                                                not entry.runtime), entry.name
        assert d.additional_constraints == ("" if entry.expected in ("bool", "str") else entry.expected), entry.name
        lo = 0 if entry.zero_is_off else entry.min
        if entry.type is int and entry.min is not None:
            assert [(r.from_value, r.to_value) for r in d.integer_range] == [(lo, entry.max)], entry.name
        elif entry.type is float and entry.min is not None:
            assert [(r.from_value, r.to_value) for r in d.floating_point_range] == [(lo, entry.max)], entry.name
        else:
            assert not d.integer_range and not d.floating_point_range, entry.name


@pytest.mark.parametrize("preset", cfg.PRESETS)
def test_a_preset_holds_known_settings_that_differ_from_their_defaults(preset):
    values = cfg.read_parameter_file(cfg.preset_path(preset))
    engine = {e.name: e.default for e in line_odom_core.config_schema()}
    node = {p.name: p.default for p in NODE_PARAMETERS}
    for name, value in values.items():
        assert name in engine or name in NODE_PARAMETER_NAMES, f"{preset}: {name} is no setting"
        taken = cfg.validate_value(name, value) if name in engine else validate_node_value(name, value)
        assert taken != {**engine, **node}[name], f"{preset}: {name} is its default ({taken!r})"


def test_node_md_parameter_tables_are_the_schema():
    """docs/NODE.md's tables are generated (python -m line_odom.docs_tables); a row added, removed or changed in a
    table and not regenerated fails here."""
    document = docs_tables.NODE_MD.read_text(encoding="utf-8")
    assert docs_tables.with_tables(document) == document, "run: python -m line_odom.docs_tables"
    block = document[document.index(docs_tables.BEGIN):document.index(docs_tables.END)]
    for entry in [*NODE_PARAMETERS, *line_odom_core.config_schema()]:
        assert f"| `{entry.name}` | `{docs_tables.default_text(entry.default)}` | {entry.expected} |" in block


def test_the_doc_check_fails_on_a_stale_table(tmp_path):
    stale = tmp_path / "NODE.md"
    stale.write_text(docs_tables.NODE_MD.read_text(encoding="utf-8").replace("| `downsample` | `1` |",
                                                                           "| `downsample` | `2` |"))
    assert docs_tables.main(["--check", "--doc", str(stale)]) == 1
    assert docs_tables.main(["--doc", str(stale)]) == 0 and docs_tables.main(["--check", "--doc", str(stale)]) == 0
