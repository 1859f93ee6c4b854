"""Ready-made simulated runs: a scene, a trajectory and a sensor, iterated frame by frame."""
from __future__ import annotations

import dataclasses
import math
from typing import Iterator, NamedTuple

import numpy as np

from line_odom.sim import scenes
from line_odom.sim.scene import Scene
from line_odom.sim.sensors import DepthCamera, Lidar
from line_odom.sim.trajectories import Trajectory, handheld_path, straight_drive, street_drive

KINDS = ("street", "room", "empty", "ground", "corridor", "wall", "far")
_SENSORS = {"hdl64": Lidar.hdl64, "vlp16": Lidar.vlp16, "os128": Lidar.os128,
            "kinect": DepthCamera.kinect, "depth": DepthCamera}


class SimFrame(NamedTuple):
    stamp: float
    data: object          # LidarScan for a Lidar, depth image (H, W) float32 for a DepthCamera
    pose: np.ndarray      # T_world_sensor (4, 4) of the rendered sensor frame


@dataclasses.dataclass
class Simulation:
    scene: Scene
    trajectory: Trajectory      # already in the sensor's frame convention
    sensor: Lidar | DepthCamera
    kind: str = ""
    motion_distortion: bool = False

    def __len__(self) -> int:
        return len(self.trajectory)

    def frame(self, i: int) -> SimFrame:
        """Frame ``i`` (noise comes from the sensor's generator in call order; iterate for reproducible runs)."""
        stamp, T = self.trajectory[i]
        if isinstance(self.sensor, Lidar):
            T_end = self.trajectory.pose_at(stamp + 1.0 / self.sensor.rate_hz) if self.motion_distortion else None
            data = self.sensor.scan(self.scene, T, stamp=float(stamp), T_end=T_end)
        else:
            data = self.sensor.render(self.scene, T)
        return SimFrame(float(stamp), data, T.copy())

    def __iter__(self) -> Iterator[SimFrame]:
        self.sensor.reseed()
        for i in range(len(self)):
            yield self.frame(i)


def _sensor(sensor, noise_std, seed):
    if sensor is None or isinstance(sensor, str):
        name = sensor or "hdl64"
        if name not in _SENSORS:
            raise ValueError(f"sensor must be a Lidar, a DepthCamera or one of {sorted(_SENSORS)}, got {sensor!r}")
        kw = {"seed": seed}
        if noise_std is not None:
            kw["noise_std"] = noise_std
        return _SENSORS[name](**kw)
    if not isinstance(sensor, (Lidar, DepthCamera)):
        raise ValueError(f"sensor must be a Lidar, a DepthCamera or a preset name, got {type(sensor).__name__}")
    return sensor


def make(kind: str = "street", frames: int = 100, seed: int = 0, *, sensor=None, rate_hz: float | None = None,
         speed: float | None = None, noise_std: float | None = None, motion_distortion: bool = False,
         speed_variation: float = 0.1, speed_period: float | None = None, **scene_kw) -> Simulation:
    """Build a run of ``frames`` frames. ``street``: HDL-64 on a car at ``speed`` (10 m/s) and ``rate_hz`` (10 Hz)
    through ``street_scene`` (1 km long unless the drive needs more, so runs of up to 1 km share their street for a
    seed). ``room``: depth camera (320x240 ``DepthCamera()`` unless ``sensor`` says otherwise) on a handheld path
    at 30 Hz. Degenerate kinds (``empty``, ``ground``, ``corridor``, ``wall``, ``far``): the sensor drives straight
    along +x at ``speed`` (10 m/s; 0 = standing still). ``noise_std`` applies to preset sensors (default: none).
    ``motion_distortion``: LiDAR sweeps are cast while the sensor moves (see ``Lidar.scan(T_end=...)``); the pose
    of a frame is then the pose at its stamp, when the sweep starts. ``speed_variation``, ``speed_period``
    (``street``): the speed swings by +-that share of it over that many seconds (default +-10 % over 15-40 s)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if int(frames) != frames or frames < 1:
        raise ValueError(f"frames must be a positive integer, got {frames!r}")
    frames = int(frames)
    if kind == "room" and (sensor is None):
        sensor = "depth"
    sensor = _sensor(sensor, noise_std, seed)
    rate = float(rate_hz) if rate_hz is not None else (30.0 if kind == "room" else 10.0)
    v = 10.0 if speed is None else float(speed)
    travel = (1.0 + max(0.1, speed_variation)) * v * (frames - 1) / rate
    if kind == "street":
        length = scene_kw.pop("length_m", max(1000.0, 1000.0 * math.ceil(travel / 1000.0)))
        scene = scenes.street_scene(length_m=length, seed=seed, **scene_kw)
        traj = street_drive(scene, frames, rate, v, seed, speed_variation=speed_variation, speed_period=speed_period)
    elif kind == "room":
        scene = scenes.room_scene(seed=seed, **scene_kw)
        traj = handheld_path(scene, frames, rate, seed)
    else:
        height = 1.73
        if kind == "empty":
            scene = scenes.empty_scene()
        elif kind == "ground":
            scene = scenes.ground_scene()
        elif kind == "corridor":
            scene = scenes.corridor_scene(**scene_kw)
            height = min(height, scene.meta["height"] / 2)
        elif kind == "wall":
            scene = scenes.wall_scene(**{"length": 2 * travel + 400.0, **scene_kw})
        else:
            scene = scenes.far_scene(**{"min_distance": travel + 200.0, "seed": seed, **scene_kw})
        traj = straight_drive(frames, rate, v, height=height)
    traj = traj.in_frame("optical" if isinstance(sensor, DepthCamera) else "body")
    return Simulation(scene, traj, sensor, kind, bool(motion_distortion))


def simulate(kind: str = "street", frames: int = 100, seed: int = 0, **kw) -> Iterator[SimFrame]:
    """Yield ``SimFrame(stamp, data, pose)`` lazily (see :func:`make`)."""
    return iter(make(kind, frames, seed, **kw))
