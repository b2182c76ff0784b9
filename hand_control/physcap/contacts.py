"""Contact-based sampling (seed 000 sec. 6, Fig. 8 right).

From the reference pose (a noisy kinematic capture) the closest distance between the object and
every finger bone tells which bones may touch it: below a threshold a contact is *potential*,
with equal probability of contact and no contact. The ``2^k`` configurations of ``k`` potential
contacts, each with its probability, are enumerated (:func:`contact_configurations`); a sampled
configuration is made consistent by inverse kinematics (:class:`ContactIK`: each finger is
closed until its most distal contacting bone reaches the object, or opened until none of its
bones is near it); the resulting *seed* poses are the centres of the sampling hypercubes.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import mujoco
import numpy as np

from hand_capture.model.joints import FINGERS, JOINT_LIMITS
from hand_capture.model.skeleton import BONE_FLEX_DOF, BONE_NAMES

__all__ = ["FINGER_BONES", "ContactConfigurations", "ContactIK", "contact_configurations"]

#: bone indices (BONE_NAMES) of each finger, proximal to distal
FINGER_BONES: dict[str, tuple[int, ...]] = {
    f: tuple(i for i, b in enumerate(BONE_NAMES) if b.startswith(f + "_")) for f in FINGERS}
_BONE_FINGER = {b: f for f, bones in FINGER_BONES.items() for b in bones}


@dataclass(frozen=True, eq=False)
class ContactConfigurations:
    """The contact configurations consistent with a reference pose.

    bones: (k,) bone indices (BONE_NAMES) of the potential contacts, nearest first.
    distances: (n_bones,) closest bone-object distance of every bone [m] (signed).
    configs: (2^k, k) bool, row j = which potential contacts touch in configuration j.
    probabilities: (2^k,) probability of each configuration (sums to 1).
    """

    bones: np.ndarray
    distances: np.ndarray
    configs: np.ndarray
    probabilities: np.ndarray


def contact_configurations(distances: np.ndarray, threshold: float, max_contacts: int,
                           candidates: np.ndarray | None = None,
                           p_contact: float = 0.5) -> ContactConfigurations:
    """Enumerate the contact configurations of sec. 6.

    Args:
        distances: (n_bones,) closest distance of each bone to the object [m].
        threshold: a bone closer than this is a potential contact [m].
        max_contacts: at most this many potential contacts (the nearest).
        candidates: bone indices that may count (default: every finger bone).
        p_contact: probability of "contact" of each potential contact (sec. 6: 0.5).

    Returns:
        the potential contacts and the ``2^k`` configurations with their probabilities
        ``p^c (1 - p)^(k - c)`` (c contacts in the configuration).
    """
    d = np.asarray(distances, dtype=np.float64)
    cand = np.array(sorted(_BONE_FINGER) if candidates is None else candidates, dtype=np.int64)
    near = cand[d[cand] < threshold]
    near = near[np.argsort(d[near], kind="stable")][:max(0, int(max_contacts))]
    k = near.size
    configs = np.array(list(itertools.product((False, True), repeat=k)),
                       dtype=bool).reshape(2 ** k, k)
    c = configs.sum(axis=1)
    probs = p_contact ** c * (1.0 - p_contact) ** (k - c)
    return ContactConfigurations(near, d.copy(), configs, probs / probs.sum())


class ContactIK:
    """Bone-object distances and per-finger inverse kinematics on a MuJoCo model of the
    scene (kinematics only, its own ``MjData``).

    Args:
        model: the capture's MuJoCo model (hand bodies named as BONE_NAMES, one capsule each).
        object_qpos: qpos address of the object's free joint.
        object_geoms: the object's geom ids.
        depth: a contacting bone is placed this far into the object [m].
        clearance: a non-contacting finger keeps this distance [m].
    """

    GRID = np.linspace(-0.6, 0.9, 16)  # closure offsets tried [rad], refined by bisection

    def __init__(self, model: mujoco.MjModel, object_qpos: int, object_geoms: np.ndarray,
                 depth: float, clearance: float) -> None:
        self.m = model
        self.d = mujoco.MjData(model)
        self.obj_adr = int(object_qpos)
        self.obj_geoms = [int(g) for g in object_geoms]
        self.depth, self.clearance = float(depth), float(clearance)
        self.bone_geoms: list[list[int]] = []
        for b in BONE_NAMES:
            bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b)
            self.bone_geoms.append([int(g) for g in np.flatnonzero(model.geom_bodyid == bid)])
        self.flex = {f: np.array([BONE_FLEX_DOF[b] for b in bones], dtype=np.int64)
                     for f, bones in FINGER_BONES.items()}
        lim = np.asarray(JOINT_LIMITS, dtype=np.float64)
        self.lo, self.hi = lim[:, 0], lim[:, 1]
        self._q = np.zeros(27)

    def _set(self, q: np.ndarray) -> None:
        self.d.qpos[0:27] = q
        mujoco.mj_kinematics(self.m, self.d)

    def set_object(self, object_pose: np.ndarray) -> None:
        """Place the object (7,) for the following queries."""
        self.d.qpos[self.obj_adr:self.obj_adr + 7] = object_pose

    def _bone_distance(self, b: int) -> float:
        m, d = self.m, self.d
        return min(mujoco.mj_geomDistance(m, d, g, o, 0.2, None)
                   for g in self.bone_geoms[b] for o in self.obj_geoms)

    def distances(self, q: np.ndarray) -> np.ndarray:
        """(n_bones,) signed closest distance of each bone to the object at pose ``q``."""
        self._set(q)
        return np.array([self._bone_distance(b) if self.bone_geoms[b] else np.inf
                         for b in range(len(BONE_NAMES))])

    def _finger_pose(self, q: np.ndarray, finger: str, delta: float) -> np.ndarray:
        out = q.copy()
        idx = self.flex[finger]
        out[idx] = np.clip(q[idx] + delta, self.lo[idx], self.hi[idx])
        return out

    def _measure(self, q: np.ndarray, finger: str, delta: float, bone: int | None) -> float:
        """Distance of ``bone`` (or, ``None``, of the nearest bone of the finger) after
        closing the finger by ``delta``."""
        self._set(self._finger_pose(q, finger, delta))
        bones = FINGER_BONES[finger] if bone is None else (bone,)
        return min(self._bone_distance(b) for b in bones)

    def solve_finger(self, q: np.ndarray, finger: str, bone: int | None) -> np.ndarray:
        """The finger's flex joints changed by one closure offset (the smallest that works):
        ``bone`` given: it reaches ``-depth`` (in contact); ``None``: every bone of the finger
        keeps ``clearance``. Returns the new (27,) pose (the other joints as in ``q``)."""
        want = -self.depth if bone is not None else self.clearance
        if bone is None and self._measure(q, finger, 0.0, None) >= want:
            return q.copy()  # already clear
        f = np.array([self._measure(q, finger, g, bone) for g in self.GRID]) - want
        # bone: f > 0 is "not yet touching"; None: f < 0 is "too close"
        ok = f <= 0 if bone is not None else f >= 0
        if not ok.any():  # unreachable: the closest the grid gets
            return self._finger_pose(q, finger, float(self.GRID[np.argmin(np.abs(f))]))
        # the sign change nearest to zero offset, refined by bisection
        best = None
        for i in range(len(self.GRID) - 1):
            if ok[i] != ok[i + 1]:
                a, b = self.GRID[i], self.GRID[i + 1]
                if best is None or min(abs(a), abs(b)) < min(abs(best[0]), abs(best[1])):
                    best = (a, b, ok[i])
        if best is None:  # ok everywhere: no change needed
            return q.copy()
        a, b, ok_a = best
        for _ in range(6):
            mid = 0.5 * (a + b)
            v = self._measure(q, finger, mid, bone) - want
            ok_mid = v <= 0 if bone is not None else v >= 0
            if ok_mid == ok_a:
                a = mid
            else:
                b = mid
        return self._finger_pose(q, finger, float(a if ok_a else b))

    def seeds(self, q_ref: np.ndarray, cc: ContactConfigurations
              ) -> tuple[np.ndarray, dict[tuple[str, int | None], np.ndarray]]:
        """The seed pose of every configuration of ``cc`` around ``q_ref``: (2^k, 27).

        Per finger with potential contacts: its most distal contacting bone touches, or (no
        contact in the configuration) the finger is opened to the clearance. Fingers without
        potential contacts keep the reference. Returns the seeds and the per-finger solutions
        (``(finger, bone or None) -> finger joint values``) they combine.
        """
        fingers = sorted({_BONE_FINGER[int(b)] for b in cc.bones})
        solutions: dict[tuple[str, int | None], np.ndarray] = {}
        seeds = np.tile(np.asarray(q_ref, dtype=np.float64), (cc.configs.shape[0], 1))
        for f in fingers:
            idx = self.flex[f]
            cols = [j for j, b in enumerate(cc.bones) if _BONE_FINGER[int(b)] == f]
            for row, cfg in enumerate(cc.configs):
                touching = [int(cc.bones[j]) for j in cols if cfg[j]]
                key = (f, max(touching) if touching else None)  # the most distal bone
                if key not in solutions:
                    solutions[key] = self.solve_finger(q_ref, f, key[1])[idx]
                seeds[row, idx] = solutions[key]
        return seeds, solutions
