"""Engine configuration: presets, ROS 2 parameter files, overrides, schema, and agreement with the C++ side."""
import textwrap

import pytest

import line_odom_core
from line_odom_core import _testing
from line_odom_core import config as cfg


@pytest.mark.parametrize("preset", cfg.PRESETS)
def test_every_preset_loads_and_is_in_range(preset):
    config = line_odom_core.load_config(preset)
    for entry in line_odom_core.config_schema():
        assert cfg.validate_value(entry.name, config[entry.name]) == config[entry.name]


def test_kitti_and_tum_presets_carry_the_papers_thresholds():
    kitti = line_odom_core.load_config("kitti_hdl64")
    tum = line_odom_core.load_config("tum_kinect")
    assert kitti["candidates.max_distance"] == 2.0 and kitti["ransac.inlier_threshold"] == 0.02
    assert tum["ransac.inlier_threshold"] == 0.005
    assert kitti["registration.passes"] == 3 and kitti["downsample"] == 1


def test_overrides_apply_and_validate():
    config = line_odom_core.load_config("kitti_hdl64", {"downsample": 6, "ransac.max_iterations": 200,
                                                        "ransac.solver": "3l1p"})
    assert config["downsample"] == 6 and config["ransac.max_iterations"] == 200
    assert config["ransac.solver"] == "3L1P"
    with pytest.raises(ValueError, match="ransac.max_iteration"):
        line_odom_core.load_config("kitti_hdl64", {"ransac.max_iteration": 5})
    with pytest.raises(ValueError, match=r"downsample.*\[1, 64\]"):
        line_odom_core.load_config("kitti_hdl64", {"downsample": 0})
    with pytest.raises(ValueError, match="ransac.solver.*auto, 7L, 3L1P, 1L2P"):
        line_odom_core.load_config("kitti_hdl64", {"ransac.solver": "5pt"})
    with pytest.raises(ValueError, match="registration.constant_velocity"):
        line_odom_core.load_config("kitti_hdl64", {"registration.constant_velocity": 1})
    with pytest.raises(ValueError, match="ransac.inlier_threshold"):
        line_odom_core.load_config("kitti_hdl64", {"ransac.inlier_threshold": float("nan")})
    with pytest.raises(ValueError, match="ransac.min_iterations"):
        line_odom_core.load_config("kitti_hdl64", {"ransac.min_iterations": 500, "ransac.max_iterations": 100})


def test_yaml_file_nested_sections_and_unknown_keys_kept_as_extra(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text(textwrap.dedent("""
        line_odom:
          ros__parameters:
            downsample: 8
            ransac:
              max_iterations: 321
            frames:
              odom: odom
              base: base_link
            topics: {points: /velodyne_points}
    """))
    config = line_odom_core.load_config(str(path))
    assert config["downsample"] == 8 and config["ransac.max_iterations"] == 321
    assert config.extra == {"frames.odom": "odom", "frames.base": "base_link", "topics.points": "/velodyne_points"}
    assert config["ransac.inlier_threshold"] == cfg._schema_map()["ransac.inlier_threshold"].default


def test_exponent_floats_without_a_dot_are_numbers_as_in_ros(tmp_path):
    """PyYAML (YAML 1.1) reads 1e-4 as a string; ROS 2's parameter parser reads a double. A parameter file and
    `--set` take it as ROS does; strings stay strings."""
    from line_odom.cli import parse_overrides

    path = tmp_path / "mine.yaml"
    path.write_text(textwrap.dedent("""
        line_odom:
          ros__parameters:
            ransac:
              degeneracy_threshold: 1e-4
              inlier_threshold: 2E-2
            sensor: {model: vlp16}
    """))
    config = line_odom_core.load_config(str(path))
    assert config["ransac.degeneracy_threshold"] == 1e-4 and config["ransac.inlier_threshold"] == 0.02
    assert parse_overrides(["ransac.degeneracy_threshold=1e-9", "registration.max_translation=+5e0",
                             "ransac.solver=7L", "seed=3", "lines.max_rms=.5e-1"]) == {
        "ransac.degeneracy_threshold": 1e-9, "registration.max_translation": 5.0, "ransac.solver": "7L", "seed": 3,
        "lines.max_rms": 0.05}
    assert line_odom_core.load_config("kitti_hdl64", parse_overrides(["ransac.degeneracy_threshold=1e-9"]))[
        "ransac.degeneracy_threshold"] == 1e-9
    assert cfg.yaml_load("e5") == "e5" and cfg.yaml_load("1e") == "1e" and cfg.yaml_load("0x1e5") == 0x1e5


def test_yaml_file_errors_name_the_problem(tmp_path):
    bad_value = tmp_path / "bad.yaml"
    bad_value.write_text("line_odom:\n  ros__parameters:\n    candidates:\n      max_distance: -1.0\n")
    with pytest.raises(ValueError, match="candidates.max_distance"):
        line_odom_core.load_config(str(bad_value))
    no_section = tmp_path / "none.yaml"
    no_section.write_text("other_node:\n  ros__parameters:\n    downsample: 2\n")
    with pytest.raises(ValueError, match="ros__parameters"):
        line_odom_core.load_config(str(no_section))
    with pytest.raises(ValueError, match="preset_or_path"):
        line_odom_core.load_config("no_such_preset")
    with pytest.raises(FileNotFoundError):
        line_odom_core.load_config(str(tmp_path / "missing.yaml"))


def test_presets_are_found_through_ament_prefix_path(tmp_path, monkeypatch):
    share = tmp_path / "share" / "line_odom" / "config"
    share.mkdir(parents=True)
    (share / "vlp16.yaml").write_text("line_odom:\n  ros__parameters:\n    downsample: 3\n")
    monkeypatch.setattr(cfg, "config_search_dirs", lambda: [tmp_path / "nowhere", share])
    assert line_odom_core.load_config("vlp16")["downsample"] == 3


def test_schema_entries_are_complete_and_defaults_valid():
    schema = line_odom_core.config_schema()
    names = [e.name for e in schema]
    assert len(names) == len(set(names))
    for e in schema:
        assert e.type in (bool, int, float, str) and e.description
        assert cfg.validate_value(e.name, e.default) == e.default
        if e.type in (int, float):
            assert e.min is not None and e.max is not None
            assert e.min <= e.default <= e.max or (e.zero_is_off and e.default == 0)
        if e.type is str:
            assert e.name in cfg.CHOICES and e.default in cfg.CHOICES[e.name]


def test_schema_matches_the_engine_settings():
    """Every schema entry is a C++ setting with the same default, and the other way round."""
    engine = _testing.odometry_config_defaults()
    schema = {e.name: e.default for e in line_odom_core.config_schema()}
    assert set(engine) == set(schema)
    for name, default in schema.items():
        if isinstance(default, str):
            assert engine[name] == default, name
        else:
            assert float(engine[name]) == pytest.approx(float(default)), name


def test_engine_rejects_what_the_schema_rejects():
    with pytest.raises(ValueError, match="no_such.key"):
        line_odom_core._core.Odometry({"no_such.key": 1})
    with pytest.raises(ValueError, match="ransac.solver"):
        line_odom_core._core.Odometry({"ransac.solver": "9L"})
    for name in ("registration.max_lines", "registration.first_motion_pairs_per_line",
                 "registration.persistence_window"):
        with pytest.raises(ValueError, match=name):
            line_odom_core._core.Odometry({name: -1})
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    assert odom._engine.settings()["downsample"] == 6


@pytest.mark.parametrize("preset", ["kitti_hdl64", "vlp16", "ouster_os128", "tum_kinect"])
def test_every_node_parameter_of_a_preset_takes_the_table_default_unless_set(preset):
    """A preset holds only what differs from the defaults (test_settings_table.py): the node's parameters it does not
    set are the table's defaults."""
    from line_odom.node_parameters import NODE_PARAMETERS, settings_from_parameters

    extra = line_odom_core.load_config(preset).extra
    settings = settings_from_parameters(preset)[1]
    for p in NODE_PARAMETERS:
        assert getattr(settings, p.attribute) == extra.get(p.name, p.default), p.name
