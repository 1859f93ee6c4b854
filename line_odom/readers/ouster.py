"""Ouster recordings through ouster-sdk: a pcap with the sensor's metadata json, or an .osf (metadata inside). One
organized cloud per scan (rows = beams, columns = azimuth, destaggered), each point's time from its column's
timestamp, in the sensor frame (os_sensor)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from line_odom.readers import pcap_packets, sensor_preset
from line_odom.readers.base import Frame, ReaderError, Source


def metadata_beside(pcap: Path) -> Path | None:
    """The metadata json of an Ouster pcap: the json beside it whose name starts the pcap's name the longest (the
    SDK's recordings are named <metadata>_<suffix>.pcap), else the only json in its folder."""
    jsons = sorted(pcap.parent.glob("*.json"))
    prefixed = [j for j in jsons if pcap.stem.startswith(j.stem)]
    if prefixed:
        return max(prefixed, key=lambda j: len(j.stem))
    return jsons[0] if len(jsons) == 1 else None


class OusterSource(Source):
    format = "ouster"
    frame_id = "os_sensor"

    def __init__(self, path: str | Path, meta: str | Path | None = None, frames: int | None = None):
        super().__init__(path)
        from ouster.sdk import open_source

        self.limit = frames
        self.osf = self.path.suffix.lower() == ".osf"
        if self.osf:
            self.meta = None
            kwargs = {}
        else:
            sizes = pcap_packets.payload_sizes(self.path)
            if pcap_packets.is_velodyne(sizes):
                raise ReaderError(f"{self.path}: a Velodyne pcap ({pcap_packets.VELODYNE_PACKET_BYTES}-byte packets), "
                                  f"not an Ouster one: use --format velodyne")
            self.meta = Path(meta) if meta is not None else metadata_beside(self.path)
            if self.meta is None:
                raise ReaderError(f"{self.path}: an Ouster pcap needs its sensor metadata json: none beside it "
                                  f"(expected <name>.json with the pcap's name starting with <name>); give it with "
                                  f"--meta")
            if not self.meta.is_file():
                raise ReaderError(f"{self.meta}: no such metadata json (for {self.path.name})")
            kwargs = {"meta": [str(self.meta)]}
        try:
            self._src = open_source(str(self.path), **kwargs)
            self.info = self._src.sensor_info[0]
        except Exception as exc:  # the SDK raises RuntimeError / ValueError / its own types for bad files
            what = "metadata json" if self.meta is not None else "osf"
            reason = (str(exc).splitlines() or [type(exc).__name__])[0]
            raise ReaderError(f"{self.meta or self.path}: ouster-sdk cannot read the {what} ({reason})") from None
        from ouster.sdk import core

        self._lut = core.XYZLut(self.info)
        self.beams = int(self.info.format.pixels_per_column)
        self.columns = int(self.info.format.columns_per_frame)
        self.product = str(self.info.prod_line)
        self.count = None
        if self.osf:
            self.count = int(self._src.frames_num[0]) if self._src.is_indexed else None
            if self.count is not None and frames is not None:
                self.count = min(self.count, frames)
        self.sensor = sensor_preset.for_organized(
            self.beams, f"Ouster {self.product} ({self.beams} beams x {self.columns} columns, from the "
                        f"{'osf' if self.osf else 'metadata json'})")

    def close(self) -> None:
        close = getattr(self._src, "close", None)
        if close is not None:
            close()

    def frames(self) -> Iterator[Frame]:
        from ouster.sdk import core

        n = 0
        for frame_set in self._src:
            scan = frame_set[0] if frame_set else None
            if scan is None:
                continue
            yield self._frame(scan, core)
            n += 1
            if self.limit is not None and n >= self.limit:
                return
        if n == 0:
            raise ReaderError(f"{self.path}: no scan of the {self.product} described by "
                              f"{self.meta.name if self.meta else 'the osf'} in it (is that metadata this "
                              f"recording's?)")

    def _frame(self, scan, core) -> Frame:
        rng = scan.field(core.ChanField.RANGE)
        xyz = self._lut(rng)
        xyz[rng == 0] = np.nan
        column_ns = np.asarray(scan.timestamp, dtype=np.int64)
        measured = column_ns > 0  # columns of packets that never arrived have no timestamp
        if not measured.any():
            raise ReaderError(f"{self.path}: scan {scan.frame_id} has no column timestamp")
        stamp_ns = int(column_ns[measured].min())
        seconds = np.where(measured, (column_ns - stamp_ns) * 1e-9, 0.0)
        time = np.ascontiguousarray(np.broadcast_to(seconds[None, :], rng.shape))
        xyz = core.destagger(self.info, xyz)
        time = core.destagger(self.info, time)
        intensity = None
        for name in ("REFLECTIVITY", "SIGNAL"):
            if scan.has_field(name):
                intensity = core.destagger(self.info, scan.field(name)).astype(np.float32)
                break
        return Frame(stamp_ns, xyz, None, time, intensity)
