"""Depth image -> hand point cloud (segmentation by depth band and connected component).

The dissertation's sensor sees the hand as the object nearest the camera (20-50 cm, ch. II.2).
:func:`segment_hand` keeps the pixels in ``[near, far]``, finds the nearest depth ``z0``
(a low percentile, robust to flying pixels), keeps the band ``[z0, z0 + band]``, and of the
connected components of that band keeps the one holding the nearest pixels (ties: the
largest). An optional wrist cut drops points far from the cloud centroid. Everything is
vectorised (OpenCV's connected components), about 1 ms at 320x240.
"""

from __future__ import annotations

import cv2
import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.tracking.config import TrackerConfig

__all__ = ["HandObservation", "segment_hand"]


class HandObservation:
    """The segmented hand of one frame.

    Attributes:
        depth_m: (H, W) float32 depth of the hand pixels [m], 0 elsewhere.
        mask: (H, W) bool hand pixels.
        points: (N, 3) back-projected hand points in the optical frame [m].
        pixels: (N, 2) their pixel coordinates (u, v).
        intrinsics: the image's pinhole.
        box: ``(row0, row1, col0, col1)`` (end exclusive) bounding the hand pixels; None
            when no hand was found (or not given).

    :func:`segment_hand` back-projects the hand pixels only when ``points`` / ``pixels`` are
    read: a frame tracked from the previous pose needs only the subsample of
    :meth:`subsample` (the same values either way).
    """

    def __init__(self, depth_m: np.ndarray, mask: np.ndarray, points: np.ndarray | None,
                 pixels: np.ndarray | None, intrinsics: Intrinsics,
                 box: tuple[int, int, int, int] | None = None) -> None:
        self.depth_m = depth_m
        self.mask = mask
        self._points = points
        self._pixels = pixels
        self.intrinsics = intrinsics
        self.box = box
        self._vuz: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_pixels(cls, depth_m: np.ndarray, mask: np.ndarray, v: np.ndarray, u: np.ndarray,
                    z: np.ndarray, intrinsics: Intrinsics,
                    box: tuple[int, int, int, int] | None = None) -> HandObservation:
        """An observation whose points are the pixels (v, u) at depths z [m], back-projected
        when first read."""
        obs = cls(depth_m, mask, None, None, intrinsics, box)
        obs._vuz = (v, u, z)
        return obs

    def _backproject(self, idx: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        v, u, z = self._vuz
        if idx is not None:
            v, u, z = v[idx], u[idx], z[idx]
        intr = self.intrinsics
        pts = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
        return pts, np.stack([u, v], axis=1).astype(np.float64)

    @property
    def points(self) -> np.ndarray:
        if self._points is None:
            self._points, self._pixels = self._backproject(None)
        return self._points

    @property
    def pixels(self) -> np.ndarray:
        if self._pixels is None:
            self._points, self._pixels = self._backproject(None)
        return self._pixels

    @property
    def n_points(self) -> int:
        return len(self._vuz[0]) if self._points is None else len(self._points)

    @property
    def outside_distance(self) -> np.ndarray:
        """(H, W) float32 distance [px] of every pixel to the nearest hand pixel (0 on the
        hand); computed once."""
        d = getattr(self, "_outside", None)
        if d is None:
            d = cv2.distanceTransform((~self.mask).astype(np.uint8), cv2.DIST_L2, 3)
            self._outside = d
        return d

    def off_hand(self, v: np.ndarray, u: np.ndarray, margin_px: float) -> np.ndarray:
        """Whether pixels (v, u) (inside the image) lie farther than ``margin_px`` from every
        hand pixel: ``outside_distance[v, u] > margin_px``, with the distance transform
        computed only around the hand (a pixel beyond that window is farther anyway)."""
        m = int(np.ceil(margin_px)) + 2
        key = getattr(self, "_off_key", None)
        if key != m:
            rows = np.flatnonzero(self.mask.any(axis=1))
            cols = np.flatnonzero(self.mask.any(axis=0))
            H, W = self.mask.shape
            if len(rows):
                r0, r1 = max(int(rows[0]) - m, 0), min(int(rows[-1]) + m + 1, H)
                c0, c1 = max(int(cols[0]) - m, 0), min(int(cols[-1]) + m + 1, W)
            else:
                r0 = r1 = c0 = c1 = 0
            sub = (~self.mask[r0:r1, c0:c1]).astype(np.uint8)
            dt = cv2.distanceTransform(sub, cv2.DIST_L2, 3) if sub.size else sub
            self._off = (dt, r0, r1, c0, c1)
            self._off_key = m
        dt, r0, r1, c0, c1 = self._off
        inw = (v >= r0) & (v < r1) & (u >= c0) & (u < c1)
        out = np.ones(v.shape, bool)
        out[inw] = dt[v[inw] - r0, u[inw] - c0] > margin_px
        return out

    @property
    def found(self) -> bool:
        return self.n_points > 0

    @property
    def centroid(self) -> np.ndarray:
        return self.points.mean(axis=0) if self.found else np.zeros(3)

    def subsample(self, n: int, rng: np.random.Generator | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """At most ``n`` points (and pixels), spread evenly (deterministic without rng)."""
        m = self.n_points
        if m <= n:
            return self.points, self.pixels
        if rng is None:
            idx = np.linspace(0, m - 1, n).astype(np.int64)
        else:
            idx = rng.choice(m, n, replace=False)
        if self._points is None:  # back-project the subsample only
            return self._backproject(idx)
        return self.points[idx], self.pixels[idx]


def _empty(shape: tuple[int, int], intr: Intrinsics) -> HandObservation:
    return HandObservation(np.zeros(shape, np.float32), np.zeros(shape, bool),
                           np.zeros((0, 3)), np.zeros((0, 2)), intr)


def check_depth(depth: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Validate a depth image: uint16 mm (or float m) of the intrinsics' size -> float32 m."""
    d = np.asarray(depth)
    if d.ndim != 2 or d.size == 0:
        raise InputError(f"depth image must be a non-empty (H, W) array, got {d.shape}")
    if d.shape != (intr.height, intr.width):
        raise InputError(f"depth image {d.shape[1]}x{d.shape[0]} does not match the "
                         f"intrinsics {intr.width}x{intr.height}")
    if d.dtype == np.uint16:
        out = d.astype(np.float32)
        out *= np.float32(0.001)
        return out
    if np.issubdtype(d.dtype, np.floating):
        out = d.astype(np.float32)
        return np.where(np.isfinite(out), out, 0.0).astype(np.float32)
    raise InputError(f"depth image must be uint16 [mm] or float [m], got {d.dtype}")


def segment_hand(depth: np.ndarray, intr: Intrinsics, cfg: TrackerConfig | None = None
                 ) -> HandObservation:
    """Segment the hand (nearest connected component in a depth band) and back-project it.

    Args:
        depth: (H, W) uint16 depth [mm] (0 = none) or float32 [m].
        intr: pinhole of the image.
        cfg: thresholds (near_m, far_m, band_m, min_hand_pixels, wrist_cut_m).

    Returns:
        A :class:`HandObservation`; ``found`` is False when no hand is in view.

    Raises:
        InputError: a malformed image.
    """
    cfg = cfg or TrackerConfig()
    d = check_depth(depth, intr)
    valid = (d > cfg.near_m) & (d < cfg.far_m)
    n_valid = int(np.count_nonzero(valid))
    if n_valid < cfg.min_hand_pixels:
        return _empty(d.shape, intr)
    vals = d[valid]
    z0 = float(np.partition(vals, min(len(vals) - 1, max(3, len(vals) // 200)))[
        min(len(vals) - 1, max(3, len(vals) // 200))])
    band = valid & (d <= z0 + cfg.band_m)
    # components of the band, labelled in its bounding box only (same components, same
    # raster order of the labels as on the whole image)
    rows = np.flatnonzero(band.any(axis=1))
    cols = np.flatnonzero(band.any(axis=0))
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    band_b = band[r0:r1, c0:c1]
    d_b = d[r0:r1, c0:c1]
    n, lab, stats, _ = cv2.connectedComponentsWithStats(band_b.astype(np.uint8),
                                                        connectivity=8)
    if n <= 1:
        return _empty(d.shape, intr)
    # the component holding the nearest pixels (those within 1 cm of z0), ties: largest
    near_lab = lab[band_b & (d_b <= z0 + 0.01)]
    counts = np.bincount(near_lab, minlength=n)
    counts[0] = 0
    score = counts * 1e6 + stats[:, cv2.CC_STAT_AREA]
    score[0] = -1
    best = int(np.argmax(score))
    if int(stats[best, cv2.CC_STAT_AREA]) < cfg.min_hand_pixels:
        return _empty(d.shape, intr)
    mask_b = lab == best
    mask = np.zeros(d.shape, bool)
    mask[r0:r1, c0:c1] = mask_b
    v, u = np.nonzero(mask_b)
    v += r0
    u += c0
    z = d[v, u].astype(np.float64)
    if cfg.wrist_cut_m > 0:
        pts = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
        keep = np.linalg.norm(pts - pts.mean(axis=0), axis=1) <= cfg.wrist_cut_m
        u, v, z = u[keep], v[keep], z[keep]
        mask = np.zeros_like(mask)
        mask[v, u] = True
        if len(z) < cfg.min_hand_pixels:
            return _empty(d.shape, intr)
    depth_hand = np.zeros(d.shape, np.float32)   # the hand's depth, 0 elsewhere
    depth_hand[v, u] = d[v, u]
    box = (int(v.min()), int(v.max()) + 1, int(u.min()), int(u.max()) + 1)
    return HandObservation.from_pixels(depth_hand, mask, v, u, z, intr, box)


def depth_normals(obs: HandObservation) -> np.ndarray:
    """Unit normals (N, 3) of the observed points from depth gradients (towards the camera)."""
    d = obs.depth_m.astype(np.float64)
    intr = obs.intrinsics
    u = obs.pixels[:, 0].astype(int)
    v = obs.pixels[:, 1].astype(int)
    H, W = d.shape
    ur, ul = np.minimum(u + 1, W - 1), np.maximum(u - 1, 0)
    vd, vu = np.minimum(v + 1, H - 1), np.maximum(v - 1, 0)
    z = d[v, u]
    dzdu = np.where((d[v, ur] > 0) & (d[v, ul] > 0), (d[v, ur] - d[v, ul]) / (ur - ul + 1e-9),
                    0.0)
    dzdv = np.where((d[vd, u] > 0) & (d[vu, u] > 0), (d[vd, u] - d[vu, u]) / (vd - vu + 1e-9),
                    0.0)
    # tangent vectors of the surface per pixel step
    tu = np.stack([z / intr.fx, np.zeros_like(z), dzdu], 1)
    tv = np.stack([np.zeros_like(z), z / intr.fy, dzdv], 1)
    n = np.cross(tu, tv)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    flip = np.einsum("ij,ij->i", n, obs.points) > 0
    n[flip] *= -1
    return n
