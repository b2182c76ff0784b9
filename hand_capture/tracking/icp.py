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

Robust data term (a departure from eq. II.23, ``robust_mm`` > 0): each pair's squared
distance is replaced by the Huber loss of its distance (scale ``robust_mm``), minimised by
iteratively reweighted least squares, the weight ``min(1, k / ||r||)`` recomputed with the
correspondences at every Gauss-Newton iteration. Points the model cannot explain (a forearm
stub, a sleeve, a surface thicker than the model's) then pull with a bounded force instead
of a force growing with their distance.

Optional wrist stub (``wrist_optional``, :func:`optional_vertices`): the model-to-data pairs
(the addition to eq. II.23 below) leave out the template's surface beyond the wrist keypoint,
where real data is forearm, sleeve, cut or nothing; a hand surface ending at the wrist
otherwise pulls the whole model towards the fingers (and calibration shrinks it).

E_d past the wrist (a departure from eq. II.19, :meth:`ModelTracker.depth_costs`
``stub_optional`` / ``arm_optional``, chosen per frame by the hybrid tracker): without a
forearm cut off, the stub's rendered pixels without data leave the union; with one, the data
past the pose's wrist that the model does not cover leaves it.

Finger penetration (a departure from eq. II.21, ``overlap_weight`` > 0): one more residual
per pair of penetrating capsules of two of the four fingers, their penetration depth [mm]
(:mod:`hand_capture.tracking.overlap`); not in palm-only iterations.

Units: the data residuals are in millimetres (so l1 = 1, l2 = 0.2 and l3 = 1000 of the
dissertation weigh a millimetre against a radian); root translations in E_smooth are in
millimetres too. A small Levenberg damping keeps the normal equations regular when a finger
has no points.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.model import JOINT_LIMITS, N_DOF, HandModel
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.overlap import FingerOverlap
from hand_capture.tracking.preprocess import HandObservation

__all__ = ["Correspondences", "ModelTracker", "beyond_wrist", "cost_grid", "depth_error",
           "downsampled_depth", "huber_sqrt_weights", "optional_vertices", "render_depth",
           "wrap_angles"]

_MM = 1000.0
#: per-DoF unit scale of E_smooth: root translation in mm, angles in rad
_SMOOTH_SCALE = np.r_[np.full(3, _MM), np.ones(N_DOF - 3)]
_LIM_LO = JOINT_LIMITS[:, 0]
_LIM_HI = JOINT_LIMITS[:, 1]
_ANGLE_DOFS = np.arange(3, N_DOF)
_FAR = np.float32(1e3)
_K3 = np.ones((3, 3), np.uint8)


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Angle differences [rad] taken modulo 2 pi into [-pi, pi)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


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
    H, W = _image_size(intr, ds)
    out = np.zeros((H, W), np.float32)
    img, r0, c0, _ = _render_batch(vertices[None], intr, ds, None)
    out[r0:r0 + img.shape[1], c0:c0 + img.shape[2]] = img[0]
    return out


def _image_size(intr: Intrinsics, ds: int) -> tuple[int, int]:
    """(rows, columns) of the image at ``1/ds`` resolution."""
    return (intr.height + ds - 1) // ds, (intr.width + ds - 1) // ds


def _render_batch(Vs: np.ndarray, intr: Intrinsics, ds: int,
                  box: tuple[int, int, int, int] | None, optional: np.ndarray | None = None
                  ) -> tuple[np.ndarray, int, int, np.ndarray | None]:
    """:func:`render_depth` of every pose's vertices ``Vs`` (B, N, 3), all in one window:
    ``(images (B, h, w) float32 [m], row0, col0, mine)``.

    The window holds every pose's splatted pixels with a 2-pixel margin and the rows /
    columns ``box = (r0, r1, c0, c1)`` (end exclusive), clipped to the image: the 3x3
    closing of a silhouette then gives what it gives on the whole image (nothing closes
    across 2 empty pixels), so each pose's image is its :func:`render_depth` there.
    ``optional`` (N,) bool: vertices splatted alone as well; ``mine`` (B, h, w) says where
    they are the rendered surface (their depth is the rendered one); None without them.
    """
    H, W = _image_size(intr, ds)
    B = len(Vs)
    Z = Vs[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):   # dropped below: z <= 1 mm, NaN
        U = np.rint((intr.fx * Vs[..., 0] / Z + intr.cx) / ds)     # (B, N) pixel columns
        R = np.rint((intr.fy * Vs[..., 1] / Z + intr.cy) / ds)     # (B, N) pixel rows
    ok = (Z > 1e-3) & (U >= 0) & (U < W) & (R >= 0) & (R < H)
    every = bool(ok.all())
    pose = np.arange(B)[:, None]
    if not every:
        pose = np.broadcast_to(pose, ok.shape)[ok]
    u, w, z = (U, R, Z) if every else (U[ok], R[ok], Z[ok])   # whole pixels, as floats
    rows = [] if box is None else [box[0], box[1] - 1]
    cols = [] if box is None else [box[2], box[3] - 1]
    if u.size:
        rows += [int(w.min()) - 2, int(w.max()) + 2]
        cols += [int(u.min()) - 2, int(u.max()) + 2]
    if not rows:
        return np.zeros((B, 0, 0), np.float32), 0, 0, None
    r0, r1 = max(min(rows), 0), min(max(rows) + 1, H)
    c0, c1 = max(min(cols), 0), min(max(cols) + 1, W)
    h, wd = r1 - r0, c1 - c0
    # each pose's image is h + 1 rows: the last one (never drawn) keeps the 3x3 operations
    # of one image from reaching the next (_splat)
    flat = ((pose * (h + 1) + (w - r0)) * wd + (u - c0)).astype(np.int64).ravel()
    z = z.astype(np.float32).ravel()
    img = _splat(flat, z, (B, h + 1, wd))
    mine = None
    if optional is not None:
        sel = np.broadcast_to(optional, ok.shape)
        sel = (sel if every else sel[ok]).ravel()
        part = _splat(flat[sel], z[sel], (B, h + 1, wd))
        mine = ((part > 0) & (img > 0) & (part <= img + np.float32(1e-6)))[:, :h]
    return img[:, :h], r0, c0, mine


def _splat(flat: np.ndarray, z: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """Z-buffers ``shape`` (B, h + 1, w) of depths ``z`` (K,) float32 [m] at the flat
    indices ``flat`` (K,), each image's last row left empty, the one-pixel holes closed
    (3x3 closing of each silhouette, filled with the nearest depth around them), empty
    pixels 0.

    The images are stacked into one (B (h + 1), w) image for OpenCV, the empty rows between
    them: the dilation of the closing reads them as nothing and the erosion, with them set
    to 1, as nothing too, like OpenCV's own border, so each image is closed alone."""
    B, h1, wd = shape
    buf = np.full(B * h1 * wd, _FAR, np.float32)
    np.minimum.at(buf, flat, z)
    buf = buf.reshape(B * h1, wd)
    occ = (buf < _FAR).astype(np.uint8)
    grown = cv2.dilate(occ, _K3)
    grown[h1 - 1::h1] = 1
    holes = (cv2.erode(grown, _K3) > 0) & (occ == 0)
    holes[h1 - 1::h1] = False
    if holes.any():
        buf[holes] = cv2.erode(buf, _K3)[holes]
    buf[buf >= _FAR] = 0.0
    return buf.reshape(shape)


def cost_grid(obs: HandObservation, cfg: TrackerConfig) -> int:
    """The downsampling of the E_d evaluation (eq. II.19) for ``obs``.

    :func:`render_depth` splats the mesh's vertices (about 3-5 mm apart: edges median 3.8,
    90th percentile 4.9 mm) and closes one-pixel holes only, so where a pixel covers much
    less than that on the hand the rendered silhouette is a sieve and E_d counts its holes.
    E_d at the true pose of the synthetic camera's renders (640x480, 70 deg, clips ``fist``
    and ``translation``, hand 0.18-0.39 m) against the size of a pixel on the hand: 40-58
    mm at 0.4-0.85 mm, 23-44 mm at 0.8-1.05 mm, 8.5-11 mm at 1.2-1.9 mm, then rising slowly
    with the rim's share (12-16 mm at 2.5-5 mm). Past about 25 mm a good pose fails the
    success test (eq. II.19). So where a pixel at the hand's median depth would cover less
    than ``cost_footprint_mm`` (1.1 mm: where the holes begin) the step is the least that
    makes it that wide; it is never less than ``cost_downsample`` (nor more than 8). Only
    near, fine cameras change: 640x480 at 70 deg from about 0.25 m in; the suite's 320x240
    camera keeps ``cost_downsample`` from 0.13 m out.
    """
    ds = int(cfg.cost_downsample)
    z = obs.median_depth_m
    if cfg.cost_footprint_mm > 0.0 and z > 0.0:
        need = cfg.cost_footprint_mm * 1e-3 * obs.intrinsics.fx / z
        ds = max(ds, int(np.ceil(need - 1e-9)))
    return min(ds, 8)


def downsampled_depth(obs: HandObservation, ds: int) -> np.ndarray:
    """The segmented depth image [m] of ``obs`` at ``1/ds`` resolution (every ``ds``-th row
    and column), as a contiguous array: the E_d of eq. II.19 reads it once per pose."""
    return np.ascontiguousarray(obs.depth_m[::ds, ::ds])


def depth_error(rendered_m: np.ndarray, observed_m: np.ndarray, cap_mm: float,
                optional: np.ndarray | None = None,
                data_optional: np.ndarray | None = None) -> float:
    """E_d of eq. II.19: sum |I_r - I| over the union of both silhouettes / its size [mm].

    The per-pixel difference is capped at ``cap_mm`` (a pixel covered by one image only
    counts the cap). An empty union (no hand, no model) gives ``cap_mm``. ``optional``
    (bool, the images' shape): rendered pixels that count only where ``observed_m`` has
    data (the optional wrist stub, ``cost_stub_optional``); ``data_optional``: observed
    pixels that count only where ``rendered_m`` has the model (the arm past the pose's
    wrist, ``cost_arm_optional``).
    """
    opt = None if optional is None else optional[None]
    dopt = None if data_optional is None else data_optional[None]
    return float(_depth_errors(rendered_m[None], observed_m, cap_mm, opt, dopt)[0])


def _depth_errors(rendered_m: np.ndarray, observed_m: np.ndarray, cap_mm: float,
                  optional: np.ndarray | None = None,
                  data_optional: np.ndarray | None = None) -> np.ndarray:
    """:func:`depth_error` of every rendered image ``rendered_m`` (B, h, w) against one
    observed image ``observed_m`` (h, w), with per-image masks ``optional`` /
    ``data_optional`` (B, h, w): (B,) [mm]. The per-pixel terms are computed for all
    images at once, the sum over each image's union in its pixels' order."""
    r = rendered_m
    o = np.broadcast_to(observed_m, r.shape)
    if optional is not None:
        r = np.where(optional & (o <= 0), np.float32(0.0), r)
    if data_optional is not None:
        o = np.where(data_optional & (r <= 0), np.float32(0.0), o)
    union = (r > 0) | (o > 0)
    both = (r > 0) & (o > 0)
    diff = np.where(both, np.minimum(np.abs(r - o) * _MM, cap_mm), cap_mm)
    out = np.full(len(r), float(cap_mm))   # an empty union: no hand, no model
    for b in range(len(r)):
        n = int(np.count_nonzero(union[b]))
        if n:
            out[b] = float(diff[b][union[b]].sum() / n)
    return out


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
    a = np.stack([a0, a1, a2], axis=1)                # (3, 3): axis k in column k
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]
    J[:, 0, 3:] = a[1] * dz - a[2] * dy               # a_k x d, the three axes at once
    J[:, 1, 3:] = a[2] * dx - a[0] * dz
    J[:, 2, 3:] = a[0] * dy - a[1] * dx
    return J


def huber_sqrt_weights(r: np.ndarray, k: float) -> np.ndarray:
    """Square roots of the Huber IRLS weights (3N,) of residuals ``r`` (3N,) [mm] taken
    per pair: ``w = min(1, k / ||r_i||)`` repeated over the pair's three rows."""
    n = np.sqrt(np.einsum("ij,ij->i", r.reshape(-1, 3), r.reshape(-1, 3)))
    w = np.minimum(1.0, k / np.maximum(n, 1e-9))
    return np.repeat(np.sqrt(w), 3)


def _empty_corr() -> Correspondences:
    return Correspondences(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)))


def _project(V: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Image coordinates (N, 2) (u, v) of points (N, 3) (pinhole, depth clamped at 1 mm)."""
    z = np.maximum(V[:, 2], 1e-3)
    uv = np.empty((len(V), 2))
    uv[:, 0] = intr.fx * V[:, 0] / z + intr.cx
    uv[:, 1] = intr.fy * V[:, 1] / z + intr.cy
    return uv


def optional_vertices(model: HandModel, cfg: TrackerConfig) -> np.ndarray:
    """(V,) bool: the vertices of ``model``'s wrist stub, farther than ``wrist_optional_m``
    (times the global scale) beyond the wrist keypoint along the forearm (middle MCP to
    wrist) in the rest pose; all False without ``wrist_optional``. The template mesh
    reaches 36 mm past the wrist keypoint there; a real hand's surface goes on into the
    forearm (cut, sleeved, or out of view), a hand surface without a forearm ends sooner,
    so these vertices get no model-to-data pairs (an addition to eq. II.23 left out)."""
    if not cfg.wrist_optional:
        return np.zeros(model.n_vertices, bool)
    return beyond_wrist(model) > cfg.wrist_optional_m * float(model.shape.global_scale)


def beyond_wrist(model: HandModel) -> np.ndarray:
    """(V,) how far each rest-pose vertex of ``model`` lies beyond the wrist keypoint along
    the forearm (the middle MCP to wrist direction) [m]; the wrist stub is where it is
    positive."""
    kp = model.joint_positions(np.zeros(N_DOF))
    d = kp[0] - kp[9]
    return (model.rest_vertices - kp[0]) @ (d / np.linalg.norm(d))


class _DofTerms:
    """Per-DoF-set constants of the smoothness (II.24) and joint-limit (II.25) terms."""

    def __init__(self, dofs: np.ndarray) -> None:
        self.n = len(dofs)
        self.ang = np.flatnonzero(dofs >= 3)
        self.scale = _SMOOTH_SCALE[dofs]
        self.scale_sq = self.scale * self.scale
        self.lo = _LIM_LO[dofs]
        self.hi = _LIM_HI[dofs]
        self.diag = np.arange(self.n) * (self.n + 1)     # flat indices of the diagonal
        self.root = self.n == 6 and dofs[0] == 0 and dofs[-1] == 5
        self.full = self.n == N_DOF and bool(np.all(dofs == np.arange(N_DOF)))


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
        #: the four fingers' capsule pairs (overlap_weight)
        self.overlap = FingerOverlap(model)
        self.rest_normals = model.normals(model.rest_vertices)
        self.labels = model.vertex_labels
        self.optional = optional_vertices(model, self.cfg)
        self.cand = np.arange(0, model.n_vertices, self.cfg.model_stride)
        self._cand_opt = self.optional[self.cand]
        # fast path of step(): the candidate vertices and their normals from one sparse
        # product [X_c | N_c] @ [[T, 0], [0, R]] (normals: rest normal turned by the main bone)
        c = self.cand
        nc = len(c)
        lab = self.labels[c]
        nrm = sp.csr_matrix((self.rest_normals[c].reshape(-1),
                             (np.repeat(np.arange(nc), 3),
                              (3 * lab[:, None] + np.arange(3)[None]).reshape(-1))),
                            shape=(nc, 3 * model.skinning_rows().shape[1] // 4))
        self._xc = model.skinning_rows(c)
        self._xcn = sp.hstack([self._xc, nrm], format="csr")
        self._xc_dense = self._xc.toarray()
        self._nx = self._xc.shape[1]
        self._tree_cache: tuple[np.ndarray, cKDTree] | None = None
        self._dof_cache: dict[bytes, _DofTerms] = {}
        self._box_cache: tuple[np.ndarray, tuple | None] | None = None
        self._points_cache: tuple[np.ndarray, np.ndarray] | None = None

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
        if len(facing) == 0 or len(points) == 0:
            return _empty_corr()
        Vf = V[facing]
        keep, sel = self._window_match(points, pixels, Vf, _project(Vf, intr))
        vi = facing[sel[keep]]
        return Correspondences(points[keep], vi, V[vi])

    def _window_match(self, points: np.ndarray, pixels: np.ndarray, Vf: np.ndarray,
                      uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eq. II.22 for the facing vertices ``Vf`` (projected at ``uv``): ``(keep, sel)``,
        whether point i has a pair within ``outlier_mm`` and the row of ``Vf`` it pairs
        with (the nearest in 3D of the ``window_candidates`` vertices nearest to its pixel
        inside the window)."""
        cfg = self.cfg
        k = min(cfg.window_candidates, len(Vf))
        # unbalanced tree: quicker to build, same neighbours
        tree = cKDTree(uv, balanced_tree=False, compact_nodes=False)
        _, idx = tree.query(pixels, k=k, p=np.inf, distance_upper_bound=cfg.window_px)
        if k == 1:
            idx = idx[:, None]
        # a missing neighbour has index len(Vf): it reads a point at infinity
        Vp = np.concatenate([Vf, np.full((1, 3), np.inf)])
        diff = Vp[idx] - points[:, None, :]
        d3 = np.einsum("nkc,nkc->nk", diff, diff)
        flat = np.arange(0, d3.size, k) + d3.argmin(axis=1)   # best of each row
        bd = np.sqrt(d3.ravel()[flat])
        sel = idx.ravel()[flat]
        if cfg.window_fallback:
            miss = ~np.isfinite(bd)
            if miss.any():
                d_fb, i_fb = cKDTree(Vf).query(points[miss])
                bd[miss] = d_fb
                sel[miss] = i_fb
        return bd * _MM <= cfg.outlier_mm, sel      # False for a point with no vertex (inf)

    def reverse_correspond(self, points: np.ndarray, V: np.ndarray, facing: np.ndarray,
                           obs: HandObservation, stride: int = 3,
                           tree: cKDTree | None = None) -> Correspondences:
        """Model-to-data pairs (an addition to eq. II.23, weight ``reverse_weight``): every
        ``stride``-th facing vertex that projects off the observed hand (farther than
        ``reverse_margin_px`` from it) is paired with its nearest observed point. This
        pulls back model parts that stick out where the camera sees nothing (e.g. a finger
        extended in front of a fist)."""
        f = facing[::stride]
        f = f[~self.optional[f]]   # not from the optional wrist stub
        if len(f) == 0 or len(points) == 0:
            return _empty_corr()
        Vf = V[f]
        keep, idx = self._reverse_match(points, Vf, _project(Vf, obs.intrinsics), obs, tree)
        if keep is None:
            return _empty_corr()
        vi = f[keep]
        return Correspondences(points[idx], vi, V[vi])

    def _reverse_match(self, points: np.ndarray, Vf: np.ndarray, uv: np.ndarray,
                       obs: HandObservation, tree: cKDTree | None
                       ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """:meth:`reverse_correspond` for vertices ``Vf`` projected at ``uv``: ``(keep,
        idx)``, the vertices off the hand and their nearest points (None, None: none)."""
        intr = obs.intrinsics
        u = np.rint(uv[:, 0]).astype(np.int64)
        v = np.rint(uv[:, 1]).astype(np.int64)
        inside = (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
        # off the hand by more than reverse_margin_px (silhouette rims are left alone: a
        # vertex on the rim of a finger may round to an empty pixel next to it)
        keep = np.ones(len(Vf), bool)
        keep[inside] = obs.off_hand(v[inside], u[inside], self.cfg.reverse_margin_px)
        if not keep.any():
            return None, None
        _, idx = (tree or cKDTree(points)).query(Vf[keep])
        return keep, idx

    # -------------------------------------------------------------------------------- GN
    def normal_equations(self, q: np.ndarray, corr: Correspondences | list,
                         q_ref: np.ndarray | None, dofs: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, float]:
        """``(A, g, E)``: Gauss-Newton system ``A dq = -g`` over ``dofs`` and the energy.

        ``corr`` is one set of data pairs (weight ``data_weight``) or a list of
        ``(Correspondences, weight)``; the fingers' penetration term (``overlap_weight``)
        is added except for the palm alone, as in :meth:`step`."""
        cfg = self.cfg
        n = len(dofs)
        blocks = []
        pairs = [(corr, cfg.data_weight)] if isinstance(corr, Correspondences) else corr
        for c, w in pairs:
            if not len(c.vertex) or w <= 0:
                continue
            if n == 6 and dofs[0] == 0 and dofs[-1] == 5:
                J = _root_jacobian(q, c.model).reshape(-1, 6) * _MM
            else:
                J = self.model.jacobian(q, c.vertex)[:, :, dofs].reshape(-1, n) * _MM
            r = c.residual_mm.reshape(-1)
            if cfg.robust_mm > 0:   # Huber IRLS weights per pair (module docstring)
                w = w * huber_sqrt_weights(r, cfg.robust_mm) ** 2
            blocks.append((J, r, w))
        if cfg.overlap_weight > 0 and not self._dof_terms(dofs).root:
            kp, jac = self.model.keypoints_and_jacobian(q[None], dofs=dofs)
            r, J = self.overlap.residuals(kp, jac)[0]
            if len(r):
                blocks.append((J, r, cfg.overlap_weight))
        return self._assemble(q, blocks, q_ref, dofs)

    def _assemble(self, q: np.ndarray, blocks: list, q_ref: np.ndarray | None,
                  dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Normal equations of eq. II.27 from data blocks ``(J (3N, n), r (3N,), weight)``
        plus the smoothness (II.24) and joint-limit (II.25) terms."""
        cfg = self.cfg
        n = len(dofs)
        A = np.zeros((n, n))
        g = np.zeros(n)
        E = 0.0
        for J, r, w in blocks:  # w: a weight, or one per residual row
            if np.ndim(w):
                Jw = J.T * w
                A += Jw @ J
                g += Jw @ r
                E += float(r @ (w * r))
            else:
                A += w * (J.T @ J)
                g += w * (J.T @ r)
                E += w * float(r @ r)
        if q_ref is not None and cfg.smooth_weight > 0:
            s = _SMOOTH_SCALE[dofs]
            d = q[dofs] - q_ref[dofs]
            ang = dofs >= 3
            d[ang] = wrap_angles(d[ang])
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
        """One Gauss-Newton iteration (correspondences rebuilt at ``q``).

        Same as ``normal_equations(q, [(correspond(...), data_weight), (reverse_correspond(...),
        reverse_weight)], ...)`` on ``posed(q)``, computed on the candidate vertices only, from
        one FK pass (vertices, normals and the Jacobian rows share it)."""
        out, corr = self._steps(q[None], obs, points, pixels, [q_ref], dofs, with_pairs=True)
        return out[0], corr[0]

    def _dof_terms(self, dofs: np.ndarray) -> _DofTerms:
        key = dofs.tobytes()
        t = self._dof_cache.get(key)
        if t is None:
            t = self._dof_cache[key] = _DofTerms(dofs)
        return t

    def _steps(self, Q: np.ndarray, obs: HandObservation, points: np.ndarray,
               pixels: np.ndarray, q_refs: list, dofs: np.ndarray, with_pairs: bool = False
               ) -> tuple[np.ndarray, list[Correspondences]]:
        """:meth:`step` for a batch of poses (B, 27): one FK pass and one skinning product
        for all of them; correspondences and normal equations per pose (the pairs are
        returned only ``with_pairs``)."""
        cfg = self.cfg
        dt = self._dof_terms(dofs)
        root = dt.root
        T, H, rot, pos = self.model.bone_basis(Q, jacobian=not root)
        B, nb = rot.shape[0], rot.shape[1]
        # [X_c | N_c] @ [[T, 0], [0, R^T]] for every pose: columns (pose, 6)
        rhs = np.zeros((self._xcn.shape[1], B, 6))
        rhs[:self._nx, :, :3] = np.swapaxes(T, 0, 1)
        rhs[self._nx:, :, 3:] = np.swapaxes(np.swapaxes(rot, 2, 3).reshape(B, 3 * nb, 3), 0, 1)
        vn = (self._xcn @ rhs.reshape(-1, 6 * B)).reshape(-1, B, 6)
        front = np.einsum("vbi,vbi->vb", vn[:, :, 3:], vn[:, :, :3]) < 0.0   # facing (V_c, B)
        wd, wr = cfg.data_weight, cfg.reverse_weight
        tree = self._point_tree(points) if wr > 0 else None
        # the fingers' penetration (hand_capture.tracking.overlap), not for the palm alone
        ov = (self._overlap_rows(Q, dofs, rot, pos)
              if cfg.overlap_weight > 0 and not root else {})
        intr = obs.intrinsics
        out = Q.copy()
        pairs = []
        for b in range(B):
            q = Q[b]
            Vc = vn[:, b, :3]
            facing = np.flatnonzero(front[:, b])
            rows_d = rows_r = pts_r = None
            if len(facing) and len(points):
                Vf = Vc[facing]
                uv = _project(Vf, intr)
                keep, sel = self._window_match(points, pixels, Vf, uv)
                rows_d = facing[sel[keep]]
                pts_d = points[keep]
                if wr > 0:   # model-to-data pairs, not from the optional wrist stub
                    fr = np.flatnonzero(~self._cand_opt[facing[::3]]) * 3
                    kr, ir = self._reverse_match(points, Vf[fr], uv[fr], obs, tree)
                    if kr is not None:
                        rows_r = facing[fr][kr]
                        pts_r = points[ir]
            if with_pairs:
                d = (np.zeros(0, np.int64), np.zeros((0, 3))) if rows_d is None else \
                    (rows_d, pts_d)
                pairs.append(Correspondences(d[1], self.cand[d[0]], Vc[d[0]]))
            # data rows: (candidate row, point, sqrt of the weight) of both pair sets
            sets = []
            if rows_d is not None and len(rows_d) and wd > 0:
                sets.append((rows_d, pts_d, wd))
            if rows_r is not None and wr > 0:
                sets.append((rows_r, pts_r, wr))
            A = np.zeros((dt.n, dt.n))
            g = np.zeros(dt.n)
            if sets:
                if len(sets) == 1:
                    rows, P, w = sets[0]
                    sw = np.sqrt(w)
                else:
                    rows = np.concatenate([x[0] for x in sets])
                    P = np.concatenate([x[1] for x in sets])
                    sw = np.repeat(np.sqrt([x[2] for x in sets]),
                                   [3 * len(x[0]) for x in sets])
                M = Vc[rows]
                r = ((M - P) * _MM).reshape(-1)
                if cfg.robust_mm > 0:   # Huber IRLS weights per pair (module docstring)
                    hw = huber_sqrt_weights(r, cfg.robust_mm)
                    sw = sw * hw
                if root:
                    J = _root_jacobian(q, M).reshape(-1, 6)
                else:
                    J = (self._xc_dense[rows] @ H[b]).reshape(-1, N_DOF)
                    if not dt.full:
                        J = J[:, dofs]
                # sqrt(w) * [mm] folded into the rows: A = J^T W J, g = J^T W r (eq. II.27)
                if np.ndim(sw):
                    J *= (sw * _MM)[:, None]
                    r *= sw
                else:
                    J *= sw * _MM
                    r *= sw
                A = J.T @ J
                g = J.T @ r
            if b in ov:   # only poses that penetrate have rows (at least one)
                r_o, J_o = ov[b]
                A += cfg.overlap_weight * (J_o.T @ J_o)
                g += cfg.overlap_weight * (J_o.T @ r_o)
            self._prior_terms(A, g, q, q_refs[b], dofs, dt)
            A.ravel()[dt.diag] += cfg.damping * (1.0 + A.ravel()[dt.diag])
            try:
                dq = -np.linalg.solve(A, g)
            except np.linalg.LinAlgError:
                continue
            if len(dt.ang):
                big = float(np.max(np.abs(dq[dt.ang])))
                if big > cfg.max_step_rad:
                    dq *= cfg.max_step_rad / big
            out[b, dofs] += dq
        return out, pairs

    def _overlap_rows(self, Q: np.ndarray, dofs: np.ndarray, rot: np.ndarray, pos: np.ndarray
                      ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """The fingers' penetration rows (:meth:`FingerOverlap.residuals`: (k,) [mm], (k,
        len(dofs))) of the poses ``Q`` (B, 27) that penetrate, by batch row; ``rot``, ``pos``
        their FK (:meth:`HandModel.bone_basis`). The keypoint Jacobian is formed only for
        those poses (about 2 % of the tracked ones), the same values as for the batch."""
        hit = np.flatnonzero(self.overlap.penetrating(self.model.keypoints_of_fk((rot, pos))))
        if not len(hit):
            return {}
        kp, jac = self.model.keypoints_and_jacobian(Q[hit], dofs=dofs,
                                                    fk=(rot[hit], pos[hit]))
        return dict(zip(hit.tolist(), self.overlap.residuals(kp, jac), strict=True))

    def _prior_terms(self, A: np.ndarray, g: np.ndarray, q: np.ndarray,
                     q_ref: np.ndarray | None, dofs: np.ndarray, dt: _DofTerms) -> None:
        """Add the smoothness (II.24) and joint-limit (II.25) terms to ``A``, ``g`` (the
        same terms as :meth:`_assemble`)."""
        cfg = self.cfg
        diag = A.ravel()   # a view: A is contiguous
        qd = q[dofs]
        if q_ref is not None and cfg.smooth_weight > 0:
            d = qd - q_ref[dofs]
            a = dt.ang
            d[a] = wrap_angles(d[a])
            diag[dt.diag] += cfg.smooth_weight * dt.scale_sq
            g += cfg.smooth_weight * dt.scale_sq * d
        if cfg.limit_weight > 0:
            viol = np.minimum(qd - dt.lo, 0.0) + np.maximum(qd - dt.hi, 0.0)
            diag[dt.diag] += cfg.limit_weight * (viol != 0)
            g += cfg.limit_weight * viol

    def _point_tree(self, points: np.ndarray) -> cKDTree:
        """KD-tree of the observed points, kept while the same array is passed."""
        c = self._tree_cache
        if c is None or c[0] is not points:
            c = (points, cKDTree(points))
            self._tree_cache = c
        return c[1]

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

    def refine_batch(self, Q: np.ndarray | list, obs: HandObservation, iterations: int,
                     q_refs: list | None = None, palm_only: bool = False,
                     points: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """:meth:`refine` of several poses (B, 27) together (same results, shared FK)."""
        Q = np.array(Q, dtype=np.float64, ndmin=2)
        if not obs.found or iterations <= 0 or not len(Q):
            return Q
        pts, pix = points if points is not None else obs.subsample(self.cfg.max_points)
        dofs = np.arange(6) if palm_only else np.arange(N_DOF)
        refs = list(q_refs) if q_refs is not None else [None] * len(Q)
        for _ in range(iterations):
            Q, _ = self._steps(Q, obs, pts, pix, refs, dofs)
        return Q

    # ------------------------------------------------------------------------------ cost
    def depth_cost(self, q: np.ndarray, obs: HandObservation,
                   observed_ds: np.ndarray | None = None) -> float:
        """E_d of eq. II.19 for pose ``q`` [mm]."""
        return float(self.depth_costs(np.asarray(q)[None], obs, observed_ds)[0])

    def depth_costs(self, Q: np.ndarray, obs: HandObservation,
                    observed_ds: np.ndarray | None = None, *, stub_optional: bool = False,
                    arm_optional: bool = False, arm_free_m: float = 0.0) -> np.ndarray:
        """:meth:`depth_cost` of poses (B, 27) (one skinning pass for all). A given
        ``observed_ds`` must be ``downsampled_depth(obs, cost_grid(obs, cfg))`` (the
        models are rendered on that grid). ``stub_optional``: the pixels where the optional
        wrist stub (:func:`optional_vertices`) is the rendered surface count only where
        data lies (a hand ending at the wrist; ``cost_stub_optional``). ``arm_optional``:
        the data pixels past each pose's wrist (the side of the plane through its wrist
        keypoint, normal to the middle MCP -> wrist direction, that holds the arm) count
        only where the model is (the arm a forearm cut leaves; ``cost_arm_optional``), up
        to ``arm_free_m`` [m] past the wrist plane when that is positive."""
        ds = cost_grid(obs, self.cfg)
        o = observed_ds if observed_ds is not None else downsampled_depth(obs, ds)
        if observed_ds is not None and observed_ds.shape != _image_size(obs.intrinsics, ds):
            raise InputError(f"depth_costs: observed_ds has shape {observed_ds.shape}, not "
                             f"that of the E_d grid (step {ds}) of this observation")
        Q = np.array(Q, dtype=np.float64, ndmin=2)
        if not len(Q):
            return np.empty(0)
        box = self._observed_box(o)
        arm = None
        if arm_optional:   # each pose's wrist keypoint and its direction away from the hand
            fk = self.model.forward(Q)   # vertices and keypoints from one FK pass
            V, kp = fk.vertices, fk.joint_positions                  # (B, V, 3), (B, 21, 3)
            d = kp[:, 0] - kp[:, 9]                                      # (B, 3)
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
            arm = (self._observed_points(o, obs.intrinsics, ds), kp[:, 0], d, arm_free_m)
        else:
            V = self.model.vertices(Q)
        opt = self.optional if stub_optional and self.optional.any() else None
        img, r0, c0, mine = _render_batch(V, obs.intrinsics, ds, box, opt)
        return self._window_errors(img, r0, c0, mine, o, arm)

    def _window_errors(self, img: np.ndarray, r0: int, c0: int, mine: np.ndarray | None,
                       o: np.ndarray, arm: tuple | None = None) -> np.ndarray:
        """E_d of eq. II.19 of each pose's image ``img`` (B, h, w) of one window (row
        ``r0``, column ``c0``; ``mine``: where the optional vertices are the surface, or
        None) against the observed image ``o`` (every silhouette lies inside the window,
        so E_d over it is E_d over the image): :func:`depth_error` of every pose."""
        B, h, w = img.shape
        ob = o[r0:r0 + h, c0:c0 + w]
        h, w = ob.shape
        free = None
        if arm is not None:   # the data past each pose's wrist, towards the arm
            data = ob > 0   # all of o's data: the window holds the observed box
            pts = arm[0]
            free = np.zeros((B, h, w), bool)
            for b in range(B):
                past = (pts - arm[1][b]) @ arm[2][b]   # [m] beyond the wrist plane
                keep = past > 0
                if arm[3] > 0:
                    keep &= past < arm[3]
                free[b][data] = keep
        return _depth_errors(img[:, :h, :w], ob, self.cfg.depth_cap_mm,
                             None if mine is None else mine[:, :h, :w], free)

    def _observed_points(self, o: np.ndarray, intr: Intrinsics, ds: int) -> np.ndarray:
        """(n, 3) the 3D points [m] of the E_d grid's observed depths ``o`` where it has
        data, in row-major pixel order (kept while the same array is passed)."""
        c = self._points_cache
        if c is None or c[0] is not o:
            rr, cc = np.nonzero(o > 0)
            z = o[rr, cc]
            P = np.stack([(cc * ds - intr.cx) / intr.fx * z, (rr * ds - intr.cy) / intr.fy * z,
                          z], axis=-1)
            c = (o, P)
            self._points_cache = c
        return c[1]

    def _observed_box(self, o: np.ndarray) -> tuple[int, int, int, int] | None:
        """Rows / columns (r0, r1, c0, c1) holding the hand pixels of ``o`` (kept while the
        same array is passed)."""
        c = self._box_cache
        if c is None or c[0] is not o:
            rr = np.flatnonzero(o.any(axis=1))
            cc = np.flatnonzero(o.any(axis=0))
            box = None if not len(rr) else (int(rr[0]), int(rr[-1]) + 1, int(cc[0]),
                                             int(cc[-1]) + 1)
            c = (o, box)
            self._box_cache = c
        return c[1]
