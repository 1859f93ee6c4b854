"""Drift of the whole pipeline over a simulated street drive (line_odom.sim, 1 cm range noise, 10 m/s at 10 Hz): the
KITTI devkit metric needs segments of at least 100 m, which the ten-frame real sequences cannot give.

Measured on this 111 m drive (seed 1) with the HDL-64 at 1/36: 0.092 % / 0.0014 deg/m, mean RPE 1.0 mm, no frame held
(0.21 % / 0.0054 deg/m when the bound was set); over 1 km (seed 0) 0.185 % against KISS-ICP's 1.98 % on the
same points (docs/RESULTS.md)."""
import numpy as np
import pytest

import line_odom_core
from line_odom import sim
from line_odom.metrics import kitti_errors, relative_pose_errors


# The HDL-64 at 1/36 (the docstring's numbers) and the other LiDAR presets on the sensor they are made for, same
# street and seed, each at its preset's resolution. Measured on this 111 m drive: VLP-16 (`vlp16`, 600 azimuth bins)
# 0.14 % / 0.0036 deg/m, mean RPE 0.86 mm; OS-128 (`ouster_os128`, 64 of 128 beams) 0.098 % / 0.0010 deg/m, 0.64 mm;
# no frame held. Their bounds leave 7-10x; over 1 km (bench/accuracy.py --only sim --sim-sensor vlp16,
# docs/RESULTS.md) KISS-ICP on the same 16-beam scans drifts 14.6 %, line_odom 0.17 %.
# (sensor, preset, overrides, bounds: t_err %, r_err deg/m, mean RPE m, frames held)
DRIVES = [
    ("hdl64", "kitti_hdl64", {"downsample": 6}, (2.0, 0.01, 0.02, 5)),
    ("vlp16", "vlp16", {}, (1.0, 0.02, 0.01, 2)),
    ("os128", "ouster_os128", {}, (1.0, 0.02, 0.01, 2)),
]


@pytest.mark.parametrize("sensor, preset, overrides, bounds", DRIVES, ids=[d[1] for d in DRIVES])
def test_street_drive_drift_bound(sensor, preset, overrides, bounds):
    max_t_err_pct, max_r_err, max_rpe_t, max_held = bounds
    run = sim.make("street", frames=112, seed=1, sensor=sensor, noise_std=0.01)
    odom = line_odom_core.Odometry(line_odom_core.load_config(preset, overrides))
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
    assert t_err_pct < max_t_err_pct and r_err_deg_per_m < max_r_err, scores
    t, _ = relative_pose_errors(estimate, truth)
    assert t.mean() < max_rpe_t
    assert held <= max_held
