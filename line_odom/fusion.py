"""What the node fuses around the registration, ROS-free: the sensor's mounting (base_to_sensor or /tf_static), the
motion guess of another odometry source (guess_odom), the gyro's rotation between two scans and over a sweep (imu),
and the gyro bias learnt from registered frames. Each input has its own lock, so the executor thread that stores
messages never waits for a registration."""
from __future__ import annotations

import math
import threading
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from line_odom import convert, frames
from line_odom.imu_rotation import GyroRotation, in_sensor_frame
from line_odom.motion_guess import MotionGuess
from line_odom.node_parameters import NodeSettings
from line_odom.static_tf import StaticTransforms, TransformError

# (counter, reason, what) -> None: counts the rejection and logs it (rate-limited)
Reject = Callable[[str, str, str], None]


def _pose_text(T: np.ndarray) -> str:
    rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    return f"{[round(float(v), 6) for v in (*T[:3, 3], *rpy)]} [x, y, z, roll, pitch, yaw]"


class Fusion:
    """settings: NodeSettings; max_translation / max_rotation_deg: the registration's limits (a guess beyond them
    is a jump, not a motion); reject, count, info: the processor's reporting."""

    def __init__(self, settings: NodeSettings, max_translation: float, max_rotation_deg: float, *, reject: Reject,
                 count: Callable[[str], None], info: Callable[[str], None]):
        self.settings = settings
        self._max_t, self._max_r = max_translation, max_rotation_deg
        self._reject, self._count, self._info = reject, count, info
        self.T_base_sensor = frames.pose_from_params(settings.base_to_sensor, "base_to_sensor")
        self.T_sensor_base = frames.inverse(self.T_base_sensor)
        self.guess = (MotionGuess(settings.base_frame, tolerance=settings.guess_tolerance,
                                  window=settings.guess_window) if settings.guess_enabled else None)
        self.guess_lock = threading.Lock()
        self.imu_lock = threading.Lock()
        self._imu_arrived = threading.Condition(self.imu_lock)  # notified by add_imu
        self.gyro = (GyroRotation(max_gap=settings.imu_max_gap, window=settings.imu_window,
                                  bias=settings.imu_gyro_bias) if settings.imu_enabled else None)
        # T_base_imu: the parameter's, or with base_to_sensor_from_tf looked up on /tf_static (None until then)
        self.T_base_imu: np.ndarray | None = (
            None if settings.base_to_sensor_from_tf
            else frames.pose_from_params(settings.imu_base_to_imu, "imu.base_to_imu"))
        self.static_tf = StaticTransforms() if settings.base_to_sensor_from_tf else None
        self.tf_lock = threading.Lock()
        self.mounted_frame: str | None = None  # the sensor frame whose /tf_static mounting is T_base_sensor
        self.guess_prev: np.ndarray | None = None  # the guess source's T_source_base at the previous frame

    def counters(self) -> dict[str, int]:
        """The counters of the enabled inputs, at zero."""
        names = []
        if self.guess is not None:
            names += ["frames_guessed", "frames_unguessed", "guess_rejected"]
        if self.gyro is not None:
            names += ["frames_imu", "frames_without_imu", "imu_rejected", "sweeps_without_gyro"]
        if self.static_tf is not None:
            names += ["frames_no_extrinsic", "tf_rejected"]
        return dict.fromkeys(names, 0)

    def clear(self) -> None:
        """A reset: the next guess is measured from the next frame."""
        self.guess_prev = None

    # ------------------------------------------------------------------ messages in
    def add_guess(self, msg) -> bool:
        if self.guess is None:
            return False
        try:
            with self.guess_lock:
                if not self.guess.add(msg):
                    self._info("guess_odom stamp went backwards: its earlier poses are forgotten")
        except convert.ConversionError as err:
            self._reject("guess_rejected", str(err), "rejected guess_odom message")
            return False
        return True

    def add_imu(self, msg) -> bool:
        if self.gyro is None:
            return False
        try:
            with self.imu_lock:
                self._imu_arrived.notify_all()
                if not self.gyro.add(msg):
                    self._info("imu stamp went back by more than imu.window: its earlier samples are forgotten")
        except convert.ConversionError as err:
            self._reject("imu_rejected", str(err), "rejected imu message")
            return False
        return True

    def add_static_tf(self, msg) -> bool:
        if self.static_tf is None:
            return False
        try:
            with self.tf_lock:
                self.static_tf.add(msg)
        except TransformError as err:
            self._reject("tf_rejected", str(err), "rejected /tf_static transform")
            return False
        return True

    # ------------------------------------------------------------------ per frame
    def mount(self, frame_id: str) -> bool:
        """base_to_sensor_from_tf: T_base_sensor from /tf_static, looked up at the first frame that has it and kept
        (a static mounting); False, with the frame logged and counted, while it is unknown or for another sensor."""
        if self.static_tf is None:
            return True
        frame_id = frame_id.lstrip("/")
        if self.mounted_frame is not None:
            if frame_id == self.mounted_frame:
                return True
            self._reject("frames_malformed", f"header.frame_id {frame_id!r} is not the sensor frame "
                                             f"{self.mounted_frame!r} whose /tf_static mounting is in use",
                         "dropped frame")
            return False
        if not frame_id:
            self._reject("frames_malformed", "header.frame_id is empty: base_to_sensor_from_tf looks the sensor's "
                                             "mounting up on /tf_static by it", "dropped frame")
            return False
        base = self.settings.base_frame
        with self.tf_lock:
            T = self.static_tf.lookup(base, frame_id)
            known = len(self.static_tf)
        if T is None:
            self._reject("frames_no_extrinsic", f"no transform {base} -> {frame_id} on /tf_static yet "
                                                f"(base_to_sensor_from_tf; {known} static transform(s) received)",
                         "dropped frame")
            return False
        self.T_base_sensor, self.T_sensor_base = T, frames.inverse(T)
        self.mounted_frame = frame_id
        self._info(f"base_to_sensor from /tf_static: {base} -> {frame_id} = {_pose_text(T)}")
        return True

    def guess_delta(self, stamp_ns: int) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(the sensor's motion since the previous frame by the guess source (T_prev_curr) or None, the source's
        T_source_base at this frame or None)."""
        if self.guess is None:
            return None, None
        with self.guess_lock:
            T = self.guess.pose_at(stamp_ns)
        if T is None or self.guess_prev is None:  # (None on the first frame after a start or reset)
            return None, T
        delta = self.T_sensor_base @ (frames.inverse(self.guess_prev) @ T) @ self.T_base_sensor
        # A jump the registration could not follow (a source reset to its origin, a glitch) is no guess: held, it
        # would move the pose by it.
        moved = float(np.linalg.norm(delta[:3, 3]))
        turned = math.degrees(float(np.linalg.norm(frames.rotation_vector(delta[:3, :3]))))
        if moved > self._max_t or turned > self._max_r:
            self._reject("guess_rejected", f"guess_odom moved the sensor {moved:.2f} m and {turned:.1f} deg between "
                                           f"two scans, beyond registration.max_translation {self._max_t:g} m / "
                                           f"registration.max_rotation_deg {self._max_r:g} deg", "ignored motion guess")
            return None, T
        return delta, T

    def imu_rotation(self, last_ns: int | None, stamp_ns: int) -> np.ndarray | None:
        """The sensor's rotation since the previous frame by the gyro (R_prev_curr), or None (first frame, the
        samples do not cover the interval, or the IMU's mounting is not known yet: counted in frames_without_imu)."""
        if self.gyro is None or last_ns is None:
            return None
        with self.imu_lock:
            R_imu, why = self.gyro.rotation(last_ns, stamp_ns)
            imu_frame = self.gyro.frame_id
        if R_imu is not None and self.T_base_imu is None:
            base = self.settings.base_frame
            T = None
            if imu_frame:
                with self.tf_lock:
                    T = self.static_tf.lookup(base, imu_frame)
            if T is None:
                why = (f"no transform {base} -> {imu_frame} on /tf_static yet (the IMU's mounting, "
                       "base_to_sensor_from_tf)" if imu_frame else
                       "the Imu messages' header.frame_id is empty: with base_to_sensor_from_tf the IMU's mounting "
                       "is looked up on /tf_static by it")
                R_imu = None
            else:
                self.T_base_imu = T
                self._info(f"IMU mounting from /tf_static: {base} -> {imu_frame} = {_pose_text(T)}")
        if R_imu is None:
            self._reject("frames_without_imu", f"scan at {stamp_ns * 1e-9:.3f} s registered without the gyro: {why}",
                         "plain prediction")
            return None
        return in_sensor_frame(R_imu, self.T_sensor_imu())

    def T_sensor_imu(self) -> np.ndarray:
        """The IMU's pose in the sensor frame (T_sensor_base T_base_imu; T_base_imu known)."""
        return self.T_sensor_base @ self.T_base_imu

    def await_gyro(self, until_ns: int) -> None:
        """Waits up to imu.wait for a gyro sample at or past `until_ns` (the scan's stamp or its sweep's end): a scan's
        message can come before the samples of its sweep (a burst, a driver starting up)."""
        if self.gyro is None or self.settings.imu_wait <= 0.0:
            return
        with self._imu_arrived:
            self._imu_arrived.wait_for(lambda: (self.gyro.newest_ns or -1) >= until_ns, timeout=self.settings.imu_wait)

    def sweep_rate(self, stamp_ns: int, times: np.ndarray) -> np.ndarray | None:
        """The sensor's mean angular velocity (rad/s, its axes) over a sweep's times by the gyro (imu.enabled), or
        None: no gyro, the mounting not known yet, or the samples do not cover the sweep (counted in
        sweeps_without_gyro; the sweep is then corrected at the prediction's turn)."""
        if self.gyro is None or self.T_base_imu is None:
            return None
        t0, t1 = stamp_ns + round(float(times.min()) * 1e9), stamp_ns + round(float(times.max()) * 1e9)
        if t1 <= t0:
            return None
        with self.imu_lock:
            R_imu, _ = self.gyro.rotation(t0, t1)
        if R_imu is None:
            self._count("sweeps_without_gyro")
            return None
        rate_imu = Rotation.from_matrix(R_imu).as_rotvec() / ((t1 - t0) * 1e-9)
        return self.T_sensor_imu()[:3, :3] @ rate_imu

    def engine_guess(self, guess: np.ndarray | None, rotation: np.ndarray | None) -> dict:
        """The registration's guess keywords: the source's translation with the gyro's rotation when both are there
        (keywords only when there is a guess: engines without them keep working)."""
        if guess is not None and rotation is not None:
            guess = guess.copy()
            guess[:3, :3] = rotation
        if guess is not None:
            return {"guess": guess}
        if rotation is not None:
            return {"rotation_guess": rotation}
        return {}

    def registered(self, first: bool, guess, guess_pose, rotation, delta: np.ndarray, stats: dict,
                   seconds: float) -> None:
        """After a registered frame: the guess source's pose kept, the gyro bias learnt, the frame counted."""
        if self.guess is not None:
            self.guess_prev = guess_pose
            if not first:
                self._count("frames_guessed" if guess is not None else "frames_unguessed")
        if rotation is not None:
            self._learn_gyro_bias(rotation, delta, stats, seconds)
            self._count("frames_imu")

    def _learn_gyro_bias(self, rotation: np.ndarray, delta: np.ndarray, stats: dict, seconds: float) -> None:
        """imu.bias_gain of the difference between the gyro's turn and a frame's registered one into the bias, when
        the frame was registered in full (no direction held at the gyro's turn) and the two agree within 0.5 deg."""
        gain = self.settings.imu_bias_gain
        in_full = stats.get("registered") and not stats.get("degenerate") and stats.get("held_directions", 0) == 0
        if gain <= 0.0 or not in_full or stats.get("turn_recovered") or not seconds > 0.0:
            return
        residual = Rotation.from_matrix(rotation.T @ delta[:3, :3]).as_rotvec()
        if np.linalg.norm(residual) > np.radians(0.5):
            return
        R_imu_sensor = self.T_sensor_imu()[:3, :3].T
        with self.imu_lock:
            self.gyro.learn_bias(R_imu_sensor @ residual, seconds, gain)

    def diagnostics_values(self) -> dict:
        values = {}
        if self.guess is not None:
            with self.guess_lock:
                values["guess_poses"] = len(self.guess)  # kept from guess_odom (guess.window)
        if self.gyro is not None:
            with self.imu_lock:
                values["imu_samples"] = len(self.gyro)  # kept from imu (imu.window)
                values["gyro_bias"] = " ".join(f"{v:.4f}" for v in np.degrees(self.gyro.bias))  # deg/s, IMU axes
        if self.static_tf is not None:
            with self.tf_lock:
                known = len(self.static_tf)
            values["base_to_sensor"] = (f"/tf_static {self.settings.base_frame} -> {self.mounted_frame}"
                                        if self.mounted_frame else f"waiting for /tf_static ({known} transforms)")
        return values
