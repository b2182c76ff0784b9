"""A stereo-like depth noise model (active IR stereo, RealSense D4xx-like).

Independent of the suite's sensor model (``hand_capture.cameras.noise``): noise is made in
the disparity domain of a left/right pair with baseline ``b`` and focal length ``f``
(``d = f b / z``), and the artefacts are those of block matching:

* **occlusion shadows**: pixels of the left (depth) image whose point the right imager
  cannot see, because a nearer surface to their right covers it, get no depth (a band
  beside every near object, as wide as the disparity step);
* **edge fattening**: near a depth discontinuity the matching window takes the nearer
  surface's disparity, so foreground objects grow by a few pixels into the background;
* **correlated noise**: disparity noise smoothed over a few pixels (window correlation),
  plus a small white part, then subpixel quantisation of the disparity;
* **holes**: invalid blobs (low texture, specular spots), grazing surfaces (normal from the
  depth gradient) and the range limits of the camera;
* **flying pixels**: a few pixels at discontinuities take a depth between the two sides.

Input: exact depth (H, W) [m] (0 = nothing); output: uint16 depth [mm] (0 = no depth).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import ConfigError

__all__ = ["StereoNoiseConfig", "apply_stereo_noise", "occlusion_shadow"]


@dataclass(frozen=True)
class StereoNoiseConfig:
    """Parameters of :func:`apply_stereo_noise` (defaults: a D435-like camera)."""

    baseline_m: float = 0.050          # D435: 50 mm; D405: 18 mm
    disparity_sd_px: float = 0.08      # correlated disparity noise [px]
    white_sd_px: float = 0.03          # per-pixel disparity noise [px]
    corr_px: float = 2.0               # correlation length of the noise [px]
    subpixel: float = 1.0 / 16         # disparity quantisation step [px]
    fatten_px: int = 2                 # largest foreground growth at edges [px]
    edge_mm: float = 15.0              # depth step that counts as a discontinuity [mm]
    hole_rate: float = 0.015           # share of pixels in invalid blobs
    grazing_cos: float = 0.2           # below this |cos| of incidence: dropped (mostly)
    flying_rate: float = 0.15          # share of edge pixels turned into flying pixels
    min_z_m: float = 0.11
    max_z_m: float = 3.0

    def __post_init__(self) -> None:
        checks = {"baseline_m": (1e-3, 1.0), "disparity_sd_px": (0.0, 5.0),
                  "white_sd_px": (0.0, 5.0), "corr_px": (0.0, 20.0), "subpixel": (0.0, 1.0),
                  "fatten_px": (0, 10), "edge_mm": (0.1, 1000.0), "hole_rate": (0.0, 0.5),
                  "grazing_cos": (0.0, 1.0), "flying_rate": (0.0, 1.0),
                  "min_z_m": (0.0, 10.0), "max_z_m": (0.01, 50.0)}
        for name, (lo, hi) in checks.items():
            v = getattr(self, name)
            if not lo <= v <= hi:
                raise ConfigError(f"StereoNoiseConfig.{name} = {v} is out of range "
                                  f"[{lo}, {hi}]")
        if self.max_z_m <= self.min_z_m:
            raise ConfigError("StereoNoiseConfig.max_z_m must exceed min_z_m")


def occlusion_shadow(depth_m: np.ndarray, intr: Intrinsics, baseline_m: float) -> np.ndarray:
    """(H, W) bool: pixels the right imager (at +x ``baseline_m``) cannot see.

    A left pixel ``u`` with disparity ``d(u)`` lands at ``x_r = u - d(u)`` in the right image;
    it is hidden when a pixel ``u' > u`` lands at or left of it (a nearer surface).
    """
    valid = depth_m > 0
    disp = np.where(valid, intr.fx * baseline_m / np.where(valid, depth_m, 1.0), 0.0)
    xr = np.arange(depth_m.shape[1])[None, :] - disp
    xr = np.where(valid, xr, np.inf)
    # minimum of x_r over the pixels strictly to the right
    rev = np.minimum.accumulate(xr[:, ::-1], axis=1)[:, ::-1]
    right_min = np.concatenate([rev[:, 1:], np.full((len(xr), 1), np.inf)], axis=1)
    return valid & (right_min < xr - 0.5)


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float
                  ) -> np.ndarray:
    """Unit-variance Gaussian noise correlated over ``sigma`` px (drawn on a grid ``sigma/2``
    coarser and interpolated up, then blurred)."""
    if sigma <= 0:
        return rng.standard_normal(shape)
    k = max(1, int(sigma // 2))
    small = rng.standard_normal((shape[0] // k + 2, shape[1] // k + 2)).astype(np.float32)
    n = cv2.resize(small, (shape[1] + 2 * k, shape[0] + 2 * k),
                   interpolation=cv2.INTER_LINEAR)[k:k + shape[0], k:k + shape[1]]
    s = cv2.GaussianBlur(n, (0, 0), sigma / k if k > 1 else sigma)
    return s / max(float(s.std()), 1e-9)


def _min_filter(img: np.ndarray, size: int) -> np.ndarray:
    return cv2.erode(img, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)


def _max_filter(img: np.ndarray, size: int) -> np.ndarray:
    return cv2.dilate(img, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)


def apply_stereo_noise(depth_m: np.ndarray, intr: Intrinsics, rng: np.random.Generator,
                       cfg: StereoNoiseConfig | None = None) -> np.ndarray:
    """Stereo-like depth (uint16 mm) from exact depth (H, W) [m] (see the module doc)."""
    cfg = cfg or StereoNoiseConfig()
    z = np.asarray(depth_m, dtype=np.float64)
    valid = z > 0
    fb = intr.fx * cfg.baseline_m
    big = 1e3
    zi = np.where(valid, z, big).astype(np.float32)
    # edge fattening: within fatten_px, a nearer surface takes over (per-row random width)
    if cfg.fatten_px > 0:
        near = _min_filter(zi, 2 * cfg.fatten_px + 1)
        near1 = _min_filter(zi, 3)
        step = (zi - near) * 1e3 > cfg.edge_mm
        wide = _smooth_noise(rng, z.shape, 3.0) > 0.3
        grow = step & (near < big) & ((near1 < zi - cfg.edge_mm * 1e-3) | wide)
        zi = np.where(grow, np.where(near1 < zi - cfg.edge_mm * 1e-3, near1, near), zi)
        valid = zi < big
    # flying pixels: a depth between the two sides of a discontinuity
    far = _max_filter(np.where(valid, zi, np.float32(0.0)), 3)
    edge = valid & ((far - zi) * 1e3 > cfg.edge_mm)
    fly = edge & (rng.random(z.shape) < cfg.flying_rate)
    zi = np.where(fly, zi + rng.uniform(0.2, 0.8, z.shape) * (far - zi), zi)
    # disparity with correlated + white noise, quantised to subpixel steps
    disp = fb / np.where(valid, zi, 1.0)
    disp = disp + cfg.disparity_sd_px * _smooth_noise(rng, z.shape, cfg.corr_px) \
        + cfg.white_sd_px * rng.standard_normal(z.shape)
    if cfg.subpixel > 0:
        disp = np.round(disp / cfg.subpixel) * cfg.subpixel
    zn = np.where(valid & (disp > 1e-3), fb / np.maximum(disp, 1e-3), 0.0)
    # holes: occlusion shadow, grazing surfaces, blobs, range limits
    bad = occlusion_shadow(np.where(valid, zi, 0.0), intr, cfg.baseline_m)
    zg = zi.astype(np.float64)
    gy, gx = np.gradient(np.where(valid, zg, np.nan))
    # surface normal from the depth gradient: n ~ (-dz/dx, -dz/dy, 1) in metric units
    with np.errstate(invalid="ignore", divide="ignore"):
        dzdx = gx * intr.fx / zg
        dzdy = gy * intr.fy / zg
        cosi = 1.0 / np.sqrt(1.0 + dzdx ** 2 + dzdy ** 2)
    graze = np.nan_to_num(cosi, nan=1.0) < cfg.grazing_cos
    bad |= graze & (rng.random(z.shape) < 0.8)
    if cfg.hole_rate > 0:
        blobs = _smooth_noise(rng, z.shape, 4.0)
        thr = np.partition(blobs.ravel(), int((1.0 - cfg.hole_rate) * (blobs.size - 1)))[
            int((1.0 - cfg.hole_rate) * (blobs.size - 1))]
        bad |= blobs > thr
    bad |= (zn < cfg.min_z_m) | (zn > cfg.max_z_m)
    out = np.where(valid & ~bad, np.rint(zn * 1e3), 0.0)
    return np.clip(out, 0, 65535).astype(np.uint16)
