"""Scan features (paper §6.2): H/V lines, their normals and 3 clusters, planes — on a synthetic scene of known
planes, on the shared KITTI frames (full, 1/36, 1/64) and TUM depth frames (full, 1/100)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from line_odom.datasets import kitti_sequence, tum_sequence
import line_odom_core
from line_odom_core import _core

# --------------------------------------------------------------------------------------------------
# Synthetic organized scan of known planes: a LiDAR-like fan (rows = elevation, cols = azimuth) ray-cast
# into a box-shaped street (ground, four walls), rotated so nothing depends on the axes.


def rotation(yaw_deg: float, tilt_deg: float) -> np.ndarray:
    y, t = np.radians(yaw_deg), np.radians(tilt_deg)
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    return Rz @ Rx


R_SCENE = rotation(23.0, 4.0)
# (n, delta) in the sensor frame, n towards the sensor: ground 1.7 m below, walls at 6 / 8 m and 5 / 4 m.
PLANES_LOCAL = [((0, 0, 1), 1.7), ((-1, 0, 0), 6.0), ((1, 0, 0), 8.0), ((0, -1, 0), 5.0), ((0, 1, 0), 4.0)]
PLANES = [(R_SCENE @ np.array(n, float), d) for n, d in PLANES_LOCAL]


def synthetic_scan(rows=48, cols=720, noise=0.002, seed=0):
    el = np.radians(np.linspace(8.0, -30.0, rows))
    az = np.radians(180.0 - (np.arange(cols) + 0.5) * 360.0 / cols)
    E, A = np.meshgrid(el, az, indexing="ij")
    rays = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)
    t = np.full(E.shape, np.inf)
    for n, d in PLANES:
        denom = rays @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            ti = -d / denom
        t = np.where((ti > 0) & (ti < t), ti, t)
    rng = np.random.default_rng(seed)
    t = t + rng.normal(0.0, noise, t.shape)
    xyz = rays * t[..., None]
    xyz[~np.isfinite(t) | (t > 60.0)] = np.nan
    return xyz


# The synthetic scan has 2 mm noise: thresholds scaled to it (the KITTI preset is for ~2 cm range noise).
SYNTHETIC_CONFIG = {"lines.split_distance": 0.02, "lines.max_rms": 0.01, "planes.max_distance": 0.03}


def plane_distances(x: np.ndarray) -> np.ndarray:
    """|n·x + delta| to every scene plane, (..., n_planes)."""
    return np.stack([np.abs(x @ n + d) for n, d in PLANES], axis=-1)


def all_lines(f):
    return [(name, f[name]) for name in ("h_lines", "v_lines")]


def assert_finite(f):
    for _, L in all_lines(f):
        for key, arr in L.items():
            assert np.isfinite(arr).all(), key
    for key, arr in f["planes"].items():
        assert np.isfinite(arr).all(), key
    assert np.isfinite(f["cluster_directions"]).all()


# --------------------------------------------------------------------------------------------------


def test_synthetic_lines_lie_on_the_planes_with_their_normals():
    xyz = synthetic_scan()
    f = _core.extract_features(xyz, SYNTHETIC_CONFIG)
    assert_finite(f)
    assert len(f["h_lines"]["rms"]) > 100 and len(f["v_lines"]["rms"]) > 300
    normals = np.array([n for n, _ in PLANES])
    for name, L in all_lines(f):
        seg = L["segments"]
        da, db = plane_distances(seg[:, 0]), plane_distances(seg[:, 1])
        on = (da < 0.01) & (db < 0.01)  # (lines, planes): both end points on the plane = the line lies in it
        # every line lies in a plane (no corner-spanning lines); lines along a corner lie in both planes
        assert on.any(axis=1).all(), name
        # Plücker consistency: unit d, m = a x d
        d, m = L["plucker"][:, :3], L["plucker"][:, 3:]
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-9)
        np.testing.assert_allclose(m, np.cross(seg[:, 0], d), atol=1e-9)
        # surface normals from H/V crossings = the normal of a plane the line lies in, for nearly every line
        known = np.linalg.norm(L["normals"], axis=1) > 0.5
        assert known.mean() > 0.9, name
        cos = np.abs(L["normals"][known] @ normals.T)  # (known lines, planes)
        match = (cos > np.cos(np.radians(3.0))) & on[known]
        # (a short line along a corner whose only crossing is at its end may take the other wall's normal:
        # 1 of ~2000 lines here; such crossings weigh less, normals.end_crossing_weight)
        assert match.any(axis=1).mean() > 0.995, name
        assert (L["rms"] < 0.01).all()  # noise 2 mm; ground rings are curves: chords keep a small sagitta


def test_synthetic_clusters_and_planes():
    f = _core.extract_features(synthetic_scan(), SYNTHETIC_CONFIG)
    axes = R_SCENE.T  # rows: the scene's three directions
    dirs = f["cluster_directions"]
    cos = np.abs(dirs @ axes.T)
    # each cluster direction is one of the scene axes, all three distinct
    assert sorted(np.argmax(cos, axis=1).tolist()) == [0, 1, 2]
    assert np.min(np.max(cos, axis=1)) > np.cos(np.radians(2.0))
    sizes = f["stats"]["cluster_sizes"]
    assert min(sizes) > 50, sizes
    # every line's cluster is the direction nearest to its normal, and nearly all are within 5 deg of it
    for _, L in all_lines(f):
        known = L["cluster"] >= 0
        cos_all = np.abs(L["normals"][known] @ dirs.T)
        np.testing.assert_array_equal(np.argmax(cos_all, axis=1), L["cluster"][known])
        c = cos_all[np.arange(known.sum()), L["cluster"][known]]
        assert np.mean(c > np.cos(np.radians(5.0))) > 0.99
    # the five planes are found (unit normals towards the sensor, delta > 0)
    P = f["planes"]["planes"]
    assert len(P) >= 5
    np.testing.assert_allclose(np.linalg.norm(P[:, :3], axis=1), 1.0, atol=1e-9)
    assert (P[:, 3] > 0).all()
    for n, d in PLANES:
        match = (P[:, :3] @ n > np.cos(np.radians(1.0))) & (np.abs(P[:, 3] - d) < 0.01)
        assert match.any(), (n, d)
    # centroids lie on their planes, lines know their plane
    cen = f["planes"]["centroids"]
    np.testing.assert_allclose(np.sum(P[:, :3] * cen, axis=1) + P[:, 3], 0.0, atol=1e-9)
    for _, L in all_lines(f):
        on = L["plane"] >= 0
        assert on.mean() > 0.8
        seg = L["segments"][on]
        Pl = P[L["plane"][on]]
        assert np.max(np.abs(np.sum(seg[:, 0] * Pl[:, :3], axis=1) + Pl[:, 3])) < 0.02


def test_holes_never_produce_lines():
    xyz = synthetic_scan(seed=1)
    rng = np.random.default_rng(2)
    xyz[rng.random(xyz.shape[:2]) < 0.2] = np.nan
    xyz[:, 100:110] = np.nan  # a 10-column gap
    xyz[5:9] = 0.0  # zero points are holes too
    valid = np.isfinite(xyz).all(axis=2) & (np.abs(xyz).sum(axis=2) > 0)
    f = _core.extract_features(xyz, SYNTHETIC_CONFIG)
    assert_finite(f)
    max_gap = int(_core.feature_config()["lines.max_gap"])
    for name, L in all_lines(f):
        assert len(L["rms"]) > 50
        for i in range(len(L["rms"])):
            line_valid = valid[L["scan_index"][i]] if name == "h_lines" else valid[:, L["scan_index"][i]]
            a, b = L["first"][i], L["last"][i]
            assert a < b and line_valid[a] and line_valid[b]
            holes = ~line_valid[a : b + 1]
            longest, run = 0, 0
            for h in holes:
                run = run + 1 if h else 0
                longest = max(longest, run)
            assert longest <= max_gap
        seg = L["segments"]  # (holes hide corners: a short line may bend within the noise there)
        assert np.max(np.min(plane_distances(seg[:, 0]), axis=1)) < 0.02
    empty = _core.extract_features(np.full((16, 64, 3), np.nan))
    assert len(empty["h_lines"]["rms"]) == len(empty["v_lines"]["rms"]) == len(empty["planes"]["rms"]) == 0
    assert_finite(empty)


def test_config_overrides_and_errors():
    fields = _core.feature_config()
    for name in ("lines.min_points_h", "lines.min_points_v", "lines.max_rms", "lines.split_distance",
                 "normals.max_deviation_deg", "planes.min_points", "planes.max_distance"):
        assert name in fields
    assert line_odom_core.feature_config("tum")["lines.threshold_per_m2"] > 0
    xyz = synthetic_scan()
    no_h = _core.extract_features(xyz, {"lines.min_points_h": 100000})
    assert len(no_h["h_lines"]["rms"]) == 0 and len(no_h["v_lines"]["rms"]) > 0
    no_planes = _core.extract_features(xyz, {"planes.enabled": False})
    assert len(no_planes["planes"]["rms"]) == 0
    with pytest.raises(ValueError, match="unknown feature parameter"):
        _core.extract_features(xyz, {"lines.min_pointz": 3})
    with pytest.raises(ValueError, match="lines.min_points_h"):
        _core.extract_features(xyz, {"lines.min_points_h": 1})
    with pytest.raises(ValueError, match="integer"):
        _core.extract_features(xyz, {"lines.max_gap": 1.5})
    with pytest.raises(ValueError, match="range_image"):
        _core.extract_features(xyz[..., :2])
    with pytest.raises(ValueError, match="preset"):
        line_odom_core.extract_features(xyz, preset="velodyne")


def test_deterministic():
    xyz = synthetic_scan()
    a, b = _core.extract_features(xyz), _core.extract_features(xyz)
    for name, L in all_lines(a):
        for key in L:
            np.testing.assert_array_equal(L[key], b[name][key])


# --------------------------------------------------------------------------------------------------
# Real frames


def kitti_features(seq: str, frame: int = 0, step: int = 1):
    ri = _core.organize_points(kitti_sequence(seq).points(frame), downsample=step)
    return ri, _core.extract_features(ri["points"])


def line_residuals(xyz: np.ndarray, f, preset: str = "kitti") -> tuple[list[np.ndarray], np.ndarray]:
    """Distances of the range-image points each line covers (its scan line, first..last) to the line, and each
    line's threshold scale 1 + a r + b r^2 at its mid-point range (the fit thresholds grow with range)."""
    cfg = line_odom_core.feature_config(preset)
    out, scale = [], []
    for name, L in all_lines(f):
        for i in range(len(L["rms"])):
            s, a, b = L["scan_index"][i], L["first"][i], L["last"][i]
            pts = xyz[s, a : b + 1] if name == "h_lines" else xyz[a : b + 1, s]
            pts = pts[np.isfinite(pts).all(axis=1)]
            d, m = L["plucker"][i, :3], L["plucker"][i, 3:]
            out.append(np.linalg.norm(np.cross(pts, d) - m, axis=1))
            r = np.linalg.norm(L["segments"][i].mean(axis=0))
            scale.append(1 + cfg["lines.threshold_per_m"] * r + cfg["lines.threshold_per_m2"] * r * r)
    return out, np.array(scale)


def assert_lines_fit_their_points(xyz, f, preset="kitti", fraction=0.99):
    """Per line, the median distance of the covered points is within max_rms (at the line's range) for nearly
    every line, and nearly all covered points are within the split threshold (stray skipped points aside)."""
    cfg = line_odom_core.feature_config(preset)
    res, scale = line_residuals(xyz, f, preset)
    med = np.array([np.median(r) for r in res])
    assert np.mean(med <= cfg["lines.max_rms"] * scale) >= fraction, np.mean(med <= cfg["lines.max_rms"] * scale)
    within = np.concatenate([r <= cfg["lines.split_distance"] * s for r, s in zip(res, scale)])
    assert within.mean() > 0.99, within.mean()
    return med


@pytest.mark.parametrize("seq", ["00", "04", "07"])
def test_kitti_ground_plane_and_lines(seq):
    ri, f = kitti_features(seq)
    assert_finite(f)
    st = f["stats"]
    assert st["h_lines"] > 2000 and st["v_lines"] > 4000, st
    assert st["lines_with_normal"] > 0.7 * (st["h_lines"] + st["v_lines"])
    # The ground: the largest plane is level (normal +z within 5 deg) about 1.73 m below the sensor (the
    # HDL-64E's mounting height), and one of the three largest is the road at 1.73 m within 6 cm. (On the 04
    # highway the lanes and shoulders are separate planes: measured 1.98, 1.61, 1.77 m; 00: 1.77, 07: 1.76.)
    P = f["planes"]["planes"]
    assert P[0, 2] > np.cos(np.radians(5.0)) and abs(P[0, 3] - 1.73) < 0.3, P[0]  # 04: a lane banked 3.4 deg
    level = P[:3, 2] > np.cos(np.radians(3.0))
    assert (level & (np.abs(P[:3, 3] - 1.73) < 0.06)).any(), P[:3]
    assert (f["planes"]["rms"] < 0.06).all()
    # Lines lie on the points they cover (a few skipped stray points aside).
    med = assert_lines_fit_their_points(ri["points"], f)
    assert np.median(med) < 0.015, np.median(med)
    lengths = [np.linalg.norm(L["segments"][:, 1] - L["segments"][:, 0], axis=1) for _, L in all_lines(f)]
    assert np.min(np.concatenate(lengths)) >= _core.feature_config()["lines.min_length"] - 1e-9


# Lines per normal cluster, measured on frames 0 and 5: 1/36 00: (436,119,44) (385,163,45),
# 07: (314,166,34) (325,137,40); 1/64 00: (291,47,17) (254,76,17), 07: (205,114,14) (205,112,10).
# Sequence 04 is a highway (road and side barriers): its third direction has 0-4 lines at 1/36, so only its
# first two clusters are held to a floor: 1/36 (486,27,_) (491,27,_), 1/64 (325,2,_) (331,4,_).
@pytest.mark.parametrize("seq,step,floor", [("00", 6, (150, 50, 20)), ("07", 6, (150, 50, 15)),
                                            ("00", 8, (100, 20, 7)), ("07", 8, (100, 40, 5)),
                                            ("04", 6, (200, 12, 0)), ("04", 8, (150, 1, 0))])
def test_kitti_sparse_clusters(seq, step, floor):
    for frame in (0, 5):
        ri, f = kitti_features(seq, frame, step)
        assert_finite(f)
        sizes = f["stats"]["cluster_sizes"]
        assert all(s >= fl for s, fl in zip(sizes, floor)), (frame, sizes)
        P = f["planes"]["planes"]
        assert P[0, 2] > np.cos(np.radians(5.0)) and abs(P[0, 3] - 1.73) < 0.3, P[0]
        assert ((P[:3, 2] > np.cos(np.radians(3.0))) & (np.abs(P[:3, 3] - 1.73) < 0.08)).any(), P[:3]
        assert_lines_fit_their_points(ri["points"], f, fraction=0.98)


@pytest.mark.parametrize("step", [1, 10])
def test_tum_depth_lines_lie_on_the_points(step):
    tum = tum_sequence(300)
    frames = range(0, 300, 30) if step == 10 else (0, 150, 299)
    third = 0
    for i in frames:
        ri = _core.organize_depth(tum.depth(i), tum.K, downsample=step)
        f = line_odom_core.extract_features(ri["points"], preset="tum")
        assert_finite(f)
        # Kinect depth is quantized (~1.3 cm steps at 2 m): thresholds grow with depth squared
        med = assert_lines_fit_their_points(ri["points"], f, preset="tum", fraction=0.98)
        assert np.median(med) < 0.005, np.median(med)
        sizes = f["stats"]["cluster_sizes"]
        if step == 10:
            # fr1/xyz looks down at a desk in front of a wall: desk and wall normals dominate; surfaces facing
            # sideways (monitor, box sides) are few at 64 x 48. Measured on frames 0, 30, .., 270:
            # first cluster 174-290, second 9-180, third 0-12 (53 in all).
            assert sizes[0] >= 100 and sizes[1] >= 4, (i, sizes)
            assert len(f["planes"]["rms"]) >= 1
            third += sizes[2]
        else:
            # measured e.g. (3153, 696, 82)
            assert sizes[0] >= 1000 and sizes[1] >= 200 and sizes[2] >= 30, sizes
    if step == 10:
        assert third >= 25, third


def test_kitti_full_frame_timing():
    """Organize + features on a full KITTI frame; prints the per-stage thread-CPU times. The line-fitting time is
    measured by bench/latency.py (timings on a shared 2-core machine are noisy); here only a loose bound that catches
    an algorithmic regression (the paper's RANSAC line fitting took 3 s)."""
    points = kitti_sequence("00").points(0)
    best = {}
    for _ in range(3):
        t0 = time.perf_counter()
        ri = _core.organize_points(points)
        t1 = time.perf_counter()
        f = _core.extract_features(ri["points"])
        st = f["stats"]
        for k, v in (("organize+convert", (t1 - t0) * 1e3), ("lines", st["lines_ms"]), ("normals", st["normals_ms"]),
                     ("planes", st["planes_ms"])):
            best[k] = min(best.get(k, np.inf), v)
    print("KITTI 00/0 full frame, best of 3 (ms):", {k: round(v, 2) for k, v in best.items()})
    assert best["lines"] < 200.0
