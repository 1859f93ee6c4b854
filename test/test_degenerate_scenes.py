"""Degenerate scenes from the simulator (line_odom.sim): empty space, only a ground plane, an endless featureless
corridor, everything beyond range, a single wall, heavy noise, a frame identical to the previous one.

The odometry must never produce NaN/inf and never claim a confident wrong pose: when the geometry does not
constrain the motion, the pose is held by the constant-velocity motion model, the covariance is inflated to at
least the configured fallback and the result says ``degenerate`` — and so do the node's diagnostics. When
structure returns, the frame-to-frame error is back within bounds.
"""
from __future__ import annotations

import numpy as np
import pytest

import line_odom_core
from line_odom import convert, sim
from line_odom.processor import OdometryProcessor

FRAMES = 5
# HDL-64E at 1/36 (the sparse setting the pipeline is built for) keeps the runs fast.
OVERRIDES = {"downsample": 6}
TRANSLATION_BOUND = 0.10  # m, frame-to-frame on structured street frames (1 m per frame, noise-free)
ROTATION_BOUND = 0.5  # deg


def make_config():
    return line_odom_core.load_config("kitti_hdl64", OVERRIDES)


def frame_error(delta: np.ndarray, true_delta: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(true_delta) @ delta
    angle = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(E[:3, 3])), float(angle)


def register(odom, frame):
    return odom.register_points(frame.data.points, frame.stamp, ring=frame.data.ring)


def check_finite(res):
    for name in ("pose", "delta", "covariance", "twist"):
        assert np.isfinite(getattr(res, name)).all(), f"{name} not finite"
    C = res.covariance
    np.testing.assert_allclose(C, C.T, atol=1e-12)
    assert np.linalg.eigvalsh(C).min() >= -1e-12


def check_held(res, prev_delta, config, unobserved_axis=None):
    """A degenerate frame: flag and reason. Held in full (solver "prediction", 6 held directions): the motion
    model's prediction (constant velocity, equal stamp steps) and a covariance no smaller than the configured
    fallback; the same covariance when the point map's alignment was taken in full (solver "points": where the lines
    register nothing the scan's points are aligned to the last scans', point_map.*). Held in part (registration.partial_updates, 1-5 held directions): the directions the lines observe
    registered, the others from the prediction, with at least the smaller fallback variance along that many
    directions; ``unobserved_axis`` (0-2: x, y, z) must be one of them: the motion along it is the prediction's,
    with the fallback translation variance."""
    assert res.degenerate and res.stats["failure"], res.stats
    held = res.stats["held_directions"]
    ts = config["registration.fallback_translation_sigma"]
    rs = np.radians(config["registration.fallback_rotation_sigma_deg"])
    if res.stats["solver"] in ("prediction", "points"):
        assert held == 6, res.stats
        if res.stats["solver"] == "prediction":
            np.testing.assert_allclose(res.delta, prev_delta, atol=1e-9)
        diag = np.diag(res.covariance)
        assert (diag[:3] >= ts ** 2 * (1 - 1e-9)).all() and (diag[3:] >= rs ** 2 * (1 - 1e-9)).all(), diag
        return
    assert 1 <= held <= 5, res.stats
    eig = np.linalg.eigvalsh(res.covariance)
    assert (eig[-held:] >= min(ts, rs) ** 2 * (1 - 1e-9)).all(), (eig, res.stats)
    # ... and only there: what the lines observe stays confident, nothing beyond the fallback anywhere
    assert (eig[:-held] < 0.1 * min(ts, rs) ** 2).all(), (eig, res.stats)
    assert (np.diag(res.covariance) <= max(ts, rs) ** 2 * (1 + 1e-6)).all(), np.diag(res.covariance)
    if unobserved_axis is not None:
        along = (res.delta @ np.linalg.inv(prev_delta))[unobserved_axis, 3]
        assert abs(along) < 1e-3, (along, res.stats)
        # (the held direction is the lines' weakest one: along the axis to within a fraction of a degree)
        assert res.covariance[unobserved_axis, unobserved_axis] >= ts ** 2 * (1 - 1e-4), res.covariance


@pytest.mark.parametrize("kind, kwargs", [
    ("empty", {}),
    ("ground", {}),
    ("corridor", {}),
    ("far", {}),
    ("wall", {}),
])
def test_degenerate_scene_holds_the_motion_model_with_inflated_covariance(kind, kwargs):
    """Straight along x at constant speed: what the scene does not show is held at the prediction (all of it, or
    along x in the corridor), and what it shows does not move (no motion is invented from nothing)."""
    config = make_config()
    odom = line_odom_core.Odometry(config)
    run = sim.make(kind, frames=FRAMES, seed=0, **kwargs)
    frames = list(run)
    first = register(odom, frames[0]) if len(frames[0].data.points) else None
    if first is None:  # nothing at all in view: the first frame still defines the origin
        first = odom.register_points(np.full((1, 3), np.nan), frames[0].stamp)
    check_finite(first)
    prev_delta = np.eye(4)  # no velocity yet: the motion model predicts standing still
    for frame in frames[1:]:
        res = register(odom, frame)
        check_finite(res)
        check_held(res, prev_delta, config, unobserved_axis=0 if kind == "corridor" else None)
        t, r = frame_error(res.delta, prev_delta)
        assert t < 0.02 and r < 0.1, (t, r, res.stats)
        prev_delta = res.delta
    assert np.isfinite(odom.pose).all()


@pytest.mark.parametrize("noise_std, seed", [(0.5, 0), (0.5, 1), (0.5, 2), (0.3, 0)])
def test_heavy_noise_is_finite_and_never_confidently_wrong(noise_std, seed):
    """0.3-0.5 m range noise: lines cannot be fitted reliably. Every frame is either flagged degenerate (prediction
    held) or registered within the bounds (a registered frame must not be a confident wrong pose). Without the
    inlier-ratio check (registration.min_inlier_ratio) 7L fits 12-20 chance inliers of 60-150 candidates and
    reports a 0.7-1.5 m wrong motion with a 0.1-0.5 m sigma."""
    config = make_config()
    odom = line_odom_core.Odometry(config)
    run = sim.make("street", frames=FRAMES, seed=seed, noise_std=noise_std)
    prev, prev_delta = None, np.eye(4)
    for frame in run:
        res = register(odom, frame)
        check_finite(res)
        if prev is not None:
            if res.degenerate:
                check_held(res, prev_delta, config)
            else:
                t, r = frame_error(res.delta, np.linalg.inv(prev.pose) @ frame.pose)
                sigma_t = np.sqrt(np.max(np.diag(res.covariance)[:3]))
                assert t < max(0.5, 3 * sigma_t), (t, sigma_t, res.stats)
            prev_delta = res.delta
        prev = frame


def test_identical_frames_give_identity_motion():
    """Standing still without noise: every frame equals the previous one; the motion is the identity (a
    well-constrained scene, so not degenerate), nothing NaN."""
    odom = line_odom_core.Odometry(make_config())
    frames = list(sim.make("street", frames=4, seed=0, speed=0.0))
    np.testing.assert_array_equal(frames[0].data.points, frames[1].data.points)
    for k, frame in enumerate(frames):
        res = register(odom, frame)
        check_finite(res)
        if k:
            assert not res.degenerate, res.stats
            t, r = frame_error(res.delta, np.eye(4))
            assert t < 1e-3 and r < 0.01, (t, r)
    # and literally the same arrays twice with a later stamp
    res = odom.register_points(frames[-1].data.points, frames[-1].stamp + 0.1, ring=frames[-1].data.ring)
    check_finite(res)
    assert frame_error(res.delta, np.eye(4))[0] < 1e-3


CORRIDOR = (0.0, 90.0)  # x range of the corridor in the structure-gap scene
GAP_RANGE = 30.0  # sensor range there: deep inside, neither end of the corridor is visible
GAP_SPEED = 2.0  # m per frame (20 m/s at 10 Hz)


def _structure_gap_scene():
    """A street with buildings, poles and parked cars, then a closed featureless corridor (floor, walls, ceiling)
    along x in CORRIDOR, then street again."""
    rng = np.random.default_rng(7)
    b = sim.SceneBuilder().add_plane([0, 0, 1], 0.0, "ground")
    x0, x1 = CORRIDOR
    for side in (-1, 1):
        b.add_box([(x0 + x1) / 2, side * 2.15, 2.0], [x1 - x0, 0.3, 4.0], 0.0, "wall")
        for lo, hi in ((-120.0, x0 - 4.0), (x1 + 4.0, 220.0)):
            x = lo
            while x < hi:
                length = rng.uniform(6, 15)
                b.add_box([x + length / 2, side * rng.uniform(9, 13), 5.0], [length, rng.uniform(5, 8),
                                                                           rng.uniform(6, 14)],
                          rng.uniform(-0.2, 0.2), "building")
                b.add_cylinder(x + rng.uniform(0, length), side * 6.5, 0.0, 5.0, 0.15, "pole")
                if rng.random() < 0.6:
                    b.add_box([x + rng.uniform(0, length), side * 4.5, 0.8], [4.2, 1.8, 1.5], rng.uniform(-0.1, 0.1),
                              "car")
                x += length + rng.uniform(1, 4)
    b.add_box([(x0 + x1) / 2, 0.0, 3.65], [x1 - x0, 4.6, 0.3], 0.0, "ceiling")
    return b.build(name="structure_gap")


def _structure_gap_frames():
    """Driving straight through the street, the corridor and the street again at GAP_SPEED per frame:
    (stamp, scan, pose) with an HDL-64E of range GAP_RANGE."""
    scene = _structure_gap_scene()
    frames_n = int((CORRIDOR[1] + 40.0 - (CORRIDOR[0] - 40.0)) / GAP_SPEED)
    traj = sim.straight_drive(frames_n, 10.0, 10.0 * GAP_SPEED, height=1.73, start=(CORRIDOR[0] - 40.0, 0.0))
    lidar = sim.Lidar.hdl64(max_range=GAP_RANGE)
    return [(float(t), lidar.scan(scene, T, stamp=float(t)), T) for t, T in traj]


def test_recovery_when_structure_returns():
    """Street, then a corridor deep enough that nothing but its four planes is in range, then street again: in
    the street every frame registers within bounds; deep in the corridor frames are flagged and held by the
    motion model (or, if registered, accurate: never confidently wrong); back in the street the error is in
    bounds again within a few frames of structure returning."""
    odom = line_odom_core.Odometry(make_config())
    frames = _structure_gap_frames()
    results, errors = [], [(0.0, 0.0)]
    for k, (stamp, scan, T) in enumerate(frames):
        res = odom.register_points(scan.points, stamp, ring=scan.ring)
        check_finite(res)
        results.append(res)
        if k:
            errors.append(frame_error(res.delta, np.linalg.inv(frames[k - 1][2]) @ T))
    x = np.array([T[0, 3] for _, _, T in frames])
    x0, x1 = CORRIDOR
    street_before = [k for k in range(1, len(frames)) if x[k] < x0 - GAP_RANGE / 2]
    deep = [k for k in range(len(frames)) if x0 + GAP_RANGE + 2 < x[k] < x1 - GAP_RANGE - 2]
    street_after = [k for k in range(len(frames)) if x[k] > x1 + 2 * GAP_SPEED]
    assert len(street_before) >= 5 and len(deep) >= 5 and len(street_after) >= 5
    report = [(k, round(x[k]), results[k].stats["solver"], round(errors[k][0], 3)) for k in range(len(frames))]
    for k in street_before + street_after:
        assert not results[k].degenerate and errors[k][0] < TRANSLATION_BOUND and errors[k][1] < ROTATION_BOUND, (
            k, report)
    for k in range(1, len(frames)):  # never a confident wrong pose anywhere along the drive
        if not results[k].degenerate:
            sigma = np.sqrt(np.diag(results[k].covariance)[:3].max())
            assert errors[k][0] < max(TRANSLATION_BOUND, 3 * sigma), (k, report)
    flagged = [k for k in deep if results[k].degenerate]
    assert len(flagged) >= len(deep) - 1, report
    for k in flagged:
        check_held(results[k], results[k - 1].delta, odom.config)


def _cloud_msg(points, stamp, ring=None):
    return convert.pointcloud2_from_xyz(points, ring=ring, frame_id="velodyne", stamp=stamp)


@pytest.mark.parametrize("kind", ["corridor", "empty"])
def test_degeneracy_is_reported_in_diagnostics_and_odometry_covariance(kind):
    """Through the node's processing core: the degenerate flag reaches the DiagnosticArray (WARN, message, value)
    and the published Odometry carries the inflated covariance; a structured frame afterwards clears it."""
    from diagnostic_msgs.msg import DiagnosticStatus

    proc = OdometryProcessor.from_parameters("kitti_hdl64", OVERRIDES)
    frames = list(sim.make(kind, frames=3, seed=0))
    outs = []
    for f in frames:
        pts = f.data.points if len(f.data.points) else np.array([[np.nan, np.nan, np.nan], [1e9, 0, 0]], np.float32)
        outs.append(proc.process_pointcloud(_cloud_msg(pts, 5.0 + f.stamp)))
    if kind == "empty":  # no point in range at all: the first frame still anchors the trajectory
        assert outs[0] is not None
    status = proc.diagnostics().status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.WARN, status.message
    assert "degenerate" in status.message
    assert values["degenerate"] == "True"
    last = outs[-1]
    assert last is not None and last.stats["degenerate"]
    cov = np.array(last.odometry.pose.covariance).reshape(6, 6)
    held = last.stats["held_directions"]
    assert np.isfinite(cov).all() and 1 <= held <= 6
    assert (np.linalg.eigvalsh(cov)[-held:] >= np.radians(5.0) ** 2 * 0.99).all()
    if kind == "corridor":  # along the corridor (x) only the motion model speaks
        assert cov[0, 0] >= 0.5 ** 2 * 0.99 and values["held_directions"] == str(held)
    else:
        assert held == 6 and np.diag(cov)[:3].min() >= 0.5 ** 2 * 0.99
    assert np.isfinite(np.array(last.odometry.twist.covariance)).all()
    # structure returns: a registered street frame pair clears the flag
    proc.reset("scene change")
    for f in list(sim.make("street", frames=3, seed=0)):
        out = proc.process_pointcloud(_cloud_msg(f.data.points, 10.0 + f.stamp, ring=f.data.ring))
        assert out is not None
    assert not out.stats["degenerate"]
    status = proc.diagnostics().status[0]
    assert status.level == DiagnosticStatus.OK and {kv.key: kv.value for kv in status.values}["degenerate"] == "False"


@pytest.mark.parametrize("overrides", [{}, {"sensor.cols": 0}], ids=["preset", "1800_azimuth_bins"])
def test_corridor_with_the_vlp16_preset_is_flagged_not_confidently_wrong(overrides):
    """VLP-16 in the endless corridor, as shipped (600 azimuth bins) and organized at the sensor's own 1800 firing
    steps (sensor.cols = 0). At 1800 bins nearly all candidate pairs lie on one of the four planes; the few pairs of
    lines without a normal (floor/ceiling ring pieces x wall columns) carry a third of the cluster weight, and four
    of them meet at the seams under a wrong shift of ~0.9 m along the corridor: they alone "observe" x (a push
    keeps 87 % of the inlier weight but 99.99 % of the inlier pairs). The pair share
    (registration.max_axis_pair_support) flags it; without it the estimate is -0.9 m (truth +1 m) with ~0
    covariance."""
    config = line_odom_core.load_config("vlp16", overrides)
    odom = line_odom_core.Odometry(config)
    frames = list(sim.make("corridor", frames=4, seed=0, sensor="vlp16"))
    prev_delta = np.eye(4)
    register(odom, frames[0])
    for frame in frames[1:]:
        res = register(odom, frame)
        check_finite(res)
        check_held(res, prev_delta, config, unobserved_axis=0)
        prev_delta = res.delta


FIRST_MOTION_CASES = [(seed, noise) for noise in (None, 0.01) for seed in range(8)]


@pytest.mark.parametrize("seed, noise_std", FIRST_MOTION_CASES)
def test_first_motion_of_a_street_drive_is_found(seed, noise_std):
    """No velocity yet (the motion model predicts standing still, ~1 m from the truth): the first motion of a
    structured street drive at 1/36, noise-free and with 1 cm range noise, is registered within the bounds for
    every seed — neither held nor a confident wrong pose found from the wrong guess."""
    odom = line_odom_core.Odometry(make_config())
    frames = list(sim.make("street", frames=2, seed=seed, noise_std=noise_std))
    register(odom, frames[0])
    res = register(odom, frames[1])
    check_finite(res)
    t, r = frame_error(res.delta, np.linalg.inv(frames[0].pose) @ frames[1].pose)
    assert not res.degenerate and t < TRANSLATION_BOUND and r < ROTATION_BOUND, (t, r, res.stats)


@pytest.mark.parametrize("start", [20, 50, 60, 80])
def test_first_motion_at_30_m_per_s_on_the_street(start):
    """A VLP-16 on the simulated street, every 3rd scan: 3 m a scan (30 m/s at 10 Hz), beyond the candidates' 2 m.
    Measured before the support scan also ran when the first pass failed (odometry.cpp first_motion): at start 20
    the coarse search's 0.2 m was reported, registered; at 50, 60 and 80 the start was flagged ill-conditioned and
    held at standing still. Of 20 fresh starts (every 10th scan) 8 were 2.6-3.3 m off; now 2 are."""
    frames = list(sim.make("street", frames=start + 4, seed=0, noise_std=0.01, sensor="vlp16"))
    odom = line_odom_core.Odometry(line_odom_core.load_config("vlp16"))
    first, second = frames[start], frames[start + 3]
    odom.register_points(first.data.points, first.stamp, ring=first.data.ring.astype(np.int32))
    res = odom.register_points(second.data.points, second.stamp, ring=second.data.ring.astype(np.int32))
    t, _ = frame_error(res.delta, np.linalg.inv(first.pose) @ second.pose)
    assert res.stats["registered"] and not res.stats["degenerate"] and t < 0.05, (t, res.stats)


@pytest.mark.parametrize("tilt_deg, start", [(15.0, 0), (15.0, 60), (15.0, 180), (-15.0, 10), (-15.0, 100)])
def test_first_motion_at_30_m_per_s_with_the_sensor_tilted(tilt_deg, start):
    """The VLP-16 of the test above pitched down (15) or up (-15 deg) on its mount, every 3rd scan (3 m a scan): the
    forward motion is then 15 deg off the sensor's x axis and the sensor's x-y plane. The first motion's scan also
    runs along the x axis laid onto the ground plane, and finds the lines' direction in that plane. Measured, 20
    fresh starts (every 10th scan): pitched down 11 wrong before (2.4-4.4 m off, 5 flagged), 4 now; pitched up 12
    before, 5 now. These starts were wrong before."""
    from scipy.spatial.transform import Rotation

    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("y", tilt_deg, degrees=True).as_matrix()
    run = sim.make("street", frames=start + 4, seed=0, noise_std=0.01, sensor="vlp16")
    odom = line_odom_core.Odometry(line_odom_core.load_config("vlp16"))
    poses = [run.trajectory.poses[k] @ tilt for k in (start, start + 3)]
    for T, k in zip(poses, (start, start + 3)):
        stamp = float(run.trajectory.stamps[k])
        scan = run.sensor.scan(run.scene, T, stamp=stamp)
        res = odom.register_points(scan.points, stamp, ring=scan.ring.astype(np.int32))
    t, _ = frame_error(res.delta, np.linalg.inv(poses[0]) @ poses[1])
    assert res.stats["registered"] and not res.stats["degenerate"] and t < 0.05, (t, res.stats)


def _swaying_corridor_frames(frames_n=12, amplitude_deg=2.0):
    """HDL-64E through the endless corridor at 1 m per frame, swaying: yaw 2 deg and 10 cm sideways, sinusoidal
    over 10 frames. The motion along the corridor is unobservable; the sway is not, and the constant-velocity
    prediction gets it wrong by up to ~1 deg a frame."""
    scene = sim.scenes.corridor_scene()
    lidar = sim.Lidar.hdl64()
    frames = []
    for k in range(frames_n):
        phase = 2 * np.pi * k / 10
        yaw = np.radians(amplitude_deg) * np.sin(phase)
        T = np.eye(4)
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        T[:3, 3] = [1.0 * k, 0.1 * np.sin(phase), 1.5]
        frames.append((0.1 * k, lidar.scan(scene, T, stamp=0.1 * k), T))
    return frames


@pytest.mark.parametrize("partial", [True, False], ids=["partial_updates", "held_in_full"])
def test_swaying_corridor_keeps_the_observed_rotation(partial):
    """Solution remapping (registration.partial_updates, on in the LiDAR presets): in a corridor the lines still
    observe rotation and sideways motion; only the motion along the corridor is held at the prediction. Holding the
    whole prediction instead loses the rotation (the point map, which would otherwise take the held directions, off)."""
    config = line_odom_core.load_config("kitti_hdl64", {**OVERRIDES, "registration.partial_updates": partial,
                                                        "point_map.enabled": False})
    odom = line_odom_core.Odometry(config)
    frames = _swaying_corridor_frames()
    rotation_errors = []
    prev_delta = np.eye(4)
    for k, (stamp, scan, T) in enumerate(frames):
        res = odom.register_points(scan.points, stamp, ring=scan.ring)
        check_finite(res)
        if k >= 2:  # frame 1 is the first motion: no velocity, nothing to hold
            check_held(res, prev_delta, config)
            assert res.stats["held_directions"] == (1 if partial else 6), res.stats
            rotation_errors.append(frame_error(res.delta, np.linalg.inv(frames[k - 1][2]) @ T)[1])
        prev_delta = res.delta
    if partial:
        assert max(rotation_errors) < 0.05, rotation_errors
    else:
        assert np.mean(rotation_errors) > 0.3, rotation_errors
