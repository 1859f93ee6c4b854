"""PointCloud2 / Image / CameraInfo <-> numpy (line_odom.convert): layouts, zero-copy, and every malformed case."""
import types

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image, PointField

from line_odom import convert
from line_odom.datasets import kitti_sequence, tum_sequence


@pytest.fixture(scope="module")
def kitti_scan():
    return kitti_sequence("07", frames=1).points(0)


def _cloud(points, **kw):
    return convert.pointcloud2_from_array(points, frame_id="velodyne", stamp=12.25, **kw)


def test_kitti_unorganized_roundtrip_is_zero_copy(kitti_scan):
    n = len(kitti_scan)
    ring = (np.arange(n) % 64).astype(np.uint16)
    msg = convert.pointcloud2_from_xyz(kitti_scan[:, :3], intensity=kitti_scan[:, 3], ring=ring,
                                       frame_id="velodyne", stamp=12.25)
    assert (msg.height, msg.width, msg.point_step) == (1, n, 18)
    cloud = convert.pointcloud2_to_arrays(msg)
    assert not cloud.organized and cloud.xyz.shape == (n, 3) and cloud.xyz.dtype == np.float32
    assert np.shares_memory(cloud.xyz, np.frombuffer(msg.data, np.uint8))  # a view on the message buffer
    np.testing.assert_array_equal(cloud.xyz, kitti_scan[:, :3])
    np.testing.assert_array_equal(cloud.intensity, kitti_scan[:, 3])
    np.testing.assert_array_equal(cloud.ring, ring)
    assert cloud.frame_id == "velodyne" and cloud.stamp == pytest.approx(12.25)


def test_float64_big_endian_padding_and_nan_filtering():
    pts = np.zeros(5, dtype={"names": ["x", "y", "z", "ring"], "formats": [">f8", ">f8", ">f8", "u1"],
                             "offsets": [0, 8, 16, 28], "itemsize": 32})
    pts["x"] = [1, 2, np.nan, 4, 5]
    pts["y"] = [10, 20, 30, np.inf, 50]
    pts["z"] = -1.5
    pts["ring"] = [0, 1, 2, 3, 63]
    msg = _cloud(pts)
    assert msg.is_bigendian and msg.point_step == 32
    cloud = convert.pointcloud2_to_arrays(msg)
    assert cloud.xyz.dtype == np.float64 and cloud.xyz.dtype.isnative
    np.testing.assert_array_equal(cloud.xyz, [[1, 10, -1.5], [2, 20, -1.5], [5, 50, -1.5]])
    np.testing.assert_array_equal(cloud.ring, [0, 1, 63])


def test_mixed_xyz_types_and_non_adjacent_fields():
    pts = np.zeros(3, dtype={"names": ["z", "intensity", "x", "y"], "formats": ["f8", "f4", "f4", "f4"],
                             "offsets": [0, 8, 16, 24], "itemsize": 40})
    pts["x"], pts["y"], pts["z"] = [1, 2, 3], [4, 5, 6], [7, 8, 9]
    cloud = convert.pointcloud2_to_arrays(_cloud(pts))
    assert cloud.xyz.dtype == np.float64
    np.testing.assert_array_equal(cloud.xyz, [[1, 4, 7], [2, 5, 8], [3, 6, 9]])


def test_organized_cloud_with_row_padding_keeps_grid_and_nans(kitti_scan):
    H, W = 4, 6
    xyz = kitti_scan[: H * W, :3].reshape(H, W, 3).copy()
    xyz[1, 2] = np.nan
    msg = convert.pointcloud2_from_xyz(xyz, frame_id="os_sensor")
    # rewrite with 8 padding bytes at the end of every row
    raw = np.frombuffer(msg.data, np.uint8).reshape(H, W * msg.point_step)
    padded = np.zeros((H, W * msg.point_step + 8), np.uint8)
    padded[:, : W * msg.point_step] = raw
    msg.row_step = W * msg.point_step + 8
    msg.data = padded.tobytes()
    cloud = convert.pointcloud2_to_arrays(msg)
    assert cloud.organized and cloud.xyz.shape == (H, W, 3)
    assert np.isnan(cloud.xyz[1, 2]).all()
    finite = np.isfinite(xyz).all(-1)
    np.testing.assert_array_equal(cloud.xyz[finite], xyz[finite])


@pytest.mark.parametrize("name, dtype, values, seconds", [
    ("t", "u4", [0, 50_000_000, 99_000_000], [0.0, 0.05, 0.099]),  # Ouster: uint32 ns
    ("time", "f4", [0.0, 0.05, 0.099], [0.0, 0.05, 0.099]),  # Velodyne: float32 s
    ("timestamp", "f8", [1.7e9, 1.7e9 + 0.05, 1.7e9 + 0.099], [1.7e9, 1.7e9 + 0.05, 1.7e9 + 0.099]),
])
def test_per_point_time_fields(name, dtype, values, seconds):
    pts = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), (name, dtype)])
    pts["x"] = [1, 2, 3]
    pts[name] = values
    cloud = convert.pointcloud2_to_arrays(_cloud(pts))
    np.testing.assert_allclose(cloud.time, seconds, rtol=1e-6, atol=1e-7)


def test_duck_typed_rosbags_style_message(kitti_scan):
    """rosbags deserializes data as a numpy uint8 array and fields as plain objects; reading must not care."""
    msg = convert.pointcloud2_from_xyz(kitti_scan[:100, :3], frame_id="velodyne", stamp=3.5)
    fields = [types.SimpleNamespace(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
              for f in msg.fields]
    stamp = types.SimpleNamespace(sec=3, nanosec=500_000_000)
    duck = types.SimpleNamespace(header=types.SimpleNamespace(stamp=stamp, frame_id="velodyne"), height=1,
                                 width=100, fields=fields, is_bigendian=False, point_step=msg.point_step,
                                 row_step=msg.row_step, data=np.frombuffer(msg.data, np.uint8).copy(),
                                 is_dense=True)
    cloud = convert.pointcloud2_to_arrays(duck)
    np.testing.assert_array_equal(cloud.xyz, kitti_scan[:100, :3])
    assert cloud.stamp == 3.5


def _xyz_cloud(n=4):
    pts = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    pts["x"] = np.arange(n)
    return _cloud(pts)


def _malformed_clouds():
    no_x = _cloud(np.zeros(3, dtype=[("y", "f4"), ("z", "f4"), ("intensity", "f4")]))
    small_step = _xyz_cloud()
    small_step.point_step = 8
    short = _xyz_cloud()
    short.data = bytes(short.data)[:-5]
    empty = _xyz_cloud()
    empty.width, empty.row_step, empty.data = 0, 0, b""
    all_nan = _xyz_cloud()
    all_nan.data = np.full(12, np.nan, np.float32).tobytes()
    unknown_type = _xyz_cloud()
    unknown_type.fields[1].datatype = 42
    short_rows = _xyz_cloud()
    short_rows.row_step = 4
    int_x = _cloud(np.zeros(3, dtype=[("x", "i4"), ("y", "f4"), ("z", "f4")]))
    float_ring = _cloud(np.array([(1, 0, 0, 0.0), (2, 0, 0, 1.5), (3, 0, 0, 2.0)],
                                 dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("ring", "f4")]))
    dup = _xyz_cloud()
    dup.fields = list(dup.fields) + [PointField(name="x", offset=0, datatype=7, count=1)]
    zero_step = _xyz_cloud()
    zero_step.point_step = 0
    return [
        ("no x field", no_x, "fields", "no 'x' field"),
        ("point_step too small", small_step, "point_step", "too small for field 'z'"),
        ("data too short", short, "data", "shorter than"),
        ("empty cloud", empty, "width", "empty cloud"),
        ("all NaN", all_nan, "data", "no finite point"),
        ("unknown datatype", unknown_type, "fields[y].datatype", "unknown PointField datatype 42"),
        ("row_step too small", short_rows, "row_step", "less than width x point_step"),
        ("integer x", int_x, "fields[x].datatype", "FLOAT32 or FLOAT64"),
        ("fractional ring", float_ring, "fields[ring].datatype", "whole numbers, got float32 value 1.5 at point 1"),
        ("duplicate field", dup, "fields[3].name", "duplicate"),
        ("zero point_step", zero_step, "point_step", "is 0"),
    ]


@pytest.mark.parametrize("case", _malformed_clouds(), ids=lambda c: c[0])
def test_malformed_cloud_raises_value_error_naming_field(case):
    _, msg, field, reason = case
    with pytest.raises(convert.PointCloudError) as info:
        convert.pointcloud2_to_arrays(msg)
    assert isinstance(info.value, ValueError)
    assert info.value.field == field, str(info.value)
    assert reason in str(info.value)
    assert str(info.value).startswith(f"PointCloud2.{field}: ")


def test_a_float_ring_field_of_whole_numbers_is_read_as_rings():
    """Some converters write every field as FLOAT32: rings all the same."""
    pts = np.zeros(4, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("ring", "f4")])
    pts["x"], pts["ring"] = np.arange(1, 5), [0, 3, 15, 7]
    cloud = convert.pointcloud2_to_arrays(_cloud(pts))
    assert cloud.ring.dtype == np.int32
    np.testing.assert_array_equal(cloud.ring, [0, 3, 15, 7])


def test_max_points_limit():
    with pytest.raises(convert.PointCloudError, match="max_points limit of 3"):
        convert.pointcloud2_to_arrays(_xyz_cloud(4), max_points=3)
    assert convert.pointcloud2_to_arrays(_xyz_cloud(4), max_points=4).num_points == 4


def test_pointfield_types_roundtrip_every_datatype():
    spec = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("a", "i1"), ("b", "u1"), ("c", "i2"), ("d", "u2"),
            ("e", "i4"), ("f", "u4"), ("g", "f8")]
    pts = np.zeros(2, dtype=spec)
    pts["x"] = 1
    msg = _cloud(pts)
    assert [f.datatype for f in msg.fields] == [7, 7, 7, 1, 2, 3, 4, 5, 6, 8]
    view = convert.read_points(msg)
    assert view.dtype == np.dtype(spec) and view.shape == (1, 2)


# ------------------------------------------------------------------------------------------ images


def test_tum_depth_as_16uc1_and_32fc1():
    seq = tum_sequence(frames=1)
    depth = seq.depth(0)  # metres
    msg16 = convert.depth_to_image(depth, encoding="16UC1", frame_id="openni_depth_optical_frame", stamp=1.0)
    assert (msg16.encoding, msg16.step) == ("16UC1", 640 * 2)
    back = convert.image_to_depth(msg16)
    assert back.dtype == np.float32 and back.shape == (480, 640)
    np.testing.assert_allclose(back, np.round(depth * 1000) / 1000, atol=1e-6)
    msg32 = convert.depth_to_image(depth, encoding="32FC1")
    np.testing.assert_array_equal(convert.image_to_depth(msg32), depth)


def test_image_step_padding_big_endian_and_invalid_pixels():
    raw = np.array([[1000, 0, 2500], [65535, 1, 7]], dtype=">u2")
    padded = np.zeros((2, 4), dtype=">u2")
    padded[:, :3] = raw
    msg = Image(height=2, width=3, encoding="16UC1", is_bigendian=True, step=8, data=padded.tobytes())
    np.testing.assert_allclose(convert.image_to_depth(msg), [[1.0, 0.0, 2.5], [65.535, 0.001, 0.007]], rtol=1e-6)
    f = np.array([[np.nan, -1.0], [np.inf, 2.0]], np.float32)
    msg = Image(height=2, width=2, encoding="32FC1", step=8, data=f.tobytes())
    np.testing.assert_array_equal(convert.image_to_depth(msg), [[0, 0], [0, 2.0]])


@pytest.mark.parametrize("mutate, field, reason", [
    (lambda m: setattr(m, "encoding", "rgb8"), "encoding", "unsupported depth encoding 'rgb8'"),
    (lambda m: setattr(m, "data", bytes(m.data)[:-3]), "data", "shorter than"),
    (lambda m: setattr(m, "step", 2), "step", "less than width"),
    (lambda m: setattr(m, "data", bytes(len(m.data))), "data", "no valid depth"),
    (lambda m: setattr(m, "width", 0), "width", "empty image"),
], ids=["unknown encoding", "short data", "small step", "all zero", "empty"])
def test_malformed_image(mutate, field, reason):
    msg = convert.depth_to_image(np.full((3, 4), 1.5))
    mutate(msg)
    with pytest.raises(convert.ImageError) as info:
        convert.image_to_depth(msg)
    assert info.value.field == field and reason in str(info.value)


# ------------------------------------------------------------------------------------------ camera info


def test_camera_info_roundtrip_and_validation():
    K = tum_sequence(frames=1).K
    info = convert.camera_info_from_K(K, 640, 480, frame_id="cam")
    np.testing.assert_array_equal(convert.camera_info_to_K(info, (480, 640)), K)
    with pytest.raises(convert.CameraInfoError, match="but the image is 320 x 240"):
        convert.camera_info_to_K(info, (240, 320))


@pytest.mark.parametrize("k, reason", [
    ([0.0] * 9, "focal length must be > 0"),
    ([525.0, 0, 320, 0, 0.0, 240, 0, 0, 1], "focal length must be > 0"),
    ([525.0, 0, 320, 0, 525, 240, 0, 0, np.nan], "NaN or inf"),
    ([525.0, 0, 320, 0, 525, 240, 0, 0, 0], "last row must be"),
], ids=["all zero", "fy zero", "nan", "bad last row"])
def test_malformed_camera_info(k, reason):
    info = CameraInfo(width=640, height=480)
    info.k = np.asarray(k, dtype=float)
    with pytest.raises(convert.CameraInfoError) as err:
        convert.camera_info_to_K(info)
    assert err.value.field == "k" and reason in str(err.value)


def test_stamp_helpers():
    s = convert.sec_to_stamp(1234.5678901234)
    assert (s.sec, s.nanosec) == (1234, 567890123)
    assert convert.stamp_to_sec(s) == pytest.approx(1234.567890123)
    with pytest.raises(ValueError, match="stamp"):
        convert.sec_to_stamp(float("nan"))


@pytest.mark.parametrize("offsets, field", [((0, 2, 8), "fields[y].offset"), ((0, 0, 0), "fields[y].offset"),
                                            ((0, 4, 6), "fields[z].offset")])
def test_overlapping_fields_are_malformed(offsets, field):
    """y at offset 2 (inside x), or x = y = z at offset 0: a writer's bug, not a layout; read as garbage otherwise."""
    from sensor_msgs.msg import PointField

    msg = _xyz_cloud(4)
    msg.fields = [PointField(name=n, offset=o, datatype=7, count=1) for n, o in zip("xyz", offsets)]
    with pytest.raises(convert.PointCloudError, match="overlap") as err:
        convert.pointcloud2_to_arrays(msg)
    assert err.value.field == field


def test_field_past_point_step_is_malformed():
    from sensor_msgs.msg import PointField

    msg = _xyz_cloud(4)
    msg.fields = list(msg.fields) + [PointField(name="intensity", offset=msg.point_step - 2, datatype=7, count=1)]
    with pytest.raises(convert.PointCloudError, match="too small for field 'intensity'"):
        convert.pointcloud2_to_arrays(msg)


@pytest.mark.parametrize("sec, nanosec, field", [(-1, 0, "sec"), (0, 1_000_000_000, "nanosec"), (3, -1, "nanosec")])
def test_header_stamp_out_of_range_names_the_field(sec, nanosec, field):
    stamp = type("Stamp", (), {"sec": sec, "nanosec": nanosec})()
    with pytest.raises(convert.ConversionError, match=f"header.stamp.{field}"):
        convert.header_stamp_ns(stamp, "PointCloud2")
    ok = type("Stamp", (), {"sec": 3, "nanosec": 999_999_999})()
    assert convert.header_stamp_ns(ok, "PointCloud2") == 3_999_999_999


def test_depth_image_over_max_pixels_is_refused_before_conversion():
    img = convert.depth_to_image(np.full((40, 50), 2.0))
    with pytest.raises(convert.TooLargeError, match="2000 pixels exceed the max_pixels limit of 1999"):
        convert.image_to_depth(img, max_pixels=1999)
    assert convert.image_to_depth(img, max_pixels=2000).shape == (40, 50)
