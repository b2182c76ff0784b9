"""Rotation-vector helpers for camera and object poses (axis * angle [rad])."""

from __future__ import annotations

import numpy as np

from hand_capture.model.joints import (
    matrix_to_quat,
    root_angles_from_matrix,
    root_rotation_matrix,
    validate_pose,
)

__all__ = ["matrix_to_rotvec", "pose_in_camera", "pose_in_world", "rotvec_to_matrix"]


def rotvec_to_matrix(r: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle [rad]), Rodrigues' formula."""
    r = np.asarray(r, dtype=float).reshape(3)
    th = float(np.linalg.norm(r))
    if th < 1e-12:
        return np.eye(3)
    k = r / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle, angle in [0, pi]) of a rotation matrix."""
    x, y, z, w = matrix_to_quat(np.asarray(R, dtype=float))
    s = float(np.sqrt(x * x + y * y + z * z))
    if s < 1e-12:
        return np.zeros(3)
    return np.array([x, y, z]) / s * (2.0 * np.arctan2(s, w))


def pose_in_camera(pose: np.ndarray, R_wc: np.ndarray, t_wc: np.ndarray) -> np.ndarray:
    """A world-frame pose (27,) expressed in the camera frame whose world pose is (R_wc, t_wc).

    Only the root changes: its position becomes ``R_wc^T (p - t_wc)`` and its rotation
    ``R_wc^T R_root``, converted back to the root's hinge angles.
    """
    q = validate_pose(pose).copy()
    R_cw = R_wc.T
    q[0:3] = R_cw @ (q[0:3] - t_wc)
    q[3:6] = root_angles_from_matrix(R_cw @ root_rotation_matrix(q[3:6]))
    return q


def pose_in_world(pose: np.ndarray, R_wc: np.ndarray, t_wc: np.ndarray) -> np.ndarray:
    """A camera-frame pose (27,) expressed in the world, the camera at (R_wc, t_wc) in it:
    the inverse of :func:`pose_in_camera` (root position ``R_wc p + t_wc``, rotation
    ``R_wc R_root``)."""
    q = validate_pose(pose).copy()
    q[0:3] = R_wc @ q[0:3] + t_wc
    q[3:6] = root_angles_from_matrix(R_wc @ root_rotation_matrix(q[3:6]))
    return q
