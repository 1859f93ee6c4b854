"""Velodyne pcap (VLP-16, VLP-32C, HDL-32E, HDL-64E, VLS-128, ...) through velodyne-decoder: one cloud per rotation,
with each point's ring (beam, 0 = lowest) and time (s from the cloud's stamp)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from line_odom.readers import pcap_packets, sensor_preset
from line_odom.readers.base import Frame, ReaderError, Source

# product id (last byte of a data packet; the sensors' manuals) -> name, for the report
PRODUCT_IDS = {0x21: "HDL-32E", 0x22: "VLP-16", 0x24: "VLP-16 Hi-Res", 0x28: "VLP-32C", 0x31: "Velarray",
               0xA1: "VLS-128"}
PARTIAL_SHARE = 0.5  # a last cloud with fewer points than this share of the one before is a cut-off rotation


class VelodynePcap(Source):
    format = "velodyne"
    frame_id = "velodyne"

    def __init__(self, path: str | Path, frames: int | None = None):
        super().__init__(path)
        sizes = pcap_packets.payload_sizes(self.path)
        if not pcap_packets.is_velodyne(sizes):
            raise ReaderError(f"{self.path}: not a Velodyne pcap: expected {pcap_packets.VELODYNE_PACKET_BYTES}-byte "
                              f"data packets, found {pcap_packets.describe(sizes)} (an Ouster pcap needs --format "
                              f"ouster and its metadata json)")
        self.limit = frames
        self.model = self._product()
        clouds = self._clouds()
        first = next(clouds, None)
        clouds.close()
        if first is None:
            raise ReaderError(f"{self.path}: velodyne-decoder found no complete rotation in the pcap")
        xyz = np.stack([first[1]["x"], first[1]["y"], first[1]["z"]], axis=1)
        self.sensor = sensor_preset.for_rings(xyz, first[1]["ring"].astype(np.int64), f"Velodyne {self.model}")

    def _product(self) -> str:
        from velodyne_decoder.util import iter_pcap

        for _, data in iter_pcap(str(self.path)):
            if len(data) == pcap_packets.VELODYNE_PACKET_BYTES:
                return PRODUCT_IDS.get(data[-1], f"product id 0x{data[-1]:02x}")
        return "unknown"

    def _clouds(self):
        import velodyne_decoder as vd

        try:
            yield from vd.read_pcap(str(self.path), vd.Config(), as_pcl_structs=True)
        except (ValueError, RuntimeError) as exc:
            raise ReaderError(f"{self.path}: velodyne-decoder cannot decode it ({exc})") from None

    def frames(self) -> Iterator[Frame]:
        previous, n = None, 0
        for stamp, points in self._clouds():
            if previous is not None:
                yield self._frame(*previous)
                n += 1
                if self.limit is not None and n >= self.limit:
                    return
            previous = (stamp, points)
        if previous is not None:
            # the decoder flushes the packets after the last full rotation as a cloud of their own
            if n and len(previous[1]) < PARTIAL_SHARE * self._last_size:
                self.notes.append(f"the last cloud ({len(previous[1])} points) is a cut-off rotation: skipped")
                return
            yield self._frame(*previous)

    def _frame(self, stamp, points) -> Frame:
        self._last_size = len(points)
        xyz = np.stack([points["x"], points["y"], points["z"]], axis=1)
        return Frame(round(stamp.host * 1e9), xyz, points["ring"].astype(np.uint16),
                     points["time"].astype(np.float64), points["intensity"].astype(np.float32))
