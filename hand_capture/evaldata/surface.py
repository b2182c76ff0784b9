"""A second hand surface family: capsules and ellipsoids on the skeleton's keypoints.

Built independently of the suite's template mesh and its skinning (``hand_capture.model.
mesh``): only the skeleton's keypoints and bone frames (forward kinematics of
:class:`~hand_capture.model.HandModel`) are used, and every surface element is placed on
them here. Per sample (:func:`sample_surface`) the finger thickness (per finger and
phalanx), the palm's outline, thickness and shape (an ellipsoid, or a slab of capsules),
the thenar bulge and the nails (present or not, thickness, length) vary, and optionally a
forearm (tapered chain of capsules out of the frame, at a random wrist angle) with or
without a sleeve.

Right hands (the model's default side); labels of the primitives: 1 hand, 2 forearm,
3 sleeve (clutter is 4, see :mod:`hand_capture.evaldata.scene`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hand_capture.evaldata.raycast import Capsule, Ellipsoid
from hand_capture.model import HandModel
from hand_capture.model.skeleton import KEYPOINT_BONE

__all__ = ["HAND", "FOREARM", "SLEEVE", "SurfaceParams", "hand_primitives", "sample_surface"]

HAND, FOREARM, SLEEVE = 1, 2, 3

#: keypoint chains per finger (thumb, index, middle, ring, little): base .. tip
_CHAINS = ((1, 2, 3, 4), (5, 6, 7, 8), (9, 10, 11, 12), (13, 14, 15, 16), (17, 18, 19, 20))
#: nominal finger radii [mm] per phalanx (proximal, middle, distal) for s_g = 1
_RADII_MM = np.array([[11.0, 9.5, 8.5], [9.5, 8.6, 7.6], [10.0, 8.9, 7.9], [9.3, 8.3, 7.4],
                      [8.2, 7.3, 6.6]])


@dataclass(frozen=True)
class SurfaceParams:
    """One held-out subject's surface (lengths in metres, for a hand of global scale 1;
    :func:`hand_primitives` multiplies them by the skeleton's scale)."""

    finger_radii: np.ndarray        # (5, 3) [m]
    palm_half_thickness: float      # [m]
    palm_margin: float              # outline beyond the index / little MCPs [m]
    palm_slab: bool                 # True: capsule slab; False: one ellipsoid
    thenar: float                   # thenar bulge radius [m]
    nails: bool
    nail_thickness: float           # [m]
    nail_length: float              # share of the distal phalanx
    forearm: bool
    forearm_radius: tuple[float, float]   # at the wrist, 25 cm up the arm [m]
    wrist_flex: float               # forearm angle to the palm: flexion [rad]
    wrist_dev: float                # ... and radial/ulnar deviation [rad]
    sleeve: bool
    sleeve_start: float             # distance from the wrist [m]
    sleeve_extra: float             # sleeve radius beyond the arm [m]


def sample_surface(rng: np.random.Generator, *, forearm: bool | None = None,
                   sleeve: bool | None = None) -> SurfaceParams:
    """A random surface of the family; ``forearm`` / ``sleeve`` None = drawn at random."""
    thick = rng.uniform(0.85, 1.2)
    radii = _RADII_MM * thick * rng.uniform(0.94, 1.06, (5, 1)) * rng.uniform(0.96, 1.04,
                                                                              (5, 3))
    fa_draw, sl_draw = rng.random(2) < 0.5   # drawn always: same subject either way
    fa = bool(fa_draw) if forearm is None else forearm
    sl = bool(sl_draw) if sleeve is None else sleeve
    return SurfaceParams(
        finger_radii=radii * 1e-3,
        palm_half_thickness=rng.uniform(0.011, 0.017),
        palm_margin=rng.uniform(0.002, 0.010),
        palm_slab=bool(rng.random() < 0.5),
        thenar=rng.uniform(0.011, 0.016),
        nails=bool(rng.random() < 0.75),
        nail_thickness=rng.uniform(0.0006, 0.0018),
        nail_length=rng.uniform(0.45, 0.8),
        forearm=fa,
        forearm_radius=(rng.uniform(0.022, 0.030), rng.uniform(0.030, 0.040)),
        wrist_flex=math.radians(rng.uniform(-35, 35)),
        wrist_dev=math.radians(rng.uniform(-20, 20)),
        sleeve=fa and sl,
        sleeve_start=rng.uniform(0.04, 0.15),
        sleeve_extra=rng.uniform(0.012, 0.03),
    )


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def hand_primitives(model: HandModel, q: np.ndarray, p: SurfaceParams) -> list:
    """The primitives of the hand (and forearm / sleeve) in pose ``q`` (27,), camera frame.

    The skeleton's size is ``model.shape.global_scale``; surface sizes scale with it.
    """
    s = float(model.shape.global_scale)
    fk = model.forward(q)
    kp = fk.joint_positions
    frames = fk.joint_frames
    rest = model.forward(np.zeros(27)).joint_frames
    # dorsal direction per bone: the rest frame's +z (back of a right hand) carried by the bone
    dorsal = np.einsum("bij,bkj,k->bi", frames[:, :3, :3], rest[:, :3, :3],
                       np.array([0.0, 0.0, 1.0]))
    prims: list = []
    for f, chain in enumerate(_CHAINS):
        for j in range(3):
            a, b = kp[chain[j]], kp[chain[j + 1]]
            r = float(p.finger_radii[f, j]) * s
            if j == 2:  # the fingertip ends at the tip keypoint
                ax = b - a
                ln = float(np.linalg.norm(ax))
                b = a + ax * max(0.2, (ln - 0.8 * r) / ln)
            prims.append(Capsule(a, b, r, HAND))
        if p.nails:
            a, b = kp[chain[2]], kp[chain[3]]
            ax = (b - a) / np.linalg.norm(b - a)
            n = dorsal[KEYPOINT_BONE[chain[3]]]
            n = n - (n @ ax) * ax
            n /= np.linalg.norm(n)
            r = float(p.finger_radii[f, 2]) * s
            ln = float(np.linalg.norm(b - a)) * p.nail_length
            c = b - ax * (0.5 * ln + 0.6 * r) + n * (r - 0.0025 * s)
            e2 = np.cross(n, ax)
            prims.append(Ellipsoid(c, np.stack([ax, e2, n], axis=1),
                                   np.array([0.5 * ln, 0.75 * r,
                                             0.0025 * s + p.nail_thickness]), HAND))
    # palm: wrist (0), index MCP (5), middle MCP (9), little MCP (17)
    w, i5, m9, l17 = kp[0], kp[5], kp[9], kp[17]
    along = m9 - w
    length = float(np.linalg.norm(along))
    along /= length
    n = dorsal[0] - (dorsal[0] @ along) * along
    n /= np.linalg.norm(n)
    lat = np.cross(n, along)
    ht = p.palm_half_thickness * s
    width = 0.5 * abs(float((i5 - l17) @ lat)) + p.palm_margin * s
    if p.palm_slab:
        pad = p.palm_margin * s
        i_side, l_side = i5 + lat * pad * np.sign((i5 - l17) @ lat), \
            l17 - lat * pad * np.sign((i5 - l17) @ lat)
        w_i = w + (i_side - w) * 0.15 - along * 0.005 * s
        w_l = w + (l_side - w) * 0.15 - along * 0.005 * s
        for a, b in ((i_side, l_side), (w_i, i_side), (w_l, l_side), (w_i, w_l),
                     (w, m9), (0.5 * (w_i + i_side), 0.5 * (w_l + l_side))):
            prims.append(Capsule(a, b, ht, HAND))
    else:
        c = w + along * 0.52 * length
        prims.append(Ellipsoid(c, np.stack([along, lat, n], axis=1),
                               np.array([0.6 * length, width, ht]), HAND))
    # thenar bulge between the wrist and the thumb's base, on the palm side
    t1, t2 = kp[1], kp[2]
    prims.append(Capsule(w + 0.3 * (t1 - w) - n * 0.2 * ht, t1 + 0.3 * (t2 - t1),
                         p.thenar * s, HAND))
    if p.forearm:
        back = -along
        back = _rot(lat, p.wrist_flex) @ back
        back = _rot(n, p.wrist_dev) @ back
        # an arm held at least 35 deg off the optical axis (it runs out of the image)
        lim = math.cos(math.radians(35.0))
        if abs(back[2]) > lim and np.linalg.norm(back[:2]) > 1e-9:
            xy = back[:2] / np.linalg.norm(back[:2])
            back = np.r_[xy * math.sqrt(1 - lim ** 2), math.copysign(lim, back[2])]
        r0, r1 = (r * s for r in p.forearm_radius)
        start = w + along * 0.006 * s
        pts = [start + back * x for x in (0.0, 0.07, 0.15, 0.26, 0.60)]
        rs = [r0, r0 + 0.3 * (r1 - r0), r0 + 0.7 * (r1 - r0), r1, r1 * 1.1]
        for k in range(4):
            prims.append(Capsule(pts[k], pts[k + 1], 0.5 * (rs[k] + rs[k + 1]), FOREARM))
        if p.sleeve:
            s0 = start + back * p.sleeve_start
            prims.append(Capsule(s0, start + back * 0.6, r1 + p.sleeve_extra, SLEEVE))
    return prims
