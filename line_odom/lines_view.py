"""The lines the odometry registered, for rviz (``~/lines``): each scan's H-lines (along its rows) and V-lines (along
its columns) as two LINE_LIST markers in the sensor frame, deskewed, as the engine registered them."""
from __future__ import annotations

import numpy as np

from line_odom import convert

H_COLOUR = (0.95, 0.35, 0.1)  # rows: orange
V_COLOUR = (0.1, 0.55, 0.95)  # columns: blue
WIDTH = 0.03  # m


def _line_list(marker_id: int, ns: str, segments: np.ndarray, colour, header):
    from geometry_msgs.msg import Point
    from visualization_msgs.msg import Marker

    marker = Marker()
    marker.header = header
    marker.ns = ns
    marker.id = marker_id
    marker.type = Marker.LINE_LIST
    marker.action = Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.scale.x = WIDTH
    marker.color.r, marker.color.g, marker.color.b = colour
    marker.color.a = 1.0
    ends = np.asarray(segments, dtype=np.float64).reshape(-1, 3)
    marker.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in ends[np.isfinite(ends).all(axis=1)]]
    return marker


def lines_message(h_segments: np.ndarray, v_segments: np.ndarray, frame_id: str, stamp_ns: int):
    """MarkerArray: marker 0 the H-lines, marker 1 the V-lines (each segment two points of a LINE_LIST)."""
    from std_msgs.msg import Header
    from visualization_msgs.msg import MarkerArray

    header = Header(frame_id=frame_id, stamp=convert.ns_to_stamp(stamp_ns))
    return MarkerArray(markers=[_line_list(0, "h_lines", h_segments, H_COLOUR, header),
                                _line_list(1, "v_lines", v_segments, V_COLOUR, header)])
