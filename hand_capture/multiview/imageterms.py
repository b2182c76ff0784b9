"""Seed 000's image terms (sec. 4.2): silhouette, colour and edge discrepancy of a posed scene.

The cost of a hypothesised scene configuration against one synchronised group of colour
images is eq. (3): ``E = w_silh sum_v E_silh + w_color sum_v E_color + w_edge sum_v E_edge``
with the weights 1.0 / 0.6 / 1.0, where

* ``E_silh`` (eq. 5) compares the rendered hand silhouette ``S_r`` with the observed one
  ``S_o``, which comes from a colour model learned on the first frame (eq. 4,
  :class:`ColourModel`);
* ``E_color`` (eq. 6) compares each rendered hand pixel's colour (the vertex colours
  sampled from the first frame, seed 000's view-dependent texture in its simplest form)
  with the observed pixels of a 5 x 5 window, weighted by the pixel distance and cut off at
  ``T = 0.25``;
* ``E_edge`` (eq. 7) is the chamfer distance between rendered and observed edges (Canny +
  distance transforms): both ways for the hand, rendered -> observed (twice) for the objects.

Everything that depends on the image alone is computed once per view (:func:`observe`: the
silhouette, both distance transforms, the observed hand-edge pixels and the 25 shifted copies
of the image for the colour window), so that a particle costs a projection, a z-buffer, a few
array reductions and one small distance transform per view (:class:`ImageCost`). Particles
are rendered by splatting a fixed subset of surface points (about 5 mm apart) into a
``scale`` times smaller image (0.25 -> 160 x 120 for the studio), all particles at once.

Deviations from the paper, each for a stated reason:

* eq. (4) gives an unnormalised mixture of super-Gaussians ``exp(-|x - mu|^0.8)``; here
  every component has a scale ``s_j`` (``exp(-(|x - mu_j| / s_j)^0.8)``) and a pixel is
  hand when the hand mixture beats a background mixture fitted the same way on the first
  frame's other pixels (the paper thresholds the hand mixture at an unstated level);
* eq. (6)'s weight ``w_ij = exp(-|i - j|^2)`` multiplies the error, which as written would
  favour the farthest pixel of the window; the error is divided by it instead (distance in
  units of the window's half size), which is what "a larger weight for the closer pixel"
  means; colours are in [0, 1] and ``|.|`` is the mean absolute channel difference;
* the sums of eq. (6) are divided by the number of rendered hand pixels (the other terms are
  ratios already), so that the weights of eq. (3) balance the terms at any resolution;
* distances of eq. (7) are in pixels of the evaluation scale and clipped at
  ``edge_clip_px`` (a stray edge far away must not dominate).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.multiview.rig import RigCamera

__all__ = ["SGMM", "ColourModel", "ImageCost", "ImageTermsConfig", "ObservedView",
           "colour_features", "edge_term", "hand_rois", "observe", "observe_group",
           "silhouette_term", "surface_points"]

_EPS = 1e-6


@dataclass(frozen=True)
class ImageTermsConfig:
    """Weights and settings of the image terms (seed 000 eq. 3-7)."""

    w_silh: float = param(1.0, "weight of the silhouette term, eq. (3)", lo=0.0, hi=100.0)
    w_color: float = param(0.6, "weight of the colour term, eq. (3)", lo=0.0, hi=100.0)
    w_edge: float = param(1.0, "weight of the edge term, eq. (3)", lo=0.0, hi=100.0)
    window: int = param(5, "colour window size, eq. (6) [px]", lo=1, hi=15)
    color_cutoff: float = param(0.25, "colour error cut-off T, eq. (6)", lo=0.01, hi=1.0)
    scale: float = param(0.25, "evaluation resolution / image resolution", lo=0.05, hi=1.0)
    canny_low: float = param(40.0, "Canny lower threshold [grey levels]", lo=1.0, hi=500.0)
    canny_high: float = param(100.0, "Canny upper threshold [grey levels]", lo=1.0, hi=1000.0)
    edge_clip_px: float = param(10.0, "largest edge distance counted, eq. (7) [px at scale]",
                                lo=1.0, hi=1000.0)
    depth_edge_m: float = param(0.015, "depth step of a rendered occlusion edge [m]",
                                lo=0.001, hi=1.0)
    point_spacing_m: float = param(0.005, "spacing of the splatted surface points [m]",
                                   lo=0.001, hi=0.05)
    color_points: int = param(400, "hand points per hand the colour term samples, eq. (6)",
                              lo=10, hi=100_000)
    components: int = param(4, "super-Gaussian components per colour mixture, eq. (4)",
                            lo=1, hi=16)

    def __post_init__(self) -> None:
        validate(self)


# ----------------------------------------------------------------------- eq. (4) colour
@dataclass
class SGMM:
    """Super-Gaussian mixture of colours, eq. (4): ``sum_j lam_j exp(-(|x - mu_j|/s_j)^0.8)``.

    Attributes:
        mu: (K, 3) centres (colours in [0, 1]).
        lam: (K,) weights, >= 0, summing to 1.
        s: (K,) scales (colour distance units).
    """

    mu: np.ndarray
    lam: np.ndarray
    s: np.ndarray

    @classmethod
    def fit(cls, x: np.ndarray, k: int = 4, iters: int = 15, seed: int = 0,
            max_samples: int = 20_000) -> SGMM:
        """EM on colours ``x`` (N, 3) in [0, 1] (seeded; at most ``max_samples`` used)."""
        rng = np.random.default_rng(seed)
        x = np.asarray(x, float).reshape(-1, 3)
        if len(x) < k:
            raise InputError(f"SGMM.fit needs at least {k} colours, got {len(x)}")
        if len(x) > max_samples:
            x = x[rng.choice(len(x), max_samples, replace=False)]
        mu = x[rng.choice(len(x), k, replace=False)].copy()
        s = np.full(k, max(float(x.std()), 0.02))
        lam = np.full(k, 1.0 / k)
        for _ in range(iters):
            d = np.linalg.norm(x[:, None, :] - mu[None], axis=2)            # (N, K)
            # normalised responsibilities of a 3-D density ~ exp(-(d/s)^0.8) / s^3
            logp = np.log(lam + 1e-12) - (d / s) ** 0.8 - 3.0 * np.log(s)
            logp -= logp.max(axis=1, keepdims=True)
            r = np.exp(logp)
            r /= r.sum(axis=1, keepdims=True)
            nk = r.sum(axis=0) + 1e-9
            lam = nk / nk.sum()
            mu = (r.T @ x) / nk[:, None]
            d = np.linalg.norm(x[:, None, :] - mu[None], axis=2)
            # scale: the mean of d^0.8 of the members sets s^0.8 (3/0.8 per 3-D sample)
            s = np.maximum((0.8 / 3.0 * (r * d ** 0.8).sum(axis=0) / nk) ** (1 / 0.8), 0.003)
        return cls(mu, lam, s)

    def density(self, x: np.ndarray) -> np.ndarray:
        """Eq. (4) per colour (..., 3) -> (...), with each component's normalisation."""
        x = np.asarray(x, float)
        d = np.linalg.norm(x[..., None, :] - self.mu, axis=-1)
        return np.sum(self.lam / self.s ** 3 * np.exp(-(d / self.s) ** 0.8), axis=-1)


def colour_features(rgb: np.ndarray) -> np.ndarray:
    """The colour coordinates the mixtures of eq. (4) live in, (..., 3) from RGB in [0, 1]:
    chromaticity r/(r+g+b), g/(r+g+b) and a quarter of the intensity, so that a camera's
    exposure changes (a common gain) hardly move a colour."""
    x = np.asarray(rgb, float)
    tot = x.sum(axis=-1, keepdims=True) + 1e-3
    return np.concatenate([x[..., :2] / tot, 0.25 * tot / 3.0], axis=-1)


class ColourModel:
    """Hand / background colour model of the first frame (eq. 4) as a 32^3 lookup table.

    Args:
        hand, background: the two mixtures.
    """

    LEVELS = 32

    def __init__(self, hand: SGMM, background: SGMM) -> None:
        self.hand = hand
        self.background = background
        n = self.LEVELS
        c = (np.arange(n) + 0.5) / n
        grid = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)          # (n, n, n, 3)
        f = colour_features(grid)
        self.lut = hand.density(f) > background.density(f)

    @classmethod
    def fit(cls, images: Sequence[np.ndarray], hand_masks: Sequence[np.ndarray],
            components: int = 4, seed: int = 0, margin_px: int = 0) -> ColourModel:
        """Fit both mixtures on the first frame: ``images`` (H, W, 3) uint8 and their hand
        masks (H, W) bool (e.g. the rendered silhouette of the initial pose). ``margin_px``
        > 0 leaves out a band that wide on both sides of each mask's outline (a rendered
        mask of a model that does not fit the subject exactly)."""
        import cv2

        if len(images) != len(hand_masks) or not images:
            raise InputError("ColourModel.fit needs one hand mask per image")
        fg, bg = [], []
        for img, m in zip(images, hand_masks, strict=True):
            a = np.asarray(img)
            mask = np.asarray(m, bool)
            if a.shape[:2] != mask.shape:
                raise InputError(f"mask {mask.shape} does not fit image {a.shape}")
            px = colour_features(a.reshape(-1, 3).astype(float) / 255.0)
            inner, outer = mask, mask
            if margin_px > 0:
                k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)
                inner = cv2.erode(mask.astype(np.uint8), k) > 0
                outer = cv2.dilate(mask.astype(np.uint8), k) > 0
                if not inner.any():
                    inner = mask
            fg.append(px[inner.ravel()])
            bg.append(px[~outer.ravel()][::7])
        return cls(SGMM.fit(np.concatenate(fg), components, seed=seed),
                   SGMM.fit(np.concatenate(bg), components, seed=seed + 1))

    def explains(self, rgb: np.ndarray) -> np.ndarray:
        """(..., ) bool per pixel of ``rgb`` (..., 3) uint8: the first mixture's density beats
        the second's (eq. 4 against the background mixture), no spatial filtering."""
        q = (np.asarray(rgb) >> 3).astype(np.intp)  # 256 / 32 levels
        return self.lut[q[..., 0], q[..., 1], q[..., 2]]

    def silhouette(self, rgb: np.ndarray) -> np.ndarray:
        """Observed hand silhouette ``S_o`` (H, W) bool of a colour image (eq. 4, thresholded
        against the background mixture, then opened with a 5 px disc)."""
        import cv2

        m = self.explains(rgb).astype(np.uint8)
        # an opening drops the thin mixed-colour lines along other objects' edges and speckle
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        return cv2.morphologyEx(m, cv2.MORPH_OPEN, k) > 0


# ------------------------------------------------------------------- per-view precompute
@dataclass
class ObservedView:
    """Everything of one observed image the terms need, at the evaluation scale.

    Attributes:
        camera: the rig camera.
        silh: (h, w) bool observed hand silhouette ``S_o``.
        d_hand: (h, w) float32 distance to the nearest observed hand edge [px], clipped.
        d_all: (h, w) float32 distance to the nearest observed edge of the image [px].
        hand_edges: (n, 2) int (row, col) of the observed hand edges ``e_o^hand``.
        shifted: (k*k, h, w, 3) float32 the image shifted over the colour window.
        inv_w: (k*k,) 1 / w_ij of each shift (eq. 6).
        scale: evaluation scale; ``fx`` etc. of the camera times it.
        origin: (row, col) of the maps' first pixel in the scaled image (a search box cuts
            the maps to the part of the image the hands and objects can be in).
    """

    camera: RigCamera
    silh: np.ndarray
    d_hand: np.ndarray
    d_all: np.ndarray
    hand_edges: np.ndarray
    shifted: np.ndarray
    inv_w: np.ndarray
    scale: float
    origin: tuple[int, int] = (0, 0)


def _dt(edges: np.ndarray, clip: float) -> np.ndarray:
    """Distance [px] of every pixel to the nearest True of ``edges``, clipped at ``clip``."""
    import cv2

    if not edges.any():
        return np.full(edges.shape, clip, np.float32)
    d = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3)
    return np.minimum(d, clip).astype(np.float32)


def observe(rgb: np.ndarray, camera: RigCamera, colour: ColourModel | None,
            config: ImageTermsConfig | None = None,
            roi: tuple[float, float, float, float] | None = None,
            silhouette: np.ndarray | None = None) -> ObservedView:
    """Precompute one view's observation (see :class:`ObservedView`).

    The observed hand silhouette is ``colour.silhouette(rgb)`` (eq. 4), or ``silhouette``
    (H, W) bool when given (e.g. from background subtraction at the first frame).

    ``roi`` (u0, v0, u1, v1) [px]: the hand's silhouette and edges are looked for only in
    this box (e.g. around the previous frame's hands and objects, :func:`hand_rois`), so
    that skin-coloured clutter elsewhere does not enter eq. (5) and (7); the maps are cut to
    the box plus the reach of the distance clip and the colour window (less work per
    particle; hypotheses must stay inside it).

    Raises:
        InputError: not an (H, W, 3) uint8 image of the camera's resolution.
    """
    import cv2

    cfg = config or ImageTermsConfig()
    img = np.asarray(rgb)
    k = camera.intrinsics
    if img.shape != (k.height, k.width, 3) or img.dtype != np.uint8:
        raise InputError(f"camera {camera.name!r}: expected a ({k.height}, {k.width}, 3) uint8 "
                         f"image, got {img.shape} {img.dtype}")
    h, w = max(1, round(k.height * cfg.scale)), max(1, round(k.width * cfg.scale))
    small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    if silhouette is not None:
        silh_full = np.asarray(silhouette, bool)
        if silh_full.shape != img.shape[:2]:
            raise InputError(f"camera {camera.name!r}: silhouette {silh_full.shape} does not "
                             f"fit the image {img.shape[:2]}")
    elif colour is not None:
        silh_full = colour.silhouette(img)
    else:
        raise InputError("observe needs a colour model or a silhouette")
    silh = cv2.resize(silh_full.astype(np.uint8), (w, h), interpolation=cv2.INTER_AREA) > 0
    if roi is not None:
        keep = np.zeros_like(silh)
        u0, v0, u1, v1 = (int(np.floor(c * cfg.scale)) for c in roi)
        keep[max(v0, 0): max(v1 + 1, 0), max(u0, 0): max(u1 + 1, 0)] = True
        silh &= keep
    grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    edges = cv2.Canny(grey, cfg.canny_low, cfg.canny_high) > 0
    # hand edges: the image edges on or next to the observed hand silhouette
    near = cv2.dilate(silh.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    hand_edges = edges & near
    sil_border = silh & ~(cv2.erode(silh.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    hand_edges |= sil_border
    r = cfg.window // 2
    f = small.astype(np.float32) / 255.0
    pad = np.pad(f, ((r, r), (r, r), (0, 0)), mode="edge")
    shifts, inv_w = [], []
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            shifts.append(pad[r + dy: r + dy + h, r + dx: r + dx + w])
            # eq. (6): w_ij = exp(-|i-j|^2), distance in units of the half window
            inv_w.append(np.exp((dy * dy + dx * dx) / max(r, 1) ** 2))
    d_hand, d_all = _dt(hand_edges, cfg.edge_clip_px), _dt(edges, cfg.edge_clip_px)
    shifted = np.stack(shifts).astype(np.float32)
    r0 = c0 = 0
    if roi is not None:  # every map cut to the box + the reach of the distances and window
        m = int(np.ceil(cfg.edge_clip_px)) + r + 1
        r0, c0 = max(v0 - m, 0), max(u0 - m, 0)
        r1, c1 = min(max(v1 + m + 1, r0 + 1), h), min(max(u1 + m + 1, c0 + 1), w)
        silh, hand_edges = silh[r0:r1, c0:c1], hand_edges[r0:r1, c0:c1]
        d_hand, d_all = d_hand[r0:r1, c0:c1], d_all[r0:r1, c0:c1]
        shifted = shifted[:, r0:r1, c0:c1]
    return ObservedView(camera, silh, d_hand, d_all, np.argwhere(hand_edges), shifted,
                        np.array(inv_w, np.float32), cfg.scale, (r0, c0))


# ----------------------------------------------------------------------- the terms alone
def silhouette_term(rendered: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Eq. (5) for rendered silhouettes (..., h, w) bool against an observed (h, w) one."""
    r = np.asarray(rendered, bool)
    o = np.asarray(observed, bool)
    ax = (-2, -1)
    n_r = np.count_nonzero(r, axis=ax)
    both = np.count_nonzero(r & o, axis=ax)
    n_o = np.count_nonzero(o)
    return (n_r - both) / (n_r + _EPS) + (n_o - both) / (n_o + _EPS)


def _border(mask: np.ndarray) -> np.ndarray:
    """Outline pixels of masks (..., h, w): set, with a 4-neighbour unset (image border
    counts as unset)."""
    m = np.asarray(mask, bool)
    inner = m.copy()
    inner[..., 1:, :] &= m[..., :-1, :]
    inner[..., :-1, :] &= m[..., 1:, :]
    inner[..., :, 1:] &= m[..., :, :-1]
    inner[..., :, :-1] &= m[..., :, 1:]
    inner[..., 0, :] = inner[..., -1, :] = False
    inner[..., :, 0] = inner[..., :, -1] = False
    return m & ~inner


def _depth_edges(depth: np.ndarray, step_m: float) -> np.ndarray:
    """Pixels of depth maps (..., h, w) (inf = empty) whose 4-neighbour is nearer by more
    than ``step_m``: the far side of an occlusion boundary inside the silhouette."""
    d = np.where(np.isfinite(depth), depth, 1e6)  # empty: far (no inf - inf)
    out = np.zeros(d.shape, bool)
    out[..., 1:, :] |= d[..., 1:, :] - d[..., :-1, :] > step_m
    out[..., :-1, :] |= d[..., :-1, :] - d[..., 1:, :] > step_m
    out[..., :, 1:] |= d[..., :, 1:] - d[..., :, :-1] > step_m
    out[..., :, :-1] |= d[..., :, :-1] - d[..., :, 1:] > step_m
    return out & np.isfinite(depth)


def edge_term(hand_edges_r: np.ndarray, view: ObservedView, obj_edges_r: np.ndarray | None,
              clip: float) -> np.ndarray:
    """Eq. (7) for rendered hand edge maps (B, h, w) and object edge maps (B, h, w) or None.

    The second (observed -> rendered) hand term needs each rendered edge map's distance
    transform: one per particle, at the evaluation scale."""
    e = np.asarray(hand_edges_r, bool)
    B = len(e)
    bb, yy, xx = np.nonzero(e)
    n_r = np.bincount(bb, minlength=B)
    t1 = np.bincount(bb, weights=view.d_hand[yy, xx], minlength=B) / (n_r + _EPS)
    t2 = np.zeros(len(e))
    if len(view.hand_edges):
        rows, cols = view.hand_edges[:, 0], view.hand_edges[:, 1]
        for b in range(len(e)):
            t2[b] = float(np.mean(_dt(e[b], clip)[rows, cols]))
    out = t1 + t2
    if obj_edges_r is not None:
        bo, yo, xo = np.nonzero(np.asarray(obj_edges_r, bool))
        n_o = np.bincount(bo, minlength=B)
        out = out + 2.0 * np.bincount(bo, weights=view.d_all[yo, xo], minlength=B) / (
            n_o + _EPS)
    return out


# ------------------------------------------------------------------- particle evaluation
def surface_points(vertices: np.ndarray, spacing_m: float) -> np.ndarray:
    """Indices of a subset of ``vertices`` (V, 3) about ``spacing_m`` apart (one vertex per
    occupied voxel of that size, the first in index order)."""
    v = np.asarray(vertices, float)
    key = np.floor((v - v.min(axis=0)) / spacing_m).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    return np.sort(first)


class ImageCost:
    """Eq. (3) for batches of scene configurations against one group of observed views.

    Args:
        scene: the :class:`~hand_capture.multiview.scene_model.SceneModel`.
        config: terms' settings.
        colours: per part (n_i, 3) colours in [0, 1] of the splatted points (only the hands'
            are used: eq. (6) is a hand term); None = no colour term until
            :meth:`learn_colours` is called.
    """

    def __init__(self, scene: object, config: ImageTermsConfig | None = None) -> None:
        self.scene = scene
        self.config = cfg = config or ImageTermsConfig()
        rest = scene.pose(np.clip(np.zeros(scene.n_params), scene.lo, scene.hi))
        self.point_idx = [surface_points(v, cfg.point_spacing_m) for v in rest.vertices]
        # eq. (6) is evaluated on an evenly spread subset of each hand's points
        self.color_sel = np.concatenate([
            off + np.linspace(0, len(self.point_idx[i]) - 1,
                              min(cfg.color_points, len(self.point_idx[i]))).astype(np.intp)
            for i, off in enumerate(np.cumsum([0] + [len(self.point_idx[i])
                                                    for i in range(scene.n_hands)])[:-1])])
        self.colours: list[np.ndarray | None] = [None] * len(self.point_idx)

    # ------------------------------------------------------------------ geometry batches
    def points(self, params: np.ndarray) -> list[np.ndarray]:
        """Splatted points per part (B, n_i, 3) [m, world] of configurations (B, n_params)."""
        from hand_capture.model.joints import root_rotation_matrix

        sc = self.scene
        P = np.atleast_2d(np.asarray(params, float))
        out = []
        for i, h in enumerate(sc.hands):
            q = P[:, sc.slices[sc.part_names[i]]]
            out.append(h.vertices(q, self.point_idx[i]))
        for j, o in enumerate(sc.objects):
            p6 = P[:, sc.slices[o.name]]        # position, XYZ angles (SceneModel layout)
            R = root_rotation_matrix(p6[:, 3:6])                       # (B, 3, 3)
            local = o.vertices[self.point_idx[sc.n_hands + j]]
            out.append(np.einsum("bij,nj->bni", R, local) + p6[:, None, :3])
        return out

    def _splat(self, view: ObservedView, pts: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Project (B, n, 3) points into a view at its scale: (flat pixel index (B, n) with
        -1 outside, depth (B, n), row, col)."""
        B, n, _ = pts.shape
        cam = view.camera
        h, w = view.silh.shape
        R, t = cam.R_wc, cam.t_wc
        X, Y, Z = (pts[..., i].reshape(-1) - t[i] for i in range(3))
        # world -> camera, pc = (p - t) R, column by column (a (N, 3) @ (3, 3) matmul is
        # several times slower than these three products on this machine)
        x = X * R[0, 0] + Y * R[1, 0] + Z * R[2, 0]
        y = X * R[0, 1] + Y * R[1, 1] + Z * R[2, 1]
        z = X * R[0, 2] + Y * R[1, 2] + Z * R[2, 2]
        ok = z > 0.02
        inv = 1.0 / np.where(ok, z, 1.0)
        k = cam.intrinsics
        s = view.scale
        col = np.floor((k.fx * x * inv + k.cx + 0.5) * s).astype(np.int64) - view.origin[1]
        row = np.floor((k.fy * y * inv + k.cy + 0.5) * s).astype(np.int64) - view.origin[0]
        ok &= (col >= 0) & (col < w) & (row >= 0) & (row < h)
        flat = np.where(ok, row * w + col, -1).reshape(B, n)
        return flat, z.reshape(B, n), row.reshape(B, n), col.reshape(B, n)

    @staticmethod
    def _masks(flat: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        B = len(flat)
        h, w = shape
        m = np.zeros(B * h * w + 1, bool)
        idx = np.where(flat >= 0, flat + (np.arange(B) * h * w)[:, None], B * h * w)
        m[idx.ravel()] = True
        return m[:-1].reshape(B, h, w)

    @staticmethod
    def _zbuffer(flat: np.ndarray, z: np.ndarray, shape: tuple[int, int]
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Nearest splatted depth per pixel (B, h, w) [m] (inf where empty) and each point's
        index into it (B, n) (the dummy last cell for points outside the image)."""
        B = len(flat)
        h, w = shape
        zb = np.full(B * h * w + 1, np.inf)
        idx = np.where(flat >= 0, flat + (np.arange(B) * h * w)[:, None], B * h * w)
        np.minimum.at(zb, idx.ravel(), z.ravel())
        return zb, idx

    def _visible(self, flat: np.ndarray, z: np.ndarray, shape: tuple[int, int],
                 tol_m: float = 0.012) -> np.ndarray:
        """(B, n) points not behind the nearest splatted point of their pixel by > tol."""
        zb, idx = self._zbuffer(flat, z, shape)
        return (flat >= 0) & (z <= zb[idx] + tol_m)

    def learn_colours(self, params: np.ndarray, views: Sequence[ObservedView]) -> None:
        """Colours of the hands' splatted points from the first frame (eq. 6's rendered
        colour): each point's colour is the median over the views that see it; points no
        view sees get the median of the rest."""
        p = np.asarray(params, float)[None]
        pts = self.points(p)
        for i in range(self.scene.n_hands):
            samples: list[list[np.ndarray]] = [[] for _ in range(pts[i].shape[1])]
            for v in views:
                flat, z, row, col = self._splat(v, pts[i])
                vis = self._visible(flat, z, v.silh.shape)[0]
                centre = v.shifted[len(v.inv_w) // 2]
                for j in np.flatnonzero(vis):
                    samples[j].append(centre[row[0, j], col[0, j]])
            c = np.array([np.median(s, axis=0) if s else [np.nan] * 3 for s in samples])
            seen = np.all(np.isfinite(c), axis=1)
            fill = np.median(c[seen], axis=0) if seen.any() else np.full(3, 0.5)
            c[~seen] = fill
            self.colours[i] = c.astype(np.float32)

    # ---------------------------------------------------------------------------- cost
    def __call__(self, params: np.ndarray, views: Sequence[ObservedView],
                 parts: bool = False) -> np.ndarray | dict[str, np.ndarray]:
        """Eq. (3) of configurations (B, n_params) against ``views``: (B,) costs, or with
        ``parts`` a dict of the weighted sums per term ("silh", "color", "edge", "total")."""
        cfg = self.config
        sc = self.scene
        P = np.atleast_2d(np.asarray(params, float))
        B = len(P)
        pts = self.points(P)
        hand_pts = np.concatenate(pts[: sc.n_hands], axis=1)
        cols = None
        if all(c is not None for c in self.colours[: sc.n_hands]):
            cols = np.concatenate(self.colours[: sc.n_hands], axis=0)
        e_s = np.zeros(B)
        e_c = np.zeros(B)
        e_e = np.zeros(B)
        for v in views:
            shape = v.silh.shape
            flat, z, row, col = self._splat(v, hand_pts)
            zb, zidx = self._zbuffer(flat, z, shape)
            depth = zb[:-1].reshape(B, *shape)
            S_r = np.isfinite(depth)
            e_s += silhouette_term(S_r, v.silh)                                  # eq. (5)
            obj_e = None
            if sc.objects:
                oflat = self._splat(v, np.concatenate(pts[sc.n_hands:], axis=1))[0]
                obj_e = _border(self._masks(oflat, shape))
            # rendered hand edges: the outline and the occlusion boundaries inside it (what
            # Canny finds in a rendered image: a finger in front of the palm)
            e_r = _border(S_r) | _depth_edges(depth, cfg.depth_edge_m)
            e_e += edge_term(e_r, v, obj_e, cfg.edge_clip_px)                    # eq. (7)
            if cols is not None and cfg.w_color > 0:                             # eq. (6)
                vis = ((flat >= 0) & (z <= zb[zidx] + 0.012))[:, self.color_sel]
                bb, jj = np.nonzero(vis)
                jj = self.color_sel[jj]
                obs = v.shifted[:, row[bb, jj], col[bb, jj]]                     # (k*k, m, 3)
                err = np.abs(obs - cols[jj][None]).mean(axis=2) * v.inv_w[:, None]
                err = np.minimum(err.min(axis=0), cfg.color_cutoff)
                tot = np.bincount(bb, weights=err, minlength=B)
                cnt = np.bincount(bb, minlength=B)
                e_c += np.where(cnt > 0, tot / np.maximum(cnt, 1), cfg.color_cutoff)
        total = cfg.w_silh * e_s + cfg.w_color * e_c + cfg.w_edge * e_e          # eq. (3)
        if parts:
            return {"silh": cfg.w_silh * e_s, "color": cfg.w_color * e_c,
                    "edge": cfg.w_edge * e_e, "total": total}
        return total


def observe_group(group: Mapping[str, np.ndarray], rig: object, colour: ColourModel,
                  config: ImageTermsConfig | None = None,
                  rois: Mapping[str, tuple[float, float, float, float]] | None = None
                  ) -> list[ObservedView]:
    """:func:`observe` for every camera of ``rig`` present in ``group`` (name -> rgb), with
    each camera's ``rois`` entry if given."""
    return [observe(group[c.name], c, colour, config, (rois or {}).get(c.name))
            for c in rig.cameras if c.name in group]


def hand_rois(scene: object, rig: object, params: np.ndarray, margin_px: float = 40.0
              ) -> dict[str, tuple[float, float, float, float]]:
    """Per camera the box (u0, v0, u1, v1) [px] around the hands and objects posed at
    ``params``, widened by ``margin_px`` and by a quarter of its size (the next frame's
    search area)."""
    state = scene.pose(params)
    pts = np.concatenate(state.vertices)
    out = {}
    for cam in rig.cameras:
        uv, front = cam.project(pts)
        if not front.any():
            continue
        lo, hi = uv[front].min(axis=0), uv[front].max(axis=0)
        pad = margin_px + 0.25 * (hi - lo)
        out[cam.name] = (*(lo - pad), *(hi + pad))
    return out
