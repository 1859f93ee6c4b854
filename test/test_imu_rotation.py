"""The gyro rotation guess (imu.enabled, topic 'imu'; docs/NODE.md "IMU rotation guess"): the engine registering from
a rotation guess on the yaw-flip drive of test_turns.py, the integration of sensor_msgs/Imu rates between two scans
(constant rate, rate steps, mounting, bias) against the truth, and what the processor does with bad IMU messages."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu

import line_odom_core
from line_odom import convert, frames, sim
from line_odom.imu_rotation import GyroRotation, ImuError, in_sensor_frame
from line_odom.processor import NodeSettings, OdometryProcessor
from line_odom.sim import scenes
from line_odom.sim.gyro import gyro_samples
from line_odom_core.config import load_config

import test_degenerate_scenes as degenerate
import test_turns
from recording_engine import RecordingEngine

# A MEMS gyro: 0.002 rad/s white noise per sample at 200 Hz, an uncalibrated bias of 0.5 deg/s about z (0.05 deg a
# frame at 10 Hz) and a little about x and y.
GYRO_NOISE = 0.002
GYRO_BIAS = (0.002, -0.003, np.radians(0.5))


def _imu_msg(stamp_ns: int, rate, frame_id: str = "imu_link") -> Imu:
    msg = Imu()
    msg.header.stamp = convert.ns_to_stamp(int(stamp_ns))
    msg.header.frame_id = frame_id
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(v) for v in rate)
    return msg


def _gyro(samples_s, rates, frame_id="imu_link", **kwargs) -> GyroRotation:
    gyro = GyroRotation(window=3600.0, **kwargs)
    for t, w in zip(samples_s, rates):
        gyro.add(_imu_msg(round(t * 1e9), w, frame_id))
    return gyro


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


# ---------------------------------------------------------------- the engine

@pytest.fixture(scope="module")
def flip_drive():
    """The yaw-flip drive (HDL-64E, 10 deg/frame, the sign flipping every 3 frames): (poses, scans, stamps)."""
    data = list(test_turns._turning_scans("hdl64", 10.0))
    return np.array([d[0] for d in data]), [d[1] for d in data], np.array([d[2] for d in data])


def _register_drive(flip_drive, rotations=None):
    poses, scans, stamps = flip_drive
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    out = []
    for k, (scan, stamp) in enumerate(zip(scans, stamps)):
        R = rotations[k - 1] if rotations is not None and k > 0 else None
        res = odom.register_points(scan.points, float(stamp), ring=scan.ring.astype(np.int32), rotation_guess=R)
        degenerate.check_finite(res)
        if k:
            out.append((np.linalg.inv(poses[k - 1]) @ poses[k], res))
    return out


def test_a_gyro_registers_every_yaw_flip(flip_drive):
    """HDL-64E at 1/36 on the yaw-flip drive. From the constant-velocity prediction frame 9 is registered 7.2 deg off
    (unflagged: docs/NODE.md "Turns"), 0.13 deg mean. With the rotation of a MEMS gyro (200 Hz, noise, 0.5 deg/s bias,
    mounted rolled over and turned: GyroRotation and in_sensor_frame) each frame's prediction has the turn, and every
    frame is registered within 0.01 deg (measured 0.004 deg mean, 0.009 max; the gyro alone is 0.10 deg a frame off,
    max 0.20: a rate step between two samples); bound 0.3 deg a frame, 0.05 mean. None searched for a turn: the
    prediction's heading is right."""
    poses, _, stamps = flip_drive
    T_sensor_imu = frames.pose_from_params([0.1, 0.2, -0.3, np.pi, 0.0, 0.5], "mount")
    samples, rates = gyro_samples(poses, stamps, rate_hz=200.0, offset=0.0023, noise_std=GYRO_NOISE, bias=GYRO_BIAS,
                                  T_body_imu=T_sensor_imu, seed=1)
    gyro = _gyro(samples, rates)
    rotations = []
    for k in range(1, len(stamps)):
        R_imu, why = gyro.rotation(round(stamps[k - 1] * 1e9), round(stamps[k] * 1e9))
        assert why is None, why
        rotations.append(in_sensor_frame(R_imu, T_sensor_imu))
    gyro_errors = [_angle_deg(R.T @ (np.linalg.inv(poses[k]) @ poses[k + 1])[:3, :3]) for k, R in enumerate(rotations)]
    assert 0.05 < np.mean(gyro_errors) < 0.3, gyro_errors  # the guess itself is off, the lines correct it

    plain = _register_drive(flip_drive)
    plain_errors = np.array([degenerate.frame_error(res.delta, truth)[1] for truth, res in plain])
    assert plain_errors.max() > 5.0, plain_errors  # the scenario: a turn reversal the prediction misses

    frames_ = _register_drive(flip_drive, rotations)
    errors = np.array([degenerate.frame_error(res.delta, truth)[1] for truth, res in frames_])
    rows = [(k + 1, round(float(e), 3), res.stats["prediction"]) for k, (e, (_, res)) in enumerate(zip(errors, frames_))]
    assert errors.max() < 0.3 and errors.mean() < 0.05, rows
    assert errors[int(np.argmax(plain_errors))] < 0.3, rows  # the 7.2 deg frame
    assert not any(res.degenerate or res.stats["turn_searched"] for _, res in frames_), rows
    assert [res.stats["prediction"] for _, res in frames_] == (
        ["standing_still+imu"] + ["constant_velocity+imu"] * (len(frames_) - 1))


def test_the_first_motion_starts_from_the_gyro_turn():
    """No velocity yet: the first motion is searched from standing still turned by the gyro. A first VLP-16 scan pair
    25 deg and 1.5 m apart (a start mid-turn; the vlp16 preset) is held in full at standing still, 25 deg off, without
    it (measured; the search from standing still finds most such turns alone: 15-28 deg and 0.5-1.5 m, HDL-64E at
    1/36 and 1/64 and the other VLP-16 seed) and registered within 0.005 deg with the rotation guess."""
    scene = scenes.street_scene(length_m=300, seed=0)
    lidar = sim.Lidar.vlp16(noise_std=0.01, seed=0)
    T0 = frames.pose_from_params([20.0, -1.75, 1.73, 0.0, 0.0, 0.0], "T0")
    T1 = frames.pose_from_params([21.5, -1.75, 1.73, 0.0, 0.0, np.radians(25.0)], "T1")
    truth = np.linalg.inv(T0) @ T1
    s0, s1 = lidar.scan(scene, T0, stamp=0.0), lidar.scan(scene, T1, stamp=0.1)
    odom = line_odom_core.Odometry(line_odom_core.load_config("vlp16"))
    odom.register_points(s0.points, 0.0, ring=s0.ring.astype(np.int32))
    res = odom.register_points(s1.points, 0.1, ring=s1.ring.astype(np.int32), rotation_guess=truth[:3, :3])
    errors = (degenerate.frame_error(res.delta, truth), res.stats["prediction"], res.degenerate)
    (t_err, r_err), prediction, held = errors
    assert r_err < 0.1 and t_err < 0.02 and not held and prediction == "standing_still+imu", errors


def test_rotation_guess_is_checked_and_exclusive_with_a_guess():
    odom = line_odom_core.Odometry("kitti_hdl64")
    xyz = np.random.default_rng(0).normal(size=(100, 3)) * 10
    odom.register_points(xyz, 0.0)
    sheared = np.eye(3)
    sheared[0, 1] = 0.1
    for bad, what in ((np.full((3, 3), np.nan), "non-finite"), (sheared, "orthonormal"), (-np.eye(3), "determinant"),
                      (np.eye(4), "shape")):
        with pytest.raises(ValueError, match="rotation_guess"):
            odom.register_points(xyz, 0.1, rotation_guess=bad)
    with pytest.raises(ValueError, match="rotation_guess: expected no guess beside it"):
        odom.register_points(xyz, 0.1, guess=np.eye(4), rotation_guess=np.eye(3))
    # the engine's own check, past the Python face (the bindings take any finite or NaN 3x3)
    for bad in (np.full((3, 3), np.nan), sheared):
        with pytest.raises(ValueError, match="rotation_guess: expected a finite rotation matrix"):
            odom._engine.register_points(xyz, 0.1, None, None, bad)
    with pytest.raises(ValueError, match="rotation_guess: expected no guess beside it"):
        odom._engine.register_points(xyz, 0.1, None, np.eye(4), np.eye(3))
    assert odom.frames == 1  # nothing registered by the rejected calls


# ---------------------------------------------------------------- the integration

def test_constant_rate_integrates_exactly_between_unaligned_stamps():
    w = np.array([0.3, -0.7, 1.9])  # rad/s about a tilted axis
    t = 10.0 + np.arange(0.0, 1.0, 1 / 400.0) + 1e-4 * np.random.default_rng(0).uniform(size=400)  # jittered stamps
    gyro = _gyro(t, [w] * len(t))
    t0, t1 = 10.0123, 10.1171  # between samples
    R, why = gyro.rotation(round(t0 * 1e9), round(t1 * 1e9))
    assert why is None
    np.testing.assert_allclose(R, Rotation.from_rotvec(w * (t1 - t0)).as_matrix(), atol=1e-7)


def test_rate_steps_and_smooth_rates_against_the_truth():
    """The yaw-flip drive's rates: 100 deg/s of yaw reversing every 0.3 s (10 deg/frame flips) beside constant roll
    and pitch rates; 200 Hz samples half a sample off the scan stamps. Each scan interval's rotation is within 0.3 deg
    of the truth (a step falls between two samples and is taken linear between them: 0.25 deg of it lands in the
    neighbouring scan interval; measured 0.25 deg max) and within 1e-6 deg where the rate is the same across both
    ends of the interval."""
    stamps = 0.1 * np.arange(13)
    rng = np.random.default_rng(3)
    poses = [np.eye(4)]
    roll_pitch = rng.uniform(-0.05, 0.05, 2)  # rad a frame
    for k in range(1, len(stamps)):
        yaw = np.radians(10.0) * (1 if (k // 3) % 2 else -1)
        poses.append(poses[-1] @ frames.pose_from_params([0.5, 0.0, 0.0, *roll_pitch, yaw], "step"))
    poses = np.array(poses)
    samples, rates = gyro_samples(poses, stamps, rate_hz=200.0, offset=0.0025)
    gyro = _gyro(samples, rates)
    errors = []
    for k in range(1, len(stamps)):
        R, why = gyro.rotation(round(stamps[k - 1] * 1e9), round(stamps[k] * 1e9))
        assert why is None, why
        errors.append(_angle_deg(R.T @ poses[k - 1][:3, :3].T @ poses[k][:3, :3]))
    errors = np.array(errors)
    assert errors.max() < 0.3, errors
    # intervals 0-1, 3-4, 6-7 and 9-10 have the same rate beyond both ends: exact
    assert errors[[0, 3, 6, 9]].max() < 1e-6 and errors.max() > 0.1, errors


def _recording_processor(overrides, engine=None):
    config = load_config("kitti_hdl64")
    settings = NodeSettings.from_mapping({**config.extra, "imu.enabled": True, **overrides})
    engine = engine or RecordingEngine("constant_velocity+imu")
    return OdometryProcessor(config, settings, engine=engine), engine


def _scan(stamp_ns, frame_id="lidar"):
    xyz = np.random.default_rng(stamp_ns % 1000).normal(size=(50, 3)) + 5.0
    return convert.pointcloud2_from_xyz(xyz, frame_id=frame_id, stamp=convert.ns_to_stamp(int(stamp_ns)))


@pytest.mark.parametrize("bias_known", [True, False])
def test_processor_turns_the_gyro_into_the_sensor_frame_and_removes_the_bias(bias_known):
    """The base turns at a constant body rate; the IMU is mounted upside down and turned (imu.base_to_imu), the LiDAR
    pitched and turned (base_to_sensor). The engine gets R_sensor = R_sensor_base R_base R_base_sensor, computed here
    from the base's rate directly; with imu.gyro_bias the gyro's bias is removed, without it each 0.1 s scan interval
    is off by |bias| 0.1 s."""
    w_base = np.array([0.05, -0.1, 0.8])
    base_to_imu = [0.3, 0.0, 0.2, np.pi, 0.0, np.pi / 2]
    base_to_sensor = [0.5, 0.0, 1.7, 0.0, 0.2, 0.3]
    bias = np.array([0.01, -0.02, 0.015])
    R_base_imu = frames.pose_from_params(base_to_imu, "imu")[:3, :3]
    proc, engine = _recording_processor({"imu.base_to_imu": base_to_imu, "base_to_sensor": base_to_sensor,
                                         **({"imu.gyro_bias": bias.tolist()} if bias_known else {})})
    for t in np.arange(0.0, 0.62, 0.005):
        assert proc.add_imu(_imu_msg(round(t * 1e9), R_base_imu.T @ w_base + bias))
    for k in range(6):
        proc.process_pointcloud(_scan(k * 100_000_000))
    X = frames.pose_from_params(base_to_sensor, "sensor")[:3, :3]
    truth = X.T @ Rotation.from_rotvec(w_base * 0.1).as_matrix() @ X
    assert "rotation_guess" not in engine.calls[0]  # the first scan: nothing to turn from
    for call in engine.calls[1:]:
        error = _angle_deg(call["rotation_guess"].T @ truth)
        if bias_known:
            assert error < 1e-6, error
        else:
            assert abs(error - np.degrees(np.linalg.norm(bias) * 0.1)) < 1e-3, error
    values = proc.diagnostics_values()
    assert (values["frames_imu"], values["frames_without_imu"], values["imu_rejected"]) == (5, 0, 0)


def test_bad_imu_messages_and_uncovered_scans_are_counted_with_their_reason():
    proc, engine = _recording_processor({"imu.max_gap": 0.05})
    accepted = []
    for t in np.arange(0.0, 0.305, 0.01):  # 100 Hz from 0 to 0.3 s, then a gap, then 0.5 to 0.6 s
        accepted.append(proc.add_imu(_imu_msg(round(t * 1e9), [0.0, 0.0, 0.5])))
    for t in np.arange(0.5, 0.605, 0.01):
        accepted.append(proc.add_imu(_imu_msg(round(t * 1e9), [0.0, 0.0, 0.5])))
    assert all(accepted)
    bad = []
    nan = _imu_msg(610_000_000, [float("nan"), 0.0, 0.0])
    bad.append((nan, "Imu.angular_velocity: expected finite rates"))
    no_rate = _imu_msg(611_000_000, [0.0, 0.0, 0.0])
    no_rate.angular_velocity_covariance[0] = -1.0
    bad.append((no_rate, "Imu.angular_velocity_covariance: element 0 is -1"))
    bad.append((_imu_msg(595_000_000, [0.0, 0.0, 0.5]), "Imu.header.stamp: 0.595000000 s is before"))
    bad.append((_imu_msg(600_000_000, [0.0, 0.0, 0.5]), "Imu.header.stamp: 0.600000000 s repeats"))
    bad.append((_imu_msg(620_000_000, [0.0, 0.0, 0.5], frame_id="other_imu"), "Imu.header.frame_id: expected the IMU "
                                                                               "frame 'imu_link'"))
    for msg, reason in bad:
        assert proc.add_imu(msg) is False
        assert proc.diagnostics_values()["last_error"].startswith(reason), (reason, proc.last_error)
    # scans at 0.0 (first), 0.1, 0.2 (covered), 0.4 (the gap 0.3-0.5 s), 0.5 (after the gap: 0.4-0.5 not covered),
    # 0.6 (covered), 0.8 (past the newest sample by more than imu.max_gap)
    stamps = [0, 100, 200, 400, 500, 600, 800]
    for ms in stamps:
        proc.process_pointcloud(_scan(ms * 1_000_000))
    got = ["rotation_guess" in call for call in engine.calls]
    assert got == [False, True, True, False, False, True, False], got
    values = proc.diagnostics_values()
    assert (values["frames_imu"], values["frames_without_imu"], values["imu_rejected"]) == (3, 3, 5), values
    assert values["imu_samples"] == 42
    assert "the newest gyro sample (0.600 s) is before the scan (0.800 s)" in values["last_error"], values
    np.testing.assert_allclose(Rotation.from_matrix(engine.calls[1]["rotation_guess"]).as_rotvec(), [0, 0, 0.05],
                               atol=1e-12)
    status = proc.diagnostics().status[0]
    assert "3 frame(s) without the gyro's rotation" in status.message and "5 imu message(s) rejected" in status.message


def test_gap_reason_names_the_missing_interval():
    gyro = _gyro(np.r_[np.arange(0.0, 0.1, 0.01), np.arange(0.2, 0.4, 0.01)], [[0.0, 0.0, 1.0]] * 30)
    R, why = gyro.rotation(50_000_000, 250_000_000)
    assert R is None and why.startswith("no gyro sample for 0.110 s between 0.090 and 0.200 s"), why
    with pytest.raises(ImuError, match="Imu.header.stamp"):
        gyro.add(_imu_msg(100_000_000, [0.0, 0.0, 1.0]))
    assert len(gyro) == 30
    # a stamp back by more than the window (a looping bag): the samples start over
    loop = GyroRotation(window=1.0)
    loop.add(_imu_msg(5_000_000_000, [0.0, 0.0, 1.0]))
    assert loop.add(_imu_msg(1_000_000_000, [0.0, 0.0, 1.0])) is False and len(loop) == 1


def test_imu_mounting_from_tf_static_and_a_guess_takes_the_gyro_rotation():
    """base_to_sensor_from_tf: the IMU's mounting is base_frame -> the Imu messages' frame on /tf_static (scans before
    it is there go without the gyro, counted); with guess.enabled too, the wheel odometry's translation is kept and its
    rotation replaced by the gyro's."""
    from nav_msgs.msg import Odometry as OdometryMsg
    from tf2_msgs.msg import TFMessage
    from node_harness import transform_stamped

    proc, engine = _recording_processor({"base_to_sensor_from_tf": True, "guess.enabled": True})
    T_base_lidar = frames.pose_from_params([0.5, 0.0, 1.7, 0.0, 0.0, 0.4], "lidar")
    T_base_imu = frames.pose_from_params([0.0, 0.1, 0.3, 0.0, 1.2, 0.0], "imu")
    proc.add_static_tf(TFMessage(transforms=[transform_stamped("base_link", "lidar", T_base_lidar)]))
    w_base = np.array([0.0, 0.0, 1.0])
    for t in np.arange(0.0, 0.42, 0.01):
        proc.add_imu(_imu_msg(round(t * 1e9), T_base_imu[:3, :3].T @ w_base))
    for k in range(5):  # wheel odometry: 1 m a scan straight ahead, no turn
        msg = OdometryMsg()
        msg.header.stamp = convert.ns_to_stamp(k * 100_000_000)
        msg.child_frame_id = "base_link"
        msg.pose.pose.position.x = float(k)
        msg.pose.pose.orientation.w = 1.0
        proc.add_guess(msg)
    proc.process_pointcloud(_scan(0))
    proc.process_pointcloud(_scan(100_000_000))
    assert "rotation_guess" not in engine.calls[1] and proc.counters["frames_without_imu"] == 1
    assert "no transform base_link -> imu_link on /tf_static yet" in proc.last_error
    proc.add_static_tf(TFMessage(transforms=[transform_stamped("base_link", "imu_link", T_base_imu)]))
    proc.process_pointcloud(_scan(200_000_000))
    guess = engine.calls[2]["guess"]
    X = T_base_lidar
    truth = np.linalg.inv(X)[:3, :3] @ Rotation.from_rotvec(w_base * 0.1).as_matrix() @ X[:3, :3]
    assert _angle_deg(guess[:3, :3].T @ truth) < 1e-6
    np.testing.assert_allclose(guess[:3, 3], np.linalg.inv(X)[:3, :3] @ [1.0, 0.0, 0.0], atol=1e-9)
    assert proc.counters["frames_imu"] == 1 and proc.counters["frames_guessed"] == 2


def test_imu_is_off_by_default_and_its_parameters_are_checked():
    config = load_config("kitti_hdl64")
    engine = RecordingEngine("constant_velocity+imu")
    proc = OdometryProcessor(config, NodeSettings.from_mapping(config.extra), engine=engine)
    assert proc.add_imu(_imu_msg(0, [0.0, 0.0, 1.0])) is False
    for k in range(2):
        proc.process_pointcloud(_scan(k * 100_000_000))
    assert engine.calls == [{}, {}] and "frames_imu" not in proc.diagnostics_values()
    with pytest.raises(ValueError, match=r"imu.gyro_bias: expected 3 finite numbers \[x, y, z\]"):
        NodeSettings.from_mapping({"imu.gyro_bias": [0.0, 0.0]})
    with pytest.raises(ValueError, match="imu.base_to_imu: expected 6 values"):
        NodeSettings.from_mapping({"imu.base_to_imu": [0.0] * 5})
    with pytest.raises(ValueError, match=r"imu.max_gap: expected float in \[0.001, 10.0\]"):
        NodeSettings.from_mapping({"imu.max_gap": 0.0})


def test_a_gyro_slightly_off_does_not_cost_the_first_motion_on_the_highway():
    """KITTI 04 at 1/64 (a highway: the hard first motion, docs/NODE.md "The first motion") from a gyro turn 0.05 deg
    off in yaw: searched from that turn alone the first motion was held at a standstill (1.31 m off, ill-conditioned;
    measured before the fallback), so the search from standing still runs too and its registration is taken: 0.009 m,
    as without the gyro (flagged as without it: the lines do not pin a highway's first forward motion down at 1/64,
    validation.*)."""
    from line_odom.datasets import kitti_sequence

    data = kitti_sequence("04")
    truth = np.linalg.inv(data.poses[0]) @ data.poses[1]
    odom = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 8}))
    odom.register_points(data.xyz(0), float(data.times[0]))
    R = truth[:3, :3] @ Rotation.from_rotvec(np.radians([0.0, 0.0, 0.05])).as_matrix()
    res = odom.register_points(data.xyz(1), float(data.times[1]), rotation_guess=R)
    t_err, _ = degenerate.frame_error(res.delta, truth)
    assert t_err < 0.05 and res.stats["registered"] and res.stats["prediction"] == "standing_still+imu", (t_err,
                                                                                                           res.stats)


def _biased_gyro_drive(gain: float, frames: int = 80):
    """The VLP-16 on the simulated street (10 m/s) through the processor, a gyro in the LiDAR's frame with the MEMS
    bias above that the node is not told about: (learned bias (3,), per-frame rotation errors in deg)."""
    run = list(sim.make("street", frames=frames, seed=0, sensor="vlp16", noise_std=0.01))
    poses = np.array([fr.pose for fr in run])
    stamps = np.array([100.0 + fr.stamp for fr in run])
    samples, rates = gyro_samples(poses, stamps, rate_hz=200.0, offset=0.0025, noise_std=GYRO_NOISE, bias=GYRO_BIAS,
                                  seed=2)
    proc = OdometryProcessor.from_parameters("vlp16", {"imu.enabled": True, "imu.bias_gain": gain,
                                                       "base_frame": "lidar"})
    messages = sorted([(round(t * 1e9), 0, w) for t, w in zip(samples, rates)] +
                      [(round(t * 1e9), 1, k) for k, t in enumerate(stamps)], key=lambda m: (m[0], m[1]))
    outs = []
    for stamp_ns, kind, what in messages:
        if kind == 0:
            proc.add_imu(_imu_msg(stamp_ns, what, "lidar"))
            continue
        scan = run[what].data
        cloud = np.zeros(len(scan.points), [("x", np.float32), ("y", np.float32), ("z", np.float32),
                                             ("ring", np.uint16)])
        cloud["x"], cloud["y"], cloud["z"] = scan.points.T
        cloud["ring"] = scan.ring
        outs.append(proc.process_pointcloud(convert.pointcloud2_from_array(
            cloud, frame_id="lidar", stamp=convert.ns_to_stamp(stamp_ns))))
    errors = [_angle_deg((np.linalg.inv(np.linalg.inv(poses[k - 1]) @ poses[k]) @
                          (np.linalg.inv(outs[k - 1].T_odom_base) @ outs[k].T_odom_base))[:3, :3])
              for k in range(1, frames)]
    return proc.gyro.bias, np.array(errors)


def test_the_gyro_bias_is_learned_from_the_registered_turns():
    """Each frame registered in full moves the bias imu.bias_gain of the way to what the scans say; measured after 80
    frames (8 s): |learned - true| 0.021 deg/s of 0.54 deg/s (gain 0.1: 0.022). With the gain 0 it stays 0."""
    learned, errors = _biased_gyro_drive(0.05)
    assert np.degrees(np.linalg.norm(learned - np.array(GYRO_BIAS))) < 0.15, np.degrees(learned)
    assert errors.mean() < 0.05, errors
    fixed, _ = _biased_gyro_drive(0.0, frames=10)
    np.testing.assert_array_equal(fixed, np.zeros(3))
