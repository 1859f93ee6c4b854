"""What the node reports: rate-limited log lines per reason, and the /diagnostics status of the odometry."""
from __future__ import annotations

import collections
import re
import threading
import time
from typing import Any, Callable

import numpy as np

LOG_WINDOW_S = 10.0
MAX_REASONS = 256  # reasons tracked at once (the oldest is forgotten beyond that: memory stays bounded)
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d*)?(?:e[-+]?\d+)?", re.IGNORECASE)


class RateLimitedLog:
    """One line per reason and window: the first occurrence of a reason is logged, repeats within `window` seconds
    are counted, and the count is told ("... 37 more like this in the last 10 s") with the next line of that reason or,
    once the window is over, by ``flush()``. A reason is the text with its numbers taken out, so a stamp or a size
    in it does not make every line new."""

    def __init__(self, emit: Callable[[str], None], window: float = LOG_WINDOW_S, clock=time.monotonic):
        self._emit = emit
        self.window = window
        self._clock = clock
        self._lock = threading.Lock()
        # reason -> [window start, repeats counted, the last repeat's text]
        self._reasons: collections.OrderedDict[str, list] = collections.OrderedDict()

    def _more(self, n: int) -> str:
        return f" ... {n} more like this in the last {self.window:g} s"

    def __call__(self, text: str, reason: str | None = None) -> bool:
        """Logs `text` unless its reason was logged within the window (then counted); True when logged."""
        key = _NUMBER.sub("#", text if reason is None else reason)
        now = self._clock()
        with self._lock:
            state = self._reasons.get(key)
            if state is not None and now - state[0] < self.window:
                state[1] += 1
                state[2] = text
                return False
            more = self._more(state[1]) if state is not None and state[1] else ""
            self._reasons[key] = [now, 0, text]
            self._reasons.move_to_end(key)
            while len(self._reasons) > MAX_REASONS:
                self._reasons.popitem(last=False)
        self._emit(text + more)
        return True

    def flush(self) -> None:
        """Tells the counts of the windows that are over, and forgets those reasons."""
        now = self._clock()
        lines = []
        with self._lock:
            for key in [k for k, s in self._reasons.items() if now - s[0] >= self.window]:
                start, n, text = self._reasons.pop(key)
                if n:
                    lines.append(text + self._more(n))
        for line in lines:
            self._emit(line)


# counter -> what the status message says of a count since the previous status
PROBLEM_COUNTERS = (
    ("frames_malformed", "frame(s) malformed"), ("frames_failed", "frame(s) failed"),
    ("frames_too_large", "frame(s) too large (max_points, max_pixels)"),
    ("frames_dropped", "frame(s) dropped (processing behind or no CameraInfo)"),
    ("frames_lost_in_transport", "input message(s) lost by DDS before reaching the node"),
    ("frames_duplicate", "frame(s) with a repeated stamp"),
    ("frames_unguessed", "frame(s) without a guess_odom pose (constant-velocity prediction)"),
    ("guess_rejected", "guess_odom message(s) rejected"),
    ("frames_without_imu", "frame(s) without the gyro's rotation (plain prediction)"),
    ("imu_rejected", "imu message(s) rejected"),
    ("frames_no_extrinsic", "frame(s) dropped: the sensor's mounting not on /tf_static yet"),
    ("tf_rejected", "/tf_static transform(s) rejected"),
    ("initial_poses_rejected", "initialpose message(s) rejected"),
    ("point_times_ignored", "frame(s) registered without deskewing (unusable point times)"),
    ("ring_fields_ignored", "frame(s) whose ring field held one value (rows from elevation)"),
    ("clouds_not_fitting_sensor", "cloud(s) not fitting the sensor model (sensor_fit)"),
)
ENGINE_STATS = (
    "solver", "inliers", "degenerate", "held_directions", "candidates", "h_lines", "v_lines", "registered_lines",
    "planes", "prediction", "unmeasured_directions", "window_scans", "turn_searched", "turn_recovered", "deskewed",
    "previous_deskewed_again", "deskewed_again", "points_refined", "point_matches")


def frame_values(counters: dict, receive_times: list, latencies_ms, stats: dict) -> dict[str, Any]:
    """The key/value pairs of the status: counters, input rate, latency, the last frame's engine statistics."""
    rate = 0.0
    if len(receive_times) >= 2 and receive_times[-1] > receive_times[0]:
        rate = (len(receive_times) - 1) / (receive_times[-1] - receive_times[0])
    values: dict[str, Any] = {**counters, "input_rate_hz": rate}
    lat = np.asarray(latencies_ms, dtype=float)
    if lat.size:
        values.update(latency_ms_last=lat[-1], latency_ms_mean=float(lat.mean()),
                      latency_ms_p95=float(np.percentile(lat, 95)))
    for key in ENGINE_STATS:
        if key in stats:
            values[key] = stats[key]
    if "persistence" in stats:  # the share of the last motion the prediction carried, x y z rx ry rz
        values["persistence"] = " ".join(f"{a:.2f}" for a in stats["persistence"])
    for stage, ms in (stats.get("ms") or {}).items():
        values[f"ms.{stage}"] = ms
    return values


def diagnostic_array(name: str, hardware_id: str, values: dict[str, Any], since: dict[str, int], stamp_msg=None):
    """A DiagnosticArray (one status): OK, or WARN when the last frame was degenerate or frames were dropped,
    malformed or failed since the previous status (`since`: counter increments)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    status = DiagnosticStatus()
    status.name = name
    status.hardware_id = hardware_id
    problems = []
    if values.get("degenerate"):
        held = values.get("held_directions", 6)
        problems.append("degenerate geometry: pose held by the motion model, covariance inflated" if held >= 6 else
                        f"degenerate geometry: {held} of 6 motion directions held by the motion model, "
                        "covariance inflated along them")
    if values.get("unmeasured_directions"):
        problems.append(f"velocity along {values['unmeasured_directions']} direction(s) not measured since the "
                        "start, reset or stamp gap (held at standing still), searched each frame")
    for key, text in PROBLEM_COUNTERS:
        if since.get(key):
            problems.append(f"{since[key]} {text}")
    if values["frames_processed"] == 0:
        status.level = DiagnosticStatus.WARN
        status.message = "waiting for input" if values["frames_received"] == 0 else "no frame processed yet"
        if problems:
            status.message += "; " + "; ".join(problems)
    elif problems:
        status.level = DiagnosticStatus.WARN
        status.message = "; ".join(problems)
    else:
        status.level = DiagnosticStatus.OK
        status.message = "tracking"
    for key, value in values.items():
        text = f"{value:.3f}" if isinstance(value, float) else str(value)
        status.values.append(KeyValue(key=key, value=text))
    array = DiagnosticArray()
    if stamp_msg is not None:
        array.header.stamp = stamp_msg
    array.status = [status]
    return array
