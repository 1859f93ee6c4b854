"""Fuzzing of message conversion (line_odom.convert): PointCloud2, depth Image and CameraInfo built with random
field layouts, dtypes, strides, sizes, byte orders, NaN/inf and truncated or oversized buffers.

Every input must give either a ConversionError (a ValueError naming the message field) or a valid result whose
values match the bytes that were sent — never another exception type, a crash or a hang. Fixed seed
(derandomize) and bounded example counts keep this fast and reproducible in CI.

Messages are duck-typed namespaces (the readers accept rclpy and rosbags messages alike), so no ROS is needed.
"""
from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from line_odom import convert
from line_odom.convert import POINT_FIELD_TYPES, CameraInfoError, ConversionError, ImageError, PointCloudError

FUZZ = settings(derandomize=True, deadline=None, max_examples=300, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
PER_CALL_SECONDS = 2.0  # "never hang": a conversion of these small inputs takes milliseconds

FIELD_NAMES = ["x", "y", "z", "ring", "intensity", "t", "time", "timestamp", "reflectivity", "rgb", "", "x "]


def field(name, offset, datatype, count=1):
    return SimpleNamespace(name=name, offset=offset, datatype=datatype, count=count)


def cloud(fields, *, width, height, point_step, row_step, data, is_bigendian=False, stamp=(0, 0), frame_id="lidar"):
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=stamp[0], nanosec=stamp[1]), frame_id=frame_id),
        height=height, width=width, fields=fields, is_bigendian=is_bigendian, point_step=point_step,
        row_step=row_step, data=data, is_dense=False)


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    try:
        return fn(*args, **kwargs)
    finally:
        assert time.perf_counter() - t0 < PER_CALL_SECONDS, f"{fn.__name__} took too long"


def convert_or_error(fn, *args, expected_error=ConversionError, **kwargs):
    """The result, or None after checking the error is the documented kind with a field and a reason."""
    try:
        return timed(fn, *args, **kwargs)
    except ConversionError as err:
        assert isinstance(err, ValueError)
        assert isinstance(err, expected_error), f"{type(err).__name__}: {err}"
        assert err.field and err.reason, str(err)
        assert str(err).startswith(f"{err.message_type}.{err.field}: ")
        return None


# ---------------------------------------------------------------------------------------------- PointCloud2

raw_fields = st.lists(
    st.builds(field, st.sampled_from(FIELD_NAMES), st.integers(-4, 48), st.integers(-1, 10), st.integers(-1, 3)),
    max_size=7)


@FUZZ
@given(fields=raw_fields, width=st.integers(-2, 40), height=st.integers(-1, 4), point_step=st.integers(-4, 64),
       row_pad=st.integers(-64, 32), data_delta=st.integers(-80, 80), big=st.booleans(),
       payload=st.binary(min_size=0, max_size=64), max_points=st.sampled_from([0, 5, 1000]))
def test_random_pointcloud2_headers_and_bytes(fields, width, height, point_step, row_pad, data_delta, big, payload,
                                              max_points):
    """Arbitrary (often nonsensical) headers over random bytes: a PointCloudError or a consistent cloud."""
    row_step = max(width, 0) * max(point_step, 0) + row_pad
    size = max(0, max(row_step, 0) * max(height, 0) + data_delta)
    data = (payload * (size // max(len(payload), 1) + 1))[:size] if payload else bytes(size)
    msg = cloud(fields, width=width, height=height, point_step=point_step, row_step=row_step, data=data,
                is_bigendian=big)
    out = convert_or_error(convert.pointcloud2_to_arrays, msg, max_points=max_points, expected_error=PointCloudError)
    if out is None:
        return
    assert width > 0 and height > 0 and point_step > 0
    assert out.xyz.dtype in (np.float32, np.float64) and out.xyz.dtype.isnative
    assert max_points == 0 or out.num_points <= max_points
    if out.organized:
        assert out.xyz.shape == (height, width, 3)
        rows_ok = np.isfinite(out.xyz).all(axis=-1) | np.isnan(out.xyz).all(axis=-1)
        assert rows_ok.all(), "an organized point is either finite or all NaN"
        assert np.isfinite(out.xyz).all(axis=-1).any()
    else:
        assert out.xyz.ndim == 2 and out.xyz.shape[1] == 3 and 0 < out.xyz.shape[0] <= width * height
        assert np.isfinite(out.xyz).all()
    for extra in (out.ring, out.intensity, out.time):
        if extra is not None:
            assert extra.shape == out.xyz.shape[:-1]


FLOAT_TYPES = [np.float32, np.float64]
EXTRA_TYPES = [np.uint8, np.uint16, np.int32, np.float32, np.float64, np.int8, np.uint32]
SPECIALS = [np.nan, np.inf, -np.inf, 0.0, -0.0, 1e30, -1e-30, 3.4e38]


@st.composite
def valid_layouts(draw):
    """A structured dtype with x, y, z (float32/float64, any order, gaps) plus extras, a point_step with padding,
    organized or not, row padding, byte order, and point values with NaN/inf/huge sprinkled in."""
    names = ["x", "y", "z"] + draw(st.lists(st.sampled_from(["ring", "intensity", "t", "time", "pad_a"]),
                                            unique=True, max_size=3))
    order = draw(st.permutations(names))
    same_xyz = draw(st.booleans())
    xyz_type = draw(st.sampled_from(FLOAT_TYPES))
    spec, offset = [], 0
    for name in order:
        offset += draw(st.sampled_from([0, 0, 1, 2, 4]))
        if name in ("x", "y", "z"):
            t = xyz_type if same_xyz else draw(st.sampled_from(FLOAT_TYPES))
        elif name == "ring":
            t = draw(st.sampled_from([np.uint8, np.uint16]))
        else:
            t = draw(st.sampled_from(EXTRA_TYPES))
        spec.append((name, t, offset))
        offset += np.dtype(t).itemsize
    point_step = offset + draw(st.integers(0, 9))
    big = draw(st.booleans())
    bo = ">" if big else "<"
    dtype = np.dtype({"names": [s[0] for s in spec], "formats": [np.dtype(s[1]).newbyteorder(bo) for s in spec],
                      "offsets": [s[2] for s in spec], "itemsize": point_step})
    height = draw(st.integers(1, 4))
    width = draw(st.integers(1, 30))
    row_pad = draw(st.integers(0, 13))
    n = height * width
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    values = rng.normal(0, 20, size=(n, 3))
    special_frac = draw(st.sampled_from([0.0, 0.1, 0.5, 1.0]))
    mask = rng.random((n, 3)) < special_frac
    values[mask] = rng.choice(SPECIALS, size=int(mask.sum()))
    return dtype, height, width, row_pad, big, values, rng


@FUZZ
@given(layout=valid_layouts(), organized=st.sampled_from([None, True, False]))
def test_valid_layouts_convert_to_the_values_sent(layout, organized):
    """Well-formed clouds in any layout: the converted points are exactly the finite points sent (after the cast
    of each field to its wire type), in order; a cloud without a finite point is a clear error."""
    dtype, height, width, row_pad, big, values, rng = layout
    points = np.zeros(height * width, dtype=dtype)
    for k, axis in enumerate("xyz"):
        with np.errstate(over="ignore", invalid="ignore"):
            points[axis] = values[:, k].astype(dtype[axis].newbyteorder("="))
    if "ring" in dtype.names:
        points["ring"] = rng.integers(0, 16, size=points.size)
    row_step = width * dtype.itemsize + row_pad
    buf = bytearray(row_step * height)
    raw = points.tobytes()
    for r in range(height):
        row = raw[r * width * dtype.itemsize:(r + 1) * width * dtype.itemsize]
        buf[r * row_step:r * row_step + len(row)] = row
    msg = cloud([field(n, dtype.fields[n][1], convert.NUMPY_TO_POINT_FIELD[dtype.fields[n][0].newbyteorder("=")])
                 for n in dtype.names], width=width, height=height, point_step=dtype.itemsize, row_step=row_step,
                data=bytes(buf), is_bigendian=big)
    sent = np.stack([points[a].astype(np.float64) for a in "xyz"], axis=-1)
    finite = np.isfinite(sent).all(axis=1)
    if not finite.any():
        with pytest.raises(PointCloudError, match=r"PointCloud2\.data: no finite point"):
            timed(convert.pointcloud2_to_arrays, msg, organized=organized)
        return
    out = timed(convert.pointcloud2_to_arrays, msg, organized=organized)
    want_organized = height > 1 if organized is None else organized
    assert out.organized == want_organized
    got = out.xyz.astype(np.float64)
    if want_organized:
        assert got.shape == (height, width, 3)
        flat = got.reshape(-1, 3)
        np.testing.assert_array_equal(flat[finite], sent[finite])
        assert np.isnan(flat[~finite]).all()
    else:
        np.testing.assert_array_equal(got, sent[finite])
        if "ring" in dtype.names:
            np.testing.assert_array_equal(out.ring, points["ring"][finite].astype(np.int32))
    assert out.frame_id == "lidar"


@FUZZ
@given(width=st.sampled_from([1, 7, 2**31, 2**32 + 1, 2**62]), height=st.sampled_from([1, 2, 2**31, 2**40]),
       point_step=st.sampled_from([12, 16, 2**31]), data_len=st.integers(0, 256))
def test_huge_declared_sizes_with_short_buffers_are_rejected_quickly(width, height, point_step, data_len):
    """A header that claims terabytes over a few bytes must fail on the size check, not allocate or overflow."""
    assume(width * height * point_step > data_len)
    msg = cloud([field("x", 0, 7), field("y", 4, 7), field("z", 8, 7)], width=width, height=height,
                point_step=point_step, row_step=width * point_step, data=bytes(data_len))
    with pytest.raises(PointCloudError) as err:
        timed(convert.pointcloud2_to_arrays, msg)
    assert err.value.field in ("data", "row_step", "point_step")


def test_non_buffer_data_and_non_integer_header_values_are_conversion_errors():
    good = dict(width=1, height=1, point_step=12, row_step=12)
    xyz = [field("x", 0, 7), field("y", 4, 7), field("z", 8, 7)]
    for data in (None, 3.5, object(), "twelve bytes"):
        with pytest.raises(ConversionError, match=r"PointCloud2\.data: not a byte buffer"):
            convert.pointcloud2_to_arrays(cloud(xyz, data=data, **good))
    for key, value in (("width", "wide"), ("height", None), ("point_step", 1.5j), ("row_step", [12])):
        with pytest.raises(PointCloudError, match=rf"PointCloud2\.{key}: expected an integer"):
            convert.pointcloud2_to_arrays(cloud(xyz, data=bytes(12), **{**good, key: value}))
    with pytest.raises(PointCloudError, match=r"fields\[x\]\.datatype"):
        convert.pointcloud2_to_arrays(cloud([field("x", 0, "FLOAT32"), *xyz[1:]], data=bytes(12), **good))


# ---------------------------------------------------------------------------------------------- Image


def image(encoding, *, width, height, step, data, is_bigendian=False):
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0), frame_id="camera"),
                           encoding=encoding, width=width, height=height, step=step, data=data,
                           is_bigendian=is_bigendian)


ENCODINGS = ["16UC1", "mono16", "32FC1", "32FC3", "8UC1", "rgb8", "", "16uc1", "64FC1"]


@FUZZ
@given(encoding=st.sampled_from(ENCODINGS), width=st.integers(-1, 30), height=st.integers(-1, 20),
       step_pad=st.integers(-8, 8), data_delta=st.integers(-40, 40), big=st.booleans(),
       payload=st.binary(min_size=1, max_size=64))
def test_random_images(encoding, width, height, step_pad, data_delta, big, payload):
    itemsize = {"16UC1": 2, "mono16": 2, "32FC1": 4}.get(encoding, 1)
    step = max(width, 0) * itemsize + step_pad
    size = max(0, max(step, 0) * max(height, 0) + data_delta)
    data = (payload * (size // len(payload) + 1))[:size]
    out = convert_or_error(convert.image_to_depth, image(encoding, width=width, height=height, step=step, data=data,
                                                         is_bigendian=big), expected_error=ImageError)
    if out is None:
        return
    assert encoding in convert.DEPTH_ENCODINGS
    assert out.shape == (height, width) and out.dtype == np.float32
    assert np.isfinite(out).all() and (out >= 0).all() and (out > 0).any()


@FUZZ
@given(encoding=st.sampled_from(["16UC1", "32FC1"]), height=st.integers(1, 12), width=st.integers(1, 12),
       pad=st.integers(0, 7), big=st.booleans(), seed=st.integers(0, 2**32 - 1),
       special_frac=st.sampled_from([0.0, 0.3, 1.0]))
def test_valid_depth_images_convert_to_the_values_sent(encoding, height, width, pad, big, seed, special_frac):
    rng = np.random.default_rng(seed)
    if encoding == "16UC1":
        pixels = rng.integers(0, 65536, size=(height, width)).astype(np.uint16)
        pixels[rng.random((height, width)) < special_frac] = 0
        metres = pixels.astype(np.float32) * np.float32(1e-3)
    else:
        pixels = rng.uniform(-1, 30, size=(height, width)).astype(np.float32)
        special = rng.random((height, width)) < special_frac
        pixels[special] = rng.choice(np.array([np.nan, np.inf, -np.inf, 0.0, -2.0], np.float32), int(special.sum()))
        metres = np.where(np.isfinite(pixels) & (pixels > 0), pixels, 0).astype(np.float32)
    wire = pixels.astype(pixels.dtype.newbyteorder(">" if big else "<"))
    step = width * wire.itemsize + pad
    buf = bytearray(step * height)
    for r in range(height):
        buf[r * step:r * step + width * wire.itemsize] = wire[r].tobytes()
    msg = image(encoding, width=width, height=height, step=step, data=bytes(buf), is_bigendian=big)
    if not (metres > 0).any():
        with pytest.raises(ImageError, match=r"Image\.data: no valid depth"):
            convert.image_to_depth(msg)
        return
    np.testing.assert_array_equal(timed(convert.image_to_depth, msg), metres)


# ---------------------------------------------------------------------------------------------- CameraInfo

k_entries = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
                      st.sampled_from([0.0, 1.0, 525.0]))


@FUZZ
@given(k=st.one_of(st.lists(k_entries, min_size=0, max_size=12), st.just(None), st.just("not a matrix")),
       size=st.tuples(st.integers(0, 1000), st.integers(0, 1000)), image_shape=st.sampled_from([None, (480, 640)]))
def test_random_camera_info(k, size, image_shape):
    msg = SimpleNamespace(k=k, width=size[0], height=size[1])
    K = convert_or_error(convert.camera_info_to_K, msg, image_shape, expected_error=CameraInfoError)
    if K is None:
        return
    assert K.shape == (3, 3) and K.dtype == np.float64 and np.isfinite(K).all()
    assert K[0, 0] > 0 and K[1, 1] > 0 and tuple(K[2]) == (0.0, 0.0, 1.0)


@FUZZ
@given(fx=st.floats(allow_nan=True, allow_infinity=True), fy=st.floats(allow_nan=True, allow_infinity=True),
       cx=st.floats(-1e3, 1e3), cy=st.floats(-1e3, 1e3))
def test_camera_info_focal_lengths(fx, fy, cx, cy):
    msg = SimpleNamespace(k=[fx, 0, cx, 0, fy, cy, 0, 0, 1], width=0, height=0)
    valid = np.isfinite([fx, fy]).all() and fx > 0 and fy > 0
    if valid:
        np.testing.assert_array_equal(convert.camera_info_to_K(msg), [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    else:
        with pytest.raises(CameraInfoError, match=r"CameraInfo\.k: "):
            convert.camera_info_to_K(msg)
