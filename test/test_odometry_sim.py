"""Drift of the whole pipeline over a simulated street drive (line_odom.sim, HDL-64 with 1 cm range noise, 10 m/s at
10 Hz): the KITTI devkit metric needs segments of at least 100 m, which the ten-frame real sequences cannot give.

Measured on this 111 m drive (seed 1, 1/36): 0.21 % / 0.0054 deg/m, mean RPE 1.7 mm, no frame held; over 300 m
(seed 0) 0.18 % against KISS-ICP's 0.87 % on the same points (docs/RESULTS.md). The bounds leave about 10x / 2x."""
import numpy as np
import pytest

import line_odom_core
from line_odom import sim
from line_odom.metrics import kitti_errors, relative_pose_errors


def test_sparse_street_drive_drift_bound():
    run = sim.make("street", frames=112, seed=1, noise_std=0.01)
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    estimate, held = [], 0
    for frame in run:
        res = odom.register_points(frame.data.points, frame.stamp, ring=frame.data.ring.astype(np.int32))
        estimate.append(res.pose)
        held += res.stats["degenerate"]
    estimate = np.array(estimate)
    truth = np.array(run.trajectory.poses)
    scores = kitti_errors(estimate, truth)
    assert scores is not None, "the drive is shorter than one 100 m segment"
    t_err_pct, r_err_deg_per_m = scores
    assert t_err_pct < 2.0 and r_err_deg_per_m < 0.01, scores
    t, _ = relative_pose_errors(estimate, truth)
    assert t.mean() < 0.02
    assert held <= 5


# The other LiDAR presets on the sensor they are made for, same street and seed, each at its preset's resolution.
# Measured on this 111 m drive: VLP-16 (`vlp16`, 600 azimuth bins) 0.14 % / 0.0036 deg/m, mean RPE 0.86 mm;
# OS-128 (`ouster_os128`, 64 of 128 beams) 0.098 % / 0.0010 deg/m, 0.64 mm; no frame held. The bounds leave 7-10x;
# over 1 km (bench/accuracy.py --only sim --sim-sensor vlp16, docs/RESULTS.md) KISS-ICP on the same 16-beam scans
# drifts 14.6 %, line_odom 0.17 %.
@pytest.mark.parametrize("sensor, preset", [("vlp16", "vlp16"), ("os128", "ouster_os128")])
def test_street_drive_drift_bound_with_the_sensor_presets(sensor, preset):
    run = sim.make("street", frames=112, seed=1, sensor=sensor, noise_std=0.01)
    odom = line_odom_core.Odometry(line_odom_core.load_config(preset))
    estimate, held = [], 0
    for frame in run:
        res = odom.register_points(frame.data.points, frame.stamp, ring=frame.data.ring.astype(np.int32))
        estimate.append(res.pose)
        held += res.stats["degenerate"]
    estimate = np.array(estimate)
    truth = np.array(run.trajectory.poses)
    scores = kitti_errors(estimate, truth)
    assert scores is not None, "the drive is shorter than one 100 m segment"
    t_err_pct, r_err_deg_per_m = scores
    assert t_err_pct < 1.0 and r_err_deg_per_m < 0.02, scores
    t, _ = relative_pose_errors(estimate, truth)
    assert t.mean() < 0.01
    assert held <= 2
