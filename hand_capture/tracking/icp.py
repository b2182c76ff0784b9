"""Model-based tracking: Gauss-Newton ICP of the skinned hand on the depth points (II.5.2).

Energy (eq. II.21), every term a sum of squares so Gauss-Newton applies (eq. II.27)::

    E(q) = l1 E_data + l2 E_smooth + l3 E_joint
    E_data   = sum_(i, j) || P_i - M_j(q) ||^2                      (II.23, millimetres)
    E_smooth = delta ||q - q_prev||^2 + (1 - delta) ||q - q_reg||^2  (II.24)
    E_joint  = sum_(d >= 7) [q_d < lo_d](q_d - lo_d)^2 + [q_d > hi_d](q_d - hi_d)^2  (II.25)

Correspondences (II.22): the model vertices that face the camera, visible or occluded (normal
towards the camera, Figure II.8), are projected into the image; for every observed point the
candidates are the facing vertices whose projection lies in a square window around the
point's pixel, and the one nearest in 3D wins. Correspondences are rebuilt every iteration.
The Jacobian of the data term is the model's analytic ``d vertex / d pose``.

Units: the data residuals are in millimetres (so l1 = 1, l2 = 0.2 and l3 = 1000 of the
dissertation weigh a millimetre against a radian); root translations in E_smooth are in
millimetres too. A small Levenberg damping keeps the normal equations regular when a finger
has no points.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from hand_capture.cameras.base import Intrinsics
from hand_capture.model import JOINT_LIMITS, N_DOF, HandModel
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.preprocess import HandObservation

__all__ = ["Correspondences", "ModelTracker", "render_depth", "depth_error"]

_MM = 1000.0
#: per-DoF unit scale of E_smooth: root translation in mm, angles in rad
_SMOOTH_SCALE = np.r_[np.full(3, _MM), np.ones(N_DOF - 3)]
_LIM_LO = JOINT_LIMITS[:, 0]
_LIM_HI = JOINT_LIMITS[:, 1]
_ANGLE_DOFS = np.arange(3, N_DOF)
_FAR = np.float32(1e3)
_K3 = np.ones((3, 3), np.uint8)


@dataclass
class Correspondences:
    """Pairs (observed point i, model vertex j) of one iteration."""

    points: np.ndarray   # (N, 3) observed points [m]
    vertex: np.ndarray   # (N,) model vertex indices
    model: np.ndarray    # (N, 3) model vertex positions [m]

    @property
    def residual_mm(self) -> np.ndarray:
        """(N, 3) ``M_j(q) - P_i`` in millimetres."""
        return (self.model - self.points) * _MM


def render_depth(vertices: np.ndarray, intr: Intrinsics, ds: int = 1) -> np.ndarray:
    """Depth image [m] of the hand model by vertex splatting (z-buffer + hole closing).

    Used for the depth discrepancy E_d of eq. II.19 / II.20 at ``1/ds`` resolution: the mesh
    vertices are about 4 mm apart, one or two pixels at hand distance, so each vertex is
    splatted into its nearest pixel and the one-pixel holes left between vertices are closed
    (3x3 morphological closing of the silhouette, filled with the nearest neighbour depth).
    """
    W = (intr.width + ds - 1) // ds
    H = (intr.height + ds - 1) // ds
    z = vertices[:, 2]
    ok = z > 1e-3
    v = vertices[ok]
    z = z[ok]
    u = np.rint((intr.fx * v[:, 0] / z + intr.cx) / ds).astype(np.int64)
    w = np.rint((intr.fy * v[:, 1] / z + intr.cy) / ds).astype(np.int64)
    inside = (u >= 0) & (u < W) & (w >= 0) & (w < H)
    buf = np.full(H * W, _FAR, np.float32)
    np.minimum.at(buf, w[inside] * W + u[inside], z[inside].astype(np.float32))
    buf = buf.reshape(H, W)
    occ = (buf < _FAR).astype(np.uint8)
    closed = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, _K3)
    holes = (closed > 0) & (occ == 0)
    if holes.any():
        buf[holes] = cv2.erode(buf, _K3)[holes]
    buf[buf >= _FAR] = 0.0
    return buf


def depth_error(rendered_m: np.ndarray, observed_m: np.ndarray, cap_mm: float) -> float:
    """E_d of eq. II.19: sum |I_r - I| over the union of both silhouettes / its size [mm].

    The per-pixel difference is capped at ``cap_mm`` (a pixel covered by one image only
    counts the cap). An empty union (no hand, no model) gives ``cap_mm``.
    """
    r = rendered_m
    o = observed_m
    union = (r > 0) | (o > 0)
    n = int(np.count_nonzero(union))
    if n == 0:
        return float(cap_mm)
    diff = np.abs(r[union] - o[union]) * _MM
    both = (r[union] > 0) & (o[union] > 0)
    diff = np.where(both, np.minimum(diff, cap_mm), cap_mm)
    return float(diff.sum() / n)


def _root_jacobian(q: np.ndarray, points: np.ndarray) -> np.ndarray:
    """d point / d (root DoFs) (N, 3, 6) of points carried by the hand: slides along x, y,
    z, then the hinges x, Rx y, Rx Ry z (joints.py conventions) through the wrist."""
    rx, ry = q[3], q[4]
    cx, sx, cy, sy = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry)
    a0 = np.array([1.0, 0.0, 0.0])
    a1 = np.array([0.0, cx, sx])                      # Rx @ e_y
    a2 = np.array([sy, -sx * cy, cx * cy])            # Rx @ Ry @ e_z
    d = points - q[0:3]
    J = np.empty((len(points), 3, 6))
    J[:, :, 0:3] = np.eye(3)
    J[:, :, 3] = np.cross(a0, d)
    J[:, :, 4] = np.cross(a1, d)
    J[:, :, 5] = np.cross(a2, d)
    return J


class ModelTracker:
    """Gauss-Newton ICP of one hand model (module docstring).

    Args:
        model: the subject's hand model (shape applied).
        config: weights and thresholds.
    """

    def __init__(self, model: HandModel, config: TrackerConfig | None = None) -> None:
        self.cfg = config or TrackerConfig()
        self.set_model(model)

    def set_model(self, model: HandModel) -> None:
        """Use another (e.g. calibrated) model."""
        self.model = model
        self.rest_normals = model.normals(model.rest_vertices)
        self.labels = model.vertex_labels
        self.cand = np.arange(0, model.n_vertices, self.cfg.model_stride)

    # ----------------------------------------------------------------------------- geometry
    def posed(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All skinned vertices (V, 3) and the facing candidate vertices' indices.

        Normals are the rest normals turned by each vertex's main bone (cheap, and accurate
        enough to tell facing from back-facing vertices)."""
        fk = self.model.forward(q)
        rot = fk.joint_frames[:, :3, :3]
        c = self.cand
        n = np.einsum("vij,vj->vi", rot[self.labels[c]], self.rest_normals[c])
        V = fk.vertices
        return V, c[np.einsum("ij,ij->i", n, V[c]) < 0.0]

    def correspond(self, points: np.ndarray, pixels: np.ndarray, V: np.ndarray,
                   facing: np.ndarray, intr: Intrinsics) -> Correspondences:
        """Eq. II.22 with the 2D window search (module docstring)."""
        cfg = self.cfg
        empty = Correspondences(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)))
        if len(facing) == 0 or len(points) == 0:
            return empty
        Vf = V[facing]
        z = np.maximum(Vf[:, 2], 1e-3)
        uv = np.stack([intr.fx * Vf[:, 0] / z + intr.cx, intr.fy * Vf[:, 1] / z + intr.cy], 1)
        k = min(cfg.window_candidates, len(facing))
        tree = cKDTree(uv)
        dist, idx = tree.query(pixels, k=k, p=np.inf, distance_upper_bound=cfg.window_px)
        if k == 1:
            dist, idx = dist[:, None], idx[:, None]
        ok = dist < np.inf
        safe = np.where(ok, idx, 0)
        diff = Vf[safe] - points[:, None, :]
        d3 = np.einsum("nkc,nkc->nk", diff, diff)
        d3[~ok] = np.inf
        best = np.argmin(d3, axis=1)
        rows = np.arange(len(points))
        bd = np.sqrt(d3[rows, best])
        sel = safe[rows, best]
        if cfg.window_fallback:
            miss = ~np.isfinite(bd)
            if miss.any():
                d_fb, i_fb = cKDTree(Vf).query(points[miss])
                bd[miss] = d_fb
                sel[miss] = i_fb
        keep = np.isfinite(bd) & (bd * _MM <= cfg.outlier_mm)
        vi = facing[sel[keep]]
        return Correspondences(points[keep], vi, V[vi])

    def reverse_correspond(self, points: np.ndarray, V: np.ndarray, facing: np.ndarray,
                           obs: HandObservation, stride: int = 3) -> Correspondences:
        """Model-to-data pairs (an addition to eq. II.23, weight ``reverse_weight``): every
        ``stride``-th facing vertex that projects off the observed hand (farther than
        ``reverse_margin_px`` from it) is paired with its nearest observed point. This
        pulls back model parts that stick out where the camera sees nothing (e.g. a finger
        extended in front of a fist)."""
        empty = Correspondences(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)))
        f = facing[::stride]
        if len(f) == 0 or len(points) == 0:
            return empty
        intr = obs.intrinsics
        Vf = V[f]
        z = np.maximum(Vf[:, 2], 1e-3)
        u = np.rint(intr.fx * Vf[:, 0] / z + intr.cx).astype(np.int64)
        v = np.rint(intr.fy * Vf[:, 1] / z + intr.cy).astype(np.int64)
        inside = (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
        # off the hand by more than reverse_margin_px (silhouette rims are left alone: a
        # vertex on the rim of a finger may round to an empty pixel next to it)
        out_px = np.full(len(f), np.inf, np.float32)
        out_px[inside] = obs.outside_distance[v[inside], u[inside]]
        keep = out_px > self.cfg.reverse_margin_px
        if not keep.any():
            return empty
        dist, idx = cKDTree(points).query(Vf[keep])
        vi = f[keep]
        return Correspondences(points[idx], vi, V[vi])

    # -------------------------------------------------------------------------------- GN
    def normal_equations(self, q: np.ndarray, corr: Correspondences | list,
                         q_ref: np.ndarray | None, dofs: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, float]:
        """``(A, g, E)``: Gauss-Newton system ``A dq = -g`` over ``dofs`` and the energy.

        ``corr`` is one set of data pairs (weight ``data_weight``) or a list of
        ``(Correspondences, weight)``."""
        cfg = self.cfg
        n = len(dofs)
        A = np.zeros((n, n))
        g = np.zeros(n)
        E = 0.0
        pairs = [(corr, cfg.data_weight)] if isinstance(corr, Correspondences) else corr
        for c, w in pairs:
            if not len(c.vertex) or w <= 0:
                continue
            if n == 6 and dofs[0] == 0 and dofs[-1] == 5:
                J = _root_jacobian(q, c.model).reshape(-1, 6) * _MM
            else:
                J = self.model.jacobian(q, c.vertex)[:, :, dofs].reshape(-1, n) * _MM
            r = c.residual_mm.reshape(-1)
            A += w * (J.T @ J)
            g += w * (J.T @ r)
            E += w * float(r @ r)
        if q_ref is not None and cfg.smooth_weight > 0:
            s = _SMOOTH_SCALE[dofs]
            d = q[dofs] - q_ref[dofs]
            ang = dofs >= 3
            d[ang] = (d[ang] + np.pi) % (2 * np.pi) - np.pi  # angles compared modulo 2 pi
            r = d * s
            A[np.diag_indices(n)] += cfg.smooth_weight * s * s
            g += cfg.smooth_weight * s * r
            E += cfg.smooth_weight * float(r @ r)
        if cfg.limit_weight > 0:
            qd = q[dofs]
            lo, hi = _LIM_LO[dofs], _LIM_HI[dofs]
            viol = np.where(qd < lo, qd - lo, np.where(qd > hi, qd - hi, 0.0))
            act = viol != 0
            A[np.diag_indices(n)] += cfg.limit_weight * act
            g += cfg.limit_weight * viol
            E += cfg.limit_weight * float(viol @ viol)
        return A, g, E

    def step(self, q: np.ndarray, obs: HandObservation, points: np.ndarray, pixels: np.ndarray,
             q_ref: np.ndarray | None, dofs: np.ndarray) -> tuple[np.ndarray, Correspondences]:
        """One Gauss-Newton iteration (correspondences rebuilt at ``q``)."""
        V, facing = self.posed(q)
        corr = self.correspond(points, pixels, V, facing, obs.intrinsics)
        pairs = [(corr, self.cfg.data_weight)]
        if self.cfg.reverse_weight > 0:
            pairs.append((self.reverse_correspond(points, V, facing, obs),
                          self.cfg.reverse_weight))
        A, g, _ = self.normal_equations(q, pairs, q_ref, dofs)
        A[np.diag_indices(len(dofs))] += self.cfg.damping * (1.0 + A.diagonal())
        try:
            dq = -np.linalg.solve(A, g)
        except np.linalg.LinAlgError:
            return q, corr
        ang = dofs >= 3
        big = float(np.max(np.abs(dq[ang]))) if ang.any() else 0.0
        if big > self.cfg.max_step_rad:
            dq *= self.cfg.max_step_rad / big
        out = q.copy()
        out[dofs] += dq
        return out, corr

    def refine(self, q: np.ndarray, obs: HandObservation, iterations: int,
               q_ref: np.ndarray | None = None, palm_only: bool = False,
               points: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Run ``iterations`` GN steps from ``q``; ``palm_only`` moves the 6 root DoFs."""
        if not obs.found or iterations <= 0:
            return q
        pts, pix = points if points is not None else obs.subsample(self.cfg.max_points)
        dofs = np.arange(6) if palm_only else np.arange(N_DOF)
        for _ in range(iterations):
            q, _ = self.step(q, obs, pts, pix, q_ref, dofs)
        return q

    # ------------------------------------------------------------------------------ cost
    def depth_cost(self, q: np.ndarray, obs: HandObservation,
                   observed_ds: np.ndarray | None = None) -> float:
        """E_d of eq. II.19 for pose ``q`` [mm]."""
        ds = self.cfg.cost_downsample
        o = observed_ds if observed_ds is not None else obs.depth_m[::ds, ::ds]
        r = render_depth(self.model.vertices(q), obs.intrinsics, ds)
        return depth_error(r[:o.shape[0], :o.shape[1]], o, self.cfg.depth_cap_mm)
