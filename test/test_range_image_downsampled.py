"""Organizing only the rows and columns that downsampling keeps (organize_points_downsampled /
organize_depth_downsampled in range_image.cpp): the same range image as organizing everything and then
downsampling, on the shared KITTI and TUM frames and on synthetic clouds that exercise the ring-wrap test
near its decision boundaries."""
from __future__ import annotations

import numpy as np
import pytest

from line_odom.datasets import kitti_sequence, tum_sequence
from line_odom_core import _core


def assert_same_image(a: dict, b: dict) -> None:
    np.testing.assert_array_equal(a["valid"], b["valid"])
    np.testing.assert_array_equal(a["points"], b["points"])  # NaN holes compare equal
    if "source_index" in a:
        np.testing.assert_array_equal(a["source_index"], b["source_index"])


@pytest.mark.parametrize("seq", ["00", "04", "07"])
@pytest.mark.parametrize("step", [1, 2, 6, 8, 10])
def test_kitti_kept_rows_only_equals_organize_then_downsample(seq, step):
    for frame in (0, 9):
        points = kitti_sequence(seq).points(frame)  # float32 x, y, z, reflectance (stride 4)
        for pts in (points, points[:, :3].astype(np.float64)):
            ref = _core.organize_points(pts, min_range=2.5, max_range=120.0, downsample=step)
            fast = _core.organize_points(pts, min_range=2.5, max_range=120.0, downsample=step,
                                         downsample_while_organizing=True)
            assert fast["stats"]["row_method"] == ref["stats"]["row_method"] == "azimuth_wrap"
            assert_same_image(fast, ref)
            assert fast["stats"]["kept_points"] == fast["valid"].sum()
            assert fast["stats"]["input_points"] == len(points)
            assert fast["stats"]["invalid_points"] == ref["stats"]["invalid_points"]


def test_ring_field_and_elevation_rows_kept_rows_only():
    points = kitti_sequence("04").points(3)
    az = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
    rings = np.cumsum(np.r_[0, (np.diff(az) < -np.pi).astype(int)]).astype(np.int32)
    shuffled = points[np.random.default_rng(1).permutation(len(points))]  # order lost: elevation rows
    for pts, ring, method in ((points, rings, "ring"), (points, 63 - rings, "ring"), (shuffled, None, "elevation")):
        for step in (1, 3, 6):
            ref = _core.organize_points(pts, ring=ring, downsample=step)
            fast = _core.organize_points(pts, ring=ring, downsample=step, downsample_while_organizing=True)
            assert fast["stats"]["row_method"] == method
            assert_same_image(fast, ref)


def ring_cloud(azimuths_per_ring: list[np.ndarray]) -> np.ndarray:
    """KITTI-order cloud: ring k (top first, HDL-64 beam table) sampled at the given azimuths, 20 m away."""
    el = np.radians(np.linspace(2.6, -23.6, 64))
    rings = []
    for k, az in enumerate(azimuths_per_ring):
        rings.append(20.0 * np.stack([np.cos(el[k]) * np.cos(az), np.cos(el[k]) * np.sin(az),
                                      np.full_like(az, np.sin(el[k]))], axis=-1))
    return np.concatenate(rings)


def test_ring_wraps_on_the_axes():
    # Rings starting exactly on the +x axis (y = 0) or 2e-12 m above or below it: those points are within the
    # margin of the sign test and take the azimuth test; the rows are the true azimuth wraps.
    base = np.radians(np.arange(0.0, 360.0, 0.5))
    az_rings = []
    for k in range(64):
        az = base.copy()
        az[0] = [0.0, 1e-13, 2 * np.pi - 1e-13][k % 3]
        az_rings.append(az)
    xyz = ring_cloud(az_rings)
    ref_az = np.mod(np.arctan2(xyz[:, 1], xyz[:, 0]), 2 * np.pi)
    expected_rings = np.cumsum(np.r_[0, (np.diff(ref_az) < -np.pi).astype(int)])
    assert expected_rings[-1] == 63
    for step in (1, 6):
        ri = _core.organize_points(xyz, downsample=step, downsample_while_organizing=True)
        assert ri["stats"]["row_method"] == "azimuth_wrap"
        assert_same_image(ri, _core.organize_points(xyz, downsample=step))
        rows, _ = np.nonzero(ri["valid"])
        np.testing.assert_array_equal(rows * step, expected_rings[ri["source_index"][ri["valid"]]])


@pytest.mark.parametrize("delta", [1e-3, 1e-5, -1e-5, -1e-3])
def test_ring_wrap_decided_by_the_half_turn(delta):
    # Consecutive points pi + delta apart, going back (azimuth falls): a wrap exactly when delta > 0. At 1e-5 rad
    # the sign test leaves the decision to the azimuths (fast_atan2 is good to 2e-6 rad).
    rings = [np.r_[np.linspace(0.2, np.pi, 40), np.linspace(np.pi + 0.1, 2 * np.pi - 0.2, 40)] for _ in range(64)]
    rings[10] = np.r_[np.linspace(0.2, np.pi, 40), np.pi + 1.0, 1.0 - delta, np.linspace(1.1, 2 * np.pi - 0.2, 30)]
    xyz = ring_cloud(rings)
    ri = _core.organize_points(xyz)
    if delta > 0:
        assert ri["stats"]["row_method"] == "elevation"  # a 65th ring: the order is not trusted
    else:
        assert ri["stats"]["row_method"] == "azimuth_wrap"


@pytest.mark.parametrize("step", [1, 2, 7, 10])
def test_tum_depth_kept_pixels_only_equals_organize_then_downsample(step):
    data = tum_sequence(3)
    for i in range(3):
        depth = data.depth(i)
        ref = _core.organize_depth(depth, data.K, min_depth=0.3, max_depth=6.0, downsample=step)
        fast = _core.organize_depth(depth, data.K, min_depth=0.3, max_depth=6.0, downsample=step,
                                    downsample_while_organizing=True)
        assert_same_image(fast, ref)
        assert fast["stats"]["kept_points"] == fast["valid"].sum()
        assert fast["stats"]["input_points"] == depth.size
        if step == 1:
            assert fast["stats"] == ref["stats"]


def test_downsample_step_must_be_positive():
    points = kitti_sequence("00").points(0)
    with pytest.raises(ValueError, match="downsample"):
        _core.organize_points(points, downsample=0, downsample_while_organizing=True)
    with pytest.raises(ValueError, match="downsample"):
        _core.organize_depth(np.ones((4, 4), np.float32), np.eye(3), downsample=0, downsample_while_organizing=True)
