"""Depth image -> hand point cloud (segmentation by depth band and connected component).

The dissertation's sensor sees the hand as the object nearest the camera (20-50 cm, ch. II.2).
:func:`segment_hand` keeps the pixels in ``[near, far]``, finds the nearest depth ``z0``
(a low percentile, robust to flying pixels), keeps the band ``[z0, z0 + band]``, and of the
connected components of that band keeps the one holding the nearest pixels (ties: the
largest). A large plane behind the hand (a table, a wall) is dropped with what lies behind
it (:func:`drop_background_plane`). An optional wrist cut drops points far from the cloud
centroid. Everything is
vectorised (OpenCV's connected components), about 1 ms at 320x240.
"""

from __future__ import annotations

import cv2
import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.tracking.config import TrackerConfig

__all__ = ["HandObservation", "cut_forearm", "drop_background_plane", "near_segments_mask",
           "segment_hand"]


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
        background_plane: whether :func:`segment_hand` dropped a background plane (a
            table, a wall) from this segment (:func:`drop_background_plane`).

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
        self.background_plane = False
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

    def points_at(self, idx: np.ndarray) -> np.ndarray:
        """(k, 3) the points ``idx`` (indices or a bool mask over the points) [m],
        back-projecting only those when the points were not read yet."""
        if self._points is None:
            return self._backproject(np.flatnonzero(idx) if idx.dtype == bool else idx)[0]
        return self._points[idx]

    @property
    def vuz(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The hand pixels' rows, columns (int) and depths [m], each (N,)."""
        if self._vuz is not None:
            return self._vuz
        return (self.pixels[:, 1].astype(np.int64), self.pixels[:, 0].astype(np.int64),
                self.points[:, 2])

    @property
    def median_depth_m(self) -> float:
        """Median depth of the hand pixels [m] (0 without any); computed once."""
        z = getattr(self, "_median_z", None)
        if z is None:
            v = self.depth_m[self.mask]
            z = float(np.median(v)) if v.size else 0.0
            self._median_z = z
        return z

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


def fill_row_gaps(d: np.ndarray, max_px: int, step_m: float, flat_px: int = 0) -> np.ndarray:
    """Fill short horizontal runs of missing depth (0) in ``d`` (H, W) [m], in place.

    A stereo camera's occlusion band lies along its baseline (the rows) beside a nearer
    surface: a run of at most ``max_px`` pixels between two measured pixels whose depths
    differ by more than ``step_m`` takes the farther one's depth (the surface the band
    hid). ``flat_px`` > 0 also fills runs of at most that many pixels between two pixels
    within ``step_m`` of each other, linearly (a matching hole). Runs that reach the
    image's edge are left alone."""
    H, W = d.shape
    if H == 0 or W < 3 or max(max_px, flat_px) <= 0:
        return d
    cols = np.arange(W)
    meas = d > 0
    # column of the nearest measured pixel to the left / right of every pixel (-1 / W: none)
    left = np.maximum.accumulate(np.where(meas, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(meas, cols, W)[:, ::-1], axis=1)[:, ::-1]
    gap = ~meas & (left >= 0) & (right < W)
    r, c = np.nonzero(gap)
    if not len(r):
        return d
    lc, rc = left[r, c], right[r, c]
    n = rc - lc - 1                        # the run's length [px]
    lv, rv = d[r, lc], d[r, rc]
    step = np.abs(lv - rv) > step_m
    fill = np.where(step, n <= max_px, n <= flat_px)
    if not fill.any():
        return d
    r, c, lc, n, lv, rv, step = (x[fill] for x in (r, c, lc, n, lv, rv, step))
    t = (c - lc) / (n + 1.0)
    d[r, c] = np.where(step, np.maximum(lv, rv), (1.0 - t) * lv + t * rv)
    return d


def fill_gaps(d: np.ndarray, cfg: TrackerConfig) -> np.ndarray:
    """Fill a stereo camera's short gaps in ``d`` (H, W) [m] with ``cfg``'s settings, in
    place: :func:`fill_row_gaps` along the rows (bands and holes), then the holes along the
    columns."""
    fill_row_gaps(d, cfg.fill_band_px, cfg.fill_step_m, cfg.fill_hole_px)
    fill_row_gaps(d.T, 0, cfg.fill_step_m, cfg.fill_hole_px)   # returns at once when 0
    return d


def segment_hand(depth: np.ndarray, intr: Intrinsics, cfg: TrackerConfig | None = None,
                 roi: tuple[np.ndarray, float] | None = None) -> HandObservation:
    """Segment the hand (nearest connected component in a depth band) and back-project it.

    Args:
        depth: (H, W) uint16 depth [mm] (0 = none) or float32 [m].
        intr: pinhole of the image.
        cfg: thresholds (near_m, far_m, band_m, min_hand_pixels, wrist_cut_m).
            The forearm is removed separately (:func:`cut_forearm`).
        roi: ``(segments (B, 2, 3) [m], radius [m])``, a tracked hand's bones: the depth
            band starts at the nearest pixel near them (:func:`near_segments_mask`) and
            the component holding most such pixels is the hand, so that something nearer
            the camera elsewhere in view is not taken for it (the component is kept whole,
            forearm included); None: the nearest pixel and component in the whole image.

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
    near, n_near = None, 0
    if roi is not None:
        near = valid & near_segments_mask(d, intr, *roi)
        n_near = int(np.count_nonzero(near))
        if n_near < cfg.min_hand_pixels:
            return _empty(d.shape, intr)
    z0 = _low_depth(d[valid])
    # the tracked hand's near end: a tenth of the pixels near it may be something else
    # (deeper only widens the band)
    z0_hand = float(np.percentile(d[near], 10)) if near is not None else z0
    for again in (False, True):
        band = valid & (d <= z0 + cfg.band_m)
        fill = max(cfg.fill_band_px, cfg.fill_hole_px)
        if fill > 0:   # a stereo camera's short gaps, around the band only (fill_gaps)
            rows = np.flatnonzero(band.any(axis=1))
            cols = np.flatnonzero(band.any(axis=0))
            r0, r1 = max(int(rows[0]) - fill, 0), int(rows[-1]) + fill + 1
            c0, c1 = max(int(cols[0]) - fill, 0), int(cols[-1]) + fill + 1
            fill_gaps(d[r0:r1, c0:c1], cfg)
            valid = (d > cfg.near_m) & (d < cfg.far_m)
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
        votes = band_b & (d_b <= z0 + 0.01)   # the nearest pixels
        if near is None:
            break
        # a tracked hand: the component holding most pixels near it, so that something
        # nearer the camera elsewhere is not taken for it; when the nearer thing leaves
        # half the hand behind the band or is not in the hand's component (its forearm
        # is), the band starts at the hand's own nearest pixel
        hand = band_b & near[r0:r1, c0:c1]
        if not again and z0_hand > z0 + 0.01 and (
                np.count_nonzero(hand) < 0.5 * n_near
                or not np.any(lab[votes] == _nearest_label(lab, stats, hand))):
            z0 = z0_hand
            continue
        votes = hand if hand.any() else votes
        break
    best = _nearest_label(lab, stats, votes)
    if int(stats[best, cv2.CC_STAT_AREA]) < cfg.min_hand_pixels:
        return _empty(d.shape, intr)
    mask_b = lab == best
    if near is not None:   # what touches the tracked hand in the image only
        mask_b = _drop_far_pieces(mask_b, d_b, near[r0:r1, c0:c1], cfg)
        if int(np.count_nonzero(mask_b)) < cfg.min_hand_pixels:
            return _empty(d.shape, intr)
    mask = np.zeros(d.shape, bool)
    mask[r0:r1, c0:c1] = mask_b
    if cfg.grow_m > 0 and _touches_border(mask_b, r0, c0, d.shape):
        mask = _grow_continuous(d, valid, mask, z0 + cfg.band_m + cfg.grow_m, cfg)
        mask_b, r0, c0 = _crop(mask)
    v, u = np.nonzero(mask_b)
    v += r0
    u += c0
    z = d[v, u].astype(np.float64)
    keep = drop_background_plane(d, v, u, z, intr, cfg) if cfg.plane_removal else None
    if keep is not None:
        v, u, z = v[keep], u[keep], z[keep]
        mask = np.zeros_like(mask)
        mask[v, u] = True
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
    obs = HandObservation.from_pixels(depth_hand, mask, v, u, z, intr, _pixel_box(v, u))
    obs.background_plane = keep is not None
    return obs


def near_segments_mask(d: np.ndarray, intr: Intrinsics, segments: np.ndarray, radius: float,
                       step: int = 4) -> np.ndarray:
    """Pixels of depth image ``d`` (H, W) [m] near the 3D line segments ``segments``
    (B, 2, 3) [m, optical frame] (a hand's bones): within ``radius`` [m] of a segment's
    projection in the image and of its depth (each third of a segment drawn at its mean
    depth, give or take the radius and 15 mm); where segments overlap in the image the
    nearer one's depth counts. Drawn on a grid of ``step`` pixels (the region is coarse:
    a radius of centimetres). (H, W) bool."""
    h, w = d.shape
    out = np.zeros((h, w), bool)
    seg = np.asarray(segments, float)
    r = float(radius)
    if not (np.all(np.isfinite(seg)) and np.isfinite(r) and r > 0):
        return out
    # each segment in three pieces (a depth that follows a bone pointing at the camera)
    t = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])[None, :, None]
    pts = seg[:, :1] + t * (seg[:, 1:] - seg[:, :1])                    # (B, 4, 3)
    seg = np.stack([pts[:, :-1], pts[:, 1:]], axis=2).reshape(-1, 2, 3)
    seg = seg[seg[:, :, 2].min(axis=1) > 1e-3]
    if not len(seg):
        return out
    hs, ws = -(-h // step), -(-w // step)
    zimg = np.zeros((hs, ws), np.float32)
    f = max(intr.fx, intr.fy) / step
    seg = seg[np.argsort(-seg[:, :, 2].mean(axis=1))]      # far first: the nearer overwrite
    uv = np.clip(np.rint(np.stack([intr.cx + intr.fx * seg[..., 0] / seg[..., 2],
                                   intr.cy + intr.fy * seg[..., 1] / seg[..., 2]], axis=-1)
                         / step), -1e5, 1e5).astype(np.int64).tolist()      # (S, 2, 2)
    thick = np.clip(np.rint(2.0 * r * f / seg[:, :, 2].min(axis=1)), 1, 32000)
    for (pa, pb), k, z in zip(uv, thick.astype(np.int64).tolist(),
                              seg[:, :, 2].mean(axis=1).tolist(), strict=True):
        cv2.line(zimg, pa, pb, z, k)
    rows, cols = np.flatnonzero(zimg.any(axis=1)), np.flatnonzero(zimg.any(axis=0))
    if not len(rows):
        return out
    r0, r1 = int(rows[0]) * step, min((int(rows[-1]) + 1) * step, h)
    c0, c1 = int(cols[0]) * step, min((int(cols[-1]) + 1) * step, w)
    z = np.repeat(np.repeat(zimg[r0 // step:-(-r1 // step), c0 // step:-(-c1 // step)], step,
                            axis=0), step, axis=1)[:r1 - r0, :c1 - c0]
    out[r0:r1, c0:c1] = (z > 0) & (np.abs(d[r0:r1, c0:c1] - z) <= np.float32(r + 0.015))
    return out


def _drop_far_pieces(mask: np.ndarray, d: np.ndarray, near: np.ndarray, cfg: TrackerConfig
                     ) -> np.ndarray:
    """The segment ``mask`` (H, W) bool of depth ``d`` [m] without the large pieces in front
    of a tracked hand: split along depth steps of ``cfg.jump_m`` (as
    :func:`split_surfaces`), a piece of at least ``cfg.split_share`` of the segment with
    under a fifth of its pixels ``near`` the hand (:func:`near_segments_mask`) whose median
    depth is nearer than that of the piece most near the hand is dropped with the step
    pixels beside it (an object in front of the hand that touches it in the image, not
    along its surface)."""
    pieces = _large_pieces(mask, d, cfg.jump_m, cfg.split_share)
    if pieces is None:
        return mask
    lab, size, large = pieces
    share = np.bincount(lab[near & mask], minlength=len(size)) / np.maximum(size, 1)
    share[~large] = -1.0
    hand = int(np.argmax(share))
    depth = np.full(len(size), np.inf)
    for k in np.flatnonzero(large):
        depth[k] = float(np.median(d[lab == k]))
    drop = large & (share < 0.2) & (depth < depth[hand])
    drop[hand] = False
    if not drop.any():
        return mask
    return mask & ~_with_steps(lab, drop)


def _large_pieces(mask: np.ndarray, d: np.ndarray, jump_m: float, share: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The segment ``mask`` (H, W) bool of depth ``d`` [m] split where 4-neighbours step
    more than ``jump_m`` in depth: ``(labels (H, W) (0: a step pixel or off the segment),
    pixels per label, whether each label is a large piece (at least ``share`` of the
    segment))``; None unless there are two large pieces or more."""
    edge = _depth_steps(d, jump_m, mask)
    n, lab = cv2.connectedComponents((mask & ~edge).astype(np.uint8), connectivity=4)
    if n <= 2:
        return None
    size = np.bincount(lab.ravel(), minlength=n)
    size[0] = 0
    large = size >= share * int(np.count_nonzero(mask))
    large[0] = False
    return (lab, size, large) if large.sum() >= 2 else None


def _with_steps(lab: np.ndarray, drop: np.ndarray) -> np.ndarray:
    """The pixels of the pieces ``drop`` (bool per label of ``lab``) with the step pixels
    beside them: (H, W) bool."""
    return cv2.dilate(np.isin(lab, np.flatnonzero(drop)).astype(np.uint8),
                      np.ones((3, 3), np.uint8)) > 0


def _low_depth(z: np.ndarray) -> float:
    """The nearest of depths ``z`` (N,) [m] but for stray pixels: the (N/200)-th smallest,
    at least the fourth (flying pixels in front of the hand)."""
    k = min(len(z) - 1, max(3, len(z) // 200))
    return float(np.partition(z, k)[k])


def _nearest_label(lab: np.ndarray, stats: np.ndarray, near: np.ndarray) -> int:
    """Of the connected components ``lab`` (0 = none; ``stats`` from OpenCV), the one holding
    most of the pixels ``near`` (bool, the image's shape); ties: the largest."""
    counts = np.bincount(lab[near], minlength=len(stats))
    counts[0] = 0
    score = counts * 1e6 + stats[:, cv2.CC_STAT_AREA]
    score[0] = -1
    return int(np.argmax(score))


def _crop(mask: np.ndarray) -> tuple[np.ndarray, int, int]:
    """A non-empty mask's bounding-box crop and the crop's first row and column."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, c0 = int(rows[0]), int(cols[0])
    return mask[r0:int(rows[-1]) + 1, c0:int(cols[-1]) + 1], r0, c0


def _area_m2(z: np.ndarray, intr: Intrinsics) -> float:
    """The area [m^2] that pixels at depths ``z`` [m] cover, as seen from the camera."""
    return float(np.sum(z * z)) / (intr.fx * intr.fy)


def fit_plane_ransac(pts: np.ndarray, tol_m: float, rng: np.random.Generator,
                     n_hypotheses: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """The plane through most of ``pts`` (RANSAC, Fischler and Bolles 1981): planes through
    ``n_hypotheses`` random triplets, the one with most points within ``tol_m`` refitted to
    those by least squares.

    Args:
        pts: (N, 3) points [m], N >= 3.
        tol_m: inlier distance [m].
        rng: the triplets' draw.

    Returns:
        ``(centre, normal)``: a point on the plane (3,) [m] and its unit normal (3,).
    """
    tri = pts[rng.integers(0, len(pts), (n_hypotheses, 3))]           # (k, 3, 3)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 1e-12
    if not ok.any():
        return pts.mean(axis=0), np.array([0.0, 0.0, 1.0])
    nrm = nrm[ok] / length[ok, None]
    off = -np.einsum("ij,ij->i", nrm, tri[ok, 0])
    inl = np.abs(pts @ nrm.T + off) < tol_m                           # (N, k)
    q = pts[inl[:, int(np.argmax(inl.sum(axis=0)))]]
    c = q.mean(axis=0)
    return c, np.linalg.svd(q - c, full_matrices=False)[2][2]


def _nearest_component(mask: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """Of the pixels ``mask`` (depth ``d`` [m]), the 8-connected component holding the
    nearest pixels (within 1 cm of :func:`_low_depth`), as :func:`segment_hand` picks the
    band's."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return None
    return lab == _nearest_label(lab, stats, mask & (d <= _low_depth(d[mask]) + 0.01))


def drop_background_plane(d: np.ndarray, v: np.ndarray, u: np.ndarray, z: np.ndarray,
                          intr: Intrinsics, cfg: TrackerConfig) -> np.ndarray | None:
    """Which pixels of a segment stay when a large plane and what lies behind it go: the
    hand's surface only.

    An addition to ch. II.2's depth band: a table, a wall or the body less than ``band_m``
    behind the hand joins the band's segment, and through a forearm resting on it the
    surface grown out of the image (:func:`_grow_continuous`) holds all of it. A segment
    covering more than ``plane_min_area_m2`` is searched for a plane
    (:func:`fit_plane_ransac`, 600 of its pixels); a plane of that area whose pixels span
    ``plane_min_width_m`` across its second axis (not a forearm's side, not a flat hand) is
    background. Its pixels within ``plane_tol_m`` and all behind it are dropped, and of
    the rest the component nearest the camera is kept (:func:`_nearest_component`).

    Args:
        d: (H, W) depth [m].
        v, u, z: (N,) the segment's pixel rows, columns and depths [m].
        intr: pinhole of the image.
        cfg: ``plane_*``, ``min_hand_pixels``.

    Returns:
        (N,) bool, the pixels kept; None when no background plane was found (or fewer
        than ``min_hand_pixels`` would be left).
    """
    if _area_m2(z, intr) < cfg.plane_min_area_m2:
        return None
    pts = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
    rng = np.random.default_rng(len(z))   # deterministic per frame
    sample = pts[rng.choice(len(pts), min(len(pts), 600), replace=False)]
    c, normal = fit_plane_ransac(sample, cfg.plane_tol_m, rng)
    r = (pts - c) @ normal
    on = np.abs(r) < cfg.plane_tol_m
    if _area_m2(z[on], intr) < cfg.plane_min_area_m2:
        return None
    q = pts[on] - pts[on].mean(axis=0)
    across = q @ np.linalg.svd(q[:: max(len(q) // 2000, 1)], full_matrices=False)[2][1]
    if np.percentile(across, 98) - np.percentile(across, 2) < cfg.plane_min_width_m:
        return None
    front = np.sign(-(c @ normal)) * r > cfg.plane_tol_m   # on the camera's side
    if np.count_nonzero(front) < cfg.min_hand_pixels:
        return None
    rest = np.zeros(d.shape, bool)
    rest[v[front], u[front]] = True
    out = _nearest_component(rest, d)
    if out is None:
        return None
    keep = out[v, u]
    return keep if np.count_nonzero(keep) >= cfg.min_hand_pixels else None


#: a pixel this close to the image border [px] may continue beyond the image
BORDER_PX = 2


def on_border(u: np.ndarray, v: np.ndarray, width: int, height: int) -> np.ndarray:
    """Per pixel (columns ``u``, rows ``v``, any shape) whether it lies within
    :data:`BORDER_PX` of the border of a ``width`` x ``height`` image."""
    return ((u < BORDER_PX) | (u >= width - BORDER_PX) | (v < BORDER_PX)
            | (v >= height - BORDER_PX))


def _touches_border(mask_b: np.ndarray, r0: int, c0: int, shape: tuple[int, int]) -> bool:
    """Whether a mask (its bounding-box crop at row ``r0``, column ``c0``) has a pixel
    :func:`on_border`."""
    vv, uu = np.nonzero(mask_b)
    return bool(on_border(uu + c0, vv + r0, shape[1], shape[0]).any())


def _depth_steps(d: np.ndarray, jump_m: float, within: np.ndarray | None = None
                 ) -> np.ndarray:
    """(H, W) bool: the pixels of depth ``d`` [m] with a 4-neighbour more than ``jump_m``
    nearer or farther (both in ``within`` when given: steps to pixels outside it do not
    count)."""
    dv = np.abs(np.diff(d, axis=0)) > jump_m
    dh = np.abs(np.diff(d, axis=1)) > jump_m
    if within is not None:
        dv &= within[:-1] & within[1:]
        dh &= within[:, :-1] & within[:, 1:]
    edge = np.zeros(d.shape, bool)
    edge[:-1] |= dv
    edge[1:] |= dv
    edge[:, :-1] |= dh
    edge[:, 1:] |= dh
    return edge


def _grow_continuous(d: np.ndarray, valid: np.ndarray, mask: np.ndarray, z_max: float,
                     cfg: TrackerConfig) -> np.ndarray:
    """The segment grown over depth-continuous pixels up to ``z_max`` [m].

    An addition to the depth band (ch. II.2 assumes the hand is the nearest object): a
    forearm reaching towards the camera from outside the image is nearer than the hand, so
    the band behind its nearest pixel can hold the arm alone. When the band's component runs
    out of the image, it is extended along the surface: pixels up to ``z_max`` connected to
    it without a depth step larger than ``jump_m`` between 4-neighbours. The forearm is then
    removed by :func:`cut_forearm`."""
    ok = valid & (d <= z_max)
    # a pixel with a larger step to a neighbour is a surface edge: not a bridge
    edge = _depth_steps(d, cfg.jump_m)
    inner = ok & ~edge
    n, lab = cv2.connectedComponents(inner.astype(np.uint8), connectivity=4)
    if n <= 1:
        return mask
    hit = np.unique(lab[mask & inner])
    hit = hit[hit > 0]
    grown = np.isin(lab, hit) | mask
    # the surface-edge pixels next to the grown region belong to it (its outline)
    rim = ok & edge & (cv2.dilate(grown.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    return grown | rim


def split_surfaces(obs: HandObservation, jump_m: float, drop_share: float,
                   min_pixels: int) -> HandObservation | None:
    """The segment without the large pieces of other surfaces that touch the hand.

    An addition to ch. II's depth band: an object just behind the hand (a box, the table
    edge) is connected to it in the band but not along the surface. The segment is split
    where neighbouring pixels (4-neighbours) step more than ``jump_m`` in depth. Of the
    pieces at least ``drop_share`` of the segment, the one reaching nearest the camera is
    kept (ch. II.2 takes the hand for the nearest object) and the others are dropped with
    the step pixels beside them; smaller pieces are kept (a finger in front of the palm
    splits off as a small piece).

    Args:
        obs: a segmented hand (:func:`segment_hand`).
        jump_m: depth step that separates surfaces [m].
        drop_share: a piece this large a share of the segment, or larger, is dropped.
        min_pixels: fewer pixels left than this: None.

    Returns:
        The observation without the dropped pieces, or None when nothing is dropped (or
        too little would be left).
    """
    if not obs.found:
        return None
    v, u, z = obs.vuz
    r0, r1, c0, c1 = obs.box
    pieces = _large_pieces(obs.mask[r0:r1, c0:c1], obs.depth_m[r0:r1, c0:c1], jump_m,
                           drop_share)
    if pieces is None:
        return None
    lab, _, large = pieces
    n = len(large)
    lv, lu = v - r0, u - c0
    lp = lab[lv, lu]     # 0: a step pixel, in no piece
    # the anchor: the large piece reaching nearest the camera (a small piece in front, such
    # as a finger, is kept whatever its depth)
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, lp, z)
    nearest[~large] = np.inf
    drop = large.copy()
    drop[int(np.argmin(nearest))] = False
    return _keep(obs, ~_with_steps(lab, drop)[lv, lu], min_pixels)


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


def _pixel_box(v: np.ndarray, u: np.ndarray) -> tuple[int, int, int, int]:
    """``(row0, row1, col0, col1)`` (end exclusive) bounding the pixels (v, u) (N,), N > 0
    (:attr:`HandObservation.box`)."""
    return int(v.min()), int(v.max()) + 1, int(u.min()), int(u.max()) + 1


def union_observation(a: HandObservation, b: HandObservation) -> HandObservation:
    """The pixels of two segments of one frame (both found) as one observation, the depth
    of ``a`` where both have a pixel (they read the same image)."""
    mask = a.mask | b.mask
    depth = np.where(a.mask, a.depth_m, np.where(b.mask, b.depth_m, 0.0))
    v, u = np.nonzero(mask)
    return HandObservation.from_pixels(depth, mask, v, u, depth[v, u].astype(np.float64),
                                       a.intrinsics, _pixel_box(v, u))


def _keep(obs: HandObservation, keep: np.ndarray, min_pixels: int) -> HandObservation | None:
    """The observation restricted to the points ``keep`` (bool over its points); None when
    fewer than ``min_pixels`` remain."""
    v, u, z = obs.vuz
    v, u, z = v[keep], u[keep], z[keep]
    if len(z) < min_pixels:
        return None
    mask = np.zeros_like(obs.mask)
    mask[v, u] = True
    depth = np.zeros_like(obs.depth_m)
    depth[v, u] = obs.depth_m[v, u]
    return HandObservation.from_pixels(depth, mask, v, u, z, obs.intrinsics, _pixel_box(v, u))


def cut_forearm(obs: HandObservation, cfg: TrackerConfig, hand_scale: float = 1.0,
                wrist: tuple[np.ndarray, np.ndarray] | None = None, flip: bool = False
                ) -> tuple[HandObservation, bool]:
    """Remove the forearm from a segmented hand (an addition to ch. II: the dissertation's
    segmentation assumes a wrist band or a hand alone; every real hand has a forearm, and
    its points drag the ICP data term (eq. II.23) and the PCA initialisation (II.4.2)).

    Two estimates of the wrist plane, no training needed:

    * ``wrist`` given (the previous frame tracked, eq. II.19): ``(w, d)``, the previous
      pose's wrist keypoint [m] and the unit direction from the middle MCP to the wrist;
      points farther than ``forearm_margin_m`` beyond the plane through ``w`` normal to
      ``d`` are dropped.
    * otherwise, from the cloud: the arm axis is the principal axis of the cloud. Its arm
      end is the end that runs out of the image while the other does not (and the cloud
      is longer than ``forearm_border_m``), or, for a cloud longer than a hand can be
      (``forearm_reach_m``), the end farther from the widest place (largest inscribed
      circle in metres: the palm). Nothing is cut otherwise. The palm centre is then the
      widest place near the hand's end, and points farther than ``forearm_wrist_m`` from
      it along the axis towards the arm are dropped. Lengths scale with ``hand_scale``.

    Args:
        obs: segmented hand (:func:`segment_hand`).
        cfg: thresholds (``forearm_*``, ``min_hand_pixels``).
        hand_scale: the tracked model's size relative to the template (global scale).
        wrist: the previous pose's wrist and forearm direction, or None.
        flip: without ``wrist``, take the other end of the cloud for the arm (a second
            guess where the first one failed, e.g. clutter taken for the palm).

    Returns:
        ``(observation, cut)``: the hand without the forearm (the input when nothing was
        cut or the cut would leave fewer than ``min_hand_pixels``), and whether a cut
        was made.
    """
    if not obs.found or obs.n_points < 3 * cfg.min_hand_pixels // 2:
        return obs, False
    pts = obs.points
    if wrist is not None:
        w, d = wrist
        keep = (pts - w) @ d <= cfg.forearm_margin_m * hand_scale
    else:
        keep = _geometric_cut(obs, cfg, hand_scale, flip)
        if keep is None:
            return obs, False
    if keep.all():
        return obs, False
    out = _keep(obs, keep, cfg.min_hand_pixels)
    return (obs, False) if out is None else (out, True)


def principal_extent(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The principal axis (3,) of points (N, 3) [m], their coordinates along it (N,), and
    its 0.5 and 99.5 percentiles [m] (the cloud's extent without stray points)."""
    X = pts - pts.mean(axis=0)
    _, vec = np.linalg.eigh(X.T @ X)
    axis = vec[:, 2]
    s = pts @ axis
    return axis, s, float(np.percentile(s, 0.5)), float(np.percentile(s, 99.5))


def touches_border(obs: HandObservation) -> bool:
    """Whether the hand has a pixel :func:`on_border` (its bounding box's corners tell)."""
    if obs.box is None:
        return False
    r0, r1, c0, c1 = obs.box
    intr = obs.intrinsics
    return bool(on_border(np.array([c0, c1 - 1]), np.array([r0, r1 - 1]), intr.width,
                          intr.height).any())


def _geometric_cut(obs: HandObservation, cfg: TrackerConfig, hand_scale: float,
                   flip: bool = False) -> np.ndarray | None:
    """Points to keep by the cloud-only rule of :func:`cut_forearm` (None: no forearm)."""
    intr = obs.intrinsics
    pts = obs.points
    axis, s, lo, hi = principal_extent(pts)
    extent = hi - lo
    if extent < cfg.forearm_border_m * hand_scale:
        return None
    px = obs.pixels
    edge = on_border(px[:, 0], px[:, 1], intr.width, intr.height)
    at_hi = bool(np.any(edge & (s > hi - 0.25 * extent)))
    at_lo = bool(np.any(edge & (s < lo + 0.25 * extent)))
    radius = _inscribed_radius(obs)
    if at_hi != at_lo:            # the arm runs out of the image, the hand does not
        arm_hi = at_hi
    elif extent > cfg.forearm_reach_m * hand_scale:   # longer than a hand can be
        c = float(s[int(np.argmax(radius))])         # the widest place: the palm
        arm_hi = hi - c > c - lo
    else:
        return None
    if arm_hi == flip:
        axis, s, lo, hi = -axis, -s, -hi, -lo
    # the palm: the widest place within a hand's length of the hand's end
    near = s <= lo + cfg.forearm_reach_m * 0.7 * hand_scale
    c = float(s[near][int(np.argmax(radius[near]))])
    return s <= c + cfg.forearm_wrist_m * hand_scale


def _inscribed_radius(obs: HandObservation) -> np.ndarray:
    """(N,) radius [m] of the largest circle inside the hand mask around each point
    (distance transform [px] x depth / focal length). Holes enclosed by the mask (a stereo
    camera's missing pixels on the palm) count as hand: else they shrink the palm's circle
    below a forearm's, and the cut takes the palm for the arm."""
    r0, r1, c0, c1 = obs.box
    sub = np.zeros((r1 - r0 + 2, c1 - c0 + 2), np.uint8)   # 1-px frame: border = off hand
    sub[1:-1, 1:-1] = obs.mask[r0:r1, c0:c1]
    outside = sub.copy()
    cv2.floodFill(outside, None, (0, 0), 2)   # the background reachable from the frame
    sub[outside == 0] = 1
    dt = cv2.distanceTransform(sub, cv2.DIST_L2, 3)[1:-1, 1:-1]
    px = obs.pixels.astype(np.int64)
    return dt[px[:, 1] - r0, px[:, 0] - c0] * obs.points[:, 2] / obs.intrinsics.fx
