"""The local point map's nearest-point lookup (registration/voxel_points.hpp) against a brute-force search, through
the engine's testing module: it looks in the query's own cube first and skips the cubes no nearer than the nearest
point found so far, which must never skip the nearest point."""
import numpy as np
import pytest

from line_odom_core import _testing


def brute_force(points: np.ndarray, queries: np.ndarray) -> np.ndarray:
    d2 = ((queries[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    return np.sqrt(d2.min(axis=1))


@pytest.mark.parametrize("voxel, max_distance, exact_within", [
    (1.0, 0.8, 0.5),   # within a voxel: the 2 x 2 x 2 cubes around the nearest corner, exact within half a voxel
    (1.0, 3.0, 1.0),   # farther: the 3 x 3 x 3 around the query's cube, exact within a voxel
    (0.06, 0.05, 0.03),
])
def test_the_nearest_map_point_is_the_nearest_point(voxel, max_distance, exact_within):
    rng = np.random.default_rng(7)
    points = rng.uniform(-8.0 * voxel, 8.0 * voxel, size=(3000, 3))
    queries = rng.uniform(-9.0 * voxel, 9.0 * voxel, size=(4000, 3))
    nearest, voxels = _testing.voxel_map_nearest(points, voxel, 1000, queries, max_distance)
    expected = brute_force(points, queries)
    found = ~np.isnan(nearest[:, 0])
    got = np.linalg.norm(nearest - queries, axis=1)
    assert (got[found] <= max_distance + 1e-12).all()
    assert ((np.array(voxels) >= 0) == found).all()
    exact = expected < min(exact_within, max_distance)
    assert exact.sum() > 500, exact.sum()
    assert found[exact].all()
    np.testing.assert_allclose(got[exact], expected[exact], rtol=0, atol=1e-12)
    # every point returned is a map point
    d_to_map = brute_force(points, nearest[found])
    assert (d_to_map < 1e-12).all()


def test_an_empty_neighbourhood_finds_nothing():
    points = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0]])
    nearest, voxels = _testing.voxel_map_nearest(points, 1.0, 20, np.array([[5.0, 5.0, 5.0], [0.1, 0.0, 0.0]]), 0.9)
    assert np.isnan(nearest[0]).all() and voxels[0] == -1
    np.testing.assert_allclose(nearest[1], [0.0, 0.0, 0.0])


def test_bad_arguments_are_refused_naming_them():
    with pytest.raises(ValueError, match="voxel"):
        _testing.voxel_map_nearest(np.zeros((1, 3)), 0.0, 20, np.zeros((1, 3)), 1.0)
    with pytest.raises(ValueError, match="max_points_per_voxel"):
        _testing.voxel_map_nearest(np.zeros((1, 3)), 1.0, 0, np.zeros((1, 3)), 1.0)
