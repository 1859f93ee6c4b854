"""Simulated sensors: a spinning LiDAR (HDL-64E, VLP-16, Ouster OS-128 patterns) and a pinhole depth camera.

LiDAR frame: x forward, y left, z up. Organized output: row 0 = the highest beam (rows ordered by elevation top to
bottom), column ``c`` at azimuth ``pi - (c + 0.5) * 2 pi / W`` (column 0 looks backwards, azimuth decreases with
the column: the spin is clockwise seen from above; the forward direction x is at column W/2). ``ring`` = row.

Depth camera: optical frame z forward, x right, y down; pixel (u, v) sees direction ((u - cx)/fx, (v - cy)/fy, 1).
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom.sim.scene import _BOX_EDGES, RayGrid, Scene, _check_pose, cast, cast_columns, rotate


def hdl64_elevations_deg() -> np.ndarray:
    """Velodyne HDL-64E (KITTI) beam elevations, top to bottom: an upper block of 32 beams 1/3 degree apart from
    +2.0 degrees and a lower block of 32 beams about 1/2 degree apart down to -24.9 degrees."""
    upper = 2.0 - np.arange(32) / 3.0
    lower = np.linspace(-8.83, -24.9, 32)
    return np.concatenate([upper, lower])


class _SphericalGrid(RayGrid):
    """Rays at (elevation[row], azimuth[col]) with elevations descending and azimuth = pi - (col + 0.5) * step."""

    def __init__(self, elevations: np.ndarray, columns: int, dtype=np.float32) -> None:
        self.elevations = np.asarray(elevations, dtype=float)
        self.columns = int(columns)
        self.step = 2 * np.pi / self.columns
        self.azimuths = np.pi - (np.arange(self.columns) + 0.5) * self.step
        el, az = np.meshgrid(self.elevations, self.azimuths, indexing="ij")
        super().__init__(np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1), dtype)
        self._neg_el = -self.elevations
        self._el_margin = 1e-6 + 0.5 * (np.abs(np.diff(self.elevations)).min() if len(self.elevations) > 1 else 0.0)

    def windows(self, corners, center, radius, dmin, dmax):
        K = len(corners)
        H, W = self.shape
        # Elevation: bound by z extent over distance extent, and by the bounding sphere; intersect both.
        z = corners[..., 2]
        zmin, zmax = z.min(axis=1), z.max(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            el_hi = np.arcsin(np.clip(zmax / np.where(zmax > 0, dmin, dmax), -1, 1))
            el_lo = np.arcsin(np.clip(zmin / np.where(zmin < 0, dmin, dmax), -1, 1))
            cn = np.linalg.norm(center, axis=1)
            outside = cn > radius
            el_c = np.arcsin(np.clip(center[:, 2] / np.where(outside, cn, 1.0), -1, 1))
            half_angle = np.arcsin(np.clip(radius / np.where(outside, cn, 1.0), 0, 1))
        el_hi = np.where(outside, np.minimum(el_hi, el_c + half_angle), el_hi)
        el_lo = np.where(outside, np.maximum(el_lo, el_c - half_angle), el_lo)
        inside = dmin <= 0
        el_hi[inside], el_lo[inside] = np.pi / 2, -np.pi / 2
        r0 = np.searchsorted(self._neg_el, -el_hi - self._el_margin, side="left")
        r1 = np.searchsorted(self._neg_el, -el_lo + self._el_margin, side="right")
        # Azimuth: exact interval of the corners when the box's xy shadow leaves out the sensor axis (a gap > pi).
        az = np.sort(np.arctan2(corners[..., 1], corners[..., 0]), axis=1)
        gaps = np.concatenate([np.diff(az, axis=1), (az[:, :1] + 2 * np.pi - az[:, -1:])], axis=1)
        g = gaps.argmax(axis=1)
        partial = (gaps[np.arange(K), g] > np.pi) & ~inside
        lo = az[np.arange(K), (g + 1) % 8]
        hi = az[np.arange(K), g] + np.where(g == 7, 0.0, 2 * np.pi)
        c0 = np.floor((np.pi - hi) / self.step - 0.5).astype(int) - 1
        c1 = np.ceil((np.pi - lo) / self.step - 0.5).astype(int) + 2
        full = ~partial | (c1 - c0 >= W)
        a = np.where(full, 0, c0 % W)
        b = np.where(full, W, a + (c1 - c0))
        out = np.zeros((K, 2, 4), dtype=np.int64)
        out[:, :, 0], out[:, :, 1] = r0[:, None], r1[:, None]
        out[:, 0, 2], out[:, 0, 3] = a, np.minimum(b, W)
        out[:, 1, 2], out[:, 1, 3] = 0, np.maximum(b - W, 0)        # the part wrapping past the last column
        return out


@dataclasses.dataclass(repr=False)
class LidarScan:
    """One LiDAR sweep. ``organized`` (H, W, 3) float32 with NaN for no return; ``range`` (H, W) float32 (NaN for
    none); ``label`` (H, W) int32 primitive id of the surface hit (-1 none); ``points`` (N, 3) float32 and ``ring``
    (N,) uint16 (= row), ``column`` (N,) the valid returns in row-major order (ring by ring); ``intensity`` (N,)
    float32 in [0, 1] (computed on first use): the surface's albedo times |cos| of the incidence angle;
    ``normals`` (N, 3) the true surface normals in the sensor frame (computed on first use); ``time`` (N,) float32
    seconds from ``stamp`` at which each point was measured (all 0 unless the sweep was cast with motion)."""

    organized: np.ndarray
    range: np.ndarray
    label: np.ndarray
    points: np.ndarray
    ring: np.ndarray
    column: np.ndarray
    time: np.ndarray
    stamp: float = 0.0
    scene: Scene | None = None
    poses: np.ndarray | None = None          # (S, 4, 4) pose each column block was cast from
    blocks: tuple = ()                       # S (c0, c1) column blocks
    directions: tuple | None = None

    def __repr__(self) -> str:
        return f"LidarScan(shape={self.range.shape}, points={len(self.points)}, stamp={self.stamp})"

    @property
    def xyz(self) -> np.ndarray:
        return self.points

    def __len__(self) -> int:
        return len(self.points)

    @functools.cached_property
    def normals(self) -> np.ndarray:
        if self.scene is None:
            raise ValueError("normals need the scene and pose the scan was taken from")
        out = np.zeros(self.points.shape, dtype=np.float32)
        hit = self.label[self.ring, self.column]
        for T, (c0, c1) in zip(self.poses, self.blocks):
            m = (self.column >= c0) & (self.column < c1)
            R, t = T[:3, :3], T[:3, 3]
            out[m] = rotate(self.scene.normals(rotate(self.points[m], R) + t, hit[m]), R.T)
        return out

    @functools.cached_property
    def intensity(self) -> np.ndarray:
        if len(self.points) == 0:
            return np.zeros(0, np.float32)
        dx, dy, dz = self.directions
        r, c = self.ring, self.column
        n = self.normals
        cos = np.abs(n[:, 0] * dx[r, c] + n[:, 1] * dy[r, c] + n[:, 2] * dz[r, c])
        return (self.scene.albedo[self.label[r, c]] * cos).astype(np.float32)


class Lidar:
    """A spinning LiDAR: beams at ``elevations_deg`` (sorted top to bottom here), ``columns`` azimuth steps per
    revolution, returns between ``min_range`` and ``max_range`` metres, optional Gaussian range noise
    ``noise_std`` (m) and random ``dropout`` (fraction of returns lost). Noise is drawn from a generator seeded
    with ``seed``: the same sensor settings, seed and sequence of scans give identical data. ``rate_hz`` (revolutions
    per second) and ``sectors`` (pose steps per revolution) matter only for sweeps cast with motion (``T_end``)."""

    def __init__(self, elevations_deg, columns: int, *, max_range: float = 120.0, min_range: float = 1.0,
                 noise_std: float = 0.0, dropout: float = 0.0, seed: int = 0, name: str = "lidar",
                 rate_hz: float = 10.0, sectors: int = 32, dtype=np.float32) -> None:
        el = np.sort(np.asarray(elevations_deg, dtype=float).ravel())[::-1]
        if el.size == 0 or not np.all(np.abs(el) < 90):
            raise ValueError(f"elevations_deg must be non-empty angles within (-90, 90), got {elevations_deg!r}")
        if int(columns) < 8:
            raise ValueError(f"columns must be >= 8, got {columns}")
        if not (0 <= min_range < max_range):
            raise ValueError(f"need 0 <= min_range < max_range, got min_range={min_range}, max_range={max_range}")
        if not noise_std >= 0:
            raise ValueError(f"noise_std must be >= 0, got {noise_std}")
        if not 0 <= dropout < 1:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        if not rate_hz > 0 or int(sectors) < 1:
            raise ValueError(f"need rate_hz > 0 and sectors >= 1, got rate_hz={rate_hz}, sectors={sectors}")
        self.name = name
        self.rate_hz, self.sectors = float(rate_hz), int(sectors)
        self.elevations_deg = el
        self.max_range, self.min_range = float(max_range), float(min_range)
        self.noise_std, self.dropout, self.seed = float(noise_std), float(dropout), int(seed)
        self.grid = _SphericalGrid(np.radians(el), int(columns), dtype)
        self._rng = np.random.default_rng(self.seed)

    # Presets -------------------------------------------------------------------------------------------------
    @classmethod
    def hdl64(cls, **kw) -> "Lidar":
        """Velodyne HDL-64E as in KITTI: 64 beams +2.0..-24.9 deg, 2083 columns (10 Hz), 120 m."""
        kw = {"max_range": 120.0, "min_range": 2.5, "name": "hdl64", **kw}
        return cls(hdl64_elevations_deg(), kw.pop("columns", 2083), **kw)

    @classmethod
    def vlp16(cls, **kw) -> "Lidar":
        """Velodyne VLP-16: 16 beams -15..+15 deg every 2 deg, 1800 columns (0.2 deg), 100 m."""
        kw = {"max_range": 100.0, "min_range": 0.5, "name": "vlp16", **kw}
        return cls(np.arange(-15.0, 15.0 + 1e-9, 2.0), kw.pop("columns", 1800), **kw)

    @classmethod
    def os128(cls, columns: int = 1024, **kw) -> "Lidar":
        """Ouster OS1-128: 128 beams uniform over +-22.5 deg, 1024 or 2048 columns, 120 m."""
        kw = {"max_range": 120.0, "min_range": 0.3, "name": "os128", **kw}
        return cls(np.linspace(22.5, -22.5, 128), columns, **kw)

    # ---------------------------------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape

    @property
    def elevations(self) -> np.ndarray:
        """Beam elevations in radians, row order (top to bottom)."""
        return self.grid.elevations

    @property
    def azimuths(self) -> np.ndarray:
        """Column azimuths in radians."""
        return self.grid.azimuths

    def reseed(self, seed: int | None = None) -> None:
        """Restart the noise sequence (from ``seed`` or the constructor's seed)."""
        self._rng = np.random.default_rng(self.seed if seed is None else int(seed))

    def sweep_poses(self, T_start, T_end) -> tuple[np.ndarray, list[tuple[int, int]]]:
        """Poses of the ``sectors`` column blocks of a sweep from ``T_start`` (column 0 fires) to ``T_end`` (one
        revolution later): each block at its middle firing time, rotation by slerp, translation linearly."""
        T0, T1 = _check_pose(T_start), _check_pose(T_end)
        W = self.shape[1]
        edges = np.linspace(0, W, min(self.sectors, W) + 1).round().astype(int)
        blocks = [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]
        f = np.array([(a + b) / 2 / W for a, b in blocks])
        rotvec = Rotation.from_matrix(T0[:3, :3].T @ T1[:3, :3]).as_rotvec()
        poses = np.tile(np.eye(4), (len(blocks), 1, 1))
        poses[:, :3, :3] = T0[:3, :3] @ Rotation.from_rotvec(f[:, None] * rotvec).as_matrix()
        poses[:, :3, 3] = (1 - f)[:, None] * T0[:3, 3] + f[:, None] * T1[:3, 3]
        return poses, blocks

    def scan(self, scene: Scene, T_world_sensor, stamp: float = 0.0, *, T_end=None) -> LidarScan:
        """Ray-cast one sweep. Without ``T_end`` every ray leaves from ``T_world_sensor`` (no motion distortion).
        With ``T_end`` (the pose one revolution, ``1 / rate_hz`` s, later) the sensor moves during the sweep:
        column c fires at ``(c + 0.5) / W`` of the revolution, cast in ``sectors`` blocks from interpolated
        poses (each at its block's middle firing time); points stay in the sensor frame of that pose (raw, not
        deskewed) and ``time`` says when it was taken (s after ``stamp``), so that time and geometry agree."""
        if T_end is None:
            poses, blocks = _check_pose(T_world_sensor)[None], [(0, self.shape[1])]
        else:
            poses, blocks = self.sweep_poses(T_world_sensor, T_end)
        rng_img, label = cast_columns(scene, poses, blocks, self.grid, self.max_range)
        valid = np.isfinite(rng_img) & (rng_img >= self.min_range)
        if self.noise_std > 0 or self.dropout > 0:
            idx = np.flatnonzero(valid)
            if self.noise_std > 0:
                flat = rng_img.reshape(-1)
                flat[idx] += self._rng.normal(0.0, self.noise_std, idx.size).astype(flat.dtype)
                valid.reshape(-1)[idx] &= flat[idx] > 0
            if self.dropout > 0:
                lost = idx[self._rng.random(idx.size) < self.dropout]
                valid.reshape(-1)[lost] = False
        rng_img = np.where(valid, rng_img, np.nan).astype(np.float32)
        label = np.where(valid, label, -1).astype(np.int32)
        g = self.grid
        organized = np.stack([g.dx * rng_img, g.dy * rng_img, g.dz * rng_img], axis=-1).astype(np.float32)
        rows, cols = np.nonzero(valid)
        if T_end is None:
            times = np.zeros(len(cols), np.float32)
        else:  # when each column's pose was taken: the middle of its block, as the geometry has it
            column_time = np.empty(self.shape[1])
            for a, b in blocks:
                column_time[a:b] = (a + b) / 2 / self.shape[1] / self.rate_hz
            times = column_time[cols].astype(np.float32)
        return LidarScan(organized=organized, range=rng_img, label=label, points=organized[rows, cols],
                         ring=rows.astype(np.uint16), column=cols.astype(np.int32), time=times, stamp=float(stamp),
                         scene=scene, poses=poses, blocks=tuple(blocks), directions=(g.dx, g.dy, g.dz))


class _PinholeGrid(RayGrid):
    def __init__(self, width, height, fx, fy, cx, cy, dtype=np.float32) -> None:
        self.fx, self.fy, self.cx, self.cy = float(fx), float(fy), float(cx), float(cy)
        u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        super().__init__(np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1), dtype)
        self.near = 1e-3

    def windows(self, corners, center, radius, dmin, dmax):
        H, W = self.shape
        a, b = corners[:, _BOX_EDGES[:, 0]], corners[:, _BOX_EDGES[:, 1]]
        za, zb = a[..., 2] - self.near, b[..., 2] - self.near
        crossing = za * zb < 0
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(crossing, za / (za - zb), 0.0)
        clipped = a + s[..., None] * (b - a)
        pts = np.concatenate([corners, clipped], axis=1)
        ok = np.concatenate([corners[..., 2] > self.near, crossing], axis=1)
        z = np.where(ok, np.maximum(pts[..., 2], self.near), 1.0)
        u = np.clip(self.fx * pts[..., 0] / z + self.cx, -1e9, 1e9)
        v = np.clip(self.fy * pts[..., 1] / z + self.cy, -1e9, 1e9)
        c0 = np.floor(np.where(ok, u, np.inf).min(axis=1)) - 1
        c1 = np.ceil(np.where(ok, u, -np.inf).max(axis=1)) + 2
        r0 = np.floor(np.where(ok, v, np.inf).min(axis=1)) - 1
        r1 = np.ceil(np.where(ok, v, -np.inf).max(axis=1)) + 2
        out = np.zeros((len(corners), 2, 4), dtype=np.int64)
        any_ok = ok.any(axis=1)
        out[:, 0, 0] = np.where(any_ok, np.clip(r0, 0, H), 0)
        out[:, 0, 1] = np.where(any_ok, np.clip(r1, 0, H), 0)
        out[:, 0, 2] = np.where(any_ok, np.clip(c0, 0, W), 0)
        out[:, 0, 3] = np.where(any_ok, np.clip(c1, 0, W), 0)
        return out


class DepthCamera:
    """A pinhole depth camera (optical frame: z forward, x right, y down). ``render`` gives depth in metres (H, W)
    float32 with 0 for no return (nothing within ``max_depth``, or closer than ``min_depth``). Optional noise:
    ``noise_std`` is the depth standard deviation at 1 m; with ``quadratic_noise`` (default, Kinect-like) it grows
    with depth squared, otherwise it is constant. ``dropout`` loses a random fraction of pixels."""

    def __init__(self, width: int = 320, height: int = 240, fx: float = 262.5, fy: float = 262.5,
                 cx: float | None = None, cy: float | None = None, *, min_depth: float = 0.3,
                 max_depth: float = 8.0, noise_std: float = 0.0, quadratic_noise: bool = True,
                 dropout: float = 0.0, seed: int = 0, dtype=np.float32) -> None:
        if int(width) < 2 or int(height) < 2:
            raise ValueError(f"width and height must be >= 2, got {width}x{height}")
        if not (fx > 0 and fy > 0):
            raise ValueError(f"fx and fy must be positive, got fx={fx}, fy={fy}")
        if not (0 <= min_depth < max_depth):
            raise ValueError(f"need 0 <= min_depth < max_depth, got {min_depth}, {max_depth}")
        if not noise_std >= 0:
            raise ValueError(f"noise_std must be >= 0, got {noise_std}")
        if not 0 <= dropout < 1:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        self.width, self.height = int(width), int(height)
        self.fx, self.fy = float(fx), float(fy)
        self.cx = (self.width - 1) / 2 if cx is None else float(cx)
        self.cy = (self.height - 1) / 2 if cy is None else float(cy)
        self.min_depth, self.max_depth = float(min_depth), float(max_depth)
        self.noise_std, self.quadratic_noise, self.dropout = float(noise_std), bool(quadratic_noise), float(dropout)
        self.seed = int(seed)
        self.grid = _PinholeGrid(self.width, self.height, self.fx, self.fy, self.cx, self.cy, dtype)
        self._rng = np.random.default_rng(self.seed)

    @classmethod
    def kinect(cls, **kw) -> "DepthCamera":
        """Kinect v1 as in TUM RGB-D fr1: 640x480, fx 517.3, fy 516.5, cx 318.6, cy 255.3, 0.5..8 m."""
        kw = {"width": 640, "height": 480, "fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3,
              "min_depth": 0.5, "max_depth": 8.0, **kw}
        return cls(**kw)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def reseed(self, seed: int | None = None) -> None:
        self._rng = np.random.default_rng(self.seed if seed is None else int(seed))

    def render(self, scene: Scene, T_world_sensor, *, return_labels: bool = False):
        """Depth image (H, W) float32 metres, 0 = no return; with ``return_labels`` also the primitive ids."""
        depth, label = cast(scene, T_world_sensor, self.grid, self.max_depth)
        valid = np.isfinite(depth) & (depth >= self.min_depth)
        if self.noise_std > 0 or self.dropout > 0:
            idx = np.flatnonzero(valid)
            flat = depth.reshape(-1)
            if self.noise_std > 0:
                z = flat[idx].astype(float)
                sigma = self.noise_std * (z * z if self.quadratic_noise else 1.0)
                flat[idx] = (z + self._rng.normal(0.0, 1.0, idx.size) * sigma).astype(flat.dtype)
                valid.reshape(-1)[idx] &= flat[idx] > 0
            if self.dropout > 0:
                valid.reshape(-1)[idx[self._rng.random(idx.size) < self.dropout]] = False
        depth = np.where(valid, depth, 0.0).astype(np.float32)
        if return_labels:
            return depth, np.where(valid, label, -1).astype(np.int32)
        return depth

    def back_project(self, depth) -> np.ndarray:
        """Points (N, 3) in the optical frame of every pixel with depth > 0 (row-major)."""
        depth = np.asarray(depth, dtype=float)
        v, u = np.nonzero(depth > 0)
        z = depth[v, u]
        return np.column_stack([(u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z])
