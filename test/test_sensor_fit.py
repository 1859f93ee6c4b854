"""A cloud read with another LiDAR's sensor model (the node's `preset`): the engine's measure of the fit
(Odometry.sensor_fit) and the processor's warning, which names the preset that fits."""
import numpy as np
import pytest

import line_odom_core
from line_odom import convert, sensor_check, sim
from line_odom.datasets import kitti_sequence
from line_odom.processor import OdometryProcessor
from line_odom_core.config import load_config


def _scan(sensor: str, frames: int = 1):
    return list(sim.make("street", frames=frames, seed=0, noise_std=0.01, sensor=sensor))


@pytest.fixture(scope="module")
def vlp16_frames():
    return _scan("vlp16", 6)


def test_sensor_fit_of_matching_and_other_sensors(vlp16_frames):
    kitti = line_odom_core.Odometry("kitti_hdl64").sensor_fit(kitti_sequence("04", 1).xyz(0))
    assert (kitti["row_method"], kitti["outside_rows"], kitti["filled_rows"], kitti["rows"]) == ("azimuth_wrap", 0, 64, 64)
    assert kitti["points"] > 100_000 and -25.0 < kitti["cloud_low_deg"] < kitti["cloud_high_deg"] < 3.0
    assert sensor_check.problem(kitti) is None

    scan = vlp16_frames[0].data
    ring = scan.ring.astype(np.int32)
    own = line_odom_core.Odometry("vlp16").sensor_fit(scan.points)
    assert own["outside_rows"] == 0 and own["filled_rows"] == 16 and sensor_check.problem(own) is None
    # measured: 39 % outside, 9 of 64 rows filled; with the ring field 16 of 64 rows
    other = line_odom_core.Odometry("kitti_hdl64").sensor_fit(scan.points)
    assert other["outside_rows"] > 0.3 * other["points"] and other["filled_rows"] <= 12
    assert other["cloud_high_deg"] == pytest.approx(15.0, abs=0.1)
    assert "outside the beams of sensor model 'hdl64'" in sensor_check.problem(other)
    assert other["band_rows"] > 30 and "outside the beams of sensor model 'hdl64'" in sensor_check.problem(other)
    # with its ring field the cloud takes 16 rows one above the other, and registers (simulated street: 0.6 mm a frame)
    ringed = line_odom_core.Odometry("kitti_hdl64").sensor_fit(scan.points, ring=ring)
    assert (ringed["row_method"], ringed["filled_rows"], ringed["band_rows"], ringed["ring_rows"]) == ("ring", 16, 16, 16)
    assert sensor_check.problem(ringed) is None

    os128 = _scan("os128")[0].data
    beyond = line_odom_core.Odometry("kitti_hdl64").sensor_fit(os128.points, ring=os128.ring.astype(np.int32))
    assert beyond["ring_rows"] == 128 and beyond["row_method"] == ""  # reported, not thrown
    assert "counts 128 rings" in sensor_check.problem(beyond)
    with pytest.raises(ValueError, match="xyz"):
        line_odom_core.Odometry("vlp16").sensor_fit(np.zeros((5, 2)))


def _processor(preset: str):
    messages = []
    log = type("Log", (), {"info": lambda self, m: None, "warning": lambda self, m: messages.append(m)})()
    return OdometryProcessor(load_config(preset), logger=log), messages


def _message(frame, ring: bool):
    return convert.pointcloud2_from_xyz(frame.data.points, ring=frame.data.ring if ring else None, frame_id="lidar",
                                        stamp=convert.ns_to_stamp(int(round(frame.stamp * 1e9))))


def test_a_cloud_of_another_sensor_is_named_with_the_preset_that_fits(vlp16_frames):
    proc, messages = _processor("kitti_hdl64")
    for frame in vlp16_frames:
        assert proc.process_pointcloud(_message(frame, False)) is not None  # still registered
    assert proc.counters["clouds_not_fitting_sensor"] == len(vlp16_frames)
    warned = [m for m in messages if "do not fit the sensor model" in m]
    assert len(warned) == 1  # not again within SENSOR_LOG_REPEAT_S
    assert "sensor model 'hdl64'" in warned[0] and "set parameter 'preset' to 'vlp16' (it fits)" in warned[0]
    values = proc.diagnostics_values()
    assert "'vlp16'" in values["sensor_fit"] and values["clouds_not_fitting_sensor"] == len(vlp16_frames)
    status = proc.diagnostics().status[0]
    assert "not fitting the sensor model" in status.message


def test_a_fitting_cloud_is_checked_once(vlp16_frames, monkeypatch):
    proc, messages = _processor("vlp16")
    calls = []
    real = proc.engine.sensor_fit
    monkeypatch.setattr(proc.engine, "sensor_fit", lambda *a, **k: calls.append(1) or real(*a, **k))
    for frame in vlp16_frames[:3]:
        assert proc.process_pointcloud(_message(frame, False)) is not None
    assert len(calls) == 1 and proc.sensor_fit == "ok" and proc.counters["clouds_not_fitting_sensor"] == 0
    assert not [m for m in messages if "sensor model" in m]


def test_rings_beyond_the_model_are_refused_naming_what_to_set():
    os128 = _scan("os128")[0].data
    with pytest.raises(ValueError, match="a sensor with more beams: set the preset or sensor.model"):
        line_odom_core.Odometry("kitti_hdl64").register_points(os128.points, 0.0, ring=os128.ring.astype(np.int32))


def test_a_cloud_no_preset_fits_asks_for_the_sensor_frame(vlp16_frames):
    scan = vlp16_frames[0].data
    lowered = scan.points + np.array([0.0, 0.0, 1.7], dtype=scan.points.dtype)  # published in a base frame below it
    fit = line_odom_core.Odometry("vlp16").sensor_fit(lowered)
    assert "outside the beams of sensor model 'vlp16'" in sensor_check.problem(fit)
    advice = sensor_check.advice(lambda preset: fit)  # as if no preset's model fitted it
    assert "none of the presets fits" in advice and "the LiDAR's own frame" in advice


@pytest.mark.parametrize("sensor, preset", [("vlp16", "vlp16"), ("os128", "ouster_os128"), ("hdl64", "kitti_hdl64")])
def test_rows_left_empty_by_open_sky_are_no_mismatch(sensor, preset):
    scan = next(iter(sim.make("ground", frames=1, seed=0, sensor=sensor))).data  # an empty plane: no return above
    for ring in (None, scan.ring.astype(np.int32)):
        fit = line_odom_core.Odometry(preset).sensor_fit(scan.points, ring=ring)
        assert fit["filled_rows"] < 0.9 * fit["rows"] and sensor_check.problem(fit) is None  # vlp16: 8 of 16 rows


def test_rings_beyond_the_model_are_reported_and_the_frames_refused():
    proc, messages = _processor("kitti_hdl64")
    for frame in _scan("os128", 2):
        assert proc.process_pointcloud(_message(frame, True)) is None
    assert proc.counters["clouds_not_fitting_sensor"] == 2 and proc.counters["frames_failed"] == 2
    warned = [m for m in messages if "do not fit the sensor model" in m]
    assert len(warned) == 1 and "counts 128 rings" in warned[0] and "'ouster_os128' (it fits)" in warned[0]
