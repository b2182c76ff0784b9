"""Penetration of the four fingers into each other (a departure from eq. II.21).

Dissertation II.5 has no collision term: the depth data alone place the fingers. On hand
surfaces other than the model's (issue #13's held-out family) two neighbouring fingers are
often fitted into one another's points, at a lower E_d (eq. II.19) than the true pose's. The
collision capsules (``HandModel.capsules``) of two different fingers of the four (index ..
little) cannot overlap on a real hand, so the Gauss-Newton energy of eq. II.21 gets one
residual per penetrating pair, ``r_i + r_j - d_ij`` [mm] weighted by ``overlap_weight``,
with ``d_ij`` the distance of the two capsules' axis segments and its gradient
``n^T (J_p - J_q)`` at their closest points (seed 002's collision term, eq. 4, in spirit,
on capsules instead of meshes). The success test and the candidate cost (eq. II.19, II.20)
stay as they are.

The thumb and the palm are left out: in a pinch or an opposed thumb their capsules overlap in
true poses. Every finger capsule's axis runs from a joint keypoint towards the next one (the
distal one ends a tip radius short of the tip keypoint), so a point on it is a fixed blend of
two keypoints of one bone, and its Jacobian the same blend of theirs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model import BONE_NAMES, N_DOF, HandModel, segment_closest

__all__ = ["FingerOverlap", "finger_overlap_pairs"]

_LONG = ("index", "middle", "ring", "little")
_MM = 1000.0
#: axes closer than this cross [m]: their separating direction is taken from their middles
_CROSSED_M = 1e-5


def finger_overlap_pairs(model: HandModel) -> np.ndarray:
    """Rows of ``model.capsule_pairs`` whose two capsules lie on two different fingers of
    the four (not the thumb, not the palm): (P,) indices."""
    finger = [BONE_NAMES[c.bone].split("_")[0] for c in model.capsules]
    return np.array([k for k, (i, j) in enumerate(model.capsule_pairs)
                     if finger[i] in _LONG and finger[j] in _LONG and finger[i] != finger[j]],
                    dtype=np.int64)


@dataclass
class FingerOverlap:
    """The four fingers' capsule pairs of one model, with each capsule's axis as a blend
    of two keypoints (module docstring)."""

    model: HandModel

    def __post_init__(self) -> None:
        m = self.model
        rows = finger_overlap_pairs(m)
        #: (P, 2) capsule indices of the pairs
        self.pairs = m.capsule_pairs[rows]
        caps = np.unique(self.pairs)
        kp = m.joint_positions(np.zeros(N_DOF))
        seg = m.capsule_segments(np.zeros(N_DOF))
        self.radius = np.array([c.radius for c in m.capsules])       # (C,) [m]
        # each capsule's axis: from keypoint a (its start) to a + f (keypoint b - a)
        self.kp_a = np.zeros(len(m.capsules), np.int64)
        self.kp_b = np.zeros(len(m.capsules), np.int64)
        self.frac = np.ones(len(m.capsules))
        for c in caps:
            a = int(np.argmin(np.linalg.norm(kp - seg[c, 0], axis=1)))
            b = a + 1
            f = float(np.linalg.norm(seg[c, 1] - seg[c, 0]) / np.linalg.norm(kp[b] - kp[a]))
            on_axis = a % 4 and np.allclose(kp[a] + f * (kp[b] - kp[a]), seg[c, 1], atol=1e-6)
            if not on_axis or not np.allclose(kp[a], seg[c, 0], atol=1e-6):
                raise InputError(f"capsule {c} ({BONE_NAMES[m.capsules[c].bone]}) does not "
                                 "run from a finger joint's keypoint towards the next one")
            self.kp_a[c], self.kp_b[c], self.frac[c] = a, b, f
        #: (C,) the MCP keypoint of each capsule's finger (the first of its four)
        self.mcp = np.where(self.kp_a > 0, 1 + 4 * ((self.kp_a - 1) // 4), 0)

    def _axes(self, kp: np.ndarray, caps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Axis end points (..., K, 3) of capsules ``caps`` from keypoints (..., 21, 3)."""
        a = kp[..., self.kp_a[caps], :]
        return a, a + self.frac[caps, None] * (kp[..., self.kp_b[caps], :] - a)

    def _closest(self, kp: np.ndarray) -> tuple[np.ndarray, ...]:
        """Of every pair, for keypoints (..., 21, 3): the two axes' end points
        ``p0, p1, q0, q1`` (..., P, 3), their closest points' parameters ``s, t`` and
        distance ``d`` (..., P), and the penetration depth ``r_i + r_j - d`` [m]."""
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        p0, p1 = self._axes(kp, i)
        q0, q1 = self._axes(kp, j)
        s, t, d = segment_closest(p0, p1, q0, q1)
        return p0, p1, q0, q1, s, t, d, self.radius[i] + self.radius[j] - d

    def depth_mm(self, kp: np.ndarray) -> np.ndarray:
        """Summed penetration depth [mm] of keypoints (B, 21, 3) (poses of this model)."""
        return np.maximum(self._closest(kp)[-1], 0.0).sum(axis=-1) * _MM

    def penetrating(self, kp: np.ndarray) -> np.ndarray:
        """(B,) bool: whether two of the four fingers' capsules penetrate, per pose of
        keypoints (B, 21, 3). Most tracked poses have none, so a caller can leave their
        keypoint Jacobians (the costlier part of :meth:`residuals`) uncomputed."""
        return (self._closest(kp)[-1] > 0.0).any(axis=-1)

    def residuals(self, kp: np.ndarray, jac: np.ndarray
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Penetration depths [mm] of the penetrating pairs of each pose and their Jacobian
        rows: keypoints (B, 21, 3), their Jacobian (B, 21, 3, n) -> per pose (k,), (k, n)
        (the pairs of all poses found at once). Weighted by ``overlap_weight`` in the
        Gauss-Newton energy."""
        p0, p1, q0, q1, s, t, d, pen = self._closest(kp)
        n_dof = jac.shape[-1]
        out = []
        for b in range(len(kp)):
            hit = np.flatnonzero(pen[b] > 0.0)
            if not len(hit):
                out.append((np.zeros(0), np.zeros((0, n_dof))))
                continue
            out.append(self._rows(kp[b], jac[b], hit, p0[b], p1[b], q0[b], q1[b], s[b][hit],
                                  t[b][hit], d[b][hit], pen[b][hit]))
        return out

    def _rows(self, kp: np.ndarray, jac: np.ndarray, hit: np.ndarray, p0: np.ndarray,
              p1: np.ndarray, q0: np.ndarray, q1: np.ndarray, s: np.ndarray, t: np.ndarray,
              d: np.ndarray, pen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`residuals` of one pose's penetrating pairs ``hit`` (rows of
        :attr:`pairs`; ``s, t, d, pen`` already taken at them)."""
        i, j = self.pairs[hit, 0], self.pairs[hit, 1]
        # where the axes cross (d = 0, e.g. two straight fingers in the palm's plane) d has
        # no gradient: the axes' middles are pushed apart instead, each towards its own
        # finger's side (from the other's MCP joint towards its own)
        crossed = d <= _CROSSED_M
        s, t = np.where(crossed, 0.5, s), np.where(crossed, 0.5, t)
        p = p0[hit] + s[:, None] * (p1[hit] - p0[hit])
        q = q0[hit] + t[:, None] * (q1[hit] - q0[hit])
        sep = np.where(crossed[:, None], kp[self.mcp[i]] - kp[self.mcp[j]], p - q)
        n = sep / np.maximum(np.linalg.norm(sep, axis=1), 1e-12)[:, None]   # (k, 3)

        def point_jac(c: np.ndarray, u: np.ndarray) -> np.ndarray:      # (k, 3, n)
            w = u * self.frac[c]
            return ((1.0 - w)[:, None, None] * jac[self.kp_a[c]]
                    + w[:, None, None] * jac[self.kp_b[c]])

        dd = np.einsum("ki,kin->kn", n, point_jac(i, s) - point_jac(j, t))
        return pen * _MM, -_MM * dd
