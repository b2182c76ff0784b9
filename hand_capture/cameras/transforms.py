"""Rotation-vector helpers for camera and object poses (axis * angle [rad])."""

from __future__ import annotations

import numpy as np

from hand_capture.model.joints import matrix_to_quat

__all__ = ["matrix_to_rotvec", "rotvec_to_matrix"]


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
