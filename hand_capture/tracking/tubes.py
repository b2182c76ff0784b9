"""A training hand surface unlike the template mesh: swept tubes on the skeleton (issue 13).

The regressor of ch. II.4.4 learns depth features of the template mesh. On hands of another
shape its candidates fall off (issue 13's validation: the suite's collision capsules as the
hand move the best candidate's wrist from 7.9 to 14.6 mm). This module draws a third
surface family for TRAINING only, built from the skeleton's keypoints alone (forward
kinematics of :class:`~hand_capture.model.HandModel`; nothing of the template's mesh, of the
collision capsules of the capsule validation family or of the held-out family
:mod:`hand_capture.evaldata`):

* each finger one continuous tube swept through its keypoints, with an elliptical cross
  section (height / width 0.75-1.15 against the palm's normal), radii tapering from base to
  tip and swelling at the knuckles, a closed rounded tip that ends a random share of its
  radius past the tip keypoint;
* the palm the convex hull of flattened ellipsoids on the wrist's sides, the four
  knuckles and the thumb's base (thickness, width and thenar bulge drawn per sample);
* optionally a stub past the wrist (0-40 mm, the template has 36 mm), else the hand ends at
  the wrist as a hand with its forearm cut off does.

Finger breadths: ANSUR II (2012) gives adult index finger breadths of about 19-21 mm at the
proximal and 16-18 mm at the distal joint; the nominal diameters below follow that, scaled
per finger and per sample by 0.85-1.2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from hand_capture.cameras.render import Mesh
from hand_capture.model import HandModel

__all__ = ["TubeSurface", "tube_mesh"]

#: keypoint chains (thumb, index, middle, ring, little), base .. tip
CHAINS = ((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (17, 18, 19, 20))
#: nominal tube diameters at each chain keypoint [mm] (hand of global scale 1)
DIAMETERS_MM = np.array([[24.0, 22.0, 20.0, 17.0], [21.0, 19.0, 17.0, 15.0],
                         [21.5, 19.5, 17.5, 15.5], [20.0, 18.0, 16.5, 14.5],
                         [18.0, 16.0, 15.0, 13.5]])
#: points of each section ring, stations per bone
_RING, _STATIONS = 10, 4


@dataclass(frozen=True)
class TubeSurface:
    """One sample of the tube family (lengths relative to the hand's global scale).

    Attributes:
        finger_scale: (5,) diameter factor per finger.
        flatness: (5,) section height / width per finger.
        knuckle: extra diameter share at the inner joints.
        tip_out: share of the tip radius the tip reaches past the tip keypoint.
        palm_mm: palm thickness [mm].
        wrist_mm: wrist width [mm].
        thenar: thenar bulge radius [mm] at the thumb's base (0: none).
        stub_mm: length of the stub past the wrist [mm] (0: none).
    """

    finger_scale: np.ndarray
    flatness: np.ndarray
    knuckle: float
    tip_out: float
    palm_mm: float
    wrist_mm: float
    thenar: float
    stub_mm: float

    @staticmethod
    def sample(rng: np.random.Generator) -> TubeSurface:
        """A random sample of the family (see the module doc for the ranges)."""
        return TubeSurface(finger_scale=rng.uniform(0.85, 1.2, 5),
                           flatness=rng.uniform(0.75, 1.15, 5),
                           knuckle=float(rng.uniform(0.0, 0.12)),
                           tip_out=float(rng.uniform(0.2, 1.0)),
                           palm_mm=float(rng.uniform(22.0, 34.0)),
                           wrist_mm=float(rng.uniform(48.0, 64.0)),
                           thenar=float(rng.uniform(0.0, 14.0)),
                           stub_mm=float(rng.uniform(0.0, 40.0)) if rng.random() < 0.5
                           else 0.0)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _tube(path: np.ndarray, radius: np.ndarray, up: np.ndarray, flat: float,
          close_end: bool) -> tuple[np.ndarray, np.ndarray]:
    """A tube along ``path`` (n, 3) [m] with radii ``radius`` (n,) [m], elliptical sections
    whose height (along ``up`` (3,), made normal to the path) is ``flat`` times the width;
    the start closed flat, the end flat or (``close_end``) by a hemispherical cap.
    Returns (vertices (m, 3), faces (k, 3))."""
    d = np.gradient(path, axis=0)
    d = _unit(d)
    a = _unit(up[None, :] - (d @ up)[:, None] * d)             # height axis per station
    b = np.cross(d, a)                                          # width axis
    if close_end:   # cap: rings shrinking on a quarter circle past the last station
        t = np.linspace(0.0, np.pi / 2, 5)[1:]
        cap = path[-1] + np.outer(np.sin(t) * radius[-1], d[-1])
        path = np.vstack([path, cap])
        radius = np.concatenate([radius, radius[-1] * np.maximum(np.cos(t), 0.15)])
        a = np.vstack([a, np.repeat(a[-1:], len(t), 0)])
        b = np.vstack([b, np.repeat(b[-1:], len(t), 0)])
    phi = np.linspace(0.0, 2 * np.pi, _RING, endpoint=False)
    ring = (np.cos(phi)[None, :, None] * b[:, None, :]
            + flat * np.sin(phi)[None, :, None] * a[:, None, :])
    V = (path[:, None, :] + radius[:, None, None] * ring).reshape(-1, 3)
    n = len(path)
    i = np.arange(n - 1)[:, None] * _RING
    j = np.arange(_RING)[None, :]
    p00, p01 = i + j, i + (j + 1) % _RING
    p10, p11 = p00 + _RING, p01 + _RING
    F = np.concatenate([np.stack([p00, p10, p11], -1).reshape(-1, 3),
                        np.stack([p00, p11, p01], -1).reshape(-1, 3)])
    ends = [(0, len(V))] + ([] if close_end else [((n - 1) * _RING, len(V) + 1)])
    centres = [path[0]] + ([] if close_end else [path[-1]])
    for start, c in ends:
        F = np.vstack([F, np.stack([np.full(_RING, c), start + j[0],
                                    start + (j[0] + 1) % _RING], -1)])
    V = np.vstack([V, np.array(centres)])
    if close_end:   # the cap's last ring closes on its tip point
        tip = path[-1]
        F = np.vstack([F, np.stack([np.full(_RING, len(V)), (n - 1) * _RING + j[0],
                                    (n - 1) * _RING + (j[0] + 1) % _RING], -1)])
        V = np.vstack([V, tip[None]])
    return V, F


def _ellipsoid_cloud(centre: np.ndarray, axes: np.ndarray, radii: np.ndarray, k: int = 24
                     ) -> np.ndarray:
    """``k`` points on an ellipsoid (a Fibonacci sphere mapped by ``axes`` (3, 3) rows and
    ``radii`` (3,) [m])."""
    i = np.arange(k) + 0.5
    z = 1 - 2 * i / k
    r = np.sqrt(1 - z * z)
    t = np.pi * (1 + 5 ** 0.5) * i
    s = np.stack([r * np.cos(t), r * np.sin(t), z], -1)
    return centre + (s * radii) @ axes


def tube_mesh(model: HandModel, q: np.ndarray, surf: TubeSurface, label: int = 1) -> Mesh:
    """The hand of ``model`` in pose ``q`` (27,) drawn with the tube surface ``surf``
    (camera frame, [m]); one mesh of several closed parts (not marked ``closed``: the
    parts' winding is not kept outward)."""
    kp = model.joint_positions(q)
    g = float(model.shape.global_scale) * 1e-3    # mm at this hand's size -> m
    across = _unit(kp[5] - kp[17])                 # little -> index knuckle
    fwd = _unit(kp[9] - kp[0])
    normal = _unit(np.cross(fwd, across))
    across = np.cross(normal, fwd)
    axes = np.stack([across, fwd, normal])
    half_t = 0.5 * surf.palm_mm * g
    parts: list[tuple[np.ndarray, np.ndarray]] = []
    # palm: hull of flattened ellipsoids on the knuckles, the wrist's sides and the thumb
    cloud = []
    for f, c in enumerate(CHAINS[1:], start=1):
        r = 0.5 * DIAMETERS_MM[f, 0] * surf.finger_scale[f] * g
        cloud.append(_ellipsoid_cloud(kp[c[0]], axes, np.array([r, r, min(r, half_t)])))
    w = 0.5 * surf.wrist_mm * g
    for side in (-1.0, 1.0):
        cloud.append(_ellipsoid_cloud(kp[0] + side * (w - half_t) * across, axes,
                                      np.array([half_t, half_t, half_t])))
    if surf.thenar > 0:
        c = 0.5 * (kp[1] + kp[2]) - 0.3 * half_t * normal
        cloud.append(_ellipsoid_cloud(c, axes, np.full(3, surf.thenar * g)))
    P = np.vstack(cloud)
    parts.append((P, ConvexHull(P).simplices))
    # fingers: one tube per chain, from inside the palm to past the tip keypoint
    for f, chain in enumerate(CHAINS):
        k = kp[list(chain)]
        r_nodes = 0.5 * DIAMETERS_MM[f] * surf.finger_scale[f] * g
        r_nodes = r_nodes * np.array([1.0, 1.0 + surf.knuckle, 1.0 + surf.knuckle, 1.0])
        start = k[0] - 0.6 * r_nodes[0] * _unit(k[1] - k[0])
        tip = k[3] + (surf.tip_out - 1.0) * r_nodes[3] * _unit(k[3] - k[2])
        nodes = np.vstack([start, k[:3], tip])
        rn = np.concatenate([[r_nodes[0]], r_nodes])
        s = np.linspace(0.0, len(nodes) - 1, (len(nodes) - 1) * _STATIONS + 1)
        lo = np.minimum(s.astype(int), len(nodes) - 2)
        u = (s - lo)[:, None]
        path = nodes[lo] * (1 - u) + nodes[lo + 1] * u
        rad = rn[lo] * (1 - u[:, 0]) + rn[lo + 1] * u[:, 0]
        parts.append(_tube(path, rad, normal, float(surf.flatness[f]), close_end=True))
    if surf.stub_mm > 0:   # past the wrist, along the forearm's line
        back = _unit(kp[0] - kp[9])
        path = kp[0] + np.outer(np.linspace(-0.5 * half_t, surf.stub_mm * g, 5), back)
        parts.append(_tube(path, np.full(5, w), normal, float(half_t / w), close_end=False))
    V, F, off = [], [], 0
    for v, f in parts:
        V.append(v)
        F.append(f + off)
        off += len(v)
    return Mesh(np.vstack(V), np.vstack(F), label, closed=False)
