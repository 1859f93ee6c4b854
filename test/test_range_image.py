"""Range images (paper §6.2 "Organized point-clouds"): KITTI ring order, ring fields, beam tables, depth
back-projection, holes and downsampling — on the shared KITTI / TUM frames and on synthetic sensors."""
from __future__ import annotations

import numpy as np
import pytest

from line_odom.datasets import kitti_sequence, tum_sequence
from line_odom_core import _core


def kitti_rings_from_wrap(points: np.ndarray) -> np.ndarray:
    """Reference ring ids for KITTI order: a new ring starts where the azimuth in [0, 2pi) wraps."""
    az = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
    starts = np.r_[0, (np.diff(az) < -np.pi).astype(int)]
    return np.cumsum(starts)


def elevation(xyz: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(xyz[..., 2], np.hypot(xyz[..., 0], xyz[..., 1])))


@pytest.mark.parametrize("seq", ["00", "04", "07"])
def test_kitti_organizes_into_64_rings_keeping_most_points(seq):
    points = kitti_sequence(seq).points(0)
    ri = _core.organize_points(points)  # default sensor: hdl64 (KITTI order)
    xyz, valid, src, stats = ri["points"], ri["valid"], ri["source_index"], ri["stats"]
    assert xyz.shape == (64, 2048, 3) and valid.shape == (64, 2048)
    assert stats["row_method"] == "azimuth_wrap"
    kept = valid.sum()
    assert kept == stats["kept_points"]
    assert kept > 0.93 * len(points), kept / len(points)  # measured 0.95: azimuths are not on an exact grid
    # Holes are NaN, valid cells hold exactly their source point, each source point at most once.
    assert np.isnan(xyz[~valid]).all() and np.isfinite(xyz[valid]).all()
    assert (src[~valid] == -1).all()
    assert len(np.unique(src[valid])) == kept
    np.testing.assert_array_equal(xyz[valid], points[src[valid], :3].astype(np.float64))
    # Rows are the rings of the file, top beam first: median elevation strictly decreasing.
    rings = kitti_rings_from_wrap(points)
    rows = np.nonzero(valid)[0]
    np.testing.assert_array_equal(rows, rings[src[valid]])
    med = np.array([np.median(elevation(xyz[r][valid[r]])) for r in range(64)])
    assert np.all(np.diff(med) < 0), med
    assert 1.5 < med[0] < 3.5 and -25.0 < med[-1] < -22.5
    # Columns are azimuth bins (column 0 behind the sensor, clockwise): within one bin of the point's azimuth.
    r, c = np.nonzero(valid)
    az = np.arctan2(xyz[r, c, 1], xyz[r, c, 0])
    expected = (np.pi - az) / (2 * np.pi) * 2048
    err = np.abs((c + 0.5 - expected + 1024) % 2048 - 1024)
    assert np.max(err) <= 1.5 + 1e-3  # a bin and its free neighbour; the engine's azimuth is good to 2e-6 rad


def test_kitti_elevation_model_when_order_is_lost():
    points = kitti_sequence("07").points(0)
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(points))
    shuffled = points[perm]
    ri = _core.organize_points(shuffled)
    assert ri["stats"]["row_method"] == "elevation"
    valid = ri["valid"]
    assert ri["points"].shape == (64, 2048, 3)
    assert valid.sum() > 0.8 * len(points)
    med = np.array([np.median(elevation(ri["points"][r][valid[r]])) for r in range(64) if valid[r].any()])
    assert np.all(np.diff(med) < 0)
    # Most points land on the ring the file order says (the beam table is the per-ring median elevation;
    # KITTI's per-point elevations scatter by about one beam spacing).
    rings = kitti_rings_from_wrap(points)
    rows = np.nonzero(valid)[0]
    agree = np.abs(rows - rings[perm[ri["source_index"][valid]]]) <= 1
    assert agree.mean() > 0.8, agree.mean()


def test_ring_field_is_used_and_bottom_first_rings_are_flipped():
    points = kitti_sequence("00").points(0)
    rings = kitti_rings_from_wrap(points).astype(np.int32)  # 0 = top beam
    auto = _core.organize_points(points)
    top_first = _core.organize_points(points, ring=rings)
    bottom_first = _core.organize_points(points, ring=63 - rings)  # Velodyne driver convention
    assert top_first["stats"]["row_method"] == "ring"
    for ri in (top_first, bottom_first):
        np.testing.assert_array_equal(ri["valid"], auto["valid"])
        np.testing.assert_array_equal(ri["source_index"], auto["source_index"])


# A VLP-16 numbers its lasers in firing order, -15, +1, -13, +3 ... deg: laser id 2k is the k-th beam from the bottom,
# 2k + 1 the (8 + k)-th. Some drivers pass those ids on as the ring field.
VLP16_LASER_OF_BEAM_FROM_BOTTOM = np.array([0, 2, 4, 6, 8, 10, 12, 14, 1, 3, 5, 7, 9, 11, 13, 15])


def test_rings_numbered_in_firing_order_are_put_in_elevation_order():
    """A ring field that numbers the lasers in firing order (interleaved elevations) gives the rows of the elevation
    order: the same image as the rings numbered from the bottom beam, reported as `ring_by_elevation`."""
    points = kitti_sequence("00").points(0)
    rings = kitti_rings_from_wrap(points).astype(np.int32)  # 0 = top beam
    keep = rings % 4 == 0  # 16 of the 64 lasers, as a VLP-16 over KITTI's field of view
    xyz, from_top = np.ascontiguousarray(points[keep, :3]), rings[keep] // 4
    from_bottom = (15 - from_top).astype(np.int32)
    firing_order = VLP16_LASER_OF_BEAM_FROM_BOTTOM[from_bottom].astype(np.int32)
    ordered = _core.organize_points(xyz, ring=from_bottom, sensor="vlp16")
    interleaved = _core.organize_points(xyz, ring=firing_order, sensor="vlp16")
    assert ordered["stats"]["row_method"] == "ring"
    assert interleaved["stats"]["row_method"] == "ring_by_elevation"
    np.testing.assert_array_equal(interleaved["valid"], ordered["valid"])
    np.testing.assert_array_equal(interleaved["source_index"], ordered["source_index"])
    # A ring without a point (a laser blocked) leaves the others in elevation order.
    blocked = firing_order != VLP16_LASER_OF_BEAM_FROM_BOTTOM[5]
    partial = _core.organize_points(np.ascontiguousarray(xyz[blocked]), ring=firing_order[blocked], sensor="vlp16")
    rows = [np.median(elevation(partial["points"][r][partial["valid"][r]])) for r in range(16) if partial["valid"][r].any()]
    assert len(rows) == 15 and np.all(np.diff(rows) < 0)


def synthetic_vlp16(range_m: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    el = np.radians(np.arange(-15, 16, 2.0))  # 16 beams
    az = np.radians(np.arange(1800) * 0.2 + 0.1)
    E, A = np.meshgrid(el, az, indexing="ij")
    xyz = range_m * np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)
    ring = np.broadcast_to(np.arange(16)[:, None], E.shape)
    order = np.argsort(A, axis=None, kind="stable")  # column-major firing order, as drivers publish it
    return xyz.reshape(-1, 3)[order].astype(np.float32), ring.reshape(-1)[order].astype(np.int32)


@pytest.mark.parametrize("with_ring", [False, True])
def test_vlp16_preset_by_elevation_or_ring(with_ring):
    xyz, ring = synthetic_vlp16()
    ri = _core.organize_points(xyz, ring=ring if with_ring else None, sensor="vlp16")
    assert ri["points"].shape == (16, 1800, 3)
    assert ri["stats"]["row_method"] == ("ring" if with_ring else "elevation")
    assert ri["valid"].all()
    el = elevation(ri["points"])
    np.testing.assert_allclose(el, np.arange(15, -16, -2.0)[:, None] * np.ones((1, 1800)), atol=1e-4)


def test_os128_preset_shape():
    el = np.radians(np.linspace(22.5, -22.5, 128))
    az = np.radians(np.arange(1024) * 360.0 / 1024 + 0.1)
    E, A = np.meshgrid(el, az, indexing="ij")
    xyz = 5.0 * np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)
    ri = _core.organize_points(xyz, sensor="os128")
    assert ri["points"].shape == (128, 1024, 3)
    assert ri["valid"].all()


def test_invalid_and_out_of_range_points_are_holes():
    xyz, _ = synthetic_vlp16()
    xyz = xyz.astype(np.float64)
    xyz[0] = np.nan
    xyz[1] = [np.inf, 0, 0]
    xyz[2] = 0.0
    xyz[3] *= 100.0  # 1000 m: beyond max_range
    xyz[4] *= 0.01  # 0.1 m: below min_range
    ri = _core.organize_points(xyz, sensor="vlp16", min_range=0.5, max_range=200.0)
    st = ri["stats"]
    assert st["invalid_points"] == 3 and st["out_of_range"] == 2
    assert st["kept_points"] == len(xyz) - 5 == ri["valid"].sum()
    assert not np.isin(np.arange(5), ri["source_index"]).any()


def test_organize_points_rejects_bad_input():
    xyz, ring = synthetic_vlp16()
    with pytest.raises(ValueError, match="points"):
        _core.organize_points(xyz[:, :2])
    with pytest.raises(ValueError, match="ring"):
        _core.organize_points(xyz, ring=ring[:-1], sensor="vlp16")
    with pytest.raises(ValueError, match="ring"):
        _core.organize_points(xyz, ring=ring + 1, sensor="vlp16")  # 16 is outside [0, 16)
    with pytest.raises(ValueError, match="unknown preset"):
        _core.organize_points(xyz, sensor="hdl32e")
    with pytest.raises(ValueError, match="downsample"):
        _core.organize_points(xyz, sensor="vlp16", downsample=0)
    with pytest.raises(ValueError, match="range"):
        _core.organize_points(xyz, sensor="vlp16", min_range=5.0, max_range=1.0)


@pytest.mark.parametrize("step,shape", [(6, (11, 342)), (8, (8, 256)), (10, (7, 205))])
def test_downsampling_keeps_every_step_th_row_and_column(step, shape):
    points = kitti_sequence("00").points(1)
    full = _core.organize_points(points)
    ds = _core.organize_points(points, downsample=step)
    assert ds["points"].shape == shape + (3,)
    np.testing.assert_array_equal(ds["valid"], full["valid"][::step, ::step])
    np.testing.assert_array_equal(ds["source_index"], full["source_index"][::step, ::step])
    # ~1/step^2 of the points remain
    ratio = ds["valid"].sum() / full["valid"].sum()
    assert 0.5 / step**2 < ratio < 1.5 / step**2


def test_tum_depth_back_projection():
    tum = tum_sequence(300)
    depth = tum.depth(0)
    K = tum.K
    ri = _core.organize_depth(depth, K)
    xyz, valid = ri["points"], ri["valid"]
    assert xyz.shape == (480, 640, 3)
    np.testing.assert_array_equal(valid, depth > 0)
    v, u = np.nonzero(valid)
    z = depth[v, u].astype(np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    np.testing.assert_allclose(xyz[v, u, 0], (u - cx) * z / fx, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(xyz[v, u, 1], (v - cy) * z / fy, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(xyz[v, u, 2], z, rtol=1e-6)
    ds = _core.organize_depth(depth, K, downsample=10)
    assert ds["points"].shape == (48, 64, 3)
    np.testing.assert_array_equal(ds["valid"], valid[::10, ::10])
    np.testing.assert_array_equal(ds["points"][ds["valid"]], xyz[::10, ::10][ds["valid"]])


def test_depth_holes_and_limits():
    K = np.array([[500.0, 0, 32], [0, 500.0, 24], [0, 0, 1]])
    depth = np.full((48, 64), 2.0, dtype=np.float32)
    depth[0, 0] = np.nan
    depth[0, 1] = np.inf
    depth[0, 2] = 0.0
    depth[0, 3] = -1.0
    depth[0, 4] = 9.0  # beyond max_depth
    ri = _core.organize_depth(depth, K, max_depth=8.0)
    assert not ri["valid"][0, :5].any() and ri["valid"].sum() == 48 * 64 - 5
    assert ri["stats"]["invalid_points"] == 4 and ri["stats"]["out_of_range"] == 1
    with pytest.raises(ValueError, match="depth"):
        _core.organize_depth(depth[None], K)
    with pytest.raises(ValueError, match="K"):
        _core.organize_depth(depth, np.zeros((3, 3)))
