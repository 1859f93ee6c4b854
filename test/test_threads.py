"""`threads`: the line fit in blocks of rows and columns on a pool of threads, and the two line-pair searches of each
pass side by side (worker_pool.hpp). Which thread fits a block never changes what it computes, so every result must
be the same as on one thread, bit for bit."""
import os
import threading
import time

import numpy as np
import pytest

import line_odom_core
from line_odom.datasets import kitti_sequence, tum_sequence


@pytest.fixture(scope="module")
def kitti07():
    data = kitti_sequence("07", 4)
    return [(data.xyz(i), float(data.times[i])) for i in range(len(data))]


def assert_same_features(a, b):
    for kind in ("h_lines", "v_lines"):
        assert a[kind].keys() == b[kind].keys()
        for key in a[kind]:
            np.testing.assert_array_equal(a[kind][key], b[kind][key], err_msg=f"{kind}.{key}")
    for key in a["planes"]:
        np.testing.assert_array_equal(a["planes"][key], b["planes"][key], err_msg=f"planes.{key}")
    np.testing.assert_array_equal(a["cluster_directions"], b["cluster_directions"])


@pytest.mark.parametrize("threads", [2, 3, 8])
def test_features_of_a_kitti_scan_do_not_depend_on_threads(kitti07, threads):
    # Every row and column of a full HDL-64E scan; normals and planes read the lines' cell labels, so a label
    # shifted wrongly while gathering the blocks shows there too.
    image = line_odom_core.organize_points(kitti07[0][0], sensor="hdl64", min_range=2.5, max_range=120.0)
    one = line_odom_core.extract_features(image["points"], preset="kitti")
    many = line_odom_core.extract_features(image["points"], preset="kitti", threads=threads)
    assert len(one["h_lines"]["rms"]) > 2000 and len(one["v_lines"]["rms"]) > 5000
    assert one["stats"]["planes"] >= 1
    assert_same_features(one, many)


def register_all(frames, overrides):
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", overrides))
    return [odom.register_points(xyz, stamp) for xyz, stamp in frames]


STAT_KEYS = ("h_lines", "v_lines", "planes", "registered_lines", "candidates", "plane_candidates", "inliers",
             "plane_inliers", "iterations", "solver", "held_directions")


def assert_same_results(one, many):
    assert len(one) == len(many)
    for k, (a, b) in enumerate(zip(one, many)):
        np.testing.assert_array_equal(a.pose, b.pose, err_msg=f"frame {k}")
        np.testing.assert_array_equal(a.covariance, b.covariance, err_msg=f"frame {k}")
        for key in STAT_KEYS:
            assert a.stats[key] == b.stats[key], (k, key)


@pytest.mark.parametrize("overrides", [{"registration.max_lines": 0}, {}, {"downsample": 6}],
                         ids=["all-lines", "preset", "1/36"])
def test_kitti_odometry_does_not_depend_on_threads(kitti07, overrides):
    one = register_all(kitti07, overrides)
    assert all(r.stats["registered"] for r in one[1:])
    for threads in (2, 0):  # 0: one per hardware thread
        assert_same_results(one, register_all(kitti07, {**overrides, "threads": threads}))


def test_tum_odometry_does_not_depend_on_threads():
    data = tum_sequence(6)
    results = {}
    for threads in (1, 2):
        odom = line_odom_core.Odometry(line_odom_core.load_config("tum_kinect", {"threads": threads}))
        results[threads] = [odom.register_depth(data.depth(i), data.K, float(data.stamps[i])) for i in range(len(data))]
    assert all(r.stats["registered"] for r in results[1][1:])
    assert_same_results(results[1], results[2])


def test_two_odometries_with_pools_run_concurrently(kitti07):
    # The engine releases the GIL: two Python threads register at once, each on its own pool, and get what each gets
    # alone.
    alone = register_all(kitti07[:3], {"registration.max_lines": 0})
    out = {}

    def run(name):
        out[name] = register_all(kitti07[:3], {"registration.max_lines": 0, "threads": 2})

    workers = [threading.Thread(target=run, args=(n,)) for n in ("a", "b")]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=120)
    assert not any(w.is_alive() for w in workers)
    assert_same_results(alone, out["a"])
    assert_same_results(alone, out["b"])


def os_threads(expected=None, timeout=5.0):
    """The process's threads once the count holds (or reaches `expected`): a thread joined from Python may still be
    leaving the kernel's list for a moment."""
    deadline = time.monotonic() + timeout
    count = len(os.listdir("/proc/self/task"))
    while time.monotonic() < deadline:
        time.sleep(0.05)
        now = len(os.listdir("/proc/self/task"))
        if now == count and (expected is None or now == expected):
            break
        count = now
    return count


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts the process's threads in /proc (Linux)")
def test_pools_are_released_with_their_odometry(kitti07):
    config = line_odom_core.load_config("kitti_hdl64", {"threads": 4, "downsample": 6})
    line_odom_core.Odometry(config).register_points(*kitti07[0])  # (libraries' own threads start on first use)
    before = os_threads()
    odom = line_odom_core.Odometry(config)
    assert os_threads(before + 3) == before + 3  # the caller is the fourth
    del odom
    for _ in range(30):
        odom = line_odom_core.Odometry(config)
        odom.register_points(*kitti07[0])
        del odom
    assert os_threads(before) == before


@pytest.mark.parametrize("value", [-1, 257])
def test_threads_out_of_range_is_an_error_naming_it(value):
    with pytest.raises(ValueError, match="threads"):
        line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"threads": value}))


def test_feature_threads_below_one_is_an_error_naming_it(kitti07):
    image = line_odom_core.organize_points(kitti07[0][0], sensor="hdl64")
    with pytest.raises(ValueError, match="threads"):
        line_odom_core.extract_features(image["points"], preset="kitti", threads=0)
