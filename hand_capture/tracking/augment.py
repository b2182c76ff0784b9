"""Depth artifacts of stereo cameras: tracker training renders, a validation family (issue 13).

The suite's sensor model (:mod:`hand_capture.cameras.noise`) is that of an active sensor:
axial noise, flying pixels, grazing dropouts. Stereo depth cameras (the RealSense D400
family) add artifacts of their own, described for those cameras by Keselman et al., "Intel
RealSense Stereoscopic Depth Cameras" (CVPR workshops 2017): the matching window fattens
near objects at depth edges, the second view leaves an occlusion band beside them, low
texture leaves holes, and the disparity error is correlated over the matching window.
The regressor's features (eq. II.15) read depth at pixel pairs, so a forest trained on the
active sensor's images only has not seen these. :func:`add_artifacts` draws them per
image, each at a random strength within :class:`ArtifactConfig` (none, some or all), on an
image that has already been through the sensor model:

* **edge fattening**: the nearer side of every depth step over ``jump_m`` grows by ``k``
  pixels (``k`` uniform in ``fatten_px``) over the farther side or the empty background;
* **occlusion band**: beside a nearer surface, on one side (drawn per image, the side of
  the second view), the farther surface is missing for up to ``shadow_px`` pixels;
* **holes**: round blobs of missing depth (radius in ``hole_radius_px``) over a share of
  the measured pixels drawn in ``hole_share``;
* **correlated error**: a smooth random field (Gaussian-filtered white noise of scale
  ``wave_px``) added to the depth, its standard deviation drawn in ``wave_sd_mm`` at 0.4 m
  and growing with the squared distance (as a disparity error does).

This is the suite's own model, written from the camera physics above; the held-out
family's stereo model (:mod:`hand_capture.evaldata.stereo`) is not used here (a test checks
that training never imports :mod:`hand_capture.evaldata`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from hand_capture.cameras.base import DEPTH_UNIT_M, depth_m_to_mm
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, InputError

__all__ = ["ArtifactConfig", "add_artifacts", "add_artifacts_mm"]

#: depth where ``wave_sd_mm`` applies [m]
_WAVE_REF_M = 0.4


@dataclass(frozen=True)
class ArtifactConfig:
    """Ranges of :func:`add_artifacts`, each drawn uniformly per image."""

    fatten_px: tuple[int, int] = param((0, 2), "foreground growth at depth steps [px]",
                                       lo=0, hi=10)
    shadow_px: tuple[int, int] = param((0, 4), "occlusion band beside nearer surfaces [px]",
                                       lo=0, hi=20)
    hole_share: tuple[float, float] = param((0.0, 0.03), "share of measured pixels in holes",
                                              lo=0.0, hi=0.5)
    hole_radius_px: tuple[float, float] = param((1.5, 6.0), "radius of a hole [px]",
                                                  lo=0.5, hi=50.0)
    wave_sd_mm: tuple[float, float] = param((0.0, 2.0), "std of the correlated error at "
                                            "0.4 m [mm]", lo=0.0, hi=20.0)
    wave_px: tuple[float, float] = param((2.0, 8.0), "scale of the correlated error [px]",
                                           lo=0.5, hi=50.0)
    jump_m: float = param(0.015, "depth step that counts as an edge [m]", lo=0.001, hi=1.0)

    def __post_init__(self) -> None:
        validate(self)
        for name in ("fatten_px", "shadow_px", "hole_share", "hole_radius_px", "wave_sd_mm",
                     "wave_px"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ConfigError(f"ArtifactConfig.{name} = {(lo, hi)}: need lo <= hi")


def _nearest_within(d: np.ndarray, k: int) -> np.ndarray:
    """(H, W) nearest measured depth in the (2k+1)^2 window around each pixel [m] (inf where
    none)."""
    inf = np.where(d > 0, d, np.inf).astype(np.float32)
    return cv2.erode(inf, np.ones((2 * k + 1, 2 * k + 1), np.uint8),
                     borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)


def add_artifacts(depth_m: np.ndarray, rng: np.random.Generator,
                  config: ArtifactConfig | None = None) -> np.ndarray:
    """A copy of ``depth_m`` (H, W) [m], 0 = no measurement, with stereo artifacts drawn
    from ``config`` (module docstring)."""
    c = config or ArtifactConfig()
    d = np.array(depth_m, dtype=np.float32, copy=True)
    if d.ndim != 2 or not np.all(np.isfinite(d)):
        raise InputError("add_artifacts: depth must be a finite (H, W) image")
    k = int(rng.integers(c.fatten_px[0], c.fatten_px[1] + 1))
    if k > 0:   # the nearer side of a step grows over the farther one
        near = _nearest_within(d, k)
        grow = np.isfinite(near) & ((d == 0) | (d - near > c.jump_m))
        d[grow] = near[grow]
    w = int(rng.integers(c.shadow_px[0], c.shadow_px[1] + 1))
    if w > 0:   # the farther surface beside a nearer one, on one side
        inf = np.where(d > 0, d, np.inf)
        side = 1 if rng.random() < 0.5 else -1
        near = np.full(d.shape, np.inf, np.float32)
        for s in range(1, w + 1):   # near[:, x] = min of inf[:, x + side * 1..w]
            if side > 0:
                near[:, :-s] = np.minimum(near[:, :-s], inf[:, s:])
            else:
                near[:, s:] = np.minimum(near[:, s:], inf[:, :-s])
        d[(d > 0) & (d - near > c.jump_m)] = 0.0
    share = float(rng.uniform(*c.hole_share))
    valid = np.flatnonzero(d > 0)
    if share > 0 and valid.size:
        r = float(rng.uniform(*c.hole_radius_px))
        n = int(math.ceil(share * valid.size / (math.pi * r * r)))
        holes = np.zeros(d.shape, np.uint8)
        for i in rng.choice(valid, size=n):
            cv2.circle(holes, (int(i % d.shape[1]), int(i // d.shape[1])), int(round(r)), 1,
                       -1)
        d[holes > 0] = 0.0
    sd = float(rng.uniform(*c.wave_sd_mm)) * 1e-3
    if sd > 0:
        s = float(rng.uniform(*c.wave_px))
        field = cv2.GaussianBlur(rng.standard_normal(d.shape).astype(np.float32), (0, 0), s)
        field /= max(float(field.std()), 1e-9)
        m = d > 0
        d[m] += sd * (d[m] / _WAVE_REF_M) ** 2 * field[m]
    return d


def add_artifacts_mm(depth_mm: np.ndarray, rng: np.random.Generator,
                     config: ArtifactConfig | None = None) -> np.ndarray:
    """:func:`add_artifacts` on a ``uint16`` millimetre image (``16UC1``, 0 = none), rounded
    back to one."""
    return depth_m_to_mm(add_artifacts(np.asarray(depth_mm) * DEPTH_UNIT_M, rng, config))
