"""A gyro on a trajectory of poses: the body rate that turns each pose into the next at a constant rate over the stamp
interval between them, sampled at the IMU's rate with white noise and a constant bias (rad/s, in the IMU's axes).

The IMU is mounted rigidly: ``T_body_imu`` (body = the trajectory's frame, e.g. the LiDAR's) turns the body's rate
into the IMU's, w_imu = R_imu_body w_body. Stamps past the last pose get the last interval's rate.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def body_rates(poses: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """(n - 1, 3) rad/s: the constant body rate of each interval, log(R_k^T R_k+1) / dt."""
    poses = np.asarray(poses, dtype=float)
    stamps = np.asarray(stamps, dtype=float)
    turns = Rotation.from_matrix(np.einsum("kji,kjl->kil", poses[:-1, :3, :3], poses[1:, :3, :3])).as_rotvec()
    return turns / np.diff(stamps)[:, None]


def gyro_samples(poses: np.ndarray, stamps: np.ndarray, *, rate_hz: float = 200.0, offset: float = 0.0,
                 noise_std: float = 0.0, bias=(0.0, 0.0, 0.0), T_body_imu: np.ndarray | None = None,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(sample stamps (m,) s, rates (m, 3) rad/s in the IMU frame) from the first to the last pose's stamp; the first
    sample `offset` s after the first stamp. noise_std: rad/s per sample (white); bias: rad/s added to every
    sample."""
    stamps = np.asarray(stamps, dtype=float)
    rates_body = body_rates(poses, stamps)
    times = np.arange(stamps[0] + offset, stamps[-1] + 1e-9, 1.0 / rate_hz)
    # the interval each sample lies in (a sample on a pose's stamp belongs to the interval it starts)
    interval = np.clip(np.searchsorted(stamps, times, side="right") - 1, 0, len(rates_body) - 1)
    R_imu_body = np.eye(3) if T_body_imu is None else np.asarray(T_body_imu, dtype=float)[:3, :3].T
    rates = rates_body[interval] @ R_imu_body.T
    rng = np.random.default_rng(seed)
    rates = rates + np.asarray(bias, dtype=float) + noise_std * rng.normal(size=rates.shape)
    return times, rates
