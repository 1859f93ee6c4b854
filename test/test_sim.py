"""Tests of the simulator line_odom.sim: sensors, ray casting against analytic answers, scenes, trajectories."""
import numpy as np
import pytest

from line_odom import sim
from line_odom.sim.scene import RayGrid, cast, rotate


def _pose(x=0.0, y=0.0, z=0.0, roll=0.0, pitch=0.0, yaw=0.0):
    T = np.eye(4)
    T[:3, :3] = sim.rpy_matrix(roll, pitch, yaw)
    T[:3, 3] = x, y, z
    return T


def _world(points, T):
    return rotate(np.asarray(points, dtype=float), T[:3, :3]) + T[:3, 3]


@pytest.fixture(scope="module")
def street():
    return sim.street_scene(length_m=1000, seed=3)


@pytest.fixture(scope="module")
def drive(street):
    return sim.street_drive(street, seed=3)


# --- sensors: beam patterns and organized layout ----------------------------------------------------------------

@pytest.mark.parametrize("make,shape,top,bottom", [
    (sim.Lidar.hdl64, (64, 2083), 2.0, -24.9),
    (sim.Lidar.vlp16, (16, 1800), 15.0, -15.0),
    (lambda: sim.Lidar.os128(), (128, 1024), 22.5, -22.5),
    (lambda: sim.Lidar.os128(columns=2048), (128, 2048), 22.5, -22.5),
])
def test_organized_shape_matches_beam_pattern(make, shape, top, bottom):
    lidar = make()
    assert lidar.shape == shape
    el = np.degrees(lidar.elevations)
    assert el[0] == pytest.approx(top, abs=1e-9) and el[-1] == pytest.approx(bottom, abs=1e-9)
    assert np.all(np.diff(el) < 0), "rows must be ordered by elevation, top to bottom"
    scan = lidar.scan(sim.ground_scene(), _pose(z=1.73))
    assert scan.organized.shape == shape + (3,) and scan.organized.dtype == np.float32
    assert scan.range.shape == shape and scan.label.shape == shape
    assert scan.points.dtype == np.float32 and scan.ring.dtype == np.uint16 and scan.points.shape == (len(scan.ring), 3)
    # The unorganized view is the organized image's valid cells, ring by ring.
    np.testing.assert_array_equal(scan.points, scan.organized[scan.ring, scan.column])
    assert np.all(np.diff(scan.ring.astype(int)) >= 0)
    # Each point's elevation is its ring's beam elevation and its azimuth its column's.
    p = scan.points.astype(float)
    np.testing.assert_allclose(np.arcsin(p[:, 2] / np.linalg.norm(p, axis=1)), lidar.elevations[scan.ring], atol=1e-5)
    az = np.arctan2(p[:, 1], p[:, 0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (az - lidar.azimuths[scan.column]))), 0, atol=1e-5)


def test_hdl64_beam_table_has_two_blocks():
    el = sim.hdl64_elevations_deg()
    spacing = -np.diff(el)
    np.testing.assert_allclose(spacing[:31], 1 / 3, atol=1e-9)
    assert np.all((spacing[32:] > 0.45) & (spacing[32:] < 0.56))
    lidar = sim.Lidar.hdl64()
    assert np.degrees(lidar.grid.step) == pytest.approx(0.1728, abs=1e-4)
    # Column W/2 looks forward (+x): its azimuth is within half a step of zero.
    assert abs(lidar.azimuths[lidar.shape[1] // 2]) <= lidar.grid.step / 2 + 1e-12


# --- analytic ray casts -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("height", [1.73, 0.5, 3.0])
def test_lidar_sees_ground_at_minus_height(height):
    lidar = sim.Lidar.hdl64()
    scan = lidar.scan(sim.ground_scene(), _pose(x=12.0, y=-40.0, z=height, yaw=0.7))
    np.testing.assert_allclose(scan.points[:, 2], -height, atol=2e-5 * 120)
    # Range of every ground return is height / sin(-elevation); upward beams have no return (NaN).
    el = lidar.elevations[:, None]
    expected = np.where(el < 0, height / np.sin(-np.minimum(el, -1e-9)), np.nan)
    expected[~(expected <= lidar.max_range) | ~(expected >= lidar.min_range)] = np.nan
    assert len(scan) == lidar.shape[1] * np.count_nonzero(np.isfinite(expected)) > 50_000
    np.testing.assert_allclose(scan.range, np.broadcast_to(expected, lidar.shape), rtol=1e-5)
    assert np.all(np.isnan(scan.organized[lidar.elevations >= 0]))


def test_ground_returns_with_noise_have_requested_spread():
    lidar = sim.Lidar.vlp16(noise_std=0.05, seed=1)
    scan = lidar.scan(sim.ground_scene(), _pose(z=1.0))
    el = lidar.elevations[scan.ring]
    residual = np.linalg.norm(scan.points, axis=1) - 1.0 / np.sin(-el)
    assert residual.std() == pytest.approx(0.05, rel=0.05)
    assert abs(residual.mean()) < 0.005


def test_single_wall_returns_analytic_distance():
    d = 6.5
    scene = sim.wall_scene(distance=d)
    lidar = sim.Lidar.os128(columns=2048)
    scan = lidar.scan(scene, _pose(z=1.73))
    assert len(scan) > 1000
    p = scan.points.astype(float)
    np.testing.assert_allclose(p[:, 1], d, atol=1e-4)           # the face y = d
    el, az = lidar.elevations[scan.ring], lidar.azimuths[scan.column]
    expected = d / (np.cos(el) * np.sin(az))                    # range along the ray to y = d
    np.testing.assert_allclose(scan.range[scan.ring, scan.column], expected, rtol=1e-5)
    # The ray straight at the wall (azimuth 90 deg, elevation ~0) measures d.
    cols = np.argsort(np.abs(lidar.azimuths - np.pi / 2))[:1]
    row = np.argmin(np.abs(lidar.elevations))
    assert scan.range[row, cols[0]] == pytest.approx(d / np.cos(lidar.elevations[row]) /
                                                      np.sin(lidar.azimuths[cols[0]]), rel=1e-6)
    # Nothing right of the sensor, nothing above the wall top (10 m) or below its bottom (0 m).
    assert np.all(np.isnan(scan.range[:, lidar.azimuths < 0]))
    assert np.all((p[:, 2] + 1.73 > -1e-3) & (p[:, 2] + 1.73 < 10 + 1e-3))


def test_box_and_cylinder_distances_analytic():
    b = sim.SceneBuilder()
    b.add_cylinder(10.0, 0.0, -5.0, 5.0, 0.5, "pole")                        # ahead: surface at x = 9.5
    b.add_box([0.0, -8.0, 0.0], [4.0, 2.0, 10.0], np.pi / 4, "box")         # right of the sensor, yawed
    scene = b.build()
    lidar = sim.Lidar([0.0], 3600, min_range=0.1, max_range=50.0)
    scan = lidar.scan(scene, np.eye(4))
    fwd = np.argmin(np.abs(lidar.azimuths))
    # Exactly: the ray at azimuth a hits the circle (x-10)^2 + y^2 = 0.25 at the smaller root.
    a = lidar.azimuths[fwd]
    u = np.array([np.cos(a), np.sin(a)])
    bq = -2 * u @ [10.0, 0.0]
    t = (-bq - np.sqrt(bq * bq - 4 * (100 - 0.25))) / 2
    assert scan.range[0, fwd] == pytest.approx(t, abs=1e-5)
    assert scene.kinds[scan.label[0, fwd]] == "pole"
    # The yawed box: every hit lies on its surface and the ray straight down -y meets the corner-facing edge.
    hits = scan.label[0] == scene.kinds.index("box")
    assert hits.any()
    assert np.abs(scene.distance(scan.organized[0, hits])).max() < 1e-4
    right = np.argmin(np.abs(lidar.azimuths + np.pi / 2))
    # Box footprint rotated 45 deg: the ray along -y meets its local face y' = +1 at x' = 1, i.e. at y = -8 + sqrt 2.
    assert scan.range[0, right] == pytest.approx(8.0 - np.sqrt(2.0), abs=0.01)
    # True normals: horizontal on the pole pointing away from its axis; on the box one of the yawed faces' normals,
    # facing the sensor; intensity = albedo * |cos incidence| within [0, 1].
    lab = scan.label[scan.ring, scan.column]
    n = scan.normals.astype(float)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    pole = lab == scene.kinds.index("pole")
    radial = scan.points[pole, :2] - [10.0, 0.0]
    np.testing.assert_allclose(n[pole, :2], radial / np.linalg.norm(radial, axis=1, keepdims=True), atol=1e-3)
    face = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4)])
    box = lab == scene.kinds.index("box")
    along = np.abs(n[box, :2] @ face)
    assert np.all((np.abs(along - 1) < 1e-6) | (along < 1e-6)) and np.all(n[box, 2] == 0)
    assert np.all(np.sum(n * scan.points, axis=1) < 0)
    cos = np.abs(np.sum(n * scan.points, axis=1)) / np.linalg.norm(scan.points, axis=1)
    np.testing.assert_allclose(scan.intensity, scene.albedo[lab] * cos, atol=1e-5)
    assert scan.intensity.dtype == np.float32 and scan.intensity.shape == (len(scan),)


def test_windowed_cast_equals_brute_force(street, drive):
    """The angular windows, range culling and occlusion culling must not change a single ray's result."""

    class FullGrid(RayGrid):
        def windows(self, corners, center, radius, dmin, dmax):
            out = np.zeros((len(corners), 2, 4), dtype=np.int64)
            out[:, 0] = (0, self.shape[0], 0, self.shape[1])
            return out

    for lidar in (sim.Lidar.vlp16(max_range=100.0), sim.Lidar(sim.hdl64_elevations_deg(), 500, max_range=100.0)):
        full = FullGrid(np.stack([lidar.grid.dx, lidar.grid.dy, lidar.grid.dz], axis=-1))
        for i, tilt in [(5, 0.0), (400, 0.3), (731, -0.2)]:
            T = drive.poses[i] @ _pose(roll=tilt, pitch=-tilt / 2)
            t_fast, lab_fast = cast(street, T, lidar.grid, 100.0)
            t_slow, lab_slow = cast(street, T, full, 100.0, occlusion_culling=False)
            assert (lab_fast >= 0).mean() > 0.5
            np.testing.assert_array_equal(lab_fast, lab_slow)
            np.testing.assert_array_equal(t_fast, t_slow)
    room = sim.room_scene(seed=2)
    cam = sim.DepthCamera(width=160, height=120, fx=130, fy=130)
    camfull = FullGrid(np.stack([cam.grid.dx, cam.grid.dy, cam.grid.dz], axis=-1))
    for T in sim.handheld_path(room, frames=60, seed=2).poses[::20]:
        t_fast, lab_fast = cast(room, T, cam.grid, 8.0)
        t_slow, lab_slow = cast(room, T, camfull, 8.0, occlusion_culling=False)
        np.testing.assert_array_equal(lab_fast, lab_slow)
        np.testing.assert_array_equal(t_fast, t_slow)


def test_street_scan_points_lie_on_scene_surfaces(street, drive):
    lidar = sim.Lidar.hdl64()
    T = drive.poses[250]
    scan = lidar.scan(street, T)
    assert len(scan) > 100_000
    kinds = {street.kinds[k] for k in np.unique(scan.label[scan.label >= 0])}
    assert {"ground", "building", "car", "pole", "kerb"} <= kinds
    sample = scan.points[::37]
    assert street.distance(_world(sample, T)).max() < 2e-3     # float32 points up to 120 m away


# --- no return ---------------------------------------------------------------------------------------------------

def test_no_return_is_nan_for_lidar_and_zero_for_depth():
    scan = sim.Lidar.hdl64().scan(sim.empty_scene(), _pose(z=1.73))
    assert len(scan) == 0 and scan.points.shape == (0, 3) and np.all(np.isnan(scan.organized))
    cam = sim.DepthCamera()
    depth = cam.render(sim.empty_scene(), np.eye(4))
    assert depth.shape == (240, 320) and depth.dtype == np.float32 and not depth.any()
    # Looking level over the ground: the sky half of the image has no return (0), the ground half has depth.
    T = _pose(z=1.5) @ sim.T_BODY_OPTICAL
    depth = cam.render(sim.ground_scene(), T)
    assert not depth[: cam.height // 2 - 1].any()
    assert np.all(depth[cam.height // 2 + 60:] > 0)          # ground nearer than max_depth
    assert np.all(depth[depth > 0] <= cam.max_depth)


def test_everything_beyond_range_gives_no_return_but_is_there():
    scene = sim.far_scene(min_distance=200.0)
    assert len(sim.Lidar.hdl64().scan(scene, _pose(z=1.73))) == 0
    far = sim.Lidar.hdl64(max_range=1000.0).scan(scene, _pose(z=1.73))
    assert len(far) > 1000 and np.linalg.norm(far.points, axis=1).min() >= 200.0 - 1e-3


def test_min_range_and_dropout():
    lidar = sim.Lidar.vlp16(min_range=3.0)
    scan = lidar.scan(sim.ground_scene(), _pose(z=0.5))
    assert np.nanmin(scan.range) >= 3.0
    full = sim.Lidar.vlp16().scan(sim.ground_scene(), _pose(z=1.0))
    dropped = sim.Lidar.vlp16(dropout=0.3, seed=4).scan(sim.ground_scene(), _pose(z=1.0))
    assert len(dropped) / len(full) == pytest.approx(0.7, abs=0.02)


# --- depth camera ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("camera", [sim.DepthCamera(), sim.DepthCamera.kinect()])
def test_depth_back_projects_onto_scene_surfaces(camera):
    room = sim.room_scene(seed=5)
    path = sim.handheld_path(room, frames=90, seed=5)
    for T in path.poses[::45]:
        depth, label = camera.render(room, T, return_labels=True)
        assert depth.shape == camera.shape and (depth > 0).mean() > 0.95
        pts = _world(camera.back_project(depth)[::7], T)
        assert room.distance(pts).max() < 1e-4
        seen = {room.kinds[k] for k in np.unique(label[label >= 0])}
        assert {"room", "desk", "monitor"} <= seen, seen


def test_depth_is_z_not_ray_length():
    cam = sim.DepthCamera(width=64, height=48, fx=40, fy=40)
    wall = sim.SceneBuilder().add_plane([1, 0, 0], -3.0).build()        # x = 3 in the world
    depth = cam.render(wall, sim.T_BODY_OPTICAL)                        # looking along +x
    np.testing.assert_allclose(depth, 3.0, atol=1e-5)
    np.testing.assert_allclose(cam.K, [[40, 0, 31.5], [0, 40, 23.5], [0, 0, 1]])


def test_depth_noise_grows_with_depth_squared():
    wall = sim.SceneBuilder().add_plane([1, 0, 0], -4.0).build()
    cam = sim.DepthCamera(noise_std=0.002, seed=1)
    depth = cam.render(wall, sim.T_BODY_OPTICAL)
    assert (depth - 4.0).std() == pytest.approx(0.002 * 16, rel=0.05)


# --- determinism --------------------------------------------------------------------------------------------------

def test_deterministic_by_seed():
    def run(seed):
        return [(f.stamp, f.data.points.copy(), f.pose) for f in
                sim.simulate("street", frames=3, seed=seed, sensor="vlp16", noise_std=0.02)]
    a, b, c = run(7), run(7), run(8)
    for fa, fb in zip(a, b):
        assert fa[0] == fb[0]
        np.testing.assert_array_equal(fa[1], fb[1])
        np.testing.assert_array_equal(fa[2], fb[2])
    assert not np.array_equal(a[2][2], c[2][2])                 # another seed: another street and drive
    assert a[2][1].shape != c[2][1].shape or not np.array_equal(a[2][1], c[2][1])
    s1, s2 = sim.street_scene(300, seed=11), sim.street_scene(300, seed=11)
    for name in ("box_center", "box_half", "box_yaw", "cyl_xy", "cyl_z", "cyl_radius"):
        np.testing.assert_array_equal(getattr(s1, name), getattr(s2, name))
    assert not np.array_equal(sim.street_scene(300, seed=12).box_center[:5], s1.box_center[:5])
    r1 = [f.data for f in sim.simulate("room", frames=2, seed=3, noise_std=0.001)]
    r2 = [f.data for f in sim.simulate("room", frames=2, seed=3, noise_std=0.001)]
    np.testing.assert_array_equal(r1[1], r2[1])


def test_noise_differs_between_frames_of_one_run():
    frames = list(sim.simulate("ground", frames=2, seed=0, speed=0.0, sensor="vlp16", noise_std=0.01))
    assert not np.array_equal(frames[0].data.points, frames[1].data.points)


# --- trajectories ----------------------------------------------------------------------------------------------

def test_street_drive_one_kilometre(street, drive):
    assert drive.length_m >= 1000.0
    assert len(drive) == len(drive.stamps) == len(drive.poses)
    np.testing.assert_allclose(np.diff(drive.stamps), 0.1)
    step = np.linalg.norm(np.diff(drive.positions, axis=0), axis=1)
    assert 0.85 < step.min() and step.max() < 1.15 and step.mean() == pytest.approx(1.0, abs=0.02)
    R = drive.poses[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # The LiDAR stays at mount height over the ground and on the road (between the kerbs).
    np.testing.assert_allclose(drive.positions[:, 2], 1.73, atol=0.011)
    line = street.meta["centerline"]
    s_dense = line.s_grid
    nearest = np.min(np.linalg.norm(drive.positions[:, None, :2] - line.point(s_dense[::8])[None], axis=2), axis=1)
    assert nearest.max() < sim.scenes.ROAD_HALF_WIDTH - 2.0
    # Nothing but the ground within 1 m of a point 1 m above the road anywhere along the drive (no collisions).
    low = drive.positions.copy()
    low[:, 2] = 1.0
    assert street.distance(low).min() >= 1.0 - 1e-9


def test_trajectories_are_smooth(drive):
    rel = drive.relative()
    # Frame-to-frame motion: forward ~1 m, tiny lateral/vertical, small rotations; it changes little per frame.
    t = rel[:, :3, 3]
    assert np.all(t[:, 0] > 0.8) and np.abs(t[:, 1]).max() < 0.1 and np.abs(t[:, 2]).max() < 0.05
    ang = np.degrees(np.arccos(np.clip((np.trace(rel[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert ang.max() < 2.0
    assert np.abs(np.diff(t, axis=0)).max() < 0.03              # bounded acceleration (m/frame^2)
    assert np.abs(np.diff(ang)).max() < 0.5
    room = sim.room_scene(seed=1)
    hand = sim.handheld_path(room, frames=300, rate_hz=30, seed=1)
    assert hand.frame == "optical" and len(hand) == 300
    ht = np.linalg.norm(hand.relative()[:, :3, 3], axis=1)
    assert 0.001 < ht.mean() < 0.02 and ht.max() < 0.03        # a few mm per frame, like TUM fr1/xyz
    assert np.abs(np.diff(hand.positions, n=2, axis=0)).max() < 1e-3
    # The camera keeps looking at the desk.
    z_axis = hand.poses[:, :3, 2]
    to_target = room.meta["target"] - hand.positions
    cosang = np.sum(z_axis * to_target, axis=1) / np.linalg.norm(to_target, axis=1)
    assert cosang.min() > np.cos(np.radians(15))


def test_street_drive_rejects_a_drive_longer_than_the_street():
    scene = sim.street_scene(length_m=200, seed=0)
    with pytest.raises(ValueError, match="frames"):
        sim.street_drive(scene, frames=1000)
    with pytest.raises(ValueError, match="centreline"):
        sim.street_drive(sim.ground_scene(), frames=10)


def test_frame_conventions_round_trip(drive):
    opt = drive.in_frame("optical")
    np.testing.assert_allclose(opt.in_frame("body").poses, drive.poses, atol=1e-12)
    # Optical z is body x (forward).
    np.testing.assert_allclose(opt.poses[:, :3, 2], drive.poses[:, :3, 0], atol=1e-12)


# --- degenerate scenes -----------------------------------------------------------------------------------------

def test_degenerate_scenes_structure():
    h = 1.73
    empty = list(sim.simulate("empty", frames=2))
    assert all(len(f.data) == 0 and np.all(np.isnan(f.data.organized)) for f in empty)

    ground = next(sim.simulate("ground", frames=1))
    np.testing.assert_allclose(ground.data.points[:, 2], -h, atol=3e-3)
    assert np.all(ground.data.label[ground.data.label >= 0] == 0)

    corridor = list(sim.simulate("corridor", frames=3, speed=2.0))
    width, height = 3.0, 3.0
    for f in corridor:
        p = _world(f.data.points, f.pose)
        on_plane = np.minimum.reduce([np.abs(p[:, 2]), np.abs(p[:, 2] - height), np.abs(np.abs(p[:, 1]) - width / 2)])
        assert on_plane.max() < 1e-3 and len(p) > 10_000
    # Featureless: a scan taken further down the corridor is the same up to float rounding.
    a, b = corridor[0].data, corridor[2].data
    np.testing.assert_array_equal(np.isnan(a.range), np.isnan(b.range))
    np.testing.assert_allclose(a.range, b.range, rtol=1e-5)

    wall = next(sim.simulate("wall", frames=1))
    assert {wall.data.label.max(), wall.data.label[wall.data.label >= 0].min()} == {0}
    np.testing.assert_allclose(wall.data.points[:, 1], 5.0, atol=1e-4)

    assert all(len(f.data) == 0 for f in sim.simulate("far", frames=3))

    noisy = next(sim.simulate("street", frames=1, sensor="vlp16", noise_std=0.5))
    clean = next(sim.simulate("street", frames=1, sensor="vlp16"))
    assert np.all(np.isfinite(noisy.data.points)) and np.all(noisy.data.range[~np.isnan(noisy.data.range)] > 0)
    both = ~np.isnan(noisy.data.range) & ~np.isnan(clean.data.range)
    assert (noisy.data.range[both] - clean.data.range[both]).std() == pytest.approx(0.5, rel=0.05)

    still = list(sim.simulate("street", frames=3, speed=0.0, sensor="vlp16"))
    np.testing.assert_array_equal(still[0].data.organized, still[2].data.organized)
    np.testing.assert_array_equal(still[0].pose, still[2].pose)


def test_simulate_camera_in_room_and_lidar_in_street():
    frames = list(sim.simulate("room", frames=4, seed=1))
    assert all(f.data.shape == (240, 320) and f.data.dtype == np.float32 for f in frames)
    assert [f.stamp for f in frames] == pytest.approx([0, 1 / 30, 2 / 30, 3 / 30])
    run = sim.make("street", frames=5, seed=1, sensor=sim.Lidar.vlp16())
    assert run.trajectory.frame == "body" and len(run) == 5
    cam_run = sim.make("street", frames=2, seed=1, sensor="depth")
    assert cam_run.trajectory.frame == "optical"
    depth = next(iter(cam_run)).data
    assert (depth > 0).mean() > 0.2


@pytest.mark.parametrize("kwargs, match", [
    ({"kind": "moon"}, "kind"),
    ({"frames": 0}, "frames"),
    ({"sensor": "hdl32"}, "sensor"),
])
def test_simulate_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sim.make(**kwargs)


def test_bad_sensor_and_pose_arguments():
    with pytest.raises(ValueError, match="min_range"):
        sim.Lidar.vlp16(min_range=200.0)
    with pytest.raises(ValueError, match="dropout"):
        sim.DepthCamera(dropout=1.0)
    with pytest.raises(ValueError, match="T_world_sensor"):
        sim.Lidar.vlp16().scan(sim.ground_scene(), np.eye(3))
    with pytest.raises(ValueError, match="T_world_sensor"):
        sim.Lidar.vlp16().scan(sim.ground_scene(), np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="add_box"):
        sim.SceneBuilder().add_box([0, np.nan, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="add_cylinder"):
        sim.SceneBuilder().add_cylinder(0, 0, 1, 0, 0.1)
    with pytest.raises(ValueError, match="add_plane"):
        sim.SceneBuilder().add_plane([0, 0, 0], 1.0)


# --- export to dataset layouts ------------------------------------------------------------------------------------

def test_write_kitti_reads_back_with_the_dataset_reader(tmp_path):
    from line_odom.datasets import KittiSequence

    run = sim.make("street", frames=3, seed=2, sensor="vlp16")
    sim.write_kitti(run, tmp_path / "seq")
    seq = KittiSequence.open(tmp_path / "seq")
    frames = list(run)
    assert len(seq) == 3
    np.testing.assert_allclose(seq.times, [f.stamp for f in frames])
    T0_inv = np.linalg.inv(frames[0].pose)
    for i, f in enumerate(frames):
        pts = seq.points(i)
        np.testing.assert_array_equal(pts[:, :3], f.data.points)
        np.testing.assert_array_equal(pts[:, 3], f.data.intensity)
        np.testing.assert_allclose(seq.poses[i], T0_inv @ f.pose, atol=1e-8)
    with pytest.raises(ValueError, match="LiDAR"):
        sim.write_kitti(sim.make("room", frames=1), tmp_path / "bad")


def test_write_tum_reads_back_with_the_dataset_reader(tmp_path):
    from line_odom.datasets import TumSequence

    run = sim.make("room", frames=4, seed=2, sensor=sim.DepthCamera.kinect())
    sim.write_tum(run, tmp_path / "tum")
    seq = TumSequence.open(tmp_path / "tum", camera="fr1")
    frames = list(run)
    np.testing.assert_allclose(seq.K, run.sensor.K)
    assert len(seq) == 4 and np.all(seq.pose_valid)
    for i, f in enumerate(frames):
        np.testing.assert_allclose(seq.depth(i), f.data, atol=0.5 / 5000 + 1e-6)
        np.testing.assert_allclose(seq.poses[i], f.pose, atol=1e-6)


# --- motion during the sweep -------------------------------------------------------------------------------------

def test_sweep_without_motion_equals_single_pose_scan(street, drive):
    lidar = sim.Lidar.vlp16(sectors=7)
    T = drive.poses[120]
    still = lidar.scan(street, T)
    swept = lidar.scan(street, T, T_end=T)
    np.testing.assert_array_equal(still.label, swept.label)
    np.testing.assert_array_equal(still.range, swept.range)
    assert len(swept.blocks) == 7 and swept.blocks[0][0] == 0 and swept.blocks[-1][1] == lidar.shape[1]
    assert not still.time.any()


def test_sweep_with_motion_is_cast_from_the_moving_sensor():
    # Driving at 20 m/s towards a wall 30 m ahead (plane x = 30): the sensor moves 2 m during the sweep.
    wall = sim.SceneBuilder().add_box([30.15, 0, 0], [0.3, 400, 400], 0.0, "wall").build()
    lidar = sim.Lidar.vlp16(sectors=16, rate_hz=10.0)
    T0, T1 = _pose(z=1.0), _pose(x=2.0, z=1.0, yaw=0.05)
    scan = lidar.scan(wall, T0, stamp=5.0, T_end=T1)
    assert len(scan) > 1000
    # Every point lies on the wall when placed with the pose of its column block...
    for T, (c0, c1) in zip(scan.poses, scan.blocks):
        m = (scan.column >= c0) & (scan.column < c1)
        if m.any():
            np.testing.assert_allclose(_world(scan.points[m], T)[:, 0], 30.0, atol=1e-4)
    # ...but not with the start pose: the raw points are distorted by the motion.
    assert np.abs(_world(scan.points, T0)[:, 0] - 30.0).max() > 0.5
    # Per-point time: when the pose of its column's block was taken (the block's middle firing time), within one
    # revolution; later columns saw the wall nearer.
    for (c0, c1) in scan.blocks:
        m = (scan.column >= c0) & (scan.column < c1)
        np.testing.assert_allclose(scan.time[m], (c0 + c1) / 2 / lidar.shape[1] * 0.1, rtol=1e-6)
    fwd = scan.ring == 7
    assert scan.time[fwd].max() < 0.1
    # Interpolated block poses: first/last block near the start/end pose, translation monotone along x.
    assert np.all(np.diff(scan.poses[:, 0, 3]) > 0) and 0 < scan.poses[0, 0, 3] < 0.1 and 1.9 < scan.poses[-1, 0, 3] < 2.0


def test_simulate_with_motion_distortion_and_pose_interpolation():
    traj = sim.street_drive(sim.street_scene(300, seed=1), frames=20, seed=1)
    for i in (0, 7, 19):
        np.testing.assert_allclose(traj.pose_at(traj.stamps[i]), traj.poses[i], atol=1e-9)
    mid = traj.pose_at((traj.stamps[3] + traj.stamps[4]) / 2)
    np.testing.assert_allclose(mid[:3, 3], (traj.poses[3, :3, 3] + traj.poses[4, :3, 3]) / 2, atol=1e-9)
    beyond = traj.pose_at(traj.stamps[-1] + 0.1)       # constant-velocity extrapolation
    step = traj.poses[-1, :3, 3] - traj.poses[-2, :3, 3]
    np.testing.assert_allclose(beyond[:3, 3], traj.poses[-1, :3, 3] + step, atol=1e-9)
    run = sim.make("street", frames=2, seed=1, sensor="vlp16", motion_distortion=True)
    frames = list(run)
    assert frames[1].data.time.max() > 0.09
    np.testing.assert_allclose(frames[1].data.poses[0][:3, 3], run.trajectory.pose_at(
        frames[1].stamp + 0.5 * (frames[1].data.blocks[0][1]) / run.sensor.shape[1] / 10.0)[:3, 3], atol=1e-6)


def test_the_street_speed_can_swing():
    run = sim.make("street", frames=60, seed=0, speed_variation=0.5, speed_period=4.0)
    step = np.linalg.norm(np.diff(np.array(run.trajectory.poses)[:, :3, 3], axis=0), axis=1)
    assert 0.45 < step.min() < 0.55 and 1.45 < step.max() < 1.55  # 10 m/s +-50 % at 10 Hz
    assert np.argmax(step) - np.argmin(step) in (-20, 20)  # half of the 4 s period apart
    default = np.array(sim.make("street", frames=20, seed=0).trajectory.poses)
    same = np.array(sim.make("street", frames=20, seed=0, speed_variation=0.1).trajectory.poses)
    np.testing.assert_array_equal(default, same)


@pytest.mark.parametrize("kw, match", [({"speed_variation": 1.0}, "speed_variation"),
                                       ({"speed_variation": -0.1}, "speed_variation"),
                                       ({"speed_period": 0.0}, "speed_period")])
def test_a_bad_speed_swing_is_refused_naming_it(kw, match):
    with pytest.raises(ValueError, match=match):
        sim.make("street", frames=5, seed=0, **kw)
