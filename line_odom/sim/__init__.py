"""line_odom.sim — a ray-casting simulator for LiDAR and depth cameras with ground truth (numpy only).

Deterministic by seed; pure numpy, vectorised over rays. Used for long runs (KITTI devkit metric), the
``line_odom demo`` built-in input and the degenerate-scene / soak tests.

Conventions (docs/DESIGN.md §3)
    Poses are 4x4 float64 arrays ``T_world_sensor`` with ``x_world = T @ x_sensor``. World: z up, metres.
    LiDAR frame: x forward, y left, z up. Camera optical frame: z forward, x right, y down.
    ``T_BODY_OPTICAL``: ``T_world_optical = T_world_body @ T_BODY_OPTICAL``.

Quick use
    >>> from line_odom import sim
    >>> scene = sim.street_scene(length_m=1000, seed=0)          # street, buildings, poles, cars, trees
    >>> traj = sim.street_drive(scene, frames=100, rate_hz=10, speed=10, seed=0)   # ~1 m per frame
    >>> lidar = sim.Lidar.hdl64(noise_std=0.01, seed=0)          # or Lidar.vlp16(), Lidar.os128(columns=2048)
    >>> scan = lidar.scan(scene, traj.poses[0], stamp=traj.stamps[0])
    >>> scan.organized.shape, scan.points.shape, scan.ring.dtype  # (64, 2083, 3) NaN = no return; (N, 3) f32; uint16
    >>> room = sim.room_scene(seed=0)
    >>> cam = sim.DepthCamera.kinect(noise_std=0.0014)           # 640x480 TUM fr1 intrinsics; DepthCamera() = 320x240
    >>> path = sim.handheld_path(room, frames=300, rate_hz=30, seed=0)   # optical-frame poses
    >>> depth = cam.render(room, path.poses[0])                   # (480, 640) float32 metres, 0 = no return
    >>> for stamp, data, T in sim.simulate("street", frames=50, seed=0):   # lazily, one frame at a time
    ...     pass                                                  # data: LidarScan (or depth image for cameras)

Sensors (``sensors.py``)
    ``Lidar(elevations_deg, columns, *, max_range=120, min_range=1, noise_std=0, dropout=0, seed=0, rate_hz=10,
    sectors=32)`` and the
    presets ``Lidar.hdl64()`` (64 beams +2.0..-24.9 deg, upper block 1/3 deg, lower ~1/2 deg, 2083 columns,
    2.5..120 m), ``Lidar.vlp16()`` (16 beams -15..15 deg step 2, 1800 columns, 0.5..100 m), ``Lidar.os128(columns=
    1024|2048)`` (128 beams +-22.5 deg, 0.3..120 m). Keyword arguments override preset values.
    ``lidar.scan(scene, T, stamp=0.0) -> LidarScan`` with
        ``organized`` (H, W, 3) float32, NaN where no return; row 0 = highest beam (rows top to bottom),
            column c at azimuth ``pi - (c + 0.5) * 2pi / W`` (column 0 looks backwards, x forward is column W/2);
        ``range`` (H, W) float32 (NaN none); ``label`` (H, W) int32 id of the primitive hit (-1 none);
        ``points`` (N, 3) float32 valid returns row by row (= ``xyz``); ``ring`` (N,) uint16 = row;
        ``column`` (N,) int32; ``stamp``; computed on first use: ``intensity`` (N,) float32 in [0, 1] (albedo times
        |cos incidence|) and ``normals`` (N, 3) true surface normals in the sensor frame.
    ``lidar.elevations`` / ``lidar.azimuths`` (radians, row / column order), ``lidar.shape``.
    Noise: Gaussian along the ray, ``noise_std`` metres; ``dropout`` drops that fraction of returns. The noise
    generator is seeded once per sensor: the same seed and scan sequence give identical data (``reseed()``).
    All rays of a sweep leave from one pose (no motion distortion) unless ``scan(..., T_end=T)`` gives the pose one
    revolution later: then columns fire in order over the sweep (``sectors`` pose steps), points stay raw in the
    sensor frame of their firing time and ``scan.time`` (N,) float32 gives it in seconds after ``stamp``.

    ``DepthCamera(width=320, height=240, fx=262.5, fy=262.5, cx=None, cy=None, *, min_depth=0.3, max_depth=8,
    noise_std=0, quadratic_noise=True, dropout=0, seed=0)``; ``DepthCamera.kinect()`` (640x480, fx 517.3, fy 516.5,
    cx 318.6, cy 255.3, 0.5..8 m). ``cam.render(scene, T_world_optical) -> depth`` (H, W) float32 metres, 0 = none
    (``return_labels=True`` adds the primitive ids); ``cam.K`` (3, 3); ``cam.back_project(depth)`` -> (N, 3).
    ``noise_std`` is sigma at 1 m depth, growing with depth squared unless ``quadratic_noise=False``.

Scenes (``scenes.py``; ``scene.py`` has ``Scene``, ``SceneBuilder`` and the ray caster)
    ``street_scene(length_m=1000, seed=0, *, curviness=1.0, margin_m=150)``: ground z = 0, kerbs, buildings
        with setbacks/upper tiers/annexes, cross streets, poles with lamp arms, trees, parked cars; the
        centreline starts at the origin heading +x and curves gently (radius >= 80 m).
    ``room_scene(seed=0)``: office room (hollow box) with desk, monitor, chair, shelf, cabinet, bin, pillar.
    Degenerate: ``empty_scene()``, ``ground_scene()``, ``corridor_scene(width=3, height=3)`` (four infinite
    planes along x), ``wall_scene(distance=5)`` (one wall, face y = distance, no ground), ``far_scene(
    min_distance=200)`` (buildings all beyond range, no ground).
    ``scene.distance(points)``: distance from world points to the nearest surface; ``scene.normals(points,
    labels)``; ``scene.kinds[label]`` names what a label id is ("ground", "building", "car", "pole", ...).
    Build your own: ``SceneBuilder().add_plane(n, d).add_box(center, size, yaw).add_cylinder(x, y, z0, z1, r)
    .build(name)``.

Trajectories (``trajectories.py``) -> ``Trajectory(stamps (N,), poses (N, 4, 4), frame "body"|"optical")``
    with ``length_m``, ``positions``, ``relative()`` (T_(k-1)k), ``pose_at(t)`` (interpolated),
    ``in_frame("optical"|"body")``, iteration over (stamp, pose).
    ``street_drive(scene, frames=None, rate_hz=10, speed=10, seed=0, *, height=1.73, lane_offset=-1.75)``:
        right lane, +-10 % speed, lane drift, small pitch/roll; ``frames=None`` covers the whole street
        (>= ``length_m`` metres of path).
    ``straight_drive(frames, rate_hz=10, speed=10, *, height=1.73, start=(0, 0), heading=0)``.
    ``handheld_path(room, frames=300, rate_hz=30, seed=0, *, amplitude=0.15, angle_deg=4)`` (optical frame).

Runs (``runner.py``)
    ``make(kind, frames=100, seed=0, *, sensor=None, rate_hz=None, speed=None, noise_std=None,
    motion_distortion=False, **scene_kw)``
    -> ``Simulation`` (``.scene``, ``.trajectory``, ``.sensor``, iterable of ``SimFrame(stamp, data, pose)``);
    ``simulate(...)`` = ``iter(make(...))``. Kinds: ``street`` (HDL-64, 10 Hz, 10 m/s), ``room`` (depth camera,
    30 Hz), ``empty``, ``ground``, ``corridor``, ``wall``, ``far`` (HDL-64 driving straight along +x at
    ``speed``, default 10 m/s, 1.73 m up; 1.5 m in the corridor). ``sensor``: a Lidar/DepthCamera or one of
    "hdl64", "vlp16", "os128", "kinect", "depth" (any sensor works in any scene); ``pose`` is always that of the
    sensor frame actually rendered (optical for cameras). ``data`` is a ``LidarScan`` for LiDARs and a depth image
    for cameras. Iterating a ``Simulation`` reseeds its sensor first, so every pass yields the same frames;
    ``run.frame(i)`` renders one frame.

Export (``export.py``)
    ``write_kitti(run, out_dir, Tr=None)`` (velodyne/*.bin with intensity, times.txt, calib.txt, poses.txt) and
    ``write_tum(run, out_dir)`` (16-bit depth PNGs, depth.txt, groundtruth.txt, intrinsics.txt): the readers in
    ``line_odom.datasets`` and peer tools read them unchanged (``DepthCamera.kinect()`` has the fr1 intrinsics).

Timing: ``python -m line_odom.sim [--frames N]`` prints per-sensor milliseconds per frame (HDL-64E street scan
    ~30-50 ms on the 2-core dev VM).

Degenerate inputs for reliability tests
    empty space ``simulate("empty")``; only a ground plane ``"ground"``; long featureless corridor ``"corridor"``;
    all points beyond range ``"far"``; a single wall ``"wall"``; heavy noise ``noise_std=0.5`` (or ``dropout``);
    a frame identical to the previous ``speed=0`` with ``noise_std=0`` (or feed the same frame twice).
"""
from line_odom.sim.export import write_kitti, write_tum
from line_odom.sim.runner import Simulation, SimFrame, make, simulate
from line_odom.sim.scene import Scene, SceneBuilder, cast
from line_odom.sim.scenes import (Centerline, corridor_scene, empty_scene, far_scene, ground_scene, room_scene,
                                  street_scene, wall_scene)
from line_odom.sim.sensors import DepthCamera, Lidar, LidarScan, hdl64_elevations_deg
from line_odom.sim.trajectories import (T_BODY_OPTICAL, Trajectory, handheld_path, look_at, rpy_matrix,
                                        straight_drive, street_drive)

__all__ = [
    "Scene", "SceneBuilder", "cast", "Centerline", "street_scene", "room_scene", "empty_scene", "ground_scene",
    "corridor_scene", "wall_scene", "far_scene", "Lidar", "LidarScan", "DepthCamera", "hdl64_elevations_deg",
    "Trajectory", "T_BODY_OPTICAL", "street_drive", "straight_drive", "handheld_path", "look_at", "rpy_matrix",
    "Simulation", "SimFrame", "make", "simulate", "write_kitti", "write_tum",
]
