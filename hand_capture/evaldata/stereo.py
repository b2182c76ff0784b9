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
from statistics import NormalDist

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


def occlusion_shadow(depth_m: np.ndarray, intr: Intrinsics, baseline_m: float, c0: int = 0
                     ) -> np.ndarray:
    """(H, W) bool: pixels the right imager (at +x ``baseline_m``) cannot see (``depth_m``
    may be a crop of the image starting at column ``c0``).

    A left pixel ``u`` with disparity ``d(u)`` lands at ``x_r = u - d(u)`` in the right image;
    it is hidden when a pixel ``u' > u`` lands at or left of it (a nearer surface).
    """
    d = np.asarray(depth_m, dtype=np.float32)
    valid = d > 0
    disp = np.float32(intr.fx * baseline_m) / np.where(valid, d, np.float32(np.inf))
    xr = np.arange(c0, c0 + d.shape[1], dtype=np.float32)[None, :] - disp
    xr[~valid] = np.inf
    # minimum of x_r over the pixels strictly to the right
    right_min = np.full_like(xr, np.inf)
    right_min[:, :-1] = np.minimum.accumulate(xr[:, :0:-1], axis=1)[:, ::-1]
    return valid & (right_min < xr - 0.5)


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float
                  ) -> np.ndarray:
    """Unit-variance Gaussian noise correlated over ``sigma`` px (drawn on a grid ``sigma/2``
    coarser and interpolated up, then blurred)."""
    if sigma <= 0:
        return rng.standard_normal(shape, dtype=np.float32)
    k = max(1, int(sigma))
    small = rng.standard_normal((shape[0] // k + 2, shape[1] // k + 2), dtype=np.float32)
    n = cv2.resize(small, (shape[1] + 2 * k, shape[0] + 2 * k),
                   interpolation=cv2.INTER_LINEAR)[k:k + shape[0], k:k + shape[1]]
    s = cv2.GaussianBlur(n, (0, 0), sigma / k if k > 1 else sigma)
    return s * np.float32(1.0 / max(float(s[::4, ::4].std()), 1e-9))


def _min_filter(img: np.ndarray, size: int) -> np.ndarray:
    return cv2.erode(img, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)


def _max_filter(img: np.ndarray, size: int) -> np.ndarray:
    return cv2.dilate(img, np.ones((size, size), np.uint8), borderType=cv2.BORDER_REPLICATE)


def _some(rng: np.random.Generator, mask: np.ndarray, rate: float) -> np.ndarray:
    """A random share ``rate`` of the True pixels of ``mask`` (drawn for those only)."""
    idx = np.flatnonzero(mask)
    out = np.zeros(mask.shape, bool)
    out.flat[idx[rng.random(idx.size) < rate]] = True
    return out


def apply_stereo_noise(depth_m: np.ndarray, intr: Intrinsics, rng: np.random.Generator,
                       cfg: StereoNoiseConfig | None = None) -> np.ndarray:
    """Stereo-like depth (uint16 mm) from exact depth (H, W) [m] (see the module doc)."""
    cfg = cfg or StereoNoiseConfig()
    full = np.asarray(depth_m, dtype=np.float32)
    out = np.zeros(full.shape, np.uint16)
    rows = np.flatnonzero((full > 0).any(axis=1))
    if rows.size == 0:
        return out
    cols = np.flatnonzero((full > 0).any(axis=0))
    m = cfg.fatten_px + 2   # the window of everything below is cropped to the valid box
    r0, r1 = max(0, rows[0] - m), min(full.shape[0], rows[-1] + 1 + m)
    c0, c1 = max(0, cols[0] - m), min(full.shape[1], cols[-1] + 1 + m)
    out[r0:r1, c0:c1] = _noise(full[r0:r1, c0:c1], intr, c0, rng, cfg)
    return out


def _noise(z: np.ndarray, intr: Intrinsics, c0: int, rng: np.random.Generator,
           cfg: StereoNoiseConfig) -> np.ndarray:
    """:func:`apply_stereo_noise` on a crop whose first column is image column ``c0``."""
    f32 = np.float32
    valid = z > 0
    fb = f32(intr.fx * cfg.baseline_m)
    big = f32(1e3)
    edge_m = f32(cfg.edge_mm * 1e-3)
    zi = np.where(valid, z, big)
    # edge fattening: within fatten_px, a nearer surface takes over (1 px everywhere, the
    # full width where a smooth random field says so)
    if cfg.fatten_px > 0:
        near = _min_filter(zi, 2 * cfg.fatten_px + 1)
        near1 = _min_filter(zi, 3)
        step = (zi - near) > edge_m
        wide = _smooth_noise(rng, z.shape, 3.0) > 0.3
        one = near1 < zi - edge_m
        grow = step & (near < big) & (one | wide)
        zi = np.where(grow, np.where(one, near1, near), zi)
        valid = zi < big
    # flying pixels: a depth between the two sides of a discontinuity
    far = _max_filter(np.where(valid, zi, f32(0.0)), 3)
    edge = valid & ((far - zi) > edge_m)
    fly = _some(rng, edge, cfg.flying_rate)
    zi[fly] += rng.uniform(0.2, 0.8, int(fly.sum())).astype(f32) * (far[fly] - zi[fly])
    # disparity with correlated + white noise, quantised to subpixel steps
    disp = fb / np.where(valid, zi, f32(1.0))
    disp += f32(cfg.disparity_sd_px) * _smooth_noise(rng, z.shape, cfg.corr_px)
    disp += f32(cfg.white_sd_px) * rng.standard_normal(z.shape, dtype=f32)
    if cfg.subpixel > 0:
        q = f32(cfg.subpixel)
        disp = np.round(disp / q) * q
    zn = np.where(valid & (disp > 1e-3), fb / np.maximum(disp, f32(1e-3)), f32(0.0))
    # holes: occlusion shadow, grazing surfaces, blobs, range limits
    bad = occlusion_shadow(np.where(valid, zi, f32(0.0)), intr, cfg.baseline_m, c0)
    gy, gx = np.gradient(np.where(valid, zi, f32(np.nan)))
    # surface normal from the depth gradient: n ~ (-dz/dx, -dz/dy, 1) in metric units
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (gx * f32(intr.fx) / zi) ** 2 + (gy * f32(intr.fy) / zi) ** 2
    # |cos incidence| = 1 / sqrt(1 + t) < c  <=>  t > 1 / c^2 - 1
    graze = t > (1.0 / max(cfg.grazing_cos, 1e-6) ** 2 - 1.0)
    bad |= _some(rng, graze, 0.8)
    if cfg.hole_rate > 0:
        blobs = _smooth_noise(rng, z.shape, 4.0)
        bad |= blobs > f32(NormalDist().inv_cdf(1.0 - cfg.hole_rate))
    bad |= (zn < cfg.min_z_m) | (zn > cfg.max_z_m)
    out = np.where(valid & ~bad, np.rint(zn * f32(1e3)), f32(0.0))
    return np.clip(out, 0, 65535).astype(np.uint16)
