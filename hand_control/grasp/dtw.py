"""Dynamic time warping and time-warp functions for the closing-phase model (III.4.1.1).

A time warp ``w`` maps the canonical timeline of a reference segment (frames ``0..T-1``) to
frame times of another segment (``w(0) = 0``, ``w(T-1) = n - 1``, strictly increasing).
Warps are registered by DTW, then kept strictly monotonic so that the log-difference
transform of eq. (III.2) exists: ``z(t) = ln(w(t) - w(t-1))``, ``t = 1..T-1``.
"""

from __future__ import annotations

import numpy as np

from hand_control.errors import InputError

__all__ = ["dtw_path", "log_increments", "register", "warp_from_increments", "warp_from_path",
           "warp_motion"]

#: the smallest slope a registered warp may have [segment frames per reference frame]
MIN_SLOPE = 0.05


def _as_motion(x: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[0] < 2:
        raise InputError(f"{name}: a motion is (T >= 2, D), got shape {np.shape(x)}")
    if not np.isfinite(a).all():
        raise InputError(f"{name}: the motion has NaN or infinite values")
    return a


def dtw_path(ref: np.ndarray, seg: np.ndarray, weights: np.ndarray | None = None,
             band: float = 0.5) -> np.ndarray:
    """The DTW alignment of ``seg`` (n, D) to ``ref`` (T, D).

    Cost: weighted squared distance between frames; steps (1,0), (0,1), (1,1); a
    Sakoe-Chiba band of ``band`` times the longer length around the diagonal (after
    rescaling the two timelines to the same length).

    Returns:
        (K, 2) int pairs ``(i_ref, i_seg)`` from ``(0, 0)`` to ``(T-1, n-1)``, both
        nondecreasing.
    """
    r = _as_motion(ref, "ref")
    s = _as_motion(seg, "seg")
    if r.shape[1] != s.shape[1]:
        raise InputError(f"dtw_path: {r.shape[1]} vs {s.shape[1]} dimensions")
    w = np.ones(r.shape[1]) if weights is None else np.asarray(weights, dtype=np.float64)
    rt, st = r * w, s * w
    cost = ((rt[:, None, :] - st[None, :, :]) ** 2).sum(axis=2)  # (T, n)
    t_n, s_n = cost.shape
    ii = np.arange(t_n)[:, None] / max(t_n - 1, 1)
    jj = np.arange(s_n)[None, :] / max(s_n - 1, 1)
    cost = np.where(np.abs(ii - jj) <= band, cost, np.inf)
    acc = np.full((t_n + 1, s_n + 1), np.inf)
    acc[0, 0] = 0.0
    for i in range(1, t_n + 1):
        row, prev = acc[i], acc[i - 1]
        c = cost[i - 1]
        # diagonal and vertical moves are vectorised; horizontal moves need the running min
        best = np.minimum(prev[1:], prev[:-1]) + c
        for j in range(1, s_n + 1):
            v = best[j - 1]
            h = row[j - 1] + c[j - 1]
            row[j] = v if v < h else h
    if not np.isfinite(acc[t_n, s_n]):
        raise InputError("dtw_path: no alignment inside the band (lengths too different)")
    i, j = t_n, s_n
    path = [(i - 1, j - 1)]
    while i > 1 or j > 1:
        moves = ((acc[i - 1, j - 1], i - 1, j - 1), (acc[i - 1, j], i - 1, j),
                 (acc[i, j - 1], i, j - 1))
        _, i, j = min(moves, key=lambda m: m[0])
        path.append((i - 1, j - 1))
    return np.array(path[::-1], dtype=np.int64)


def warp_from_path(path: np.ndarray, n_ref: int, n_seg: int, smooth: int = 3,
                   min_slope: float = MIN_SLOPE) -> np.ndarray:
    """A strictly increasing warp (n_ref,) from a DTW path: the mean segment frame matched
    to each reference frame, its increments clipped to ``min_slope``, smoothed by a moving
    average of ``smooth`` frames, and rescaled to end at ``n_seg - 1``."""
    p = np.asarray(path)
    w = np.zeros(n_ref)
    np.add.at(w, p[:, 0], p[:, 1])
    cnt = np.bincount(p[:, 0], minlength=n_ref)
    if (cnt == 0).any():
        raise InputError("warp_from_path: the path skips reference frames")
    w /= cnt
    d = np.diff(w)
    if smooth > 1 and d.size >= smooth:
        k = np.ones(smooth) / smooth
        d = np.convolve(np.pad(d, (smooth // 2, smooth - 1 - smooth // 2), mode="edge"), k,
                        mode="valid")
    return warp_from_increments(d, n_seg, min_slope)


def warp_from_increments(d: np.ndarray, n_seg: float, min_slope: float = MIN_SLOPE
                         ) -> np.ndarray:
    """``w(0) = 0``, ``w(t) = sum_{i<=t} d_i`` with every ``d_i >= min_slope`` (relative to
    the mean slope), rescaled so that ``w(T-1) = n_seg - 1``."""
    d = np.asarray(d, dtype=np.float64)
    total = float(n_seg) - 1.0
    if total <= 0:
        raise InputError(f"a warp needs a segment of at least 2 frames, got {n_seg}")
    mean = total / d.size
    d = np.maximum(d, min_slope * mean)
    d *= total / d.sum()
    return np.r_[0.0, np.cumsum(d)]


def log_increments(w: np.ndarray) -> np.ndarray:
    """eq. (III.2)'s transform ``z(t) = ln(w(t) - w(t-1))``, t = 1..T-1.

    Raises:
        InputError: the warp is not strictly increasing.
    """
    d = np.diff(np.asarray(w, dtype=np.float64))
    if not (d > 0).all():
        raise InputError("log_increments: the warp is not strictly increasing")
    return np.log(d)


def warp_motion(seg: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``seg`` (n, D) evaluated at the (fractional) frame times ``w`` (T,): linear
    interpolation per dimension; the warped motion on the reference's timeline (T, D)."""
    s = _as_motion(seg, "seg")
    t = np.clip(np.asarray(w, dtype=np.float64), 0.0, s.shape[0] - 1.0)
    i0 = np.floor(t).astype(np.int64)
    i1 = np.minimum(i0 + 1, s.shape[0] - 1)
    a = (t - i0)[:, None]
    return (1.0 - a) * s[i0] + a * s[i1]


def register(ref: np.ndarray, seg: np.ndarray, weights: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """DTW registration of ``seg`` to ``ref``: ``(warp (T,), warped motion (T, D))``."""
    r = _as_motion(ref, "ref")
    s = _as_motion(seg, "seg")
    w = warp_from_path(dtw_path(r, s, weights), r.shape[0], s.shape[0])
    return w, warp_motion(s, w)
