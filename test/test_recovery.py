"""A start mid-drive where the scene does not observe the forward motion: the first motion is held at standing still
and the velocity along the unobserved direction was never measured (stats["unmeasured_directions"]). The engine
searches that direction each frame (odometry.cpp search_unmeasured) and takes the motion it finds only when every
direction is observed and its support clearly beats the held one's; a velocity that was measured is never searched.

The scene is test_degenerate_scenes' street -> featureless corridor (x 0..90 m) -> street, an HDL-64E or VLP-16 with
30 m range, the odometry started deep in the corridor (x = 40 m) at speed. Measured (docs/NODE.md, "The first
motion"): at 1-2 m a frame every preset recovered before the exit, through the corridor's open end, with or without
the search; beyond the candidates' 2 m the held velocity's candidates miss the motion: at 3 m a frame the forward
motion came back 7 frames after the exit at 1/36, 1/64 and on the VLP-16 (1-4 frames registered 1.8-4.7 m off on
the way, unflagged) and never at full resolution. With the search: within 1 frame of the exit, none of them wrong.
"""
from __future__ import annotations

import numpy as np
import pytest

import line_odom_core
from line_odom import sim

import test_degenerate_scenes as degenerate

START_X = 40.0  # deep in the corridor: nothing but its four planes within GAP_RANGE
END_X = 112.0
FRAME_BOUND = 0.1  # m: a frame's translation error that counts as having the motion


def _drive(preset, overrides, sensor, speed, start_x=START_X, end_x=END_X):
    """Straight along the corridor and out into the street at `speed` m a frame (10 Hz): per frame (true motion,
    result)."""
    scene = degenerate._structure_gap_scene()
    lidar = getattr(sim.Lidar, sensor)(max_range=degenerate.GAP_RANGE)
    odom = line_odom_core.Odometry(line_odom_core.load_config(preset, overrides))
    out, prev = [], None
    for k, x in enumerate(np.arange(start_x, end_x, speed)):
        T = np.eye(4)
        T[:3, 3] = [x, 0.0, 1.73]
        scan = lidar.scan(scene, T, stamp=0.1 * k)
        res = odom.register_points(scan.points, 0.1 * k, ring=scan.ring.astype(np.int32))
        degenerate.check_finite(res)
        out.append((None if prev is None else np.linalg.inv(prev) @ T, x, res))
        prev = T
    return out


@pytest.mark.parametrize("preset, overrides, sensor, speed", [
    ("kitti_hdl64", {"downsample": 6}, "hdl64", 3.0),
    ("kitti_hdl64", {"downsample": 8}, "hdl64", 2.5),
    ("vlp16", {}, "vlp16", 3.0),
    ("kitti_hdl64", {}, "hdl64", 3.0),
], ids=["hdl64_1_36_3m", "hdl64_1_64_2.5m", "vlp16_3m", "hdl64_full_3m"])
def test_a_start_in_the_corridor_at_speed_recovers_the_forward_motion(preset, overrides, sensor, speed):
    """Started at speed deep in the corridor: the first motion is held (6 unmeasured directions), the forward motion
    stays unmeasured (held at zero, flagged) while only the corridor is in view, and is found once the street is:
    every frame from the second one past the corridor's end (x > 90 m + 2 frames) has it within 0.1 m, not flagged.
    Measured with the search: from the frame at x 91-94 m (within 1 frame of the exit); before it 1/36 and the
    VLP-16 took it at x = 112 m (7 frames late), 1/64 at 2.5 m a frame at x = 102.5 m, full resolution never.
    Never a confident wrong motion on the way."""
    frames = _drive(preset, overrides, sensor, speed)
    first = frames[1][2]
    assert first.stats["held_directions"] == 6 and first.stats["unmeasured_directions"] == 6, first.stats
    report = [(round(x, 1), round(float(np.linalg.norm(res.delta[:3, 3] - truth[:3, 3])), 3), res.degenerate,
               res.stats["unmeasured_directions"], res.stats["recovered"]) for truth, x, res in frames[1:]]
    deep = [row for row in report[1:] if row[0] < degenerate.CORRIDOR[1] - degenerate.GAP_RANGE - 2]
    assert deep and all(row[2] and row[3] == 1 and row[1] > 1.0 for row in deep), report  # held at zero, flagged
    past_exit = [row for row in report if row[0] > degenerate.CORRIDOR[1] + 2 * speed]
    assert len(past_exit) >= 5, report
    assert all(row[1] < FRAME_BOUND and not row[2] and row[3] == 0 for row in past_exit), report
    assert sum(row[4] for row in report) == 1, report  # found by the search once, then measured frame by frame
    assert all(row[1] < FRAME_BOUND or row[2] for row in report), report  # never confidently wrong


@pytest.mark.parametrize("preset, overrides, sensor", [
    ("kitti_hdl64", {"downsample": 6}, "hdl64"),
    ("vlp16", {}, "vlp16"),
], ids=["hdl64_1_36", "vlp16"])
@pytest.mark.parametrize("x", [40.0, 80.0])
def test_standing_still_in_the_corridor_keeps_the_held_velocity(preset, overrides, sensor, x):
    """Standing still deep in the corridor (x = 40 m) and in view of the street through its end (80 m), with 1 cm
    range noise: the held standing still is right. The forward direction stays unmeasured and is searched on every
    frame; no shift along it is taken (measured: every motion found from a support peak was degenerate), so every
    frame stays within 5 mm of standing still."""
    scene = degenerate._structure_gap_scene()
    lidar = getattr(sim.Lidar, sensor)(max_range=degenerate.GAP_RANGE, noise_std=0.01, seed=1)
    odom = line_odom_core.Odometry(line_odom_core.load_config(preset, overrides))
    T = np.eye(4)
    T[:3, 3] = [x, 0.0, 1.73]
    results = []
    for k in range(10):
        scan = lidar.scan(scene, T, stamp=0.1 * k)
        results.append(odom.register_points(scan.points, 0.1 * k, ring=scan.ring.astype(np.int32)))
    moved = [round(float(np.linalg.norm(r.delta[:3, 3])), 4) for r in results[1:]]
    unmeasured = [r.stats["unmeasured_directions"] for r in results[1:]]
    assert unmeasured[0] == 6 and all(u == 1 for u in unmeasured[1:]), unmeasured  # searched on frames 2-9
    assert not any(r.stats["recovered"] for r in results), unmeasured
    assert max(moved) < 0.005, moved


def test_a_measured_velocity_is_never_searched_and_stays_as_it_is():
    """KITTI 04 at 1/36 from scan 0: the first motion is found (0.009 m off), and the forward motion, which the
    highway's lines do not observe at this density, is held at that measured velocity on the next 8 frames. The
    search never runs (no unmeasured direction), so those frames are the constant-velocity ones: 0.019 m a frame
    (docs/RESULTS.md; bench/accuracy.py's row is unchanged to the printed digit). From scan 2 the lines leave the first
    motion open along the road; the points, aligned also from the shifts along the directions a vehicle travels, put
    it 0.09 m short (from standing still alone they stayed there, and every frame was held 1.32 m off). The frames
    after it hold that velocity, flagged while it is unmeasured, and none is taken from the search."""
    from line_odom.datasets import kitti_sequence

    data = kitti_sequence("04")
    for start in (0, 2):
        odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
        rows = []
        for i in range(start, len(data)):
            res = odom.register_points(data.xyz(i), float(data.times[i]))
            if i > start:
                truth = np.linalg.inv(data.poses[i - 1]) @ data.poses[i]
                rows.append((float(np.linalg.norm(res.delta[:3, 3] - truth[:3, 3])), res.degenerate,
                             res.stats["unmeasured_directions"], res.stats["recovered"]))
        errors = np.array([row[0] for row in rows])
        assert not any(row[3] for row in rows), rows
        if start == 0:
            assert all(row[2] == 0 for row in rows) and errors.mean() < 0.03, rows
        else:
            assert rows[0][2] == 6 and errors.max() < 0.15, rows
            assert all(row[1] for row in rows if row[2] > 0), rows  # flagged while the velocity is unmeasured


def test_the_unmeasured_velocity_reaches_the_diagnostics():
    """Through the node's processing core: a start in the endless corridor at 1 m a frame reports the forward
    direction unmeasured (diagnostics value and WARN message) until a reset and a structured start clear it."""
    from diagnostic_msgs.msg import DiagnosticStatus

    from line_odom.processor import OdometryProcessor

    proc = OdometryProcessor.from_parameters("kitti_hdl64", degenerate.OVERRIDES)
    for f in sim.make("corridor", frames=3, seed=0):
        assert proc.process_pointcloud(degenerate._cloud_msg(f.data.points, 5.0 + f.stamp)) is not None
    status = proc.diagnostics().status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.WARN and values["unmeasured_directions"] == "1", values
    assert "not measured" in status.message, status.message
    proc.reset("scene change")
    for f in sim.make("street", frames=3, seed=0):
        proc.process_pointcloud(degenerate._cloud_msg(f.data.points, 10.0 + f.stamp, ring=f.data.ring))
    status = proc.diagnostics().status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.OK and values["unmeasured_directions"] == "0", status.message
