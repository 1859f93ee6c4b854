"""Points are read where they lie: strided views (cloud[:, :3] of an (N, 4) scan, a PointCloud2 buffer) reach the
engine without a copy and give the same poses as contiguous copies; layouts it cannot read in place are copied by
the Python wrapper and refused by the raw binding with an error naming xyz. Also the Eigen rotation helpers the
per-frame Python path uses instead of scipy."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import line_odom_core
from line_odom import convert
from line_odom.datasets import kitti_sequence
from line_odom_core import _core
from line_odom_core.odometry import _float_array


@pytest.fixture(scope="module")
def scans():
    data = kitti_sequence("07", 3)
    return [data.points(i) for i in range(3)], [float(t) for t in data.times[:3]]


def odometry():
    return line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))


def poses(register, clouds, times):
    odom = odometry()
    return np.array([getattr(odom, register)(c, t).pose for c, t in zip(clouds, times)])


def test_strided_view_is_read_in_place_with_the_poses_of_a_copy(scans):
    raw, times = scans
    views = [p[:, :3] for p in raw]
    assert not views[0].flags.c_contiguous
    assert np.shares_memory(_float_array("xyz", views[0], 2, 3, "points"), raw[0])
    in_place = poses("register_points", views, times)
    copied = poses("register_points", [np.ascontiguousarray(v) for v in views], times)
    assert np.array_equal(in_place, copied)
    assert np.linalg.norm(in_place[-1][:3, 3]) > 0.1  # the car moved (0.09 m a frame): a registration happened


def test_pointcloud2_buffer_reaches_the_engine_without_a_copy(scans):
    raw, _ = scans
    arr = np.zeros(len(raw[0]), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    for k, name in enumerate(("x", "y", "z", "intensity")):
        arr[name] = raw[0][:, k]
    msg = convert.pointcloud2_from_array(arr, frame_id="velo", stamp=1.0)
    cloud = convert.pointcloud2_to_arrays(msg)
    xyz = _float_array("xyz", cloud.xyz, 2, 3, "points")
    assert np.shares_memory(xyz, np.frombuffer(msg.data, np.uint8))
    assert np.array_equal(xyz, raw[0][:, :3])


def test_organized_view_gives_the_poses_of_a_copy(scans):
    raw, times = scans
    # an organized (H, W, 4) grid whose last channel is not a coordinate
    grids = []
    for p in raw:
        n = (len(p) // 64) * 64
        grids.append(p[:n].reshape(64, -1, 4))
    views = [g[..., :3] for g in grids]
    assert np.shares_memory(_float_array("xyz", views[0], 3, 3, "grid"), grids[0])
    assert np.array_equal(poses("register_organized", views, times),
                          poses("register_organized", [np.ascontiguousarray(v) for v in views], times))


def test_layouts_the_engine_cannot_read_are_copied_or_refused(scans):
    raw, times = scans
    base = np.ascontiguousarray(raw[0][:, :3])
    misaligned = np.frombuffer(b"\0" + base.tobytes(), np.uint8)[1:].view(np.float32).reshape(base.shape)
    reversed_rows = base[::-1]
    reversed_columns = np.ascontiguousarray(base[:, ::-1])[:, ::-1]
    assert not misaligned.flags.aligned
    engine = odometry()._engine
    for layout in (misaligned, reversed_rows, reversed_columns):
        assert np.array_equal(layout, base[::-1] if layout is reversed_rows else base)
        with pytest.raises(ValueError, match="xyz: expected each point's x, y, z adjacent"):
            engine.register_points(layout, 0.0, None)
        copy = _float_array("xyz", layout, 2, 3, "points")
        assert copy.flags.c_contiguous and not np.shares_memory(copy, layout)
    # through the wrapper: the same poses as the contiguous points
    assert np.array_equal(poses("register_points", [misaligned, misaligned], times[:2]),
                          poses("register_points", [base, base], times[:2]))


def test_rotation_helpers_match_scipy_including_zero_and_pi():
    rotations = list(Rotation.random(500, random_state=3).as_matrix())
    for angle in (0.0, 1e-9, 1e-3, np.pi - 1e-9, np.pi):
        for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 1.0), (0.3, -0.5, 0.8)):
            axis = np.asarray(axis) / np.linalg.norm(axis)
            rotations.append(Rotation.from_rotvec(angle * axis).as_matrix())
    for R in rotations:
        phi = _core.rotation_vector(R)
        assert np.linalg.norm(phi) <= np.pi + 1e-12
        np.testing.assert_allclose(Rotation.from_rotvec(phi).as_matrix(), R, atol=1e-12)
        q = _core.quaternion_xyzw(R)
        assert q[3] >= 0.0 and abs(np.linalg.norm(q) - 1.0) < 1e-12
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-12)
