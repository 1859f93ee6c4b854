"""A folder of scans, one file each: KITTI-layout .bin (float32 x, y, z, reflectance), .pcd (pypcd4) or .ply
(plyfile). Fields ring and t / time / timestamp are used when a file has them (line_odom.convert's meaning: integer
times are nanoseconds, times beyond a day are clock times). Stamps from a times.txt beside the scans (seconds, one a
line), else 0.1 s apart."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from line_odom import bags, convert, datasets
from line_odom.readers import sensor_preset
from line_odom.readers.base import Frame, ReaderError, Source, nominal_stamps_ns, sorted_files

SUFFIXES = (".bin", ".pcd", ".ply")
KITTI_RINGS = 64  # a .bin whose point order splits into 64 lines is a KITTI HDL-64E scan (bags.kitti_rings)


def scan_suffix(folder: Path) -> str | None:
    """The one scan suffix of the folder's files, None when it holds none; ReaderError when it mixes them."""
    found = sorted({p.suffix.lower() for p in folder.iterdir() if p.is_file() and p.suffix.lower() in SUFFIXES})
    if len(found) > 1:
        raise ReaderError(f"{folder}: scans of several formats ({', '.join(found)}); expected one per folder")
    return found[0] if found else None


def read_pcd(path: Path) -> dict[str, np.ndarray]:
    import pypcd4

    try:
        pc = pypcd4.PointCloud.from_path(path)
    except Exception as exc:  # pypcd4 raises several types for a bad header or body
        raise ReaderError(f"{path}: not a readable PCD file ({type(exc).__name__}: {exc})") from None
    data = pc.pc_data
    fields = {name: np.asarray(data[name]) for name in data.dtype.names}
    height, width = int(pc.metadata.height), int(pc.metadata.width)
    if height > 1 and width > 1 and height * width == len(data):  # an organized cloud: rows = beams
        fields = {name: a.reshape(height, width) for name, a in fields.items()}
    return fields


def read_ply(path: Path) -> dict[str, np.ndarray]:
    import plyfile

    try:
        ply = plyfile.PlyData.read(str(path))
        vertex = ply["vertex"].data
    except Exception as exc:  # plyfile raises PlyParseError, KeyError (no vertex element), ...
        raise ReaderError(f"{path}: not a readable PLY file with a vertex element ({type(exc).__name__}: {exc})") \
            from None
    return {name: np.asarray(vertex[name]) for name in vertex.dtype.names}


def read_bin(path: Path) -> dict[str, np.ndarray]:
    try:
        raw = datasets.read_kitti_bin(path)
    except ValueError as exc:
        raise ReaderError(str(exc)) from None
    fields = {"x": raw[:, 0], "y": raw[:, 1], "z": raw[:, 2], "intensity": raw[:, 3]}
    ring = bags.kitti_rings(raw)
    if len(raw) and int(ring.max()) + 1 == KITTI_RINGS:
        fields["ring"] = ring
    return fields


READERS = {".bin": read_bin, ".pcd": read_pcd, ".ply": read_ply}


def frame_from_fields(fields: dict[str, np.ndarray], stamp_ns: int, path: Path) -> Frame:
    missing = [a for a in "xyz" if a not in fields]
    if missing:
        raise ReaderError(f"{path}: no field {', '.join(missing)} (expected x, y, z; has {', '.join(fields)})")
    xyz = np.stack([fields["x"], fields["y"], fields["z"]], axis=-1)
    organized = xyz.ndim == 3
    ring = fields.get("ring")
    if ring is not None and ring.dtype.kind not in "iu":
        raise ReaderError(f"{path}: field ring is {ring.dtype}, expected an integer type")
    intensity = next((fields[n] for n in convert.INTENSITY_FIELDS if n in fields), None)
    raw_time = next((fields[n] for n in convert.TIME_FIELDS if n in fields), None)
    time = None
    if raw_time is not None:
        seconds = raw_time.astype(np.float64) * (1e-9 if raw_time.dtype.kind in "iu" else 1.0)
        measured = np.isfinite(xyz).all(axis=-1)
        clock = measured.any() and np.median(np.abs(seconds[measured])) > convert.ABSOLUTE_TIME_S
        cloud = convert.CloudArrays(xyz, organized, time=seconds,
                                    stamp=float(seconds[measured].min()) if clock else 0.0)
        try:
            time = convert.sweep_times(cloud)
        except convert.ConversionError as err:
            raise ReaderError(f"{path}: {err}") from None
        if clock:  # stamped at the sweep's first point
            stamp_ns = round(cloud.stamp * 1e9)
    if not organized:
        keep = np.isfinite(xyz).all(axis=1)
        if not keep.all():
            xyz, ring, time, intensity = (None if a is None else a[keep] for a in (xyz, ring, time, intensity))
    return Frame(stamp_ns, np.ascontiguousarray(xyz, dtype=np.float32 if xyz.dtype == np.float32 else np.float64),
                 None if ring is None or organized else ring.astype(np.uint16), time,
                 None if intensity is None else intensity.astype(np.float32))


class ScanFolder(Source):
    format = "scans"
    frame_id = "lidar"

    def __init__(self, path: str | Path, frames: int | None = None):
        super().__init__(path)
        if not self.path.is_dir():
            raise ReaderError(f"{self.path}: not a folder of scans")
        self.suffix = scan_suffix(self.path)
        if self.suffix is None:
            raise ReaderError(f"{self.path}: no scans ({', '.join(SUFFIXES)} files)")
        self.files = sorted_files(self.path, (self.suffix,))
        times = self.path / "times.txt"
        if times.is_file():
            stamps = np.loadtxt(times, ndmin=1)
            if len(stamps) < len(self.files):
                raise ReaderError(f"{times}: {len(stamps)} stamps for {len(self.files)} scans")
            self.stamps_ns = [round(float(s) * 1e9) for s in stamps[: len(self.files)]]
        else:
            self.stamps_ns = nominal_stamps_ns(len(self.files))
            self.notes.append("no times.txt beside the scans: stamped 0.1 s apart")
        if frames is not None:
            self.files = self.files[:frames]
        self.count = len(self.files)
        first = self._frame(0)
        self.sensor = sensor_preset.for_points(first.xyz, first.ring, f"{self.suffix} scans")

    def _frame(self, i: int) -> Frame:
        return frame_from_fields(READERS[self.suffix](self.files[i]), self.stamps_ns[i], self.files[i])

    def frames(self) -> Iterator[Frame]:
        for i in range(len(self.files)):
            yield self._frame(i)
