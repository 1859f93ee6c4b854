"""The static world of the simulator and ray casting into it.

A :class:`Scene` holds three kinds of primitives in the world frame (z up, metres):

- infinite planes ``n·x + delta = 0``;
- boxes with a centre, half extents and a yaw about the world z axis (a box that contains the sensor is seen
  from the inside, so one box makes a room: floor, ceiling and four walls);
- vertical cylinders (axis parallel to world z) with a bottom and a top cap.

Ray casting is analytic and vectorised over rays: for every box and cylinder the rays that can hit it are
bounded by an angular window (a contiguous block of the sensor's ray grid, see ``RayGrid.windows``), primitives
are visited near to far, and a primitive whose window is already covered by nearer hits is skipped. Primitives
farther than the sensor's maximum range are culled by their bounding sphere before anything else.
"""
from __future__ import annotations

import dataclasses

import numpy as np

# Corner sign pattern of a box (8, 3) and its 12 edges as index pairs into the corners.
_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
_BOX_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                       if np.count_nonzero(_CORNER_SIGNS[i] != _CORNER_SIGNS[j]) == 1])


# Diffuse reflectivity by primitive kind (LiDAR intensity = albedo * |cos incidence|).
_ALBEDO = {"ground": 0.2, "floor": 0.3, "kerb": 0.35, "building": 0.5, "car": 0.75, "pole": 0.6, "tree": 0.3,
           "room": 0.6, "wall": 0.55, "ceiling": 0.7}


def rotate(points: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``points @ R.T`` for (N, 3) points, written out: a BLAS matmul of an (N, 3) by (3, 3) array is slow (and
    threads badly on a loaded machine)."""
    p = np.asarray(points)
    return p[:, 0:1] * R[:, 0] + p[:, 1:2] * R[:, 1] + p[:, 2:3] * R[:, 2]


def yaw_matrix(yaw: float | np.ndarray) -> np.ndarray:
    """Rotation(s) about z: (3, 3) for a scalar yaw, (N, 3, 3) for an array."""
    yaw = np.asarray(yaw, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(yaw.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


class SceneBuilder:
    """Collects primitives; :meth:`build` freezes them into a :class:`Scene`. Each primitive has a ``kind`` tag
    ("ground", "building", "car", "pole", ...) that ends up in ``Scene.kinds`` (indexed by primitive id)."""

    def __init__(self) -> None:
        self._planes: list[tuple[np.ndarray, float, str]] = []
        self._boxes: list[tuple[np.ndarray, np.ndarray, float, str]] = []
        self._cylinders: list[tuple[float, float, float, float, float, str]] = []

    def add_plane(self, normal, delta: float, kind: str = "plane") -> "SceneBuilder":
        n = np.asarray(normal, dtype=float).reshape(3)
        norm = np.linalg.norm(n)
        if not (norm > 0 and np.isfinite(norm) and np.isfinite(delta)):
            raise ValueError(f"add_plane: normal must be a finite non-zero 3-vector and delta finite, got {normal!r}, {delta!r}")
        self._planes.append((n / norm, float(delta) / norm, kind))
        return self

    def add_box(self, center, size, yaw: float = 0.0, kind: str = "box") -> "SceneBuilder":
        """``size`` is the full extent (length along the yawed x, width along y, height along z)."""
        c = np.asarray(center, dtype=float).reshape(3)
        s = np.asarray(size, dtype=float).reshape(3)
        if not np.all(s > 0) or not np.all(np.isfinite(np.r_[c, s, yaw])):
            raise ValueError(f"add_box: need a finite center and yaw and three positive finite extents, "
                             f"got center={center!r}, size={size!r}, yaw={yaw!r}")
        self._boxes.append((c, s / 2.0, float(yaw), kind))
        return self

    def add_cylinder(self, x: float, y: float, z0: float, z1: float, radius: float,
                     kind: str = "cylinder") -> "SceneBuilder":
        if not (radius > 0 and z1 > z0) or not np.all(np.isfinite([x, y, z0, z1, radius])):
            raise ValueError(f"add_cylinder: need finite values, radius > 0 and z1 > z0, got x={x}, y={y}, radius={radius}, "
                             f"z0={z0}, z1={z1}")
        self._cylinders.append((float(x), float(y), float(z0), float(z1), float(radius), kind))
        return self

    def build(self, name: str = "", **meta) -> "Scene":
        P, B, C = len(self._planes), len(self._boxes), len(self._cylinders)
        plane_n = np.array([p[0] for p in self._planes]).reshape(P, 3)
        plane_d = np.array([p[1] for p in self._planes]).reshape(P)
        box_c = np.array([b[0] for b in self._boxes]).reshape(B, 3)
        box_h = np.array([b[1] for b in self._boxes]).reshape(B, 3)
        box_yaw = np.array([b[2] for b in self._boxes]).reshape(B)
        cyl = np.array([c[:5] for c in self._cylinders]).reshape(C, 5)
        kinds = tuple([p[2] for p in self._planes] + [b[3] for b in self._boxes] + [c[5] for c in self._cylinders])
        return Scene(plane_n=plane_n, plane_d=plane_d, box_center=box_c, box_half=box_h, box_yaw=box_yaw,
                     cyl_xy=cyl[:, 0:2].copy(), cyl_z=cyl[:, 2:4].copy(), cyl_radius=cyl[:, 4].copy(),
                     kinds=kinds, name=name, meta=dict(meta))


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """Primitives as arrays. Primitive ids (used by label images): planes first, then boxes, then cylinders."""

    plane_n: np.ndarray      # (P, 3) unit normals
    plane_d: np.ndarray      # (P,)   offsets: n·x + d = 0
    box_center: np.ndarray   # (B, 3)
    box_half: np.ndarray     # (B, 3) half extents along the box's own axes
    box_yaw: np.ndarray      # (B,)   rotation about world z
    cyl_xy: np.ndarray       # (C, 2) axis position
    cyl_z: np.ndarray        # (C, 2) bottom and top
    cyl_radius: np.ndarray   # (C,)
    kinds: tuple = ()
    name: str = ""
    meta: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        # Bounding oriented boxes of all finite primitives (boxes, then cylinders) for culling and ray windows.
        box_R = yaw_matrix(self.box_yaw)
        cyl_c = np.column_stack([self.cyl_xy, self.cyl_z.mean(axis=1)]) if len(self.cyl_radius) else np.zeros((0, 3))
        cyl_h = np.column_stack([self.cyl_radius, self.cyl_radius, (self.cyl_z[:, 1] - self.cyl_z[:, 0]) / 2])
        object.__setattr__(self, "box_R", box_R)
        object.__setattr__(self, "bound_center", np.concatenate([self.box_center, cyl_c]).reshape(-1, 3))
        object.__setattr__(self, "bound_half", np.concatenate([self.box_half, cyl_h.reshape(-1, 3)]).reshape(-1, 3))
        object.__setattr__(self, "bound_R", np.concatenate([box_R, np.broadcast_to(np.eye(3), (len(cyl_c), 3, 3))])
                           .reshape(-1, 3, 3))
        object.__setattr__(self, "bound_radius", np.linalg.norm(self.bound_half, axis=1))
        # Diffuse reflectivity per primitive: by kind, varied deterministically per primitive (golden-ratio hash).
        base = np.array([_ALBEDO.get(k, 0.5) for k in self.kinds], dtype=float).reshape(-1)
        vary = (np.arange(len(base)) * 0.6180339887498949) % 1.0
        object.__setattr__(self, "albedo", np.clip(base * (0.8 + 0.4 * vary), 0.0, 1.0))

    @property
    def num_planes(self) -> int:
        return len(self.plane_d)

    @property
    def num_boxes(self) -> int:
        return len(self.box_yaw)

    @property
    def num_cylinders(self) -> int:
        return len(self.cyl_radius)

    def __len__(self) -> int:
        return self.num_planes + self.num_boxes + self.num_cylinders

    def normals(self, points, labels) -> np.ndarray:
        """Outward unit surface normals (N, 3) at world ``points`` (N, 3) lying on the primitives ``labels`` (N,)
        (ids as in label images; -1 gives a zero vector)."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        lab = np.asarray(labels).reshape(-1)
        if len(lab) != len(p):
            raise ValueError(f"labels must have one id per point: {len(lab)} ids for {len(p)} points")
        out = np.zeros_like(p)
        P, B = self.num_planes, self.num_boxes
        m = (lab >= 0) & (lab < P)
        out[m] = self.plane_n[lab[m]]
        m = (lab >= P) & (lab < P + B)
        if m.any():
            i = lab[m] - P
            c, s = np.cos(self.box_yaw[i]), np.sin(self.box_yaw[i])
            d = p[m] - self.box_center[i]
            local = np.column_stack([c * d[:, 0] + s * d[:, 1], c * d[:, 1] - s * d[:, 0], d[:, 2]])
            axis = np.argmin(np.abs(np.abs(local) - self.box_half[i]), axis=1)
            sign = np.sign(local[np.arange(len(i)), axis])
            sign[sign == 0] = 1.0
            n = np.zeros((len(i), 3))
            a0, a1, a2 = axis == 0, axis == 1, axis == 2
            n[a0, 0], n[a0, 1] = c[a0] * sign[a0], s[a0] * sign[a0]
            n[a1, 0], n[a1, 1] = -s[a1] * sign[a1], c[a1] * sign[a1]
            n[a2, 2] = sign[a2]
            out[m] = n
        m = lab >= P + B
        if m.any():
            i = lab[m] - P - B
            radial = p[m, :2] - self.cyl_xy[i]
            rho = np.linalg.norm(radial, axis=1)
            gaps = np.column_stack([np.abs(rho - self.cyl_radius[i]), np.abs(p[m, 2] - self.cyl_z[i, 0]),
                                    np.abs(p[m, 2] - self.cyl_z[i, 1])])
            face = np.argmin(gaps, axis=1)
            n = np.zeros((len(i), 3))
            n[:, :2] = radial / np.maximum(rho, 1e-12)[:, None]
            n[face == 1] = (0.0, 0.0, -1.0)
            n[face == 2] = (0.0, 0.0, 1.0)
            out[m] = n
        return out

    def distance(self, points) -> np.ndarray:
        """Unsigned distance (N,) from world points (N, 3) to the nearest primitive surface (inf if none)."""
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        best = np.full(len(p), np.inf)
        for n, d in zip(self.plane_n, self.plane_d):
            best = np.minimum(best, np.abs(p[:, 0] * n[0] + p[:, 1] * n[1] + p[:, 2] * n[2] + d))
        for c, h, R in zip(self.box_center, self.box_half, self.box_R):
            q = np.abs(rotate(p - c, R.T)) - h
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            inside = np.minimum(q.max(axis=1), 0.0)
            best = np.minimum(best, np.abs(outside + inside))
        for xy, z, r in zip(self.cyl_xy, self.cyl_z, self.cyl_radius):
            q = np.column_stack([np.linalg.norm(p[:, :2] - xy, axis=1) - r, np.abs(p[:, 2] - z.mean()) - (z[1] - z[0]) / 2])
            outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
            inside = np.minimum(q.max(axis=1), 0.0)
            best = np.minimum(best, np.abs(outside + inside))
        return best


class RayGrid:
    """Rays from the sensor origin on an (H, W) grid, directions in the sensor frame as three (H, W) arrays.

    Subclasses say which block(s) of the grid can see a convex set (``windows``). ``t`` along a ray is the range
    for unit directions (LiDAR) or the depth for directions with z = 1 (pinhole camera).
    """

    def __init__(self, directions: np.ndarray, dtype=np.float32) -> None:
        d = np.asarray(directions, dtype=dtype)
        self.shape = d.shape[:2]
        self.dtype = np.dtype(dtype)
        self.dx, self.dy, self.dz = (np.ascontiguousarray(d[..., k]) for k in range(3))
        self.dd = self.dx * self.dx + self.dy * self.dy + self.dz * self.dz

    def windows(self, corners: np.ndarray, center: np.ndarray, radius: np.ndarray,
                dmin: np.ndarray, dmax: np.ndarray) -> np.ndarray:
        """Per convex object (K): up to two blocks (row0, row1, col0, col1) of the grid holding every ray that can
        hit it, as an int array (K, 2, 4) (an unused block is empty: row1 <= row0 or col1 <= col0). Inputs in the
        sensor frame: ``corners`` (K, 8, 3) of its bounding box, its bounding sphere ``center`` (K, 3) and
        ``radius`` (K,), and the nearest/farthest distance of the box from the origin ``dmin``/``dmax`` (K,)."""
        raise NotImplementedError


def _check_pose(T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_world_sensor must be a finite 4x4 pose, got shape {T.shape}")
    return T


def cast(scene: Scene, T_world_sensor: np.ndarray, grid: RayGrid, max_range: float,
         occlusion_culling: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit along every ray: ``t`` (H, W) (inf = no hit within ``max_range``) and the primitive id
    (H, W) int32 (-1 = none). ``max_range`` bounds ``t`` (range for LiDAR, depth for a camera)."""
    return cast_columns(scene, [_check_pose(T_world_sensor)], [(0, grid.shape[1])], grid, max_range, occlusion_culling)


def cast_columns(scene: Scene, poses, column_blocks, grid: RayGrid, max_range: float,
                 occlusion_culling: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`cast`, but the grid's columns ``column_blocks[j] = (c0, c1)`` are cast from ``poses[j]`` (a
    sweeping sensor that moves while it turns)."""
    dt = grid.dtype.type
    H, W = grid.shape
    best = np.full((H, W), np.inf, dtype=grid.dtype)
    label = np.full((H, W), -1, dtype=np.int32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for T, (c0, c1) in zip(poses, column_blocks):
            T = _check_pose(T)
            R_ws, t_ws = T[:3, :3], T[:3, 3]
            b, lab = best[:, c0:c1], label[:, c0:c1]
            dx, dy, dz = grid.dx[:, c0:c1], grid.dy[:, c0:c1], grid.dz[:, c0:c1]
            for i, (n, d) in enumerate(zip(scene.plane_n, scene.plane_d)):
                n_s = R_ws.T @ n
                d_s = float(n @ t_ws + d)
                t = dt(-d_s) / (dx * dt(n_s[0]) + dy * dt(n_s[1]) + dz * dt(n_s[2]))
                hit = (t > 0) & (t < b)
                b[hit] = t[hit]
                lab[hit] = i
            if len(scene.bound_radius):
                _cast_objects(scene, R_ws, t_ws, grid, best, label, max_range, occlusion_culling, c0, c1)
    far = ~(best <= max_range)
    best[far] = np.inf
    label[far] = -1
    return best, label


def _cast_objects(scene, R_ws, t_ws, grid, best, label, max_range, occlusion_culling, col0, col1) -> None:
    dt = grid.dtype.type
    c_rel = scene.bound_center - t_ws
    near = np.linalg.norm(c_rel, axis=1) - scene.bound_radius <= max_range
    ids = np.flatnonzero(near)
    if ids.size == 0:
        return
    R_sb = np.einsum("ji,kjl->kil", R_ws, scene.bound_R[ids])          # R_ws^T R_b
    c_s = rotate(c_rel[ids], R_ws.T)                                      # R_ws^T (c - t)
    half = scene.bound_half[ids]
    corners = c_s[:, None, :] + np.einsum("kij,knj->kni", R_sb, _CORNER_SIGNS[None] * half[:, None, :])
    origin_local = -np.einsum("kji,kj->ki", R_sb, c_s)                   # R_sb^T (0 - c_s)
    q = np.abs(origin_local) - half
    dmin = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    dmax = np.linalg.norm(corners, axis=2).max(axis=1)
    keep = dmin <= max_range
    order = np.flatnonzero(keep)[np.argsort(dmin[keep], kind="stable")]
    if order.size == 0:
        return
    blocks = grid.windows(corners[order], c_s[order], scene.bound_radius[ids[order]], dmin[order], dmax[order])
    blocks[..., 2] = np.maximum(blocks[..., 2], col0)
    blocks[..., 3] = np.minimum(blocks[..., 3], col1)
    used = (blocks[..., 1] > blocks[..., 0]) & (blocks[..., 3] > blocks[..., 2])
    nb, npl = scene.num_boxes, scene.num_planes
    for j, b in zip(*np.nonzero(used)):
        k = order[j]
        pid = ids[k]
        r0, r1, c0, c1 = (int(v) for v in blocks[j, b])
        view = best[r0:r1, c0:c1]
        if occlusion_culling and dmin[k] > 0 and np.all(view <= dmin[k]):
            continue
        dx, dy, dz = grid.dx[r0:r1, c0:c1], grid.dy[r0:r1, c0:c1], grid.dz[r0:r1, c0:c1]
        if pid < nb:
            t = _intersect_box(dx, dy, dz, R_sb[k], origin_local[k], half[k], dt)
        else:
            ci = pid - nb
            base = R_ws.T @ (np.array([*scene.cyl_xy[ci], scene.cyl_z[ci, 0]]) - t_ws)
            t = _intersect_cylinder(dx, dy, dz, grid.dd[r0:r1, c0:c1], R_ws[2], base,
                                    scene.cyl_z[ci, 1] - scene.cyl_z[ci, 0], scene.cyl_radius[ci], dt)
        hit = t < view
        if hit.any():
            view[hit] = t[hit]
            label[r0:r1, c0:c1][hit] = npl + pid


def _intersect_box(dx, dy, dz, R_sb, o, h, dt):
    """Slab test in the box frame; from outside the entry, from inside the exit (the box seen from within)."""
    tnear = None
    for k in range(3):
        dk = dx * dt(R_sb[0, k]) + dy * dt(R_sb[1, k]) + dz * dt(R_sb[2, k])
        inv = dt(1.0) / dk
        ta = dt(-h[k] - o[k]) * inv
        tb = dt(h[k] - o[k]) * inv
        lo, hi = np.fmin(ta, tb), np.fmax(ta, tb)
        if tnear is None:
            tnear, tfar = lo, hi
        else:
            np.fmax(tnear, lo, out=tnear)
            np.fmin(tfar, hi, out=tfar)
    t = np.where(tnear > 0, tnear, tfar)
    t[~((tnear <= tfar) & (tfar > 0))] = np.inf
    return t


def _intersect_cylinder(dx, dy, dz, dd, axis, base, height, radius, dt):
    """Nearest positive hit of a capped cylinder with unit ``axis`` and bottom centre ``base`` (sensor frame).

    Written for float32 rays far from the sensor: the ray's squared distance from the axis comes from the
    constant vector axis x w (exact in float64) instead of a difference of large squares."""
    w = -base                                   # origin relative to the bottom centre
    wa = float(w @ axis)
    ww = float(w @ w)
    axw = np.cross(axis, w)
    da = dx * dt(axis[0]) + dy * dt(axis[1]) + dz * dt(axis[2])
    wd = dx * dt(w[0]) + dy * dt(w[1]) + dz * dt(w[2])
    cross = dx * dt(axw[0]) + dy * dt(axw[1]) + dz * dt(axw[2])      # a·(w x d): perpendicular moment
    A = dd - da * da                                                 # |d_perp|^2
    t_c = (dt(wa) * da - wd) / A                                     # closest approach to the axis
    half2 = (dt(radius * radius) - cross * cross / A) / A            # half chord squared
    half = np.sqrt(np.maximum(half2, 0))
    inside = ww - wa * wa <= radius * radius
    t_side = t_c + half if inside else t_c - half
    axial = dt(wa) + t_side * da
    t = np.where((half2 >= 0) & (t_side > 0) & (axial >= 0) & (axial <= height), t_side, np.inf).astype(dx.dtype)
    for cap in (0.0, height):
        tc = dt(cap - wa) / da
        # squared distance from the axis at the cap hit: |w_perp + tc d_perp|^2, from the moment and the closest point
        rad2 = cross * cross / A + (tc - t_c) ** 2 * A
        ok = (tc > 0) & (rad2 <= radius * radius) & (tc < t)
        t[ok] = tc[ok]
    return t
