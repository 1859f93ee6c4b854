"""Drift of the whole pipeline over a simulated street drive (line_odom.sim, HDL-64 with 1 cm range noise, 10 m/s at
10 Hz): the KITTI devkit metric needs segments of at least 100 m, which the ten-frame real sequences cannot give.

Measured on this 111 m drive (seed 1, 1/36): 0.21 % / 0.0054 deg/m, mean RPE 1.7 mm, no frame held; over 300 m
(seed 0) 0.18 % against KISS-ICP's 0.87 % on the same points (docs/RESULTS.md). The bounds leave about 10x / 2x."""
import numpy as np

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
