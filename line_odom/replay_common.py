"""What replay.py and replay_realtime.py share (the input chosen, the node's output, the node's settings), in a module
of its own so that neither imports the other for it."""
from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from line_odom import evaluation

PRESET_FOR_INPUT = {"pointcloud": "kitti_hdl64", "depth": "tum_kinect"}


@dataclasses.dataclass
class ReplayInput:
    kind: str  # "pointcloud" or "depth"
    topic: str
    info_topic: str | None = None  # CameraInfo topic for depth


@dataclasses.dataclass
class ReplayRun:
    """What the node produced for a recording."""

    estimate: evaluation.Trajectory  # sensor poses at the frame stamps
    odometry_msgs: list  # (stamp_ns, nav_msgs/Odometry) as the node published them
    latencies_ms: list[float]
    frames_in: int
    counters: dict[str, int]


def node_settings(kind: str, params: str | None = None, overrides: Mapping[str, Any] | None = None):
    """(engine Config, NodeSettings) for this input kind: the --params file (or preset name), else the preset for the
    input kind."""
    from line_odom.processor import settings_from_parameters

    return settings_from_parameters(params or PRESET_FOR_INPUT[kind], {**(overrides or {}), "input": kind})
