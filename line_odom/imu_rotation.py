"""The rotation guess from a gyro: sensor_msgs/Imu angular velocities kept for a few seconds and integrated on SO(3)
between two scans' stamps.

The engine registers each scan from its own translation prediction turned by this rotation instead of the
prediction's (``register_*(..., rotation_guess=R_prev_curr)``): a robot reversing its turn puts the whole change into
the constant-velocity prediction's heading, a gyro measures it (docs/NODE.md, "IMU rotation guess").

Integration: the rate is taken linear between samples (held past the ends by up to ``max_gap``), and each piece
between consecutive samples or scan stamps turns by the exponential of its mean rate times its length. The result
is the IMU's rotation R_imu(t0)^T R_imu(t1); ``in_sensor_frame`` conjugates it by the mounting.
"""
from __future__ import annotations

import bisect
import math

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom import convert
from line_odom.motion_guess import keep_window


class ImuError(convert.ConversionError):
    def __init__(self, field: str, reason: str):
        super().__init__("Imu", field, reason)


def gyro_sample(msg) -> tuple[int, str, np.ndarray]:
    """(stamp in ns, header.frame_id, angular velocity (3,) rad/s) of a sensor_msgs/Imu; ImuError naming the field
    when the rate is unusable."""
    covariance = msg.angular_velocity_covariance
    if len(covariance) and float(covariance[0]) == -1.0:
        raise ImuError("angular_velocity_covariance", "element 0 is -1: the message carries no angular velocity "
                                                      "(sensor_msgs/Imu convention)")
    w = msg.angular_velocity
    rate = np.array([w.x, w.y, w.z], dtype=float)
    if not np.isfinite(rate).all():
        raise ImuError("angular_velocity", f"expected finite rates (rad/s), got {rate.tolist()}")
    return convert.header_stamp_ns(msg.header.stamp, "Imu"), str(msg.header.frame_id).lstrip("/"), rate


class GyroRotation:
    """Gyro samples of one IMU by stamp, and the rotation between two stamps.

    max_gap: seconds between samples an interval may span (also from a scan's stamp to the nearest sample past an
    end); window: seconds of samples kept behind the newest; bias: rad/s subtracted from every rate (IMU axes)."""

    def __init__(self, *, max_gap: float = 0.05, window: float = 5.0, bias=(0.0, 0.0, 0.0)):
        self.max_gap_ns = int(round(max_gap * 1e9))
        self.window_ns = int(round(window * 1e9))
        self.bias = np.asarray(bias, dtype=float).reshape(3)
        self.frame_id: str | None = None  # of the first sample kept; samples of another frame are rejected
        self._stamps: list[int] = []
        self._rates: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_ns(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def clear(self) -> None:
        self._stamps.clear()
        self._rates.clear()

    def add(self, msg) -> bool:
        """Keeps the message's rate. ImuError when it is unusable: no or non-finite rate, another frame_id than the
        first sample's, a stamp at or before the newest kept (out of order) unless it lies more than the window back
        (a bag looping, a restarted clock): then the samples are forgotten first and False is returned."""
        stamp, frame_id, rate = gyro_sample(msg)
        if self.frame_id is not None and frame_id != self.frame_id:
            raise ImuError("header.frame_id", f"expected the IMU frame {self.frame_id!r} of the earlier samples, "
                                              f"got {frame_id!r}")
        restarted = False
        if self._stamps and stamp <= self._stamps[-1]:
            if stamp >= self._stamps[-1] - self.window_ns:
                what = "repeats" if stamp == self._stamps[-1] else "is before"
                raise ImuError("header.stamp", f"{stamp * 1e-9:.9f} s {what} the newest sample's "
                                               f"{self._stamps[-1] * 1e-9:.9f} s (stamps must increase)")
            self.clear()
            restarted = True
        self.frame_id = frame_id
        self._stamps.append(stamp)
        self._rates.append(rate)
        keep_window(self._stamps, self._rates, stamp, self.window_ns)
        return not restarted

    def learn_bias(self, residual: np.ndarray, seconds: float, gain: float) -> None:
        """Moves the bias a share `gain` towards what a registered rotation says it is: `residual` =
        rotvec(R_gyro^T R_registered) in IMU axes over an interval of `seconds` (the gyro turned by -residual more
        than the scans did, so its rates were high by -residual / seconds)."""
        self.bias = self.bias - gain * np.asarray(residual, dtype=float) / seconds

    def coverage_gap(self, t0_ns: int, t1_ns: int) -> str | None:
        """Why the samples do not cover [t0, t1] within max_gap, or None when they do."""
        stamps = self._stamps
        if not stamps:
            return "no gyro sample received yet"
        if t0_ns < stamps[0] - self.max_gap_ns:
            return (f"the oldest gyro sample kept ({stamps[0] * 1e-9:.3f} s) is after the previous scan "
                    f"({t0_ns * 1e-9:.3f} s) by more than imu.max_gap {self.max_gap_ns * 1e-9:g} s")
        if t1_ns > stamps[-1] + self.max_gap_ns:
            return (f"the newest gyro sample ({stamps[-1] * 1e-9:.3f} s) is before the scan ({t1_ns * 1e-9:.3f} s) "
                    f"by more than imu.max_gap {self.max_gap_ns * 1e-9:g} s")
        lo = max(bisect.bisect_right(stamps, t0_ns) - 1, 0)
        hi = min(bisect.bisect_left(stamps, t1_ns), len(stamps) - 1)
        gaps = np.diff(stamps[lo:hi + 1])
        if gaps.size and int(gaps.max()) > self.max_gap_ns:
            k = lo + int(np.argmax(gaps))
            return (f"no gyro sample for {gaps.max() * 1e-9:.3f} s between {stamps[k] * 1e-9:.3f} and "
                    f"{stamps[k + 1] * 1e-9:.3f} s (imu.max_gap {self.max_gap_ns * 1e-9:g} s)")
        return None

    def rate_at(self, stamp_ns: int) -> np.ndarray:
        """The bias-corrected rate at stamp_ns: linear between the samples around it, the end ones' past the ends."""
        stamps = self._stamps
        k = bisect.bisect_left(stamps, stamp_ns)
        if k == 0:
            return self._rates[0] - self.bias
        if k == len(stamps):
            return self._rates[-1] - self.bias
        t0, t1 = stamps[k - 1], stamps[k]
        alpha = (stamp_ns - t0) / (t1 - t0)
        return (1.0 - alpha) * self._rates[k - 1] + alpha * self._rates[k] - self.bias

    def rotation(self, t0_ns: int, t1_ns: int) -> tuple[np.ndarray | None, str | None]:
        """(R_imu(t0)^T R_imu(t1), None), or (None, why) when the samples do not cover the interval."""
        if t1_ns < t0_ns:
            return None, f"the interval ends ({t1_ns * 1e-9:.9f} s) before it starts ({t0_ns * 1e-9:.9f} s)"
        why = self.coverage_gap(t0_ns, t1_ns)
        if why is not None:
            return None, why
        inner = self._stamps[bisect.bisect_right(self._stamps, t0_ns):bisect.bisect_left(self._stamps, t1_ns)]
        knots = [t0_ns, *inner, t1_ns]
        rates = [self.rate_at(t) for t in knots]
        R = np.eye(3)
        for a in range(len(knots) - 1):
            dt = (knots[a + 1] - knots[a]) * 1e-9
            if dt > 0.0:
                R = R @ Rotation.from_rotvec(0.5 * (rates[a] + rates[a + 1]) * dt).as_matrix()
        return R, None


def in_sensor_frame(R_imu: np.ndarray, T_sensor_imu: np.ndarray) -> np.ndarray:
    """The sensor's rotation between two stamps from the IMU's: R_sensor_imu R_imu R_imu_sensor (a rigid mounting; the
    lever arm does not turn anything)."""
    R_sensor_imu = np.asarray(T_sensor_imu, dtype=float)[:3, :3]
    R = R_sensor_imu @ R_imu @ R_sensor_imu.T
    u, _, vt = np.linalg.svd(R)  # back onto SO(3) after the products' rounding
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
