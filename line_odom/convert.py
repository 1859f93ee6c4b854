"""Message <-> numpy conversion for sensor_msgs PointCloud2, Image and CameraInfo.

Readers are duck-typed (they work on rclpy messages and on rosbags-deserialized messages alike) and build a
zero-copy structured view of the message buffer from the cloud's fields, honouring point_step, row_step,
height and is_bigendian. Every malformed input raises a :class:`ConversionError` (a ``ValueError``) that
names the offending field and the reason. Builders (numpy -> message) import the message packages lazily so
that reading needs no ROS installation.
"""
from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
from numpy.lib.recfunctions import structured_to_unstructured

# sensor_msgs/PointField datatype constants -> numpy scalar types
POINT_FIELD_TYPES = {
    1: np.int8,
    2: np.uint8,
    3: np.int16,
    4: np.uint16,
    5: np.int32,
    6: np.uint32,
    7: np.float32,
    8: np.float64,
}
NUMPY_TO_POINT_FIELD = {np.dtype(t): code for code, t in POINT_FIELD_TYPES.items()}
MAX_POINT_STEP = 2**31 - 1  # a structured dtype's itemsize is a C int

RING_FIELDS = ("ring",)
INTENSITY_FIELDS = ("intensity", "reflectivity", "reflectance", "i")
TIME_FIELDS = ("t", "time", "timestamp")

# depth encodings -> (numpy type, metres per unit)
DEPTH_ENCODINGS = {
    "16UC1": (np.uint16, 1e-3),
    "mono16": (np.uint16, 1e-3),
    "32FC1": (np.float32, 1.0),
}


class ConversionError(ValueError):
    """A message that cannot be converted: ``field`` names the offending message field, ``reason`` says why."""

    def __init__(self, message_type: str, field: str, reason: str):
        self.message_type = message_type
        self.field = field
        self.reason = reason
        super().__init__(f"{message_type}.{field}: {reason}")


class PointCloudError(ConversionError):
    def __init__(self, field: str, reason: str):
        super().__init__("PointCloud2", field, reason)


class ImageError(ConversionError):
    def __init__(self, field: str, reason: str):
        super().__init__("Image", field, reason)


class CameraInfoError(ConversionError):
    def __init__(self, field: str, reason: str):
        super().__init__("CameraInfo", field, reason)


class TooLargeError(ConversionError):
    """A well-formed message larger than the configured limit (max_points, max_pixels)."""


class CloudTooLargeError(PointCloudError, TooLargeError):
    pass


class ImageTooLargeError(ImageError, TooLargeError):
    pass


# ---------------------------------------------------------------------------------------------- stamps


def stamp_to_sec(stamp) -> float:
    """builtin_interfaces/Time -> seconds (float)."""
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def stamp_to_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def header_stamp_ns(stamp, message_type: str) -> int:
    """A received message's header.stamp as integer nanoseconds; ConversionError naming the field for a stamp no
    clock gives: before the epoch (ROS time is never negative) or nanosec >= 1e9 (not normalised; REP and
    builtin_interfaces/Time keep it below one second)."""
    sec, nanosec = _as_stamp_int(stamp, "sec", message_type), _as_stamp_int(stamp, "nanosec", message_type)
    if sec < 0:
        raise ConversionError(message_type, "header.stamp.sec", f"expected >= 0 (ROS time is never negative), "
                                                                 f"got {sec}")
    if not 0 <= nanosec < 1_000_000_000:
        raise ConversionError(message_type, "header.stamp.nanosec", f"expected 0 <= nanosec < 1000000000, "
                                                                     f"got {nanosec}")
    return sec * 1_000_000_000 + nanosec


def _as_stamp_int(stamp, name: str, message_type: str) -> int:
    value = getattr(stamp, name, None)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConversionError(message_type, f"header.stamp.{name}", f"expected an integer, got {value!r}")
    return int(value)


def ns_to_stamp(ns: int):
    """integer nanoseconds -> builtin_interfaces/Time."""
    from builtin_interfaces.msg import Time

    ns = int(ns)
    if ns < 0:
        raise ValueError(f"stamp: expected nanoseconds >= 0, got {ns}")
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def sec_to_stamp(seconds: float):
    """seconds -> builtin_interfaces/Time (rounded to the nanosecond)."""
    if not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"stamp: expected finite seconds >= 0, got {seconds}")
    return ns_to_stamp(round(seconds * 1e9))


def set_header(msg, frame_id: str, stamp) -> None:
    """header.frame_id, and header.stamp from seconds or a builtin_interfaces/Time (None: left unset)."""
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = sec_to_stamp(stamp) if isinstance(stamp, (int, float)) else stamp


def _buffer(data, message_type: str) -> np.ndarray:
    """The message's byte buffer as a flat uint8 array without copying (array.array, bytes, ndarray, ...)."""
    try:
        buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    except (TypeError, ValueError) as exc:
        raise ConversionError(message_type, "data", f"not a byte buffer ({type(data).__name__}): {exc}") from None
    if buf.dtype != np.uint8:
        buf = buf.view(np.uint8) if buf.flags.c_contiguous else np.ascontiguousarray(buf).view(np.uint8)
    return buf.reshape(-1)


# ---------------------------------------------------------------------------------------------- PointCloud2


def _as_int(value, field: str, error=PointCloudError) -> int:
    try:
        number = int(value)
    except (TypeError, ValueError):
        raise error(field, f"expected an integer, got {value!r}") from None
    if number < 0:
        raise error(field, f"expected >= 0, got {number}")
    return number


def pointcloud2_dtype(fields, point_step: int, is_bigendian: bool = False) -> np.dtype:
    """Structured numpy dtype (itemsize = point_step) for a list of sensor_msgs/PointField."""
    point_step = _as_int(point_step, "point_step")
    if point_step == 0:
        raise PointCloudError("point_step", "is 0")
    if point_step > MAX_POINT_STEP:
        raise PointCloudError("point_step", f"{point_step} bytes per point exceeds {MAX_POINT_STEP} (numpy's limit)")
    order = ">" if is_bigendian else "<"
    names, formats, offsets = [], [], []
    spans: dict[str, tuple[int, int]] = {}  # each field's bytes [start, end) within a point
    for i, f in enumerate(fields):
        name = str(f.name)
        if not name:
            raise PointCloudError(f"fields[{i}].name", "is empty")
        if name in names:
            raise PointCloudError(f"fields[{i}].name", f"duplicate field name {name!r}")
        datatype = _as_int(f.datatype, f"fields[{name}].datatype")
        if datatype not in POINT_FIELD_TYPES:
            raise PointCloudError(f"fields[{name}].datatype", f"unknown PointField datatype {datatype} (expected 1..8)")
        offset = _as_int(f.offset, f"fields[{name}].offset")
        count = _as_int(f.count, f"fields[{name}].count")
        if count == 0:
            continue  # a field with no elements occupies no bytes
        scalar = np.dtype(POINT_FIELD_TYPES[datatype]).newbyteorder(order)
        size = scalar.itemsize * count
        if offset + size > point_step:
            raise PointCloudError(
                "point_step",
                f"{point_step} bytes is too small for field {name!r} (offset {offset} + {size} bytes = {offset + size})",
            )
        for other, (start, end) in spans.items():
            if offset < end and start < offset + size:
                raise PointCloudError(f"fields[{name}].offset", f"bytes {offset}..{offset + size - 1} overlap field "
                                                               f"{other!r} at bytes {start}..{end - 1}")
        spans[name] = (offset, offset + size)
        names.append(name)
        formats.append(scalar if count == 1 else np.dtype((scalar, (count,))))
        offsets.append(offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def read_points(msg) -> np.ndarray:
    """Zero-copy structured view (height, width) of a PointCloud2's points."""
    height = _as_int(msg.height, "height")
    width = _as_int(msg.width, "width")
    dtype = pointcloud2_dtype(msg.fields, msg.point_step, bool(msg.is_bigendian))
    point_step = dtype.itemsize
    if height == 0 or width == 0:
        raise PointCloudError("width" if width == 0 else "height", f"empty cloud ({width} x {height} points)")
    row_step = _as_int(msg.row_step, "row_step")
    if height == 1 and row_step == 0:
        row_step = width * point_step  # some writers leave row_step unset for unorganized clouds
    if row_step < width * point_step:
        raise PointCloudError("row_step", f"{row_step} is less than width x point_step = {width} x {point_step}")
    buf = _buffer(msg.data, "PointCloud2")
    needed = row_step * (height - 1) + width * point_step
    if buf.size < needed:
        raise PointCloudError(
            "data",
            f"{buf.size} bytes is shorter than the {needed} bytes that width x height x point_step "
            f"({width} x {height} x {point_step}, row_step {row_step}) need",
        )
    return np.ndarray(shape=(height, width), dtype=dtype, buffer=buf, offset=0, strides=(row_step, point_step))


def _field_names(points: np.ndarray) -> tuple[str, ...]:
    return points.dtype.names or ()


def _scalar_field(points: np.ndarray, name: str) -> np.ndarray:
    sub = points[name]
    if sub.ndim != points.ndim:  # count > 1: use the first element
        sub = sub[..., 0]
    return sub


def _xyz_view(points: np.ndarray) -> np.ndarray:
    """(..., 3) array of x, y, z: a strided zero-copy view when the three fields are adjacent native floats of
    one type, a copy otherwise. Always native byte order, float32 or float64."""
    names = _field_names(points)
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise PointCloudError("fields", f"no {axis!r} field (fields: {list(names) or 'none'})")
    fields = points.dtype.fields
    types = [fields[a][0] for a in ("x", "y", "z")]
    offsets = [fields[a][1] for a in ("x", "y", "z")]
    for axis, t in zip(("x", "y", "z"), types):
        if t.kind != "f" or t.shape != ():
            raise PointCloudError(f"fields[{axis}].datatype", f"expected FLOAT32 or FLOAT64 with count 1, got {t}")
    t0 = types[0]
    if all(t == t0 for t in types):
        # a view when x, y, z are evenly spaced fields of one type (the common layout), a copy otherwise
        xyz = structured_to_unstructured(points[["x", "y", "z"]], copy=False)
        return xyz if xyz.dtype.isnative else xyz.astype(xyz.dtype.newbyteorder("="))
    out_type = np.float64 if any(t.itemsize == 8 for t in types) else np.float32
    out = np.empty(points.shape + (3,), dtype=out_type)
    for k, axis in enumerate(("x", "y", "z")):
        out[..., k] = points[axis]
    return out


@dataclasses.dataclass
class CloudArrays:
    """A converted PointCloud2. Unorganized clouds: xyz (N, 3) with non-finite points removed (per-point arrays
    filtered alike); organized clouds (height > 1): xyz (H, W, 3) with NaN where there is no return."""

    xyz: np.ndarray
    organized: bool
    ring: np.ndarray | None = None
    intensity: np.ndarray | None = None
    time: np.ndarray | None = None  # per-point time in seconds (relative or absolute, as the driver sends it)
    frame_id: str = ""
    stamp: float = 0.0

    @property
    def num_points(self) -> int:
        return int(np.prod(self.xyz.shape[:-1]))


def _ring(points: np.ndarray) -> np.ndarray | None:
    if "ring" not in _field_names(points):
        return None
    ring = _scalar_field(points, "ring")
    if ring.dtype.kind == "f":
        # Some converters write every field as floats: whole numbers are rings all the same.
        whole = np.isfinite(ring) & (ring == np.round(ring)) & (np.abs(ring) < 2**31)
        if not whole.all():
            bad = np.flatnonzero(~whole.reshape(-1))[0]
            raise PointCloudError("fields[ring].datatype",
                                  f"expected an integer type (UINT8/UINT16) or whole numbers, got {ring.dtype} value "
                                  f"{ring.reshape(-1)[bad]} at point {bad}")
    elif ring.dtype.kind not in "iu":
        raise PointCloudError("fields[ring].datatype", f"expected an integer type (UINT8/UINT16), got {ring.dtype}")
    return ring.astype(np.int32)


def _point_time(points: np.ndarray) -> np.ndarray | None:
    for name in TIME_FIELDS:
        if name in _field_names(points):
            raw = _scalar_field(points, name)
            if raw.dtype.kind in "iu":  # integer per-point time is in nanoseconds (Ouster "t")
                return raw.astype(np.float64) * 1e-9
            return raw.astype(np.float64)
    return None


ABSOLUTE_TIME_S = 1e5  # per-point times beyond a day are clock times (Hesai, Livox), not offsets within a sweep
MAX_SWEEP_S = 1.0


def sweep_times(cloud: CloudArrays) -> np.ndarray | None:
    """The cloud's per-point times as seconds from its header stamp (the engine's `time`), or None without a time
    field. Clock times have the stamp subtracted; offsets (Velodyne `time`, Ouster `t`) are taken as from the stamp.
    The times of points without a return (NaN in an organized cloud) do not matter and become 0. PointCloudError
    naming the field when a point's time is not finite or the times do not lie within one sweep (1 s)."""
    if cloud.time is None:
        return None
    times = np.array(cloud.time, dtype=np.float64)
    xyz = cloud.xyz
    measured = np.isfinite(xyz[..., 0]) & np.isfinite(xyz[..., 1]) & np.isfinite(xyz[..., 2])
    times[~measured] = 0.0
    if not np.isfinite(times).all():
        raise PointCloudError("fields[time]", f"expected a finite time for every point, got "
                                              f"{int((~np.isfinite(times)).sum())} non-finite")
    if measured.any() and np.median(np.abs(times[measured])) > ABSOLUTE_TIME_S:
        times[measured] -= cloud.stamp
    first, last = (float(times[measured].min()), float(times[measured].max())) if measured.any() else (0.0, 0.0)
    if last - first > MAX_SWEEP_S or max(abs(first), abs(last)) > 2 * MAX_SWEEP_S:
        raise PointCloudError("fields[time]", f"expected the points' times within one sweep of the header stamp "
                                              f"(seconds, or clock times), got {first:.6g} .. {last:.6g} s from it")
    return times


def pointcloud2_to_arrays(msg, *, max_points: int = 0, organized: bool | None = None) -> CloudArrays:
    """Convert a PointCloud2 to numpy. ``organized`` (default: height > 1) selects (H, W, 3) output.
    Raises PointCloudError for malformed clouds, an empty cloud, a cloud without a finite point, or more
    than ``max_points`` points (0 = no limit)."""
    points = read_points(msg)
    if max_points and points.size > max_points:
        raise CloudTooLargeError(
            "width",
            f"{points.size} points exceed the max_points limit of {max_points} ({msg.width} x {msg.height})")
    if organized is None:
        organized = points.shape[0] > 1
    xyz = _xyz_view(points)
    # per coordinate: numpy reduces an axis of length 3 ~30x slower than it combines three strided columns
    finite = np.isfinite(xyz[..., 0]) & np.isfinite(xyz[..., 1]) & np.isfinite(xyz[..., 2])
    n_finite = int(np.count_nonzero(finite))
    if n_finite == 0:
        raise PointCloudError("data", f"no finite point among {points.size} (all NaN or inf)")
    ring = _ring(points)
    intensity = next((_scalar_field(points, n) for n in INTENSITY_FIELDS if n in _field_names(points)), None)
    if intensity is not None:
        intensity = intensity.astype(np.float32)
    ptime = _point_time(points)
    header = getattr(msg, "header", None)
    frame_id = str(getattr(header, "frame_id", "")) if header is not None else ""
    stamp = stamp_to_sec(header.stamp) if header is not None else 0.0
    if organized:
        if n_finite < finite.size:
            xyz = np.where(finite[..., None], xyz, np.nan).astype(xyz.dtype, copy=False)
        return CloudArrays(xyz, True, ring, intensity, ptime, frame_id, stamp)
    xyz = xyz.reshape(-1, 3)
    flat = finite.reshape(-1)
    extras = [a.reshape(-1) if a is not None else None for a in (ring, intensity, ptime)]
    if n_finite < flat.size:
        xyz = xyz[flat]
        extras = [a[flat] if a is not None else None for a in extras]
    return CloudArrays(xyz, False, *extras, frame_id=frame_id, stamp=stamp)


def pointcloud2_from_array(points: np.ndarray, *, frame_id: str = "", stamp=None, is_dense: bool | None = None):
    """Build a PointCloud2 from a structured array: (N,) -> unorganized (height 1), (H, W) -> organized.
    Field types must be one of the PointField types; byte order follows the array (big-endian allowed)."""
    from sensor_msgs.msg import PointCloud2, PointField

    points = np.asarray(points)
    if points.dtype.names is None:
        raise ValueError("points: expected a structured array with named fields (use pointcloud2_from_xyz)")
    if points.ndim == 1:
        points = points.reshape(1, -1)
    if points.ndim != 2:
        raise ValueError(f"points: expected shape (N,) or (H, W), got {points.shape}")
    fields, bigendian = [], None
    for name in points.dtype.names:
        t, offset = points.dtype.fields[name][:2]
        count = int(np.prod(t.shape)) if t.shape else 1
        base = t.base if t.shape else t
        code = NUMPY_TO_POINT_FIELD.get(base.newbyteorder("="))
        if code is None:
            raise ValueError(f"points[{name!r}]: dtype {base} has no PointField datatype")
        if base.itemsize > 1:
            big = base.byteorder == ">" or (base.byteorder == "=" and sys.byteorder == "big")
            if bigendian is not None and big != bigendian:
                raise ValueError(f"points[{name!r}]: mixed byte orders")
            bigendian = big
        fields.append(PointField(name=name, offset=int(offset), datatype=code, count=count))
    msg = PointCloud2()
    set_header(msg, frame_id, stamp)
    msg.height, msg.width = int(points.shape[0]), int(points.shape[1])
    msg.fields = fields
    msg.is_bigendian = bool(bigendian)
    msg.point_step = int(points.dtype.itemsize)
    msg.row_step = msg.point_step * msg.width
    msg.data = np.ascontiguousarray(points).tobytes()
    if is_dense is None:
        has_xyz = all(a in points.dtype.names for a in ("x", "y", "z"))
        is_dense = bool(has_xyz and all(np.isfinite(points[a]).all() for a in ("x", "y", "z")))
    msg.is_dense = bool(is_dense)
    return msg


def pointcloud2_from_xyz(
    xyz: np.ndarray,
    *,
    intensity: np.ndarray | None = None,
    ring: np.ndarray | None = None,
    time: np.ndarray | None = None,
    frame_id: str = "",
    stamp=None,
    dtype=np.float32,
    ring_dtype=np.uint16,
):
    """Build a PointCloud2 with fields x, y, z (float32 or float64), optional intensity (float32), ring
    (uint16 or uint8) and per-point time (float32 seconds). xyz (N, 3) -> unorganized, (H, W, 3) -> organized."""
    xyz = np.asarray(xyz)
    if xyz.shape[-1:] != (3,) or xyz.ndim not in (2, 3):
        raise ValueError(f"xyz: expected shape (N, 3) or (H, W, 3), got {xyz.shape}")
    shape = xyz.shape[:-1]
    spec = [("x", dtype), ("y", dtype), ("z", dtype)]
    extras = {"intensity": (intensity, np.float32), "ring": (ring, ring_dtype), "time": (time, np.float32)}
    for name, (values, t) in extras.items():
        if values is not None:
            if np.shape(values) != shape:
                raise ValueError(f"{name}: expected shape {shape} like xyz, got {np.shape(values)}")
            spec.append((name, t))
    points = np.empty(shape, dtype=spec)
    points["x"], points["y"], points["z"] = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    for name, (values, _) in extras.items():
        if values is not None:
            points[name] = values
    return pointcloud2_from_array(points, frame_id=frame_id, stamp=stamp)


# ---------------------------------------------------------------------------------------------- Image


def image_dimension(msg, name: str) -> int:
    """An Image's height or width, checked (ImageError naming it)."""
    return _as_int(getattr(msg, name), name, ImageError)


def image_to_depth(msg, *, max_pixels: int = 0) -> np.ndarray:
    """Depth Image (16UC1/mono16 millimetres, 32FC1 metres) -> (H, W) float32 metres, 0 where there is no
    measurement (0, NaN, inf, negative). Raises ImageError for malformed images or an image without depth,
    TooLargeError for more than ``max_pixels`` pixels (0 = no limit) before touching a pixel."""
    encoding = str(msg.encoding)
    if encoding not in DEPTH_ENCODINGS:
        raise ImageError("encoding", f"unsupported depth encoding {encoding!r} (expected one of {sorted(DEPTH_ENCODINGS)})")
    scalar, scale = DEPTH_ENCODINGS[encoding]
    height = image_dimension(msg, "height")
    width = image_dimension(msg, "width")
    if height == 0 or width == 0:
        raise ImageError("width" if width == 0 else "height", f"empty image ({width} x {height})")
    if max_pixels and width * height > max_pixels:
        raise ImageTooLargeError("width", f"{width} x {height} = {width * height} pixels exceed the max_pixels "
                                              f"limit of {max_pixels}")
    dtype = np.dtype(scalar).newbyteorder(">" if msg.is_bigendian else "<")
    step = _as_int(msg.step, "step", ImageError)
    if step < width * dtype.itemsize:
        raise ImageError("step", f"{step} is less than width x {dtype.itemsize} bytes = {width * dtype.itemsize}")
    buf = _buffer(msg.data, "Image")
    needed = step * (height - 1) + width * dtype.itemsize
    if buf.size < needed:
        raise ImageError("data", f"{buf.size} bytes is shorter than the {needed} bytes a {width} x {height} "
                                 f"{encoding} image with step {step} needs")
    raw = np.ndarray(shape=(height, width), dtype=dtype, buffer=buf, offset=0, strides=(step, dtype.itemsize))
    depth = raw.astype(np.float32)
    if scale != 1.0:
        depth *= np.float32(scale)
    depth[~(np.isfinite(depth) & (depth > 0))] = 0.0
    if not depth.any():
        raise ImageError("data", "no valid depth (every pixel is 0, NaN, inf or negative)")
    return depth


def depth_to_image(depth_m: np.ndarray, *, encoding: str = "16UC1", frame_id: str = "", stamp=None):
    """(H, W) metres -> sensor_msgs/Image in 16UC1 (millimetres, rounded; 0 = none) or 32FC1 (metres)."""
    from sensor_msgs.msg import Image

    depth_m = np.asarray(depth_m, dtype=np.float64)
    if depth_m.ndim != 2:
        raise ValueError(f"depth_m: expected shape (H, W), got {depth_m.shape}")
    if encoding in ("16UC1", "mono16"):
        valid = np.isfinite(depth_m) & (depth_m > 0)
        mm = np.where(valid, np.round(depth_m * 1000.0), 0.0)
        if (mm > 65535).any():
            raise ValueError("depth_m: depth beyond 65.535 m cannot be encoded as 16UC1 millimetres (use 32FC1)")
        pixels = mm.astype(np.uint16)
    elif encoding == "32FC1":
        pixels = depth_m.astype(np.float32)
    else:
        raise ValueError(f"encoding: expected 16UC1, mono16 or 32FC1, got {encoding!r}")
    msg = Image()
    set_header(msg, frame_id, stamp)
    msg.height, msg.width = int(pixels.shape[0]), int(pixels.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = sys.byteorder == "big"
    msg.step = int(pixels.shape[1] * pixels.itemsize)
    msg.data = np.ascontiguousarray(pixels).tobytes()
    return msg


# ---------------------------------------------------------------------------------------------- CameraInfo


def camera_info_to_K(msg, image_shape: tuple[int, int] | None = None) -> np.ndarray:
    """CameraInfo -> 3x3 intrinsic matrix K (float64), validated: finite entries, fx, fy > 0, last row
    (0, 0, 1), and when ``image_shape`` (H, W) is given and the CameraInfo states its size, matching size."""
    try:
        K = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    except (TypeError, ValueError):
        raise CameraInfoError("k", f"expected 9 numbers, got {np.size(msg.k)}") from None
    if not np.isfinite(K).all():
        raise CameraInfoError("k", "contains NaN or inf")
    fx, fy = K[0, 0], K[1, 1]
    if not (fx > 0 and fy > 0):
        raise CameraInfoError("k", f"focal length must be > 0 (fx = {fx}, fy = {fy}); is the camera calibrated?")
    if not np.allclose(K[2], (0.0, 0.0, 1.0)):
        raise CameraInfoError("k", f"last row must be (0, 0, 1), got {tuple(K[2])}")
    if image_shape is not None and int(msg.width) and int(msg.height):
        if (int(msg.height), int(msg.width)) != tuple(image_shape):
            raise CameraInfoError(
                "width", f"CameraInfo is {msg.width} x {msg.height} but the image is {image_shape[1]} x {image_shape[0]}"
            )
    return K


def camera_info_from_K(K: np.ndarray, width: int, height: int, *, frame_id: str = "", stamp=None):
    """3x3 K -> sensor_msgs/CameraInfo (plumb_bob, zero distortion, P = [K | 0])."""
    from sensor_msgs.msg import CameraInfo

    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K: expected shape (3, 3), got {K.shape}")
    msg = CameraInfo()
    set_header(msg, frame_id, stamp)
    msg.width, msg.height = int(width), int(height)
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = K.reshape(-1).tolist()
    msg.r = np.eye(3).reshape(-1).tolist()
    msg.p = np.hstack([K, np.zeros((3, 1))]).reshape(-1).tolist()
    return msg
