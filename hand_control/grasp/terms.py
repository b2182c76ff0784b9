"""Energy terms of the closing-phase synthesis (dissertation eq. III.4-III.9), vectorised over
particles and frames.

Everything is evaluated in the object's body frame (origin at the centre of mass, z up; the
object rests on a support plane ``z = -bottom``). A closing motion comes from the deformable
model in the object frame of III.3, whose x axis points from the hand to the object; a yaw
``theta`` about z maps it onto the body frame (``p_body = Rz(theta) p``), so the synthesis
chooses the approach direction as well.

Units: distances in the terms are in millimetres and angles in radians, the scale at which
the dissertation's weights (w_p 0.06, w_c 0.9, w_k 1.0, w_d 0.4, w_q 2.0; w1 0.06, w2 4.0;
penetration penalty d = 10) balance (a 5 mm contact error weighs 2, a penetrating frame 10).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.hand import HandModel
from hand_capture.model.skeleton import BONE_INDEX, BONE_NAMES, LEVELS
from hand_control.errors import InputError
from hand_control.grasp.objects import SignedDistanceField

__all__ = ["ContactPoints", "EnergyWeights", "HandGeometry", "collision_term",
           "contact_distance_term", "grasp_quality_terms", "rot_z"]


@dataclass(frozen=True)
class EnergyWeights:
    """Weights of eq. (III.4) and (III.9) and the penalty of eq. (III.7)."""

    w_p: float = param(0.06, "motion prior weight (eq. III.4)", lo=0.0)
    w_c: float = param(0.9, "motion control weight (eq. III.4)", lo=0.0)
    w_k: float = param(1.0, "collision weight (eq. III.4); 0 = ablation", lo=0.0)
    w_d: float = param(0.4, "contact distance weight (eq. III.4)", lo=0.0)
    w_q: float = param(2.0, "grasp quality weight (eq. III.4)", lo=0.0)
    w1: float = param(0.06, "contact polygon weight (eq. III.9); 0 = ablation", lo=0.0)
    w2: float = param(4.0, "friction cone weight (eq. III.9); 0 = ablation", lo=0.0)
    penetration_penalty: float = param(10.0, "d of eq. (III.7)", lo=0.0)
    penetration_tolerance: float = param(
        0.002, "a hand capsule counts as penetrating beyond this depth [m] (the field's voxel)",
        lo=0.0, hi=0.02)

    def __post_init__(self) -> None:
        validate(self)


def rot_z(theta: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations about z by ``theta`` [rad]."""
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros(np.shape(theta) + (3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 1, 0], r[..., 1, 1] = c, -s, s, c
    r[..., 2, 2] = 1.0
    return r


@dataclass(frozen=True, eq=False)
class ContactPoints:
    """The contact points of a grip mode on the hand: bone indices (C,) and points in the bone
    frames (C, 3) [m] (the skin where the bone touches the object)."""

    bones: np.ndarray
    local: np.ndarray

    def __post_init__(self) -> None:
        b = np.asarray(self.bones, dtype=np.int64)
        p = np.asarray(self.local, dtype=np.float64)
        if b.ndim != 1 or p.shape != (len(b), 3) or not np.isfinite(p).all() or len(b) == 0:
            raise InputError(f"contact points need C bones and (C, 3) finite local points, "
                             f"got {b.shape} and {p.shape}")
        if (b < 0).any() or (b >= len(BONE_NAMES)).any():
            raise InputError(f"contact bones must be in 0..{len(BONE_NAMES) - 1}")
        object.__setattr__(self, "bones", b)
        object.__setattr__(self, "local", p)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(BONE_NAMES[b] for b in self.bones)

    @property
    def is_thumb(self) -> np.ndarray:
        """(C,) contacts on the thumb (the antagonist of every other finger, III.4.1.2)."""
        return np.array([BONE_NAMES[b].startswith("thumb") for b in self.bones])

    @staticmethod
    def fingertips(fingers: tuple[str, ...], model: HandModel | None = None) -> ContactPoints:
        """The fingertip pads of ``fingers`` (HandModel's pad points on the distal bones)."""
        model = model or HandModel()
        order = ("thumb", "index", "middle", "ring", "little")
        bad = [f for f in fingers if f not in order]
        if bad:
            raise InputError(f"unknown fingers {bad}; valid: {order}")
        idx = [order.index(f) for f in fingers]
        return ContactPoints(LEVELS[2][idx], model._pad_local[idx])

    @staticmethod
    def from_names(bones: list[str], local: np.ndarray) -> ContactPoints:
        unknown = [b for b in bones if b not in BONE_INDEX]
        if unknown:
            raise InputError(f"unknown bones {unknown}; valid: {BONE_NAMES}")
        return ContactPoints(np.array([BONE_INDEX[b] for b in bones]), local)


class HandGeometry:
    """The hand's collision capsules as sample points for field lookups, and batched FK.

    Args:
        model: the hand (default: the template right hand the simulation exports).
        samples: points per capsule along its axis (ends included).
    """

    def __init__(self, model: HandModel | None = None, samples: int = 3) -> None:
        self.model = model or HandModel()
        caps = self.model.capsules
        s = np.linspace(0.0, 1.0, samples)
        self.bones = np.repeat([c.bone for c in caps], samples)
        self.local = np.concatenate([c.p0[None] + s[:, None] * (c.p1 - c.p0)[None]
                                     for c in caps])
        self.radii = np.repeat([c.radius for c in caps], samples)

    def frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bone rotations (..., 16, 3, 3) and origins (..., 16, 3) of poses (..., 27)."""
        lead = q.shape[:-1]
        rot, pos = self.model._fk(np.ascontiguousarray(q.reshape(-1, q.shape[-1])))
        return rot.reshape(lead + rot.shape[1:]), pos.reshape(lead + pos.shape[1:])

    @staticmethod
    def points(rot: np.ndarray, pos: np.ndarray, bones: np.ndarray, local: np.ndarray
               ) -> np.ndarray:
        """Points fixed in bones: (..., N, 3) for bone frames (..., 16, 3, 3), (..., 16, 3)."""
        return np.matmul(rot[..., bones, :, :], local[:, :, None])[..., 0] + pos[..., bones, :]


def collision_term(sdf: SignedDistanceField, points: np.ndarray, radii: np.ndarray,
                   floor_z: float | None, penalty: float = 10.0, tolerance: float = 0.002
                   ) -> np.ndarray:
    """Eq. (III.6)-(III.7): mean over frames of ``d`` for every frame in which a hand capsule
    penetrates the object (or the support plane ``z = floor_z``) deeper than ``tolerance``
    (the field read at the nearest voxel: a yes/no test of many points).

    Args:
        points: (P, F, S, 3) capsule sample points in the body frame [m].
        radii: (S,) their capsule radii [m].

    Returns:
        (P,) the term per particle.
    """
    depth = radii - sdf.nearest(points)  # > 0: inside the object
    hit = (depth > tolerance).any(axis=-1)
    if floor_z is not None:
        hit |= ((floor_z + radii - points[..., 2]) > tolerance).any(axis=-1)
    return penalty * hit.mean(axis=-1)


def contact_distance_term(sdf: SignedDistanceField, contacts: np.ndarray) -> np.ndarray:
    """Eq. (III.8): sum over contact points of the distance to their closest surface point,
    ``|f(x; p_i) - O_i| = |sdf(f(x; p_i))|`` [mm], for contacts (P, C, 3) in the body frame."""
    return 1e3 * np.abs(sdf(contacts)).sum(axis=-1)


def grasp_quality_terms(sdf: SignedDistanceField, contacts: np.ndarray, is_thumb: np.ndarray,
                        mu: float) -> tuple[np.ndarray, np.ndarray]:
    """The two grasp metrics of eq. (III.9) at the grasp pose, contacts (P, C, 3) body frame.

    * ``E_g^1 = |CM - C|`` [mm]: distance of the centroid of the contact polygon (the contacts'
      closest surface points) from the centre of mass (the body frame's origin).
    * ``E_g^2 = sum_pairs (a_1 + a_2)`` [rad]: for every antagonist pair (the thumb against
      each other contact), the angles between the line joining the two surface points and the
      inward normals there, beyond the friction cone's half angle ``atan(mu)``.

    Returns:
        ``(E_g1, E_g2)``, (P,) each.
    """
    surf, normal, _ = sdf.closest(contacts)
    eg1 = 1e3 * np.linalg.norm(surf.mean(axis=-2), axis=-1)
    th = np.nonzero(is_thumb)[0]
    ot = np.nonzero(~np.asarray(is_thumb))[0]
    eg2 = np.zeros(contacts.shape[0])
    if len(th) == 0 or len(ot) == 0:
        return eg1, eg2
    phi = math.atan(mu)
    a = surf[:, th][:, :, None, :]  # (P, T, 1, 3)
    b = surf[:, ot][:, None, :, :]  # (P, 1, O, 3)
    line = b - a
    line /= np.maximum(np.linalg.norm(line, axis=-1, keepdims=True), 1e-9)
    n_a = -normal[:, th][:, :, None, :]  # inward normals
    n_b = -normal[:, ot][:, None, :, :]
    ang_a = np.arccos(np.clip((line * n_a).sum(-1), -1.0, 1.0))
    ang_b = np.arccos(np.clip((-line * n_b).sum(-1), -1.0, 1.0))
    eg2 = (np.maximum(ang_a - phi, 0.0) + np.maximum(ang_b - phi, 0.0)).sum(axis=(1, 2))
    return eg1, eg2
