"""Motion compensation (sensor.deskew): a LiDAR sweep measured while the sensor moves, given with each point's time,
is moved into the sensor frame at the stamp at the predicted velocity, and the previous scan is corrected again at
that velocity when it was corrected at another one, so that both scans of a registration are corrected alike.

The simulated street (10 m/s, 1 cm range noise) with sweeps cast while the sensor moves (`motion_distortion`: each
block of columns from the pose at its firing time, `time` per point). Measured (docs/NODE.md, "Motion distortion"),
mean translation error per frame over frames 3-49: VLP-16 (`vlp16`) 0.0033 m as measured, 0.0011 m deskewed
(undistorted sweeps: 0.0009); HDL-64E at 1/36 0.0031 -> 0.0016 m (0.0010). Deskewing each scan at the velocity of the
frame before without correcting the previous scan again feeds each frame's error into the next: 0.11 m at 1/36.
"""
from __future__ import annotations

import numpy as np
import pytest

import line_odom_core
from line_odom import convert, sim
from line_odom.processor import OdometryProcessor

import test_degenerate_scenes as degenerate

FRAMES = 50


@pytest.fixture(scope="module")
def vlp16_sweeps():
    return list(sim.make("street", frames=FRAMES, seed=0, sensor="vlp16", noise_std=0.01, motion_distortion=True))


@pytest.fixture(scope="module")
def hdl64_sweeps():
    return list(sim.make("street", frames=FRAMES, seed=0, sensor="hdl64", noise_std=0.01, motion_distortion=True))


def _drive(frames, preset, overrides, with_time=True, organized=False):
    odom = line_odom_core.Odometry(line_odom_core.load_config(preset, overrides))
    results = []
    for fr in frames:
        scan = fr.data
        if organized:
            time = np.zeros(scan.organized.shape[:2])
            time[scan.ring, scan.column] = scan.time
            res = odom.register_organized(scan.organized, fr.stamp, time=time if with_time else None)
        else:
            res = odom.register_points(scan.points, fr.stamp, ring=scan.ring.astype(np.int32),
                                       time=scan.time if with_time else None)
        degenerate.check_finite(res)
        results.append(res)
    return results


def _translation_errors(frames, results):
    errors = []
    for k in range(3, len(frames)):
        truth = np.linalg.inv(frames[k - 1].pose) @ frames[k].pose
        errors.append(degenerate.frame_error(results[k].delta, truth)[0])
    return np.array(errors)


def test_a_distorted_vlp16_drive_is_deskewed(vlp16_sweeps):
    """Measured 0.0011 m deskewed, 0.0033 m as measured: bounds 0.002 and 0.0028."""
    deskewed = _drive(vlp16_sweeps, "vlp16", {})
    raw = _drive(vlp16_sweeps, "vlp16", {}, with_time=False)
    assert _translation_errors(vlp16_sweeps, deskewed).mean() < 0.002
    assert _translation_errors(vlp16_sweeps, raw).mean() > 0.0028
    # standing still until the first motion is registered: the first two scans are used as measured
    assert [res.stats["deskewed"] for res in deskewed[:3]] == [False, False, True]
    assert all(res.stats["deskewed"] for res in deskewed[2:])
    assert not any(res.stats["deskewed"] or res.stats["previous_deskewed_again"] for res in raw)


def test_both_scans_of_a_pair_are_deskewed_alike(hdl64_sweeps):
    """HDL-64E at 1/36, 30 frames: measured 0.0015 m (the previous scan corrected again on 27 frames); never correcting
    it again (an impossible tolerance) 0.11 m, worse than not deskewing at all (0.0039)."""
    frames = hdl64_sweeps[:30]
    alike = _drive(frames, "kitti_hdl64", {"downsample": 6})
    apart = _drive(frames, "kitti_hdl64", {"downsample": 6, "sensor.deskew_tolerance": 10.0})
    assert _translation_errors(frames, alike).mean() < 0.004
    assert _translation_errors(frames, apart).mean() > 0.02
    assert sum(res.stats["previous_deskewed_again"] for res in alike) >= 10
    assert not any(res.stats["previous_deskewed_again"] for res in apart)


def test_an_organized_cloud_with_a_time_image_is_deskewed(vlp16_sweeps):
    """Measured 0.0011 m with the time image, 0.0033 m without."""
    frames = vlp16_sweeps[:30]
    deskewed = _drive(frames, "vlp16", {}, organized=True)
    raw = _drive(frames, "vlp16", {}, with_time=False, organized=True)
    assert all(res.stats["deskewed"] for res in deskewed[2:])
    assert _translation_errors(frames, deskewed).mean() < 0.7 * _translation_errors(frames, raw).mean()


def test_deskew_off_ignores_the_times(vlp16_sweeps):
    frames = vlp16_sweeps[:8]
    off = _drive(frames, "vlp16", {"sensor.deskew": False})
    raw = _drive(frames, "vlp16", {}, with_time=False)
    np.testing.assert_array_equal(np.array([r.pose for r in off]), np.array([r.pose for r in raw]))
    assert not any(res.stats["deskewed"] for res in off)


@pytest.mark.parametrize("bad, match", [
    (np.zeros(5), r"time: expected one time per point of shape \(10,\)"),
    (np.full(10, np.nan), "time: expected finite seconds within 10 s"),
    (np.full(10, 1.7e9), "time: expected finite seconds within 10 s"),
    (np.zeros((10, 2)), "time: expected one time per point"),
])
def test_unusable_times_are_refused_naming_time(bad, match):
    odom = line_odom_core.Odometry(line_odom_core.load_config("vlp16"))
    with pytest.raises(ValueError, match=match):
        odom.register_points(np.random.default_rng(0).normal(size=(10, 3)) * 5, 0.0, time=bad)


def _cloud(scan, stamp, times):
    dtype = np.dtype([("x", np.float32), ("y", np.float32), ("z", np.float32), ("ring", np.uint16),
                      ("time", times.dtype)])
    points = np.zeros(len(scan.points), dtype)
    for k, name in enumerate("xyz"):
        points[name] = scan.points[:, k]
    points["ring"], points["time"] = scan.ring, times
    return convert.pointcloud2_from_array(points, frame_id="lidar", stamp=stamp)


def test_the_processor_deskews_point_clouds_with_a_time_field(vlp16_sweeps):
    """Offsets from the stamp (Velodyne `time`) and clock times (Hesai, Livox) give the same poses; times that span
    more than a sweep are not used: the frame is registered as measured, counted in point_times_ignored."""
    frames = vlp16_sweeps[:6]
    poses = {}
    for kind in ("offsets", "clock"):
        proc = OdometryProcessor.from_parameters("vlp16")
        for fr in frames:
            times = fr.data.time.astype(np.float64) + (fr.stamp + 1.7e9 if kind == "clock" else 0.0)
            out = proc.process_pointcloud(_cloud(fr.data, 1.7e9 + fr.stamp, times))
            assert out is not None
        poses[kind] = out.T_odom_base
        assert proc.counters["frames_deskewed"] == len(frames) - 2
        assert proc.counters["point_times_ignored"] == 0
    np.testing.assert_allclose(poses["offsets"], poses["clock"], atol=1e-6)

    proc = OdometryProcessor.from_parameters("vlp16")
    for fr in frames:
        spread = fr.data.time.astype(np.float64) * 30.0  # 3 s across a sweep: not a sweep's times
        assert proc.process_pointcloud(_cloud(fr.data, 1.7e9 + fr.stamp, spread)) is not None
    assert proc.counters["point_times_ignored"] == len(frames) and proc.counters["frames_deskewed"] == 0
    assert "fields[time]" in proc.last_error


def test_deskewing_with_a_gyro_rotation_guess(vlp16_sweeps):
    """The rotation guess turns the deskew velocity as it turns the prediction: both together on the distorted drive
    (the true rotation between the stamps as the gyro's) register as well as deskewing alone."""
    frames = vlp16_sweeps[:20]
    odom = line_odom_core.Odometry(line_odom_core.load_config("vlp16"))
    results = []
    for k, fr in enumerate(frames):
        turn = None if k == 0 else (np.linalg.inv(frames[k - 1].pose) @ fr.pose)[:3, :3]
        res = odom.register_points(fr.data.points, fr.stamp, ring=fr.data.ring.astype(np.int32), time=fr.data.time,
                                   rotation_guess=turn)
        degenerate.check_finite(res)
        results.append(res)
    assert all(res.stats["deskewed"] for res in results[1:])  # the gyro's turn deskews from the first motion on
    assert all(res.stats["prediction"].endswith("+imu") for res in results[1:])
    assert _translation_errors(frames, results).mean() < 0.002
