"""Depth-sensor noise: turns a clean rendered depth image into a realistic ``16UC1`` image.

The dissertation trains its regressor on rendered depth images and notes that synthetic data
is much cleaner than real data, so it adds random and silhouette noise (ch. II.4.4) without
giving a model. This module uses the usual empirical model of active depth sensors
(structured light and time of flight, e.g. Nguyen, Izadi & Lovell 2012 for the Kinect):

* axial noise, Gaussian with a standard deviation growing with the squared distance and
  with the incidence angle ``theta`` between the surface normal and the viewing ray::

      sigma(z, theta) = sigma_base + sigma_quad * z^2
                        + sigma_angle / sqrt(z) * theta^2 / (pi/2 - theta)^2

  (the defaults give 1.2 mm at 0.4 m facing the camera, 2.8 mm at 1 m);
* quantisation: to the 1 mm unit of the output, and optionally to the sub-pixel disparity
  step of a structured-light / stereo sensor (depth step ``z^2 * step / (f * baseline)``);
* missing pixels on grazing surfaces: the dropout probability ramps linearly from 0 at
  ``grazing_start_deg`` to 1 at ``grazing_full_deg``;
* flying pixels at depth discontinuities: a pixel next to a depth jump larger than
  ``jump_m`` takes, with probability ``flying_prob``, a depth mixed between its own and its
  neighbour's (uniformly); next to empty background the far side is ``flying_empty_m``
  behind the surface;
* random isolated dropouts, a working range, and dropped frames.

Everything is drawn from the caller's ``numpy.random.Generator`` so a seed reproduces a run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.base import DEPTH_UNIT_M, Intrinsics, depth_m_to_mm
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, InputError

__all__ = ["ColorNoise", "DepthNoiseConfig", "DepthNoiseModel", "add_color_noise"]


@dataclass(frozen=True)
class DepthNoiseConfig:
    """Parameters of :class:`DepthNoiseModel` (all lengths in metres)."""

    enabled: bool = param(True, "apply the noise model (false: only 1 mm quantisation)")
    sigma_base_m: float = param(0.0009, "axial noise std at zero distance [m]", lo=0.0, hi=0.1)
    sigma_quad_per_m: float = param(
        0.0019, "growth of the axial noise std with squared distance [m/m^2]", lo=0.0, hi=1.0)
    sigma_angle_m: float = param(
        0.0001, "angle term of the axial std, times theta^2/(pi/2-theta)^2/sqrt(z) [m^1.5]",
        lo=0.0, hi=0.1)
    baseline_m: float = param(
        0.0, "stereo/projector baseline for disparity quantisation [m]; 0 = off", lo=0.0,
        hi=1.0)
    disparity_step_px: float = param(0.125, "disparity quantisation step [px]", lo=1e-4,
                                     hi=10.0)
    min_range_m: float = param(0.1, "nearest measurable depth [m]", lo=0.0, hi=100.0)
    max_range_m: float = param(4.0, "farthest measurable depth [m]", lo=0.01, hi=65.0)
    grazing_start_deg: float = param(
        70.0, "incidence angle where grazing dropout starts [deg]", lo=0.0, hi=90.0)
    grazing_full_deg: float = param(
        85.0, "incidence angle where every pixel is dropped [deg]", lo=0.0, hi=90.0)
    jump_m: float = param(0.015, "depth jump between neighbours that marks an edge [m]",
                          lo=0.0, hi=10.0)
    flying_prob: float = param(0.3, "probability of a flying pixel at an edge pixel",
                               lo=0.0, hi=1.0)
    flying_empty_m: float = param(
        0.1, "far side of an edge with empty background, behind the surface [m]", lo=0.0,
        hi=10.0)
    dropout_prob: float = param(0.001, "probability of a random missing pixel", lo=0.0,
                                hi=1.0)
    frame_drop_prob: float = param(0.0, "probability that a whole frame is dropped", lo=0.0,
                                   hi=1.0)
    color_noise_std: float = param(2.0, "std of the colour noise [8-bit levels]", lo=0.0,
                                   hi=100.0)

    def __post_init__(self) -> None:
        validate(self)
        if self.grazing_full_deg < self.grazing_start_deg:
            raise ConfigError(
                f"DepthNoiseConfig.grazing_full_deg ({self.grazing_full_deg}) must be >= "
                f"grazing_start_deg ({self.grazing_start_deg})")
        if self.max_range_m <= self.min_range_m:
            raise ConfigError(
                f"DepthNoiseConfig.max_range_m ({self.max_range_m}) must be > min_range_m "
                f"({self.min_range_m})")


class DepthNoiseModel:
    """Applies :class:`DepthNoiseConfig` to clean depth images (see the module docstring)."""

    def __init__(self, config: DepthNoiseConfig | None = None) -> None:
        self.config = config or DepthNoiseConfig()

    def axial_sigma(self, z: np.ndarray, cos_incidence: np.ndarray | float = 1.0
                    ) -> np.ndarray:
        """Standard deviation of the axial noise [m] at depth ``z`` [m] and incidence cos."""
        z = np.asarray(z, dtype=np.float64)
        return self._axial_sigma(z, np.arccos(np.clip(cos_incidence, 0.0, 1.0)))

    def _axial_sigma(self, z: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """:meth:`axial_sigma` from the incidence angle ``theta`` [rad] (float64 arrays)."""
        c = self.config
        # the angle term diverges at 90 deg; beyond grazing_full_deg pixels are dropped anyway
        theta = np.minimum(theta, math.radians(max(c.grazing_full_deg, 1e-3)) - 1e-3)
        theta = np.minimum(theta, math.pi / 2 - 1e-3)
        angle = theta**2 / (math.pi / 2 - theta) ** 2
        return c.sigma_base_m + c.sigma_quad_per_m * z**2 + \
            c.sigma_angle_m / np.sqrt(np.maximum(z, 1e-6)) * angle

    def quantization_step(self, z: np.ndarray, fx: float) -> np.ndarray:
        """Depth step [m] of the sensor at depth ``z``: disparity step or the 1 mm unit."""
        c = self.config
        z = np.asarray(z, dtype=np.float64)
        if c.baseline_m <= 0:
            return np.full(z.shape, DEPTH_UNIT_M)
        return np.maximum(z**2 * c.disparity_step_px / (fx * c.baseline_m), DEPTH_UNIT_M)

    def drop_frame(self, rng: np.random.Generator) -> bool:
        """Whether the next frame is dropped (``frame_drop_prob``)."""
        p = self.config.frame_drop_prob
        return bool(p > 0 and rng.random() < p)

    def apply(self, depth_m: np.ndarray, cos_incidence: np.ndarray, intr: Intrinsics,
              rng: np.random.Generator) -> np.ndarray:
        """Noisy depth [m] (float32, 0 = no measurement) from a clean depth image.

        Args:
            depth_m: (H, W) clean z-depth [m], 0 where nothing was seen.
            cos_incidence: (H, W) |cos| of the incidence angle (from the renderer).
            intr: intrinsics of the image (fx for disparity quantisation).
            rng: random generator (seeded by the caller).
        """
        depth_m, valid = self._valid(depth_m, cos_incidence)
        if not self.config.enabled:
            return np.where(valid, depth_m, 0.0).astype(np.float32)
        out = np.zeros(depth_m.shape, np.float32)
        noisy = self._noisy_window(depth_m, valid, cos_incidence, intr, rng)
        if noisy is not None:
            out[noisy[0]] = noisy[1]
        return out

    def apply_mm(self, depth_m: np.ndarray, cos_incidence: np.ndarray, intr: Intrinsics,
                 rng: np.random.Generator) -> np.ndarray:
        """Like :meth:`apply`, quantised to a ``uint16`` millimetre image (``16UC1``)."""
        if not self.config.enabled:
            return depth_m_to_mm(self.apply(depth_m, cos_incidence, intr, rng))
        depth_m, valid = self._valid(depth_m, cos_incidence)
        out = np.zeros(depth_m.shape, np.uint16)
        noisy = self._noisy_window(depth_m, valid, cos_incidence, intr, rng)
        if noisy is not None:  # 0 m is 0 mm: only the window needs converting
            out[noisy[0]] = depth_m_to_mm(noisy[1])
        return out

    def _valid(self, depth_m: np.ndarray, cos_incidence: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        c = self.config
        depth_m = np.asarray(depth_m, dtype=np.float32)
        if depth_m.shape != np.shape(cos_incidence):
            raise InputError(f"depth {depth_m.shape} and cos_incidence "
                             f"{np.shape(cos_incidence)} differ in shape")
        return depth_m, (depth_m >= c.min_range_m) & (depth_m <= c.max_range_m)

    def _noisy_window(self, depth_m: np.ndarray, valid: np.ndarray, cos_incidence: np.ndarray,
                      intr: Intrinsics, rng: np.random.Generator
                      ) -> tuple[tuple[slice, slice], np.ndarray] | None:
        """The noise applied on the bounding box of the valid pixels: (window, float32 depth
        in it), or None when no pixel is valid."""
        rows = np.flatnonzero(valid.any(axis=1))
        if rows.size == 0:
            return None
        cols = np.flatnonzero(valid.any(axis=0))
        win = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        # sides of the window on the image border: beyond them is unknown, not empty
        border = (rows[0] == 0, rows[-1] == depth_m.shape[0] - 1,
                  cols[0] == 0, cols[-1] == depth_m.shape[1] - 1)
        # the valid pixels: flat indices in the window and their depth and incidence cosine
        vw = valid[win]
        idx = np.flatnonzero(vw)
        r, cc = np.divmod(idx, vw.shape[1])
        full = (r + rows[0]) * depth_m.shape[1] + (cc + cols[0])
        z = depth_m.ravel()[full].astype(np.float64)
        cos = np.asarray(cos_incidence).ravel()[full].astype(np.float64)
        return win, self._apply_pixels(vw, idx, z, cos, intr, rng, border)

    def _apply_pixels(self, valid: np.ndarray, idx: np.ndarray, z: np.ndarray,
                      cos: np.ndarray, intr: Intrinsics, rng: np.random.Generator,
                      border: tuple[bool, bool, bool, bool]) -> np.ndarray:
        """Noisy (H, W) float32 window from its valid pixels (flat indices ``idx`` into the
        (H, W) mask ``valid``, clean depth ``z`` and cosine ``cos`` there, float64)."""
        c = self.config
        H, W = valid.shape
        keep = np.ones(idx.size, bool)

        # flying pixels: mix with the neighbour across the largest depth jump
        if c.flying_prob > 0:
            # depth with an infinite frame around the window (inf = nothing seen); a side on
            # the image border repeats its outer row/column instead
            pad = np.full((H + 2, W + 2), np.inf)
            r, cc = np.divmod(idx, W)
            at = (r + 1) * (W + 2) + (cc + 1)  # the valid pixels in the padded array
            flat = pad.ravel()
            flat[at] = z
            top, bottom, left, right = border
            if top:
                pad[0] = pad[1]
            if bottom:
                pad[-1] = pad[-2]
            if left:
                pad[:, 0] = pad[:, 1]
            if right:
                pad[:, -1] = pad[:, -2]
            # the neighbour with the largest |jump| (the first of up, down, left, right on a
            # tie); no neighbour (inf) counts as flying_empty_m behind the surface
            jump = best = None
            for off in (-(W + 2), W + 2, -1, 1):
                nb = flat[at + off]
                nb = np.where(np.isinf(nb), z + c.flying_empty_m, nb)
                dz = nb - z
                a = np.abs(dz)
                if jump is None:
                    jump, best = dz, a
                else:
                    more = a > best
                    jump = np.where(more, dz, jump)
                    best = np.where(more, a, best)
            edge = np.flatnonzero(np.abs(jump) > c.jump_m)
            if edge.size:
                fly = edge[rng.random(edge.size) < c.flying_prob]
                z[fly] += rng.random(fly.size) * jump[fly]

        # missing pixels on grazing surfaces and random dropouts
        cos_start = math.cos(math.radians(c.grazing_start_deg))
        cos_full = math.cos(math.radians(c.grazing_full_deg))
        theta = np.arccos(np.clip(cos, 0.0, 1.0))
        span = max(math.radians(c.grazing_full_deg - c.grazing_start_deg), 1e-9)
        p = np.clip((theta - math.radians(c.grazing_start_deg)) / span, 0.0, 1.0)
        p[cos <= cos_full] = 1.0
        p[cos >= cos_start] = 0.0
        p = p + c.dropout_prob
        keep &= rng.random(idx.size) >= p

        # axial noise, then quantisation
        sigma = self._axial_sigma(z, theta)
        z = z + sigma * rng.standard_normal(idx.size)
        if c.baseline_m > 0:
            fb = intr.fx * c.baseline_m
            disp = fb / np.maximum(z, 1e-6)
            disp = np.maximum(np.round(disp / c.disparity_step_px), 1) * c.disparity_step_px
            z = fb / disp
        keep &= (z >= c.min_range_m) & (z <= c.max_range_m)

        out = np.zeros(H * W, np.float32)
        out[idx[keep]] = z[keep]
        return out.reshape(H, W)


def add_color_noise(rgb: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Add Gaussian noise of ``std`` levels to an 8-bit RGB image (clipped, uint8)."""
    if std <= 0:
        return rgb
    noisy = rgb.astype(np.float32) + rng.standard_normal(rgb.shape, dtype=np.float32) * \
        np.float32(std)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


class ColorNoise:
    """Fast colour noise: a pool of Gaussian samples drawn once, read at a random offset.

    Drawing fresh normals for every pixel of every frame costs more than rendering; a pool
    twice the image size read from a random start gives per-frame noise that is Gaussian
    per pixel with the right std (neighbouring frames share samples at shifted places).
    """

    def __init__(self, shape: tuple[int, ...], std: float, rng: np.random.Generator) -> None:
        self.shape = tuple(shape)
        self.std = float(std)
        n = int(np.prod(self.shape))
        self._n = n
        self._pool = np.clip(np.rint(rng.standard_normal(2 * n) * std), -127, 127
                             ).astype(np.int16)

    def apply(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.std <= 0:
            return rgb
        if rgb.shape != self.shape:
            raise InputError(f"colour noise was built for {self.shape}, got {rgb.shape}")
        off = int(rng.integers(0, self._n))
        noisy = rgb.reshape(-1).astype(np.int16)
        noisy += self._pool[off:off + self._n]
        np.clip(noisy, 0, 255, out=noisy)
        return noisy.astype(np.uint8).reshape(self.shape)
