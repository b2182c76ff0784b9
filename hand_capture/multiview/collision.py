"""Collision term Gamma(theta) of seed 002 (sec. 4.2, eq. (4)): local distance fields.

Colliding (face, vertex) pairs between two parts (hand-hand and hand-object) are found with a
spatial tree over the parts' face centroids (a kd-tree: the bounding-volume hierarchy's role
in seed 002's [32]) after an axis-aligned bounding-box test of the two parts. For a face
``f_s`` (centroid ``c``, outward unit normal ``n``, circumradius ``rho``) the local distance
field applied to a vertex ``v`` of the other part is

    Psi_{f_s -> f_t}(v) = d(v)^2   with d(v) = (c - v) . n,
    when 0 < d(v) <= depth_m and |(v - c) + d(v) n| <= rho + d(v)   (the cone under f_s,
    circumscribing the face's circle and widening into the mesh at 45 degrees), else 0,

so the penalty grows the further a vertex is inside the cone, fields of neighbouring faces add
up, and it is zero without contact. Both directions are used (each part's faces against the
other part's vertices), the sum of eq. (4). The detected pairs are accumulated over a frame's
iterations (Algorithm 1: C = C u {collisions at theta_i}); each pair gives one least-squares
residual ``d(v)`` (zero once the vertex left the cone), whose Jacobian is
``n . (dc/dtheta - dv/dtheta)`` (the face normal's rotation neglected).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.multiview.scene_model import SceneModel, SceneState

__all__ = ["CollisionPairs", "collision_energy", "detect_collisions", "face_frames",
           "pair_residuals"]


@dataclass(frozen=True)
class CollisionPairs:
    """Colliding pairs: face ``face`` of part ``face_part`` against vertex ``vert`` of part
    ``vert_part`` (equal-length int arrays)."""

    face_part: np.ndarray
    face: np.ndarray
    vert_part: np.ndarray
    vert: np.ndarray

    @staticmethod
    def empty() -> CollisionPairs:
        z = np.zeros(0, np.int64)
        return CollisionPairs(z, z, z, z)

    def __len__(self) -> int:
        return int(len(self.face))

    def union(self, other: CollisionPairs) -> CollisionPairs:
        """Both sets, without duplicates."""
        a = np.stack([np.concatenate([self.face_part, other.face_part]),
                      np.concatenate([self.face, other.face]),
                      np.concatenate([self.vert_part, other.vert_part]),
                      np.concatenate([self.vert, other.vert])], axis=1)
        if not len(a):
            return self
        u = np.unique(a, axis=0)
        return CollisionPairs(u[:, 0], u[:, 1], u[:, 2], u[:, 3])


def face_frames(vertices: np.ndarray, faces: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroids (F, 3), outward unit normals (F, 3) and circumradii (F,) of a mesh's faces."""
    tri = vertices[faces]
    c = tri.mean(axis=1)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-15)
    rho = np.linalg.norm(tri - c[:, None], axis=2).max(axis=1)
    return c, n, rho


def _in_cone(x: np.ndarray, c: np.ndarray, n: np.ndarray, rho: np.ndarray, depth_m: float
             ) -> tuple[np.ndarray, np.ndarray]:
    d = np.einsum("ij,ij->i", c - x, n)
    lat = np.linalg.norm((x - c) + d[:, None] * n, axis=1)
    return d, (d > 0) & (d <= depth_m) & (lat <= rho + d)


def detect_collisions(model: SceneModel, state: SceneState, parts: list[tuple[int, int]],
                      depth_m: float = 0.02, k: int = 4) -> CollisionPairs:
    """Every vertex of one part inside a local distance field of the other's faces, for each
    pair of parts in ``parts`` (both directions); ``k`` nearest face centroids are tested per
    vertex."""
    from scipy.spatial import cKDTree

    fp, fi, vp, vi = [], [], [], []
    for a, b in parts:
        va, vb = state.vertices[a], state.vertices[b]
        lo = np.maximum(va.min(0), vb.min(0)) - depth_m
        hi = np.minimum(va.max(0), vb.max(0)) + depth_m
        if np.any(lo > hi):   # bounding boxes apart: no contact
            continue
        for sp, tp in ((a, b), (b, a)):
            vs, vt = state.vertices[sp], state.vertices[tp]
            c, n, rho = face_frames(vs, model.faces[sp])
            cand = np.flatnonzero(np.all((vt >= lo) & (vt <= hi), axis=1))
            if not len(cand):
                continue
            tree = cKDTree(c)
            dist, idx = tree.query(vt[cand], k=min(k, len(c)),
                                   distance_upper_bound=float(rho.max()) + depth_m)
            idx = idx.reshape(len(cand), -1)
            for j in range(idx.shape[1]):
                ok = idx[:, j] < len(c)
                f = idx[ok, j]
                v = cand[ok]
                _, inside = _in_cone(vt[v], c[f], n[f], rho[f], depth_m)
                fp.append(np.full(int(inside.sum()), sp))
                fi.append(f[inside])
                vp.append(np.full(int(inside.sum()), tp))
                vi.append(v[inside])
    if not fp:
        return CollisionPairs.empty()
    return CollisionPairs(*(np.concatenate(x).astype(np.int64) for x in (fp, fi, vp, vi)))


def pair_residuals(model: SceneModel, state: SceneState, pairs: CollisionPairs,
                   depth_m: float = 0.02) -> np.ndarray:
    """Residual ``d(v)`` [m] per pair (0 outside its cone): eq. (4) is their squared sum."""
    out = np.zeros(len(pairs))
    for sp in np.unique(pairs.face_part):
        sel = np.flatnonzero(pairs.face_part == sp)
        c, n, rho = face_frames(state.vertices[sp], model.faces[sp])
        f = pairs.face[sel]
        x = np.stack([state.vertices[p][v] for p, v in zip(pairs.vert_part[sel],
                                                           pairs.vert[sel], strict=True)])
        d, inside = _in_cone(x, c[f], n[f], rho[f], depth_m)
        out[sel] = np.where(inside, d, 0.0)
    return out


def collision_energy(model: SceneModel, state: SceneState, pairs: CollisionPairs,
                     depth_m: float = 0.02) -> float:
    """Gamma(theta) of eq. (4) [m^2] over ``pairs``."""
    return float(np.sum(pair_residuals(model, state, pairs, depth_m) ** 2))
