"""Retargeting a captured control (seed 000 sec. 7.2): the hand and object targets of an
optimised capture applied to a new object, whose centre of mass and principal axes are aligned
with the source object's (longest axis on longest axis), or to the same object with another
mass or friction. The new simulation shows whether the control still carries the object:
where it is physically possible it does, and at a very low friction the object slips out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.model.joints import matrix_to_quat_wxyz
from hand_control.physcap.capture import CapturedObject, PhysCapResult
from hand_control.physcap.optimise import _goal_figures, quat_mul, replay_control
from hand_control.physcap.world import mesh_principal_frame, object_half_height, object_spec

__all__ = ["RetargetOutcome", "align_object", "principal_half_extents", "retarget"]


@dataclass(frozen=True, eq=False)
class RetargetOutcome:
    """One retargeted simulation: its object, and whether it carried the object to the
    source's final position (within ``success_tolerance``) without dropping it."""

    label: str
    obj: CapturedObject
    success: bool
    dropped: bool
    final_error_m: float
    lift_m: float
    object_pose: np.ndarray  # (T, 7) simulated


def principal_half_extents(obj: CapturedObject) -> np.ndarray:
    """(3,) half extents [m] of the collision shape along the object frame's x, y, z (the
    principal axes of a uniform primitive)."""
    if obj.kind == "mesh":
        return mesh_principal_frame(obj.mesh)[2]
    spec = object_spec(obj)
    s = spec.size
    if spec.kind == "ball":
        return np.full(3, s[0])
    if spec.kind == "stick":  # along x
        return np.array([s[1], s[0], s[0]])
    return np.asarray(s, float)


def align_object(source: CapturedObject, source_pose: np.ndarray, target: CapturedObject
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The pose (7,) of ``target`` aligned with ``source`` at ``source_pose``: the same centre
    of mass in x, y (resting on the table) and principal axes matched by length (sec. 7.2);
    and the body-frame rotation (quaternion) from the target's frame to the source's."""
    es, et = principal_half_extents(source), principal_half_extents(target)
    ps, pt = np.argsort(-es, kind="stable"), np.argsort(-et, kind="stable")
    if es.max() < 1.05 * es.min():  # an isotropic source has no major axis: the target's
        # longest axis goes along the source frame's most vertical axis (standing it up)
        w, x, y, z = np.asarray(source_pose[3:7], float)
        up = np.abs([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
        first = int(np.argmax(up))
        ps = np.array([first] + [i for i in range(3) if i != first])
    m = np.zeros((3, 3))
    m[ps, pt] = 1.0  # target axis pt[i] -> source axis ps[i]
    if np.linalg.det(m) < 0:
        m[:, pt[2]] *= -1.0
    q_align = matrix_to_quat_wxyz(m)
    quat = quat_mul(source_pose[3:7], q_align)
    quat = quat / np.linalg.norm(quat)
    pos = np.asarray(source_pose[0:3], float).copy()
    pos[2] = object_half_height(target, quat) + 1e-4
    return np.r_[pos, quat], q_align


def retarget(result: PhysCapResult, target: CapturedObject | None = None, *,
             mass: float | None = None, friction: float | None = None,
             label: str = "") -> RetargetOutcome:
    """Apply ``result``'s control to ``target`` (default: the captured object) with
    optionally another ``mass`` [kg] / ``friction``; success as in the optimisation (the
    final position of the source's simulated motion, shifted by the new resting height)."""
    src = result.obj
    tgt = target or src
    pose0, q_align = align_object(src, result.object_pose[0], tgt)
    dz = pose0[2] - result.object_pose[0, 2]
    obj_targets = result.object_targets.copy()
    obj_targets[:, 2] += dz
    obj_targets[:, 3:7] = quat_mul(obj_targets[:, 3:7], q_align[None])
    _, pose, _ = replay_control(tgt, result.hand_q[0], pose0, result.targets, obj_targets,
                                result.config, mass=mass, friction=friction)
    goal = result.object_pose.copy()
    goal[:, 2] += dz
    reached, dropped, final = _goal_figures(result.config, pose, goal)
    lift = float(np.nanmax(pose[:, 2]) - pose[0, 2]) if np.isfinite(pose).any() else 0.0
    return RetargetOutcome(label or tgt.kind, tgt, bool(reached and not dropped), dropped,
                           final, lift, pose)
