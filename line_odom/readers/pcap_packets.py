"""What a pcap holds, from the sizes of its UDP payloads: Velodyne data packets are 1206 bytes (the sensors' manuals),
Ouster's are larger and need the sensor's metadata json to be decoded."""
from __future__ import annotations

import collections
from pathlib import Path

from line_odom.readers.base import ReaderError

VELODYNE_PACKET_BYTES = 1206
SNIFF_PACKETS = 400


def payload_sizes(path: Path, limit: int = SNIFF_PACKETS) -> collections.Counter:
    """Payload bytes -> packets, over the first `limit` packets (velodyne_decoder's pcap iterator: innermost layer
    of each Ethernet frame)."""
    from velodyne_decoder.util import iter_pcap

    sizes: collections.Counter = collections.Counter()
    try:
        for i, (_, data) in enumerate(iter_pcap(str(path))):
            sizes[len(data)] += 1
            if i + 1 >= limit:
                break
    except (ValueError, OSError) as exc:  # dpkt: "invalid tcpdump header" for pcapng or another file
        raise ReaderError(f"{path}: not a readable libpcap capture ({exc})") from None
    return sizes


def is_velodyne(sizes: collections.Counter) -> bool:
    return sizes.get(VELODYNE_PACKET_BYTES, 0) > 0 and sizes[VELODYNE_PACKET_BYTES] >= 0.5 * sum(sizes.values())


def describe(sizes: collections.Counter) -> str:
    common = ", ".join(f"{n} x {size} bytes" for size, n in sizes.most_common(3))
    return f"UDP payloads {common}" if sizes else "no UDP packets"
