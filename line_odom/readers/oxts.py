"""KITTI raw OXTS GPS/INS records as poses, the way the KITTI raw devkit's convertOxtsToPose defines them: a Mercator
projection scaled at the first record's latitude, R = Rz(yaw) Ry(pitch) Rx(roll), every pose relative to the first;
and the same poses for the Velodyne through calib_imu_to_velo.txt.

Written here after the devkit's MATLAB (a text record of 30 numbers and a dozen lines of math) rather than taken from
pykitti, the Python port on PyPI: its last release predates NumPy 2, and this module is tested against known answers
(test/test_readers.py)."""
from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from line_odom.readers.base import ReaderError

EARTH_RADIUS_M = 6378137.0
OXTS_VALUES = 30  # lat lon alt roll pitch yaw, then velocities, accelerations, rates, accuracies, modes


def read_oxts(path: Path) -> np.ndarray:
    """One oxts/data/*.txt record: the 30 values (lat, lon in deg, alt in m, roll, pitch, yaw in rad, ...)."""
    try:
        values = np.array(path.read_text().split(), dtype=float)
    except ValueError as exc:
        raise ReaderError(f"{path}: expected {OXTS_VALUES} numbers (an OXTS record), {exc}") from None
    if values.size != OXTS_VALUES or not np.isfinite(values[:6]).all():
        raise ReaderError(f"{path}: expected {OXTS_VALUES} numbers (an OXTS record: lat lon alt roll pitch yaw ...) "
                          f"with finite pose values, got {values.size}")
    return values


def _rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def oxts_poses(records: np.ndarray) -> np.ndarray:
    """(N, 30) OXTS records -> (N, 4, 4) IMU poses in the first IMU pose's frame."""
    records = np.asarray(records, dtype=float)
    scale = np.cos(np.radians(records[0, 0]))
    poses = np.tile(np.eye(4), (len(records), 1, 1))
    for i, (lat, lon, alt, roll, pitch, yaw) in enumerate(records[:, :6]):
        poses[i, :3, 3] = (scale * np.radians(lon) * EARTH_RADIUS_M,
                           scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + lat) / 2.0)), alt)
        poses[i, :3, :3] = _rotation(roll, pitch, yaw)
    return np.linalg.inv(poses[0]) @ poses


def read_calib_rigid(path: Path) -> np.ndarray:
    """A KITTI raw calibration file of a rigid transform (R: 9 numbers, T: 3 numbers) -> 4x4 (x_to = T x_from;
    calib_imu_to_velo.txt gives T_velo_imu)."""
    if not path.is_file():
        raise ReaderError(f"{path}: no such calibration file (expected R: and T: lines)")
    fields = {}
    for line in path.read_text().splitlines():
        key, sep, rest = line.partition(":")
        if sep and key.strip() in ("R", "T"):
            try:
                fields[key.strip()] = np.array(rest.split(), dtype=float)
            except ValueError:
                raise ReaderError(f"{path}: line {key.strip()}: expected numbers, got {rest.strip()!r}") from None
    R, t = fields.get("R"), fields.get("T")
    if R is None or R.size != 9 or t is None or t.size != 3:
        raise ReaderError(f"{path}: expected 'R:' with 9 numbers and 'T:' with 3 (a rigid transform)")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.reshape(3, 3), t
    if not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-4) or np.linalg.det(T[:3, :3]) < 0:
        raise ReaderError(f"{path}: R is not a rotation matrix")
    return T


def velodyne_poses(imu_poses: np.ndarray, T_velo_imu: np.ndarray) -> np.ndarray:
    """IMU poses (in the first IMU frame) -> Velodyne poses in the first Velodyne frame."""
    return T_velo_imu @ imu_poses @ np.linalg.inv(T_velo_imu)


def read_timestamps_ns(path: Path) -> list[int]:
    """A KITTI raw timestamps.txt ('2011-09-26 13:02:25.964389445' a line) -> nanoseconds since the epoch (the
    clock as written, taken as UTC)."""
    out = []
    for k, line in enumerate(path.read_text().splitlines()):
        line = line.strip()
        if not line:
            continue
        whole, _, fraction = line.partition(".")
        try:
            seconds = datetime.datetime.strptime(whole, "%Y-%m-%d %H:%M:%S").replace(tzinfo=datetime.timezone.utc)
            nanos = int((fraction + "000000000")[:9]) if fraction else 0
        except ValueError:
            raise ReaderError(f"{path}: line {k + 1}: expected 'YYYY-MM-DD HH:MM:SS.fffffffff', got {line!r}") from None
        out.append(int(seconds.timestamp()) * 1_000_000_000 + nanos)
    return out
