"""registration.max_lines: a full-resolution scan registers the lines of every s-th row and column, s the smallest
step within the budget; the first scan is fitted on every row and column, the next ones only on the rows and
columns the budget will keep (line_selection.hpp)."""
import numpy as np
import pytest

import line_odom_core
from line_odom.datasets import kitti_sequence
from line_odom.metrics import relative_pose_errors


def kept(features, step):
    return sum(int(np.count_nonzero(features[k]["scan_index"] % step == 0)) for k in ("h_lines", "v_lines"))


@pytest.fixture(scope="module")
def kitti_frame():
    data = kitti_sequence("07", 1)
    return data.xyz(0)


@pytest.mark.parametrize("budget", [3000, 1200])
def test_step_is_the_smallest_within_the_budget(kitti_frame, budget):
    # The same lines the pipeline fits (kitti preset, full resolution), counted per step in numpy.
    image = line_odom_core.organize_points(kitti_frame, sensor="hdl64", min_range=2.5, max_range=120.0)
    features = line_odom_core.extract_features(image["points"], preset="kitti")
    fitted = kept(features, 1)
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"registration.max_lines": budget}))
    stats = odom.register_points(kitti_frame, 0.0).stats
    assert stats["h_lines"] + stats["v_lines"] == fitted > budget
    step = stats["line_step"]
    assert step >= 2 and kept(features, step - 1) > budget
    assert stats["registered_lines"] == kept(features, step) <= budget


def test_later_scans_fit_only_the_rows_and_columns_they_keep():
    data = kitti_sequence("07", 3)
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64"))
    stats = [odom.register_points(data.xyz(i), float(data.times[i])).stats for i in range(3)]
    assert stats[0]["fit_step"] == 1 and stats[0]["line_step"] == 4  # ~10,700 lines fitted, every 4th kept
    for i in (1, 2):
        assert stats[i]["fit_step"] == 4 and stats[i]["line_step"] == 4
        # exactly the lines a full fit has on rows and columns 0, 4, 8, ...: each scan is fitted on its own
        image = line_odom_core.organize_points(data.xyz(i), sensor="hdl64", min_range=2.5, max_range=120.0)
        everything = line_odom_core.extract_features(image["points"], preset="kitti")
        # (what this saves in time is bench/latency.py's to show: a time compared here fails on a loaded machine)
        assert stats[i]["h_lines"] + stats[i]["v_lines"] == stats[i]["registered_lines"] == kept(everything, 4)


def test_no_budget_registers_every_line(kitti_frame):
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"registration.max_lines": 0}))
    stats = odom.register_points(kitti_frame, 0.0).stats
    assert stats["line_step"] == 1 and stats["registered_lines"] == stats["h_lines"] + stats["v_lines"]


def test_sparse_scans_are_under_the_preset_budget(kitti_frame):
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    stats = odom.register_points(kitti_frame, 0.0).stats
    assert stats["line_step"] == 1 and stats["registered_lines"] == stats["h_lines"] + stats["v_lines"]


def test_budget_keeps_full_resolution_accuracy():
    # KITTI 07, five frames at full resolution: measured mean 0.0059 m / 0.0085 deg with the preset's budget (the lines
    # of every 4th row and column, fitted only there after the first scan), 0.0077 m / 0.014 deg with every line;
    # KISS-ICP on ten frames 0.023 m / 0.041 deg.
    data = kitti_sequence("07", 5)
    config = line_odom_core.load_config("kitti_hdl64")
    assert config["registration.max_lines"] > 0
    odom = line_odom_core.Odometry(config)
    results = [odom.register_points(data.xyz(i), float(data.times[i])) for i in range(len(data))]
    assert all(1 < r.stats["line_step"] and r.stats["registered_lines"] <= config["registration.max_lines"]
               for r in results)
    t, r = relative_pose_errors(np.array([res.pose for res in results]), data.poses)
    assert t.mean() < 0.02 and r.mean() < 0.05, (t, r)


def test_a_budget_below_one_row_still_gives_a_finite_pose(kitti_frame):
    data = kitti_sequence("07", 2)
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"registration.max_lines": 1}))
    results = [odom.register_points(data.xyz(i), float(data.times[i])) for i in range(2)]
    assert np.isfinite(results[1].pose).all()
    # only the lines of row and column 0 are left: nothing to register with, the prediction is held and said so
    assert results[1].stats["registered_lines"] <= results[1].stats["h_lines"] + results[1].stats["v_lines"]
    assert results[1].stats["line_step"] > 1


def test_negative_budget_is_rejected():
    with pytest.raises(ValueError, match="registration.max_lines"):
        line_odom_core.load_config("kitti_hdl64", {"registration.max_lines": -1})
