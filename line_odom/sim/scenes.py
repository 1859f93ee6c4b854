"""Procedural scenes, deterministic by seed: a street along a curving centreline, an indoor room, and the
degenerate scenes of the reliability tests (empty, ground only, featureless corridor, single wall, all beyond
range)."""
from __future__ import annotations

import numpy as np

from line_odom.sim.scene import Scene, SceneBuilder

ROAD_HALF_WIDTH = 7.0        # kerb line: two lanes and a parking lane each side
SIDEWALK_WIDTH = 3.0
LANE_OFFSET = -1.75          # driving lane centre (right-hand traffic)


class Centerline:
    """A smooth planar curve parameterised by arc length ``s``: heading ``psi(s)`` is a sum of sinusoids
    (psi(0) = 0, position(0) = 0), its curvature bounded by ``max_curvature``."""

    def __init__(self, amplitudes, wavelengths, phases, s0: float, s1: float, step: float = 0.25) -> None:
        self.a = np.asarray(amplitudes, dtype=float)
        self.k = 2 * np.pi / np.asarray(wavelengths, dtype=float)
        self.phi = np.asarray(phases, dtype=float)
        self.s0, self.s1 = float(s0), float(s1)
        self.s_grid = np.arange(self.s0, self.s1 + step, step)
        psi = self.heading(self.s_grid)
        # Positions by trapezoidal integration of the unit tangent, shifted so position(0) = 0.
        tx, ty = np.cos(psi), np.sin(psi)
        x = np.concatenate([[0.0], np.cumsum((tx[1:] + tx[:-1]) / 2 * np.diff(self.s_grid))])
        y = np.concatenate([[0.0], np.cumsum((ty[1:] + ty[:-1]) / 2 * np.diff(self.s_grid))])
        self._x = x - np.interp(0.0, self.s_grid, x)
        self._y = y - np.interp(0.0, self.s_grid, y)

    @classmethod
    def random(cls, rng: np.random.Generator, s0: float, s1: float, curviness: float = 1.0,
               max_curvature: float = 1 / 80) -> "Centerline":
        n = 3
        wavelengths = rng.uniform(180.0, 700.0, n)
        amplitudes = rng.uniform(0.15, 0.5, n) * rng.choice([-1.0, 1.0], n) * float(curviness)
        phases = rng.uniform(0, 2 * np.pi, n)
        kappa = np.abs(np.sum(amplitudes * 2 * np.pi / wavelengths * np.cos(
            np.linspace(s0, s1, 4000)[:, None] * 2 * np.pi / wavelengths + phases), axis=1)).max() if curviness else 0.0
        if kappa > max_curvature:
            amplitudes = amplitudes * (max_curvature / kappa)
        return cls(amplitudes, wavelengths, phases, s0, s1)

    def heading(self, s) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        return np.sum(self.a * (np.sin(self.k * s[..., None] + self.phi) - np.sin(self.phi)), axis=-1)

    def curvature(self, s) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        return np.sum(self.a * self.k * np.cos(self.k * s[..., None] + self.phi), axis=-1)

    def point(self, s) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        return np.stack([np.interp(s, self.s_grid, self._x), np.interp(s, self.s_grid, self._y)], axis=-1)

    def frame(self, s, lateral=0.0):
        """Point at arc length ``s`` moved ``lateral`` metres to the left, and the heading there."""
        psi = self.heading(s)
        p = self.point(s) + np.stack([-np.sin(psi), np.cos(psi)], axis=-1) * np.asarray(lateral)[..., None]
        return p, psi


def street_scene(length_m: float = 1000.0, seed: int = 0, *, curviness: float = 1.0,
                 margin_m: float = 150.0) -> Scene:
    """A street ``length_m`` long (plus ``margin_m`` before and after, so a sensor at either end still sees
    street): flat ground z = 0, kerbs, building blocks of varied length/height with setbacks, upper tiers and low
    front annexes on both sides, cross streets, poles (some with lamp arms), trees (trunk + canopy cylinders) and
    parked cars (body + cabin boxes). The centreline curves gently (``curviness`` 0 = straight) and starts at
    the origin heading along +x; ``scene.meta['centerline']`` lets trajectories follow it."""
    if not length_m > 0:
        raise ValueError(f"length_m must be positive, got {length_m}")
    rng = np.random.default_rng(seed)
    s0, s1 = -float(margin_m), float(length_m) + float(margin_m)
    line = Centerline.random(rng, s0, s1, curviness)
    b = SceneBuilder().add_plane([0, 0, 1], 0.0, "ground")

    # Cross streets: gaps in the kerbs, buildings and parking.
    crossings = []
    s = s0 + rng.uniform(40, 150)
    while s < s1:
        w = rng.uniform(12, 20)
        crossings.append((s, s + w))
        s += w + rng.uniform(120, 280)
    crossings = np.array(crossings).reshape(-1, 2)

    def free(a, c):
        return not np.any((crossings[:, 0] < c) & (crossings[:, 1] > a))

    def box_along(s_mid, lateral, size, z0, kind, yaw_jitter=0.0):
        p, psi = line.frame(s_mid, lateral)
        b.add_box([p[0], p[1], z0 + size[2] / 2], size, psi + yaw_jitter, kind)

    kerb_mid = ROAD_HALF_WIDTH + SIDEWALK_WIDTH / 2
    for side in (1.0, -1.0):
        # Kerbs (raised sidewalks) in 20 m pieces.
        for a in np.arange(s0, s1, 20.0):
            if free(a, a + 20.0):
                box_along(a + 10.0, side * kerb_mid, (20.0, SIDEWALK_WIDTH, 0.15), 0.0, "kerb")
        # Buildings.
        s = s0
        while s < s1:
            length = rng.uniform(8.0, 25.0)
            if not free(s - 2.0, s + length + 2.0):
                s += 3.0
                continue
            setback = rng.uniform(0.0, 3.0) if rng.random() < 0.6 else 0.0
            depth, height = rng.uniform(8.0, 15.0), rng.uniform(6.0, 22.0)
            front = ROAD_HALF_WIDTH + SIDEWALK_WIDTH + setback
            mid = s + length / 2
            box_along(mid, side * (front + depth / 2), (length, depth, height), 0.0, "building")
            if rng.random() < 0.35 and height < 18:      # set-back upper tier
                back = rng.uniform(1.5, 4.0)
                box_along(mid, side * (front + back + (depth - back) / 2),
                          (length * rng.uniform(0.5, 0.9), depth - back, rng.uniform(3.0, 9.0)), height, "building")
            if rng.random() < 0.3 and setback > 1.2:      # low annex in front (shop, porch)
                box_along(mid, side * (front - setback / 2), (length * rng.uniform(0.3, 0.7), setback,
                                                              rng.uniform(2.5, 4.0)), 0.0, "building")
            s += length + (0.0 if rng.random() < 0.4 else rng.uniform(1.0, 6.0))
        # Poles, some with a lamp arm over the road.
        s = s0 + rng.uniform(0, 20)
        while s < s1:
            p, psi = line.frame(s, side * (ROAD_HALF_WIDTH + 0.5))
            top = rng.uniform(5.0, 8.0)
            b.add_cylinder(p[0], p[1], 0.0, top, rng.uniform(0.08, 0.15), "pole")
            if rng.random() < 0.5:
                box_along(s, side * (ROAD_HALF_WIDTH + 0.5 - 0.8), (0.15, 1.6, 0.15), top - 0.3, "pole")
            s += rng.uniform(20.0, 35.0)
        # Trees.
        s = s0 + rng.uniform(0, 15)
        while s < s1:
            if free(s - 3, s + 3) and rng.random() < 0.5:
                p, _ = line.frame(s, side * (ROAD_HALF_WIDTH + 2.0))
                trunk = rng.uniform(2.2, 3.5)
                b.add_cylinder(p[0], p[1], 0.0, trunk, rng.uniform(0.12, 0.25), "tree")
                b.add_cylinder(p[0], p[1], trunk - 0.3, trunk + rng.uniform(2.0, 3.5), rng.uniform(1.0, 1.6), "tree")
            s += rng.uniform(12.0, 25.0)
        # Parked cars along the kerb.
        s = s0
        while s < s1:
            length, width = rng.uniform(3.8, 4.9), rng.uniform(1.65, 1.9)
            if free(s - 1, s + length + 1) and rng.random() < 0.55:
                mid = s + length / 2
                lateral = side * (ROAD_HALF_WIDTH - 0.25 - width / 2)
                jitter = rng.normal(0, 0.03)
                if rng.random() < 0.15:                   # van
                    box_along(mid, lateral, (length + 0.6, width + 0.1, rng.uniform(1.9, 2.3)), 0.25, "car", jitter)
                else:
                    box_along(mid, lateral, (length, width, 0.75), 0.3, "car", jitter)
                    p, psi = line.frame(mid, lateral)
                    back = -0.1 * length
                    b.add_box([p[0] + back * np.cos(psi), p[1] + back * np.sin(psi), 1.05 + 0.25],
                              (0.5 * length, 0.9 * width, 0.5), psi + jitter, "car")
            s += length + rng.uniform(0.8, 3.0)
    return b.build(name="street", centerline=line, length_m=float(length_m), crossings=crossings, seed=seed)


def room_scene(seed: int = 0) -> Scene:
    """An office room seen from inside (one hollow box: floor, ceiling, walls) with a desk (top, legs, monitor,
    keyboard, books), a chair, an open shelf, a cabinet, a bin and a pillar. ``meta['viewpoint']`` and
    ``meta['target']``: where a handheld camera stands and what it looks at (the desk)."""
    rng = np.random.default_rng(seed)
    Lx, Ly, Lz = rng.uniform(5.0, 7.0), rng.uniform(4.0, 6.0), rng.uniform(2.6, 3.0)
    b = SceneBuilder().add_box([0, 0, Lz / 2], [Lx, Ly, Lz], 0.0, "room")
    # Desk against the +x wall.
    dx, dy = Lx / 2 - 0.45, rng.uniform(-Ly / 2 + 1.2, Ly / 2 - 1.2)
    top_z = 0.74
    b.add_box([dx, dy, top_z - 0.02], [0.8, 1.6, 0.04], 0.0, "desk")
    for sx in (-0.35, 0.35):
        for sy in (-0.75, 0.75):
            b.add_box([dx + sx, dy + sy, (top_z - 0.04) / 2], [0.05, 0.05, top_z - 0.04], 0.0, "desk")
    b.add_box([dx + 0.25, dy + rng.uniform(-0.3, 0.3), top_z + 0.35], [0.05, 0.6, 0.38], rng.uniform(-0.2, 0.2), "monitor")
    b.add_box([dx + 0.25, dy, top_z + 0.08], [0.15, 0.1, 0.16], 0.0, "monitor")
    b.add_box([dx - 0.15, dy + rng.uniform(-0.2, 0.2), top_z + 0.015], [0.16, 0.45, 0.03], 0.0, "keyboard")
    for _ in range(3):
        size = [rng.uniform(0.15, 0.3), rng.uniform(0.1, 0.25), rng.uniform(0.03, 0.25)]
        b.add_box([dx + rng.uniform(-0.2, 0.25), dy + rng.choice([-1, 1]) * rng.uniform(0.45, 0.7), top_z + size[2] / 2],
                  size, rng.uniform(-0.5, 0.5), "clutter")
    # Chair in front of the desk.
    chx, chy = dx - 0.75, dy + rng.uniform(-0.3, 0.3)
    b.add_box([chx, chy, 0.47], [0.45, 0.45, 0.06], 0.0, "chair")
    b.add_box([chx - 0.22, chy, 0.75], [0.05, 0.45, 0.5], 0.0, "chair")
    b.add_cylinder(chx, chy, 0.0, 0.44, 0.03, "chair")
    # Open shelf against the -y wall: two sides and four boards.
    shx, depth, width, height = rng.uniform(-Lx / 2 + 0.8, Lx / 2 - 2.0), 0.35, 1.0, 1.8
    shy = -Ly / 2 + depth / 2
    for sx in (-width / 2, width / 2):
        b.add_box([shx + sx, shy, height / 2], [0.03, depth, height], 0.0, "shelf")
    for z in np.linspace(0.05, height - 0.05, 4):
        b.add_box([shx, shy, z], [width, depth, 0.03], 0.0, "shelf")
    # Cabinet against the +y wall, a bin and a pillar.
    b.add_box([rng.uniform(-Lx / 2 + 0.6, Lx / 2 - 1.5), Ly / 2 - 0.25, 0.5], [0.8, 0.5, 1.0], 0.0, "cabinet")
    b.add_cylinder(dx - 0.2, dy + 1.1, 0.0, 0.35, 0.15, "bin")
    b.add_cylinder(rng.uniform(-Lx / 2 + 1.0, 0.0), Ly / 2 - rng.uniform(0.8, 1.5), 0.0, Lz, 0.2, "pillar")
    viewpoint = np.array([dx - rng.uniform(1.4, 1.8), dy + rng.uniform(-0.3, 0.3), rng.uniform(1.3, 1.6)])
    target = np.array([dx, dy, top_z + 0.1])
    return b.build(name="room", size=(Lx, Ly, Lz), viewpoint=viewpoint, target=target, seed=seed)


def empty_scene() -> Scene:
    """Nothing at all: every ray misses."""
    return SceneBuilder().build(name="empty")


def ground_scene() -> Scene:
    """Only the ground plane z = 0."""
    return SceneBuilder().add_plane([0, 0, 1], 0.0, "ground").build(name="ground")


def corridor_scene(width: float = 3.0, height: float = 3.0) -> Scene:
    """An endless featureless corridor along x: floor z = 0, ceiling z = ``height``, walls y = +-width/2 (four
    infinite planes: translation along x is unobservable)."""
    if not (width > 0 and height > 0):
        raise ValueError(f"corridor width and height must be positive, got {width}, {height}")
    return (SceneBuilder().add_plane([0, 0, 1], 0.0, "floor").add_plane([0, 0, 1], -height, "ceiling")
            .add_plane([0, 1, 0], -width / 2, "wall").add_plane([0, 1, 0], width / 2, "wall")
            .build(name="corridor", width=width, height=height))


def wall_scene(distance: float = 5.0, length: float = 200.0, height: float = 10.0) -> Scene:
    """A single wall and nothing else (no ground): its face is the plane y = ``distance`` (to the left of a
    sensor at the origin heading along x), spanning x in [-length/2, length/2] and z in [0, height]."""
    if not (distance > 0 and length > 0 and height > 0):
        raise ValueError(f"wall distance, length and height must be positive, got {distance}, {length}, {height}")
    thickness = 0.3
    return (SceneBuilder().add_box([0.0, distance + thickness / 2, height / 2], [length, thickness, height], 0.0, "wall")
            .build(name="wall", distance=distance))


def far_scene(min_distance: float = 200.0, seed: int = 0) -> Scene:
    """Large buildings all around, all at least ``min_distance`` metres away, no ground: a sensor with a shorter
    range sees nothing, one with a longer range sees the buildings."""
    rng = np.random.default_rng(seed)
    b = SceneBuilder()
    for ang in np.linspace(0, 2 * np.pi, 12, endpoint=False):
        r = min_distance + rng.uniform(10, 100)
        depth = rng.uniform(20, 40)
        c = (r + depth / 2) * np.array([np.cos(ang), np.sin(ang)])
        b.add_box([c[0], c[1], 20.0], [depth, rng.uniform(30, 60), 40.0], ang, "building")
    return b.build(name="far", min_distance=min_distance)
