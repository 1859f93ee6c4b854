"""A stand-in for line_odom_core.Odometry in the processor's tests: it stands still and records the keywords of every
register_points call (the motion guess, the gyro's rotation), so a test can check what the processor passed."""
import numpy as np


class RecordingEngine:
    def __init__(self, prediction: str = "constant_velocity"):
        self.calls = []
        self.prediction = prediction

    def register_points(self, xyz, stamp, ring=None, **kwargs):
        self.calls.append(kwargs)

        class R:
            pose = np.eye(4)
            delta = np.eye(4)
            covariance = np.eye(6) * 1e-4
            stats = {"solver": "3L1P", "degenerate": False, "prediction": self.prediction, "ms": {"total": 1.0}}
        return R()

    @property
    def guesses(self):
        """The `guess` of every call (None when there was none)."""
        return [call.get("guess") for call in self.calls]

    def reset(self, pose=None):
        pass
