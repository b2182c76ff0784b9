"""Contact frames and polyhedral friction cones (friction pyramids).

Each contact force is a non-negative combination of the edges of a pyramid inscribed in its
Coulomb cone, ``f_k = B_k lambda_k, lambda_k >= 0`` (dissertation 003, sec. III.4.1.3 and
III.5.3, where ``B_k`` is 3x4). An inscribed pyramid keeps every such force inside the true cone.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = [
    "contact_frames", "cross", "cross_matrices", "edge_directions", "pyramid_edges",
]


_EYE = np.eye(3)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis, broadcast (much cheaper than ``np.cross`` on small arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def contact_frames(normals: np.ndarray) -> np.ndarray:
    """Right-handed orthonormal contact frames ``[t1 t2 n]`` (columns) for unit normals.

    The tangents are the first two columns of the Householder reflection that maps
    ``-sign(n_z) e_z`` onto ``n`` (well conditioned for every unit normal; deterministic).

    Args:
        normals: (K, 3) unit normals.

    Returns:
        (K, 3, 3) rotation matrices whose third column is the normal.
    """
    sign = np.copysign(1.0, normals[:, 2])
    v = normals.copy()
    v[:, 2] += sign  # |v|^2 = 2 (1 + |n_z|) >= 2
    frames = _EYE - (2.0 / (v * v).sum(axis=1))[:, None, None] * (v[:, :, None] * v[:, None, :])
    frames[:, :, 0] *= sign[:, None]  # the reflection has det -1: fix the handedness
    frames[:, :, 2] = normals
    return frames


@lru_cache(maxsize=16)
def edge_directions(n_edges: int) -> np.ndarray:
    """(2, E) cosines and sines of the pyramid edge angles ``2 pi j / E``."""
    theta = 2.0 * np.pi * np.arange(n_edges) / n_edges
    dirs = np.stack([np.cos(theta), np.sin(theta)])
    dirs.setflags(write=False)  # shared by the cache
    return dirs


def pyramid_edges(normals: np.ndarray, mu: np.ndarray, n_edges: int) -> np.ndarray:
    """Unit edge vectors of the friction pyramid of each contact (the columns of ``B_k``).

    Edge ``j`` is ``n + mu (cos(th_j) t1 + sin(th_j) t2)``, normalised, ``th_j = 2 pi j / E``:
    the edges lie on the Coulomb cone, so the pyramid is inscribed in it.

    Args:
        normals: (K, 3) unit normals.
        mu: (K,) friction coefficients.
        n_edges: number of edges E per pyramid (4 in the dissertation).

    Returns:
        (K, E, 3) unit edge vectors.
    """
    local = np.empty((normals.shape[0], 3, n_edges))
    local[:, 0:2] = mu[:, None, None] * edge_directions(n_edges)
    local[:, 2] = 1.0
    local /= np.sqrt(1.0 + mu * mu)[:, None, None]
    return np.matmul(contact_frames(normals), local).transpose(0, 2, 1)


def _skew_basis() -> np.ndarray:
    """(3, 9) map from r to the row-major entries of [r]x."""
    basis = np.zeros((3, 3, 3))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        basis[i, k, j], basis[i, j, k] = 1.0, -1.0  # [e_i]x e_j = e_k
    return basis.reshape(3, 9)


_SKEW = _skew_basis()


def cross_matrices(r: np.ndarray) -> np.ndarray:
    """Skew matrices ``[r]x`` with ``[r]x v = r x v``, for (K, 3) vectors -> (K, 3, 3)."""
    return (r @ _SKEW).reshape(r.shape[0], 3, 3)
