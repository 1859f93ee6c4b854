"""registration.window: a scan registered against the lines of the last N scans (moved into the previous scan's frame
by the estimated motions), kept only when the pairs with the previous scan alone observe every direction of the
result. On real KITTI frames: more accurate where every direction is observed (KITTI kept to 16 of its lasers, the
package's 16-beam case, and full resolution), and on the sparse highway, where the older scans' lines would make the
forward motion look observed, exactly the frame-to-frame result."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import line_odom_core
from line_odom.datasets import kitti_sequence
from line_odom.metrics import relative_pose_errors

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from accuracy import beams_config, kitti_beams  # noqa: E402


def run_beams(seq: str, beams: int, window: int):
    data = kitti_sequence(seq)
    odom = line_odom_core.Odometry(beams_config(beams, {"registration.window": window}))
    results = []
    for i in range(len(data)):
        xyz, ring = kitti_beams(data, i, beams)
        results.append(odom.register_points(xyz, float(data.times[i]), ring=ring))
    t, r = relative_pose_errors(np.array([res.pose for res in results]), data.poses)
    return results, t, r


def run_kitti(seq: str, downsample: int, window: int, **overrides):
    data = kitti_sequence(seq)
    odom = line_odom_core.Odometry(line_odom_core.load_config(
        "kitti_hdl64", {"downsample": downsample, "registration.window": window, **overrides}))
    results = [odom.register_points(data.xyz(i), float(data.times[i])) for i in range(len(data))]
    t, r = relative_pose_errors(np.array([res.pose for res in results]), data.poses)
    return results, t, r


def test_sixteen_lasers_on_the_highway_with_a_window_of_three_scans():
    # KITTI 04 kept to every 4th laser: frame to frame each scan's motion along the road is off by about +-0.02 m,
    # alternating in sign (measured mean 0.0330 m; KISS-ICP 0.0279 m on the same points, with its multi-scan map).
    # Against the last 3 scans: measured 0.0198 m, every frame registered on the window. Bounds: < 0.025 m with the
    # window, > 0.028 m without (so the test fails when the window stops taking effect).
    results, t, r = run_beams("04", 16, 3)
    _, t_single, _ = run_beams("04", 16, 1)
    assert t.mean() < 0.025 and r.mean() < 0.08, (t, r)
    assert t_single.mean() > 0.028, t_single
    scans = [res.stats["window_scans"] for res in results]
    assert scans[0] == 0 and scans[1] == 1 and all(s >= 2 for s in scans[3:]), scans  # (the window fills up)


def test_older_scans_are_taken_only_while_the_window_holds_fewer_lines_than_one_registration():
    # With 32 of KITTI's lasers a scan registers about 2,300-2,600 lines (registration.max_lines 3000): two scans
    # pass the budget, so the window of 3 takes 2; with 16 lasers (1,200-1,500 lines a scan) it takes 3; without the
    # budget, 32 lasers take 3 again.
    def window_scans(beams, overrides):
        data = kitti_sequence("07")
        odom = line_odom_core.Odometry(beams_config(beams, {"registration.window": 3, **overrides}))
        stats = []
        for i in range(6):
            xyz, ring = kitti_beams(data, i, beams)
            stats.append(odom.register_points(xyz, float(data.times[i]), ring=ring).stats)
        assert all(s["registered_lines"] < 3000 for s in stats)
        return [s["window_scans"] for s in stats]

    assert window_scans(32, {})[3:] == [2, 2, 2]
    assert window_scans(16, {})[3:] == [3, 3, 3]
    assert window_scans(32, {"registration.max_lines": 0})[3:] == [3, 3, 3]


def test_the_window_never_makes_the_sparse_highway_observable():
    # KITTI 04 at 1/36: the forward motion is held at the prediction on 8 frames (and the first motion flagged: the
    # lines do not pin it down, validation.*). Registered directly on the last
    # scans' lines, frame 2 came out as a confident 7L motion 0.049 m short and the held frames kept that velocity
    # (mean 0.049-0.062 m instead of 0.019). With the check on the previous scan's pairs alone every frame is the
    # frame-to-frame one, to the bit.
    windowed, t, _ = run_kitti("04", 6, 3)
    single, t_single, _ = run_kitti("04", 6, 1)
    assert [res.stats["window_scans"] for res in windowed[2:]] == [1] * (len(windowed) - 2)
    np.testing.assert_array_equal(np.array([res.pose for res in windowed]), np.array([res.pose for res in single]))
    assert sum(res.degenerate for res in windowed) == 9 and t.mean() < 0.03, t


def test_full_resolution_with_a_window_of_two_scans():
    # KITTI 07 (car starting, every direction observed): measured 0.0082 m / 0.014 deg frame to frame, 0.0079 m / 0.014
    # deg with the window of 2. Bound as the frame-to-frame test's (test_odometry_kitti.py), plus: the window is used.
    results, t, r = run_kitti("07", 1, 2, **{"registration.max_lines": 3000})
    assert t.mean() < 0.02 and r.mean() < 0.05, (t, r)
    assert all(res.stats["window_scans"] == 2 for res in results[2:]), [res.stats["window_scans"] for res in results]


def test_a_reset_or_a_held_frame_empties_the_window():
    data = kitti_sequence("07", 5)
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6,
                                                                              "registration.window": 3}))
    scans = [odom.register_points(data.xyz(i), float(data.times[i])).stats["window_scans"] for i in range(4)]
    assert scans == [0, 1, 2, 3], scans
    odom.reset()
    again = [odom.register_points(data.xyz(i), 10.0 + float(data.times[i])).stats["window_scans"] for i in range(3)]
    assert again == [0, 1, 2], again
    # a frame held in full (an empty scan) leaves nothing to place the older scans by: the next frame starts over
    odom.register_points(np.zeros((0, 3)), 10.0 + float(data.times[3]))
    after = odom.register_points(data.xyz(4), 10.0 + float(data.times[4])).stats["window_scans"]
    assert after == 1, after


def test_the_window_gives_the_same_poses_on_two_threads():
    a, _, _ = run_kitti("07", 6, 3)
    b, _, _ = run_kitti("07", 6, 3, threads=2)
    np.testing.assert_array_equal(np.array([res.pose for res in a]), np.array([res.pose for res in b]))


@pytest.mark.parametrize("window", [0, 11])
def test_a_window_out_of_range_is_refused_naming_the_setting(window):
    with pytest.raises(ValueError, match="registration.window"):
        line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"registration.window": window}))
