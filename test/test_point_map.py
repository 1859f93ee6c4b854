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


def test_a_full_cube_gives_way_only_to_points_from_a_place_sampled_before():
    """A cube holding three points is filled by a sensor standing still (scans 0 and 1 at the origin), then a scan from
    2 m away adds a point: the point scan 1 added from where scan 0 stood gives way, scan 0's stay. Without
    same_place (the first points stay, as KISS-ICP's map) the new point is not taken; a sensor that moved between
    every scan keeps its first points either way."""
    points = np.array([[0.1, 0.1, 0.1], [0.2, 0.1, 0.1], [0.3, 0.1, 0.1], [0.9, 0.1, 0.1]])
    scan_of = [0, 0, 1, 2]
    queries = points.copy()
    standing = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    given_way, _ = _testing.voxel_map_nearest(points, 1.0, 3, queries, 0.9, scan_of=scan_of,
                                              sensor_positions=standing, same_place=0.1)
    np.testing.assert_allclose(given_way[:, 0], [0.1, 0.2, 0.2, 0.9])
    first, _ = _testing.voxel_map_nearest(points, 1.0, 3, queries, 0.9, scan_of=scan_of, sensor_positions=standing)
    np.testing.assert_allclose(first[:, 0], [0.1, 0.2, 0.3, 0.3])
    moving = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    kept, _ = _testing.voxel_map_nearest(points, 1.0, 3, queries, 0.9, scan_of=scan_of, sensor_positions=moving,
                                         same_place=0.1)
    np.testing.assert_allclose(kept[:, 0], [0.1, 0.2, 0.3, 0.3])
    with pytest.raises(ValueError, match="scan_of"):
        _testing.voxel_map_nearest(points, 1.0, 3, queries, 0.9, scan_of=[0, 1])


@pytest.mark.parametrize("standing", [1026, 1500])
def test_a_sensor_standing_for_many_scans_keeps_the_first_point_and_the_last_ones(standing):
    """Scans from one place each add a point to a cube holding three, past the scans the map numbers before it
    renumbers those it still holds (right after it: 1026; and later): the first standing point stays, the others gave
    way in turn, the last two are held. Then a scan from 2 m away adds one in place of the older of those two."""
    points = np.c_[0.1 + 0.0005 * np.arange(standing), np.full(standing, 0.1), np.full(standing, 0.1)]
    queries = points[[0, standing - 3, standing - 2, standing - 1]]
    held = np.array([True, False, True, True])

    def nearest(points, positions):
        found, _ = _testing.voxel_map_nearest(points, 1.0, 3, queries, 1e-4, scan_of=list(range(len(points))),
                                              sensor_positions=positions, same_place=0.1)
        return ~np.isnan(found[:, 0])

    np.testing.assert_array_equal(nearest(points, np.zeros((standing, 3))), held)
    moved = np.vstack([np.zeros((standing, 3)), [[2.0, 0.0, 0.0]]])
    np.testing.assert_array_equal(nearest(np.vstack([points, [[0.95, 0.1, 0.1]]]), moved), [True, False, False, True])


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


def _street_scan(position_x: float) -> np.ndarray:
    """A sparse scan (seven rings down to the ground, two up) from (position_x, 0) at 1.73 m over flat ground, of the
    ground and six poles, in the sensor's frame: its ground rings are the same circles wherever the sensor stands."""
    height = 1.73
    ring_elevations = np.radians([-2.0, -5.5, -9.0, -12.5, -16.0, -19.5, -23.0, 1.0, 2.0])
    azimuths = np.radians(np.arange(0.0, 360.0, 0.2))
    ground = []
    for elevation in ring_elevations[ring_elevations < 0]:
        r = height / np.tan(-elevation)
        ground.append(np.c_[r * np.cos(azimuths), r * np.sin(azimuths), np.full(azimuths.size, -height)])
    poles = np.array([[8.0, 4.0], [12.0, -5.0], [-6.0, 7.0], [15.0, 8.0], [-10.0, -6.0], [5.0, -9.0]])
    pole_points = []
    for px, py in poles - [position_x, 0.0]:
        d = np.hypot(px, py)
        toward_sensor = -np.array([px, py]) / d
        for elevation in ring_elevations:
            z = d * np.tan(elevation)
            if z > -height:
                for side in (-0.05, 0.05):  # two returns across the pole's face
                    offset = 0.1 * toward_sensor + side * np.array([-toward_sensor[1], toward_sensor[0]])
                    pole_points.append([px + offset[0], py + offset[1], z])
    return np.vstack(ground + [np.array(pole_points)])


def test_ring_arcs_along_the_ground_do_not_hold_a_scan_where_the_last_one_was():
    """A sparse scan's rings on the ground are where the sensor put them, not where the world is: moved 0.3 m along
    the street, the new scan's ground rings lie exactly on the last scan's (in the sensor frame). Matched point to
    point they hold the alignment near standing still; as the ground's plane (the map's arcs along the ground plane
    its scan was measured over) they say only where the ground is, and the poles place the scan."""
    last, current = _street_scan(0.0), _street_scan(0.3)
    ground = np.array([0.0, 0.0, 1.0, 1.73])  # z = -1.73 in the sensor's frame
    with_ground = _testing.point_map_alignment(last, ground, 1.0, current, np.eye(4), 1.0)
    without = _testing.point_map_alignment(last, None, 1.0, current, np.eye(4), 1.0)
    assert abs(with_ground[0, 3] - 0.3) < 0.03, with_ground[:3, 3]
    assert abs(with_ground[1, 3]) < 0.03 and abs(with_ground[2, 3]) < 0.03, with_ground[:3, 3]
    assert without[0, 3] < 0.15, without[:3, 3]  # the lean this removes
