"""Trajectory metrics: frame-to-frame relative pose error (RPE, Sturm et al. 2012)."""
from __future__ import annotations

import numpy as np


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices (..., 3, 3) in degrees."""
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def relative_pose_errors(estimate: np.ndarray, ground_truth: np.ndarray, delta: int = 1):
    """Per-pair RPE between poses i and i+delta: (translation m (N-delta,), rotation deg (N-delta,)).

    Error E_i = inv(inv(G_i) G_{i+d}) inv(E_i) E_{i+d} (evo's convention for delta in frames)."""
    estimate = np.asarray(estimate, dtype=float)
    ground_truth = np.asarray(ground_truth, dtype=float)
    if estimate.shape != ground_truth.shape or estimate.ndim != 3 or estimate.shape[1:] != (4, 4):
        raise ValueError(f"estimate and ground_truth: expected two (N, 4, 4) arrays of the same N, got "
                         f"{estimate.shape} and {ground_truth.shape}")
    rel_est = np.linalg.inv(estimate[:-delta]) @ estimate[delta:]
    rel_gt = np.linalg.inv(ground_truth[:-delta]) @ ground_truth[delta:]
    err = np.linalg.inv(rel_gt) @ rel_est
    return np.linalg.norm(err[:, :3, 3], axis=1), rotation_angle_deg(err[:, :3, :3])
