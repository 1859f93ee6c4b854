"""Every recording `line_odom replay` takes, one reader per format, and the guess of the format from the path (as
KISS-ICP's pipeline picks its dataloader). rosbag2 bags are read by line_odom.bags (replay_bag), not here.

    source = open_source("OS-1-128.pcap")        # meta= the metadata json, else the json beside it
    for frame in source.frames(): ...            # Frame: stamp_ns, xyz, ring, time, intensity | depth
"""
from __future__ import annotations

from pathlib import Path

from line_odom.readers.base import Frame, ReaderError, Sensor, Source

FORMATS = ("rosbag2", "ros1", "velodyne", "ouster", "kitti", "kitti_raw", "tum", "scans")


def rosbag2_dir(path: Path) -> Path | None:
    """The rosbag2 directory of `path` (the directory, or a .db3 / .mcap file inside it), None when it is not one."""
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return path
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return None


def guess_format(path: str | Path) -> str:
    """The format of a recording from its path (and, for a .pcap, its packets); ReaderError naming what was
    expected when it is none of FORMATS."""
    from line_odom.readers import kitti_raw, pcap_packets, scan_folder

    path = Path(path)
    if not path.exists():
        raise ReaderError(f"{path}: no such bag, file or folder")
    if rosbag2_dir(path) is not None:
        return "rosbag2"
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".bag":
            return "ros1"
        if suffix == ".osf":
            return "ouster"
        if suffix in (".pcap", ".pcapng"):
            return "velodyne" if pcap_packets.is_velodyne(pcap_packets.payload_sizes(path)) else "ouster"
    elif path.is_dir():
        if kitti_raw.is_drive(path):
            return "kitti_raw"
        if (path / "velodyne").is_dir():
            return "kitti"
        if (path / "depth.txt").is_file():
            return "tum"
        if scan_folder.scan_suffix(path) is not None:
            return "scans"
    raise ReaderError(f"{path}: unknown recording format: expected a rosbag2 folder (metadata.yaml), a ROS 1 .bag, a "
                      f"Velodyne or Ouster .pcap, an Ouster .osf, a KITTI odometry sequence (velodyne/), a KITTI raw "
                      f"drive (velodyne_points/data/), a TUM RGB-D folder (depth.txt) or a folder of .bin / .pcd / "
                      f".ply scans (or name it with --format {'|'.join(FORMATS)})")


def open_source(path: str | Path, format: str | None = None, *, frames: int | None = None, topic: str | None = None,
                meta: str | Path | None = None) -> Source:
    """The recording at `path` opened by its reader (format: one of FORMATS but rosbag2, else guessed). topic: the
    ROS 1 bag's sensor topic; meta: an Ouster pcap's metadata json."""
    format = format or guess_format(path)
    if format not in FORMATS:
        raise ReaderError(f"--format: expected one of {', '.join(FORMATS)}, got {format!r}")
    path = Path(path)
    if not path.exists():
        raise ReaderError(f"{path}: no such bag, file or folder")
    if format == "rosbag2":
        raise ReaderError(f"{path}: rosbag2 bags are replayed by line_odom.replay.replay_bag")
    if format == "ros1":
        from line_odom.readers.ros1_bag import Ros1Bag

        return Ros1Bag(path, topic, frames)
    if format == "velodyne":
        from line_odom.readers.velodyne_pcap import VelodynePcap

        return VelodynePcap(path, frames)
    if format == "ouster":
        from line_odom.readers.ouster import OusterSource

        return OusterSource(path, meta, frames)
    if format == "kitti":
        from line_odom.readers.kitti_odometry import KittiOdometry

        return KittiOdometry(path, frames)
    if format == "kitti_raw":
        from line_odom.readers.kitti_raw import KittiRaw

        return KittiRaw(path, frames)
    if format == "tum":
        from line_odom.readers.tum_rgbd import TumRgbd

        return TumRgbd(path, frames)
    from line_odom.readers.scan_folder import ScanFolder

    return ScanFolder(path, frames)


__all__ = ["FORMATS", "Frame", "ReaderError", "Sensor", "Source", "guess_format", "open_source", "rosbag2_dir"]
