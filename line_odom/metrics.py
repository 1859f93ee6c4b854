"""Trajectory metrics.

- RPE: frame-to-frame relative pose error (Sturm et al. 2012), as evo_rpe computes it for a delta in frames.
- ATE: absolute trajectory error after the least-squares SE(3) alignment of the estimated positions onto the
  ground truth (Umeyama 1991), as ``evo_ape -a``.
- KITTI: the odometry benchmark's segment errors (Geiger et al. 2012), computed the way the devkit's
  evaluate_odometry.cpp does: ground-truth path length per frame, segments of 100..800 m starting every
  10th frame, ``t_err = |t(inv(dE) dG)| / len`` and ``r_err = angle(inv(dE) dG) / len`` averaged over all
  segments. The path lengths are accumulated in float32 as the devkit does (they decide where a segment ends);
  the errors are computed in double (the devkit's float acos loses precision on small rotation errors).
- NEES: the normalized estimation error squared of each frame's motion against its reported covariance (Bar-Shalom,
  Li, Kirubarajan 2001, §5.4): e^T C^-1 e, whose mean over frames is 6 for a consistent 6-DoF covariance.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

KITTI_SEGMENT_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP_FRAMES = 10


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices (..., 3, 3) in degrees (norm of the SO(3) logarithm, as evo computes it)."""
    R = np.asarray(R, dtype=float)
    flat = R.reshape(-1, 3, 3)
    if len(flat) == 0:
        return np.zeros(R.shape[:-2])
    return np.degrees(Rotation.from_matrix(flat).magnitude()).reshape(R.shape[:-2])


def _check_pair(estimate, ground_truth):
    estimate = np.asarray(estimate, dtype=float)
    ground_truth = np.asarray(ground_truth, dtype=float)
    if estimate.shape != ground_truth.shape or estimate.ndim != 3 or estimate.shape[1:] != (4, 4):
        raise ValueError(f"estimate and ground_truth: expected two (N, 4, 4) arrays of the same N, got "
                         f"{estimate.shape} and {ground_truth.shape}")
    return estimate, ground_truth


def relative_pose_errors(estimate: np.ndarray, ground_truth: np.ndarray, delta: int = 1):
    """Per-pair RPE between poses i and i+delta: (translation m (N-delta,), rotation deg (N-delta,)).

    Error E_i = inv(inv(G_i) G_{i+d}) inv(E_i) E_{i+d} (evo's convention for delta in frames)."""
    estimate, ground_truth = _check_pair(estimate, ground_truth)
    if delta < 1:
        raise ValueError(f"delta: expected a positive number of frames, got {delta}")
    if len(estimate) <= delta:
        return np.zeros(0), np.zeros(0)
    rel_est = np.linalg.inv(estimate[:-delta]) @ estimate[delta:]
    rel_gt = np.linalg.inv(ground_truth[:-delta]) @ ground_truth[delta:]
    err = np.linalg.inv(rel_gt) @ rel_est
    return np.linalg.norm(err[:, :3, 3], axis=1), rotation_angle_deg(err[:, :3, :3])


def motion_errors(delta: np.ndarray, ground_truth_delta: np.ndarray) -> np.ndarray:
    """Error (N, 6) of frame motions (N, 4, 4) in the chart of the engine's covariance: D = delta inv(truth),
    (x y z) = D's translation, (rx ry rz) = D's rotation vector (rad), i.e. delta = exp(e) truth."""
    delta, ground_truth_delta = _check_pair(delta, ground_truth_delta)
    D = delta @ np.linalg.inv(ground_truth_delta)
    rotvec = Rotation.from_matrix(D[:, :3, :3]).as_rotvec() if len(D) else np.zeros((0, 3))
    return np.concatenate([D[:, :3, 3], rotvec], axis=1)


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Per-frame e^T C^-1 e of errors (N, k) against covariances (N, k, k)."""
    errors = np.asarray(errors, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    if errors.ndim != 2 or covariances.shape != errors.shape + errors.shape[1:]:
        raise ValueError(f"errors, covariances: expected (N, k) and (N, k, k), got {errors.shape} and "
                         f"{covariances.shape}")
    if len(errors) == 0:
        return np.zeros(0)
    return np.einsum("ni,ni->n", errors, np.linalg.solve(covariances, errors[..., None])[..., 0])


def umeyama_alignment(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rigid transform T (4x4) minimising sum |target_i - (R source_i + t)|^2 over (N, 3) point sets
    (Umeyama 1991, eqs. 34-43, scale fixed to 1). Degenerate sets (collinear) still give a minimiser."""
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) == 0:
        raise ValueError(f"source and target: expected two non-empty (N, 3) arrays of the same N, got "
                         f"{source.shape} and {target.shape}")
    mean_s, mean_t = source.mean(axis=0), target.mean(axis=0)
    cov = (target - mean_t).T @ (source - mean_s) / len(source)
    U, _, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0.0:
        S[2, 2] = -1.0
    T = np.eye(4)
    T[:3, :3] = U @ S @ Vt
    T[:3, 3] = mean_t - T[:3, :3] @ mean_s
    return T


def absolute_trajectory_errors(estimate: np.ndarray, ground_truth: np.ndarray):
    """Per-pose ATE (m) after aligning the estimated positions onto the ground truth with SE(3) Umeyama;
    returns (errors (N,), alignment T (4x4) to apply to the estimate)."""
    estimate, ground_truth = _check_pair(estimate, ground_truth)
    if len(estimate) == 0:
        return np.zeros(0), np.eye(4)
    T = umeyama_alignment(estimate[:, :3, 3], ground_truth[:, :3, 3])
    aligned = estimate[:, :3, 3] @ T[:3, :3].T + T[:3, 3]
    return np.linalg.norm(aligned - ground_truth[:, :3, 3], axis=1), T


def frame_motions(poses: np.ndarray) -> np.ndarray:
    """The translation (m) between each pair of consecutive poses."""
    return np.array([np.linalg.norm((np.linalg.inv(a) @ b)[:3, 3]) for a, b in zip(poses[:-1], poses[1:])])


def trajectory_distances(poses: np.ndarray) -> np.ndarray:
    """Cumulative path length per frame, accumulated in float32 like the devkit's trajectoryDistances."""
    steps = np.linalg.norm(np.diff(np.asarray(poses, dtype=float)[:, :3, 3], axis=0), axis=1)
    dist = np.zeros(len(poses), dtype=np.float32)
    for i, step in enumerate(steps, start=1):
        dist[i] = np.float32(float(dist[i - 1]) + float(step))
    return dist


def path_length(poses: np.ndarray) -> float:
    poses = np.asarray(poses, dtype=float)
    if len(poses) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum())


def _last_frame_from_segment_length(dist: np.ndarray, first_frame: int, length: float) -> int:
    later = np.nonzero(dist[first_frame:] > np.float32(dist[first_frame] + np.float32(length)))[0]
    return int(later[0]) + first_frame if len(later) else -1


def kitti_segment_errors(estimate: np.ndarray, ground_truth: np.ndarray,
                         lengths=KITTI_SEGMENT_LENGTHS, step: int = KITTI_STEP_FRAMES) -> np.ndarray:
    """The devkit's per-segment errors as rows (first_frame, length m, t_err (fraction), r_err rad/m)."""
    estimate, ground_truth = _check_pair(estimate, ground_truth)
    dist = trajectory_distances(ground_truth)
    rows = []
    for first in range(0, len(ground_truth), step):
        for length in lengths:
            last = _last_frame_from_segment_length(dist, first, length)
            if last == -1:
                continue
            delta_gt = np.linalg.inv(ground_truth[first]) @ ground_truth[last]
            delta_est = np.linalg.inv(estimate[first]) @ estimate[last]
            err = np.linalg.inv(delta_est) @ delta_gt
            cos = np.clip(0.5 * (np.trace(err[:3, :3]) - 1.0), -1.0, 1.0)
            rows.append((first, length, np.linalg.norm(err[:3, 3]) / length, np.arccos(cos) / length))
    return np.array(rows, dtype=float).reshape(-1, 4)


def kitti_errors(estimate: np.ndarray, ground_truth: np.ndarray) -> tuple[float, float] | None:
    """KITTI odometry score (t_err %, r_err deg/m) averaged over all segments, or None when the
    ground-truth path is too short for a 100 m segment."""
    rows = kitti_segment_errors(estimate, ground_truth)
    if len(rows) == 0:
        return None
    return float(100.0 * rows[:, 2].mean()), float(np.degrees(rows[:, 3].mean()))


def paired_difference(a: np.ndarray, b: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """Mean of a - b over paired samples (two methods' errors on the same frames) and its bootstrap confidence
    interval (scipy.stats.bootstrap, BCa, 10,000 resamples, fixed seed): an interval spanning 0 means the frames do
    not tell which mean is lower."""
    from scipy.stats import bootstrap

    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1 or len(a) < 2:
        raise ValueError(f"a and b: expected two 1-D arrays of the same length >= 2, got {a.shape} and {b.shape}")
    d = a - b
    if np.ptp(d) <= 1e-9 * max(1.0, float(np.abs(d).max())):  # every pair the same: no spread to resample
        return float(d.mean()), float(d.mean()), float(d.mean())
    ci = bootstrap((d,), np.mean, confidence_level=confidence, n_resamples=10000, method="BCa",
                   random_state=np.random.default_rng(0)).confidence_interval
    return float(d.mean()), float(ci.low), float(ci.high)
