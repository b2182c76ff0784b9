"""Analytic ray casting of capsules, ellipsoids and bounded planes (numpy).

A second renderer, independent of the suite's triangle rasteriser
(``hand_capture.cameras.render``): every pixel's ray through the pinhole (lens distortion
ignored) is intersected in closed form with each primitive, inside the pixel rectangle that
bounds the primitive's projection, and the nearest hit is kept (a z-buffer over primitives).

Rays are ``p(t) = t * d`` with ``d = ((u - cx) / fx, (v - cy) / fy, 1)`` for pixel centres, so
the ray parameter ``t`` is directly the depth ``z`` [m] of the hit (the camera optical frame:
x right, y down, z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.base import Intrinsics

__all__ = ["BoundedPlane", "Capsule", "Ellipsoid", "RayImage", "raycast"]


@dataclass(frozen=True)
class Capsule:
    """Points within ``radius`` [m] of the segment ``a``-``b`` (3,) [m]; ``label`` tags it."""

    a: np.ndarray
    b: np.ndarray
    radius: float
    label: int = 1

    def bound(self) -> tuple[np.ndarray, float]:
        c = 0.5 * (self.a + self.b)
        return c, 0.5 * float(np.linalg.norm(self.b - self.a)) + self.radius

    def intersect(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Depth of the first hit of the rays ``(dx, dy, 1)`` (N,) each [m]; inf if missed."""
        a, b, r = self.a, self.b, self.radius
        ba = b - a
        oa = -a
        baba = float(ba @ ba)
        dd = dx * dx + dy * dy + 1.0
        bard = _dot(dx, dy, ba)
        rdoa = _dot(dx, dy, oa)
        baoa = float(ba @ oa)
        oaoa = float(oa @ oa)
        t = np.full(len(dx), np.inf)
        if baba > 1e-18:  # the cylinder between the caps
            aa = baba * dd - bard ** 2
            bb = baba * rdoa - baoa * bard
            cc = baba * oaoa - baoa ** 2 - r * r * baba
            h = bb ** 2 - aa * cc
            ok = (h >= 0) & (aa > 1e-18)
            tc = np.full(len(dx), np.inf)
            tc[ok] = (-bb[ok] - np.sqrt(h[ok])) / aa[ok]
            y = baoa + np.where(ok, tc, 0.0) * bard
            ok &= (y > 0) & (y < baba) & (tc > 0)
            t = np.where(ok, tc, t)
        for c in (a, b):  # the two spherical caps
            t = np.minimum(t, _sphere(dx, dy, dd, c, r))
        return t


def _dot(dx: np.ndarray, dy: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(dx, dy, 1) . v`` per ray."""
    return dx * float(v[0]) + dy * float(v[1]) + float(v[2])


def _sphere(dx: np.ndarray, dy: np.ndarray, dd: np.ndarray, c: np.ndarray, r: float
            ) -> np.ndarray:
    dc = _dot(dx, dy, c)
    h = dc ** 2 - dd * (float(c @ c) - r * r)
    ok = h >= 0
    t = np.full(len(dx), np.inf)
    t[ok] = (dc[ok] - np.sqrt(h[ok])) / dd[ok]
    t[t <= 0] = np.inf
    return t


@dataclass(frozen=True)
class Ellipsoid:
    """``centre`` (3,) [m], ``axes`` (3, 3) columns = unit principal axes, ``radii`` (3,) [m]."""

    centre: np.ndarray
    axes: np.ndarray
    radii: np.ndarray
    label: int = 1

    def bound(self) -> tuple[np.ndarray, float]:
        return self.centre, float(np.max(self.radii))

    def intersect(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        o = (self.axes.T @ -self.centre) / self.radii
        dl = [_dot(dx, dy, self.axes[:, k] / self.radii[k]) for k in range(3)]
        a = dl[0] ** 2 + dl[1] ** 2 + dl[2] ** 2
        b = dl[0] * o[0] + dl[1] * o[1] + dl[2] * o[2]
        c = float(o @ o) - 1.0
        h = b ** 2 - a * c
        ok = h >= 0
        t = np.full(len(dx), np.inf)
        t[ok] = (-b[ok] - np.sqrt(h[ok])) / a[ok]
        t[t <= 0] = np.inf
        return t


@dataclass(frozen=True)
class BoundedPlane:
    """A rectangle: ``centre`` (3,), unit ``normal``, in-plane unit axes ``e1``, ``e2`` and
    half sizes ``half`` (2,) [m] (a table top, a wall)."""

    centre: np.ndarray
    normal: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    half: tuple[float, float]
    label: int = 4

    def bound(self) -> tuple[np.ndarray, float]:
        return self.centre, float(math.hypot(*self.half))

    def intersect(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        nd = _dot(dx, dy, self.normal)
        t = np.full(len(dx), np.inf)
        ok = np.abs(nd) > 1e-12
        t[ok] = float(self.normal @ self.centre) / nd[ok]
        t[~ok] = 0.0
        ok &= (t > 0) & (np.abs(t * _dot(dx, dy, self.e1) - float(self.centre @ self.e1))
                         <= self.half[0]) & \
            (np.abs(t * _dot(dx, dy, self.e2) - float(self.centre @ self.e2)) <= self.half[1])
        return np.where(ok, t, np.inf)


@dataclass
class RayImage:
    """Output of :func:`raycast`: ``depth`` (H, W) float64 [m] (0 = nothing hit) and
    ``label`` (H, W) int16 (the hit primitive's label, 0 = nothing)."""

    depth: np.ndarray
    label: np.ndarray


def _pixel_box(centre: np.ndarray, radius: float, intr: Intrinsics
               ) -> tuple[int, int, int, int] | None:
    """Conservative pixel rectangle (v0, v1, u0, u1) of a sphere's projection; None if the
    sphere is wholly behind the camera."""
    z = float(centre[2])
    if z + radius <= 1e-6:
        return None
    W, H = intr.width, intr.height
    zmin = z - radius
    if zmin <= 1e-3:
        return 0, H, 0, W
    us = [intr.cx + intr.fx * (centre[0] + s * radius) / zz for s in (-1, 1)
          for zz in (zmin, z + radius)]
    vs = [intr.cy + intr.fy * (centre[1] + s * radius) / zz for s in (-1, 1)
          for zz in (zmin, z + radius)]
    u0, u1 = max(0, int(math.floor(min(us)))), min(W, int(math.ceil(max(us))) + 1)
    v0, v1 = max(0, int(math.floor(min(vs)))), min(H, int(math.ceil(max(vs))) + 1)
    if u0 >= u1 or v0 >= v1:
        return None
    return v0, v1, u0, u1


def raycast(primitives: list, intr: Intrinsics, base: RayImage | None = None) -> RayImage:
    """Nearest hit of every pixel ray with ``primitives`` (:class:`Capsule`,
    :class:`Ellipsoid`, :class:`BoundedPlane`) in the camera frame; ``base`` = an image of
    other (static) primitives rendered before, to draw over."""
    H, W = intr.height, intr.width
    if base is not None:
        depth = np.where(base.depth > 0, base.depth, np.inf)
        label = base.label.copy()
    else:
        depth = np.full((H, W), np.inf)
        label = np.zeros((H, W), np.int16)
    xs = (np.arange(W) - intr.cx) / intr.fx
    ys = (np.arange(H) - intr.cy) / intr.fy
    for prim in primitives:
        box = _pixel_box(*prim.bound(), intr)
        if box is None:
            continue
        v0, v1, u0, u1 = box
        gx, gy = np.meshgrid(xs[u0:u1], ys[v0:v1])
        t = prim.intersect(gx.ravel(), gy.ravel()).reshape(v1 - v0, u1 - u0)
        sub = depth[v0:v1, u0:u1]
        near = t < sub
        sub[near] = t[near]
        label[v0:v1, u0:u1][near] = prim.label
    depth[~np.isfinite(depth)] = 0.0
    return RayImage(depth, label)
