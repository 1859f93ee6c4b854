"""Rigid-transform helpers for publishing odometry (REP-103/105): pose parameters, SE(3) adjoint and log,
and the covariance bookkeeping between the sensor's frame-to-frame estimate and the base's odometry.

Conventions (docs/DESIGN.md §3): ``T_ab`` maps frame-b coordinates into frame a; 6-vectors and 6x6 covariances
are ordered (x y z rx ry rz) = (rho, phi); a "left" perturbation is ``T = exp(xi) T_hat``.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

# Eigen's: scipy's Rotation costs ~0.2 ms a call on the per-frame path. quaternion_xyzw gives [x, y, z, w], w >= 0.
from line_odom_core._core import quaternion_xyzw, rotation_vector  # noqa: F401
from line_odom_core.odometry import log_se3  # noqa: F401  (one definition of the twist: line_odom_core.odometry)


def pose_from_params(values: Sequence[float], name: str) -> np.ndarray:
    """[x, y, z, roll, pitch, yaw] (radians; R = Rz(yaw) Ry(pitch) Rx(roll)) or [x, y, z, qx, qy, qz, qw]
    -> 4x4 transform. ValueError naming the parameter for any other length or a non-finite / zero quaternion."""
    try:
        v = np.asarray(list(values), dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected numbers [x, y, z, roll, pitch, yaw] or [x, y, z, qx, qy, qz, qw], "
                         f"got {values!r}") from None
    if v.size not in (6, 7):
        raise ValueError(f"{name}: expected 6 values [x, y, z, roll, pitch, yaw] or 7 values "
                         f"[x, y, z, qx, qy, qz, qw], got {v.size}: {v.tolist()}")
    if not np.isfinite(v).all():
        raise ValueError(f"{name}: expected finite values, got {v.tolist()}")
    T = np.eye(4)
    T[:3, 3] = v[:3]
    if v.size == 6:
        T[:3, :3] = Rotation.from_euler("xyz", v[3:]).as_matrix()
    else:
        q = v[3:]
        norm = float(np.linalg.norm(q))
        if norm < 1e-9:
            raise ValueError(f"{name}: quaternion [qx, qy, qz, qw] has zero norm")
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"{name}: quaternion [qx, qy, qz, qw] must have unit norm, got norm {norm:.6g}")
        T[:3, :3] = Rotation.from_quat(q / norm).as_matrix()
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def adjoint(T: np.ndarray) -> np.ndarray:
    """Ad_T for (rho, phi) ordering: T exp(xi) T^-1 = exp(Ad_T xi)."""
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[:3, 3:] = skew(t) @ R
    Ad[3:, 3:] = R
    return Ad


def ad(xi: np.ndarray) -> np.ndarray:
    """The se(3) adjoint ad_xi for (rho, phi) ordering (the derivative of Ad at the identity)."""
    out = np.zeros((6, 6))
    out[:3, :3] = skew(xi[3:])
    out[:3, 3:] = skew(xi[:3])
    out[3:, 3:] = skew(xi[3:])
    return out


def left_jacobian_inverse(xi: np.ndarray) -> np.ndarray:
    """Inverse left Jacobian of SE(3), log(exp(d) exp(xi)) = xi + J_l^-1(xi) d + O(d^2); the Bernoulli series
    I - ad/2 + ad^2/12 - ad^4/720, accurate for frame-to-frame motions (|phi| well under 1 rad)."""
    a = ad(xi)
    a2 = a @ a
    return np.eye(6) - 0.5 * a + a2 / 12.0 - (a2 @ a2) / 720.0


def conjugate_covariance(cov: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Covariance of Ad_T xi given that of xi."""
    Ad = adjoint(T)
    return symmetrize(Ad @ cov @ Ad.T)


def left_to_ros_pose_covariance(cov_left: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Left-perturbation covariance of pose T -> the PoseWithCovariance convention: position errors along the
    parent frame's axes (t = t_hat + dt) and small rotations about the parent frame's axes (R = exp(dphi) R_hat).
    To first order dt = rho - [t]x phi, dphi = phi."""
    J = np.eye(6)
    J[:3, 3:] = -skew(T[:3, 3])
    return symmetrize(J @ cov_left @ J.T)


def symmetrize(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)
