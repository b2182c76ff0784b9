"""Vertex-to-image correspondences of the multi-view tracker (seed 002 sec. 4, Algorithm 1).

A correspondence is a triplet (k, c, p): vertex ``k`` should project to pixel ``p`` in camera
``c`` (seed 002 eq. (2)). Three kinds come from the images:

* **edges** (:func:`edge_correspondences`): the rendered depth map of the current estimate is
  thresholded on its gradient; each visible vertex on such a model edge is matched to the
  nearest image edge pixel (Canny) whose gradient orientation is within 45 degrees of the
  model edge's. Image edges are split into six orientation bins once per frame and every
  bin (with its two neighbours) gets a distance transform with nearest-pixel labels, so a
  lookup is O(1) per vertex (:class:`ImageFeatures`).
* **optical flow** (:func:`flow_correspondences`): pyramidal Lucas-Kanade (OpenCV) carries the
  visible vertices' projections of the previous frame's estimate into the current image,
  kept when the backward flow returns within a pixel; optionally not where a mask of
  untrusted pixels (the bench's structural-noise circles, seed 002 sec. 5.1) touches the LK
  window at its start or end.
* **salient points** (:func:`match_salient`): visible salient vertices (nail centres) and the
  detector's salient image points are associated by bipartite matching with outlier nodes,
  eq. (3), solved exactly as a linear assignment on the augmented square matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError

__all__ = ["FLOW_IGNORE_MARGIN_PX", "FLOW_WINDOW_PX", "ImageFeatures", "N_ORIENT",
           "edge_correspondences", "flow_correspondences", "image_features", "match_salient",
           "model_edges", "saturation_image", "window_clear"]

#: orientation bins of edge normals over [0, pi)
N_ORIENT = 6
_BIG = 1e9


def to_grey(rgb: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey of an (H, W, 3) uint8 RGB image (or a grey image as is)."""
    import cv2

    a = np.asarray(rgb)
    if a.ndim == 2:
        return a.astype(np.uint8, copy=False)
    if a.ndim != 3 or a.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) colour image, got {a.shape}")
    return cv2.cvtColor(a.astype(np.uint8, copy=False), cv2.COLOR_RGB2GRAY)


def _orient_bin(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Bin in [0, N_ORIENT) of the gradient direction modulo pi."""
    ang = np.mod(np.arctan2(gy, gx), np.pi)
    return np.minimum((ang / np.pi * N_ORIENT).astype(np.int64), N_ORIENT - 1)


@dataclass
class ImageFeatures:
    """One camera image's features for a frame (computed once, looked up every iteration).

    Attributes:
        grey: (H, W) uint8.
        edges: (H, W) bool Canny edges.
        labels: per orientation bin b, (H, W) int32 index into ``coords[b]`` of the nearest
            edge pixel among bins b-1, b, b+1 (-1: none).
        coords: per bin (N_b, 2) float pixel (u, v) of those edge pixels.
        normals: per bin (N_b, 2) unit image gradient direction at those pixels.
    """

    grey: np.ndarray
    edges: np.ndarray
    labels: list[np.ndarray]
    coords: list[np.ndarray]
    normals: list[np.ndarray]

    def nearest_edge(self, uv: np.ndarray, bins: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest edge pixel (N, 2) with a similar orientation to pixels ``uv`` (N, 2) whose
        model edge normal falls in ``bins`` (N,), its distance (N,) [px] (inf: none) and the
        image edge's unit normal there (N, 2)."""
        h, w = self.grey.shape
        col = np.clip(np.round(uv[:, 0]).astype(np.int64), 0, w - 1)
        row = np.clip(np.round(uv[:, 1]).astype(np.int64), 0, h - 1)
        out = np.zeros((len(uv), 2))
        nrm = np.zeros((len(uv), 2))
        dist = np.full(len(uv), np.inf)
        for b in range(N_ORIENT):
            sel = np.flatnonzero(bins == b)
            if not len(sel) or not len(self.coords[b]):
                continue
            lab = self.labels[b][row[sel], col[sel]]
            p = self.coords[b][lab]
            out[sel] = p
            nrm[sel] = self.normals[b][lab]
            dist[sel] = np.linalg.norm(p - uv[sel], axis=1)
        return out, dist, nrm


def saturation_image(rgb: np.ndarray) -> np.ndarray:
    """(H, W) uint8 HSV saturation of an (H, W, 3) uint8 RGB image. Shading scales a
    surface's colour: it changes the grey level, not the saturation."""
    import cv2

    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) colour image, got {a.shape}")
    return cv2.cvtColor(a.astype(np.uint8, copy=False), cv2.COLOR_RGB2HSV)[:, :, 1]


def _blur(img: np.ndarray, blur_px: float) -> np.ndarray:
    """``img`` after a Gaussian of ``blur_px`` [px] (0: as it is)."""
    import cv2

    k = 2 * int(np.ceil(2.0 * blur_px)) + 1     # 5 x 5 at 1 px
    return cv2.GaussianBlur(img, (k, k), blur_px) if blur_px > 0 else img


def _sobel(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sobel gradients (gx, gy) (H, W) float32 of ``img``."""
    import cv2

    return cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)


def image_features(rgb: np.ndarray, canny: tuple[float, float] = (30.0, 90.0),
                   blur_px: float = 1.0, saturation: float = 0.0) -> ImageFeatures:
    """Canny edges and their orientation-binned nearest-pixel maps of one colour image,
    smoothed first by a Gaussian of ``blur_px`` [px] (0: none; Canny's Sobel still
    smooths). A wide blur pulls two close edges of opposite polarity apart (a shaded rim
    along an outline: the outline's gradient peak moves outwards, the rim's inwards).

    ``saturation`` > 0 (a colour image): each pixel's gradient is the grey level's or
    ``saturation`` times the HSV saturation's (:func:`saturation_image`), whichever is the
    larger; Canny runs on that gradient. A surface seen at grazing incidence is shaded
    darker than its inside and, often, than the background: the grey level's strongest
    edge then lies about a pixel inside the outline, while the saturation edge of skin
    against a grey or differently coloured background stays on it. The larger of the two
    (not their sum, whose contrasts can cancel: skin brighter but less saturated than a
    wooden table) keeps every edge either channel sees. The features' ``grey`` (what the
    optical flow tracks) stays the grey level."""
    import cv2

    grey = to_grey(rgb)
    blur = _blur(grey, blur_px)
    gx, gy = _sobel(blur)
    if saturation > 0.0 and np.ndim(rgb) == 3:
        sx, sy = _sobel(_blur(saturation_image(rgb), blur_px))
        take = np.hypot(sx, sy) * saturation > np.hypot(gx, gy)
        gx = np.where(take, saturation * sx, gx).astype(np.float32)
        gy = np.where(take, saturation * sy, gy).astype(np.float32)
        lim = np.iinfo(np.int16).max
        edges = cv2.Canny(np.clip(gx, -lim, lim).astype(np.int16),
                          np.clip(gy, -lim, lim).astype(np.int16), canny[0], canny[1],
                          L2gradient=True) > 0
    else:
        edges = cv2.Canny(blur, canny[0], canny[1], L2gradient=True) > 0
    bins = np.full(grey.shape, -1, dtype=np.int64)
    bins[edges] = _orient_bin(gx[edges], gy[edges])
    labels, coords, normals = [], [], []
    mag = np.maximum(np.hypot(gx, gy), 1e-9)
    sub = _subpixel_offsets(edges, gx, gy, mag)
    for b in range(N_ORIENT):
        near = edges & ((bins == b) | (bins == (b + 1) % N_ORIENT) |
                        (bins == (b - 1) % N_ORIENT))
        rc = np.argwhere(near)  # row-major, the order of cv2's per-pixel labels
        coords.append(rc[:, ::-1].astype(float) + sub[near])
        normals.append(np.stack([gx[near] / mag[near], gy[near] / mag[near]], axis=1)
                       .astype(float))
        if not len(rc):
            labels.append(np.zeros(grey.shape, np.int32))
            continue
        src = np.where(near, 0, 255).astype(np.uint8)
        _, lab = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
        labels.append((lab - 1).astype(np.int32))
    return ImageFeatures(grey, edges, labels, coords, normals)


def _subpixel_offsets(edges: np.ndarray, gx: np.ndarray, gy: np.ndarray, mag: np.ndarray
                      ) -> np.ndarray:
    """(H, W, 2) sub-pixel shift (du, dv) of every edge pixel to the peak of the gradient
    magnitude along the gradient: a parabola through the magnitudes one pixel before, at and
    after it (Canny keeps one of the two pixels straddling a step, a half-pixel bias)."""
    h, w = edges.shape
    out = np.zeros((h, w, 2))
    r, c = np.nonzero(edges)
    if not len(r):
        return out
    nx, ny = gx[r, c] / mag[r, c], gy[r, c] / mag[r, c]
    cp = np.clip(np.round(c + nx).astype(np.int64), 0, w - 1)
    rp = np.clip(np.round(r + ny).astype(np.int64), 0, h - 1)
    cm = np.clip(np.round(c - nx).astype(np.int64), 0, w - 1)
    rm = np.clip(np.round(r - ny).astype(np.int64), 0, h - 1)
    m0, mp, mm = mag[r, c], mag[rp, cp], mag[rm, cm]
    den = mm - 2.0 * m0 + mp
    d = np.where(den < -1e-9, 0.5 * (mm - mp) / np.where(den < -1e-9, den, -1.0), 0.0)
    d = np.clip(d, -0.5, 0.5)
    out[r, c, 0] = d * nx
    out[r, c, 1] = d * ny
    return out


def model_edges(depth: np.ndarray, labels: np.ndarray, jump_m: float = 0.012
                ) -> tuple[np.ndarray, np.ndarray]:
    """Edges of a rendered depth map: pixels next to a depth jump over ``jump_m`` [m] or a
    change of part label (the gradient of the rendered depth thresholded, seed 002 sec. 4),
    and the orientation bin of the depth gradient there (the edge normal).

    Returns:
        (edge (h, w) bool, bins (h, w) int64, -1 off the edges).
    """
    import cv2

    far = float(depth.max()) + 0.3 if depth.size else 1.0
    d = np.where(depth > 0, depth, far).astype(np.float32)
    jump = np.zeros(d.shape, bool)
    for ax in (0, 1):
        dd = np.abs(np.diff(d, axis=ax)) > jump_m
        dl = np.diff(labels.astype(np.int16), axis=ax) != 0
        e = dd | dl
        if ax == 0:
            jump[1:] |= e
            jump[:-1] |= e
        else:
            jump[:, 1:] |= e
            jump[:, :-1] |= e
    jump &= depth > 0  # on the model
    gx = cv2.Sobel(d, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(d, cv2.CV_32F, 0, 1, ksize=3)
    bins = np.full(d.shape, -1, dtype=np.int64)
    strong = jump & (np.hypot(gx, gy) > 1e-6)
    bins[strong] = _orient_bin(gx[strong], gy[strong])
    return strong, bins


def edge_correspondences(uv: np.ndarray, pix_scaled: np.ndarray, edge_bins: np.ndarray,
                         feats: ImageFeatures, max_px: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Edge correspondences of visible vertices (seed 002 sec. 4).

    Args:
        uv: (N, 2) projections of visible vertices [px, full image].
        pix_scaled: (N, 2) int (col, row) of the vertices in the rendered (scaled) image
            (col < 0: not to be used).
        edge_bins: the rendered edges' orientation bins (:func:`model_edges`).
        feats: the image's features.
        max_px: farthest accepted image edge [px].

    Returns:
        (sel, targets, normals): indices into ``uv`` of the vertices on a model edge that
        found an image edge, the image points (n, 2) they should project to and the image
        edge's unit normal there (n, 2) (the residual is measured along it: a vertex may
        slide along the edge).
    """
    h, w = edge_bins.shape
    c = np.clip(pix_scaled[:, 0], 0, w - 1)
    r = np.clip(pix_scaled[:, 1], 0, h - 1)
    b = np.where(pix_scaled[:, 0] >= 0, edge_bins[r, c], -1)
    on = np.flatnonzero(b >= 0)
    if not len(on):
        return on, np.zeros((0, 2)), np.zeros((0, 2))
    tgt, dist, nrm = feats.nearest_edge(uv[on], b[on])
    ok = dist <= max_px
    return on[ok], tgt[ok], nrm[ok]


#: side of the Lucas-Kanade window at every pyramid level [px]
FLOW_WINDOW_PX = 15
#: distance [px] within which a flow-ignore mask pixel drops a flow feature: the LK
#: half-window (the finest level's window, which sets the final estimate, then sees none)
FLOW_IGNORE_MARGIN_PX = FLOW_WINDOW_PX // 2


def window_clear(mask: np.ndarray | None, uv: np.ndarray, half_px: int) -> np.ndarray:
    """(N,) bool: no pixel of ``mask`` ((H, W) bool, None: nothing masked) lies in the
    (2 ``half_px`` + 1)^2 square window around each point ``uv`` (N, 2) [px]; pixels of the
    window outside the image count as clear."""
    uv = np.nan_to_num(np.asarray(uv, dtype=float).reshape(-1, 2), nan=-1e6)
    if mask is None or not len(uv):
        return np.ones(len(uv), bool)
    m = np.asarray(mask, dtype=bool)
    h, w = m.shape
    d = np.arange(-half_px, half_px + 1)
    col = np.round(uv[:, 0]).astype(np.int64)[:, None, None] + d[None, None, :]
    row = np.round(uv[:, 1]).astype(np.int64)[:, None, None] + d[None, :, None]
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    hit = m[np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)] & inside
    return ~hit.reshape(len(uv), -1).any(axis=1)


def flow_correspondences(prev_grey: np.ndarray, grey: np.ndarray, uv_prev: np.ndarray,
                         fb_px: float = 1.0, ignore_prev: np.ndarray | None = None,
                         ignore: np.ndarray | None = None,
                         margin_px: int = FLOW_IGNORE_MARGIN_PX
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal Lucas-Kanade flow of points ``uv_prev`` (N, 2) [px] from the previous image
    to this one, kept where the backward flow returns within ``fb_px`` and the window has
    texture.

    ``ignore_prev`` / ``ignore``: (H, W) bool masks of the previous / this image's pixels
    whose flow is not to be trusted (seed 002 sec. 5.1: the optical flow features of the
    structural-noise circles are not considered). A point is dropped when a masked pixel
    lies within ``margin_px`` of its start in the previous image or of its tracked end in
    this one (default the LK half-window, 7 px: the finest level's window, which sets the
    final estimate, then sees no masked pixel; the coarser levels' larger footprints only
    seed it and are not screened).

    Returns:
        (sel, targets): indices of the kept points and where they moved to (n, 2) [px].
    """
    import cv2

    if not len(uv_prev):
        return np.zeros(0, np.int64), np.zeros((0, 2))
    p0 = uv_prev.astype(np.float32).reshape(-1, 1, 2)
    lk = {"winSize": (FLOW_WINDOW_PX, FLOW_WINDOW_PX), "maxLevel": 3,
          "minEigThreshold": 5e-3,
          "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)}
    p1, st, _ = cv2.calcOpticalFlowPyrLK(prev_grey, grey, p0, None, **lk)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(grey, prev_grey, p1, None, **lk)
    fb = np.linalg.norm((p0b - p0).reshape(-1, 2), axis=1)
    ok = (st.reshape(-1) == 1) & (st2.reshape(-1) == 1) & (fb < fb_px)
    ok &= window_clear(ignore_prev, uv_prev, margin_px)
    ok &= window_clear(ignore, p1.reshape(-1, 2), margin_px)
    sel = np.flatnonzero(ok)
    return sel, p1.reshape(-1, 2)[sel].astype(float)


def match_salient(projected: np.ndarray, detected: np.ndarray, lam: float = 60.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Salient vertex <-> salient image point association, eq. (3) of seed 002.

    The |Xi| x |Delta| distance matrix ``w_st`` is made square with virtual elements, and
    outlier nodes ``alpha_s`` (vertex s unmatched) and ``beta_t`` (detection t unmatched) cost
    ``lam`` [px] each; assigning a virtual node to anything else is forbidden (infinite
    weight). The integer programme is a perfect matching on the (r + d) x (d + r) matrix

        [[ w        , diag(lam) ],
         [ diag(lam), 0         ]]

    (off-diagonal entries of the diagonal blocks infinite), solved exactly by
    ``scipy.optimize.linear_sum_assignment``.

    Args:
        projected: (r, 2) projections of the visible salient vertices [px].
        detected: (d, 2) salient image points [px].
        lam: the outlier penalty lambda [px] (seed 002: 60).

    Returns:
        (s, t): index arrays of the matched pairs (vertex s <-> detection t).
    """
    from scipy.optimize import linear_sum_assignment

    P = np.asarray(projected, dtype=float).reshape(-1, 2)
    D = np.asarray(detected, dtype=float).reshape(-1, 2)
    r, d = len(P), len(D)
    if r == 0 or d == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(D))):
        raise InputError("salient points must be finite")
    C = np.full((r + d, d + r), _BIG)
    C[:r, :d] = np.linalg.norm(P[:, None] - D[None], axis=2)
    C[np.arange(r), d + np.arange(r)] = lam          # alpha_s
    C[r + np.arange(d), np.arange(d)] = lam          # beta_t
    C[r:, d:] = 0.0                                   # virtual <-> virtual
    rows, cols = linear_sum_assignment(C)
    keep = (rows < r) & (cols < d)
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)
