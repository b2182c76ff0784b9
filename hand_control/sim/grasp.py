"""Grasp poses by fingertip inverse kinematics onto contact points on the object's surface.

A grasp is planned, not hand-tuned: contact points are laid out on the object's surface with
the thumb opposing the fingers (precision grasp from above: index and middle pads on the far
side of the object, the thumb pad on the near side, at the height of the centre of mass), and
the hand pose that puts each fingertip pad there is found by damped least-squares inverse
kinematics on the MuJoCo model itself (``mj_jac`` of the fingertip points), over all 27 DoFs:
the wrist places itself, the palm is held above the object and palm-down by a prior, finger
joints stay inside their limits.

The fingertip pad is the centre of the distal capsule's end cap; its target is the contact
point moved out along the surface normal by the cap radius minus ``depth`` (a small
interpenetration that the PD servos turn into a squeeze, the same for every controller).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from hand_capture.model.joints import JOINT_LIMITS, JOINT_NAMES, quat_wxyz_to_matrix
from hand_control.contact.types import ContactSet
from hand_control.errors import InputError, SolverError

__all__ = ["GraspPlan", "fingertip_ik", "plan_grasp", "surface_contacts"]

#: fingers that touch the object in the default precision grasp; the thumb opposes them
GRASP_FINGERS: tuple[str, ...] = ("thumb", "index", "middle")


def surface_contacts(kind: str, size: Sequence[float], center: Sequence[float],
                     quat_wxyz: Sequence[float] = (1, 0, 0, 0),
                     fingers: Sequence[str] = GRASP_FINGERS, spread: float = 0.4,
                     upright_cylinder: bool = False, height: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Contact points on an object's surface and their outward normals, world frame.

    The fingers other than the thumb share the far side (+x of the world, away from the
    wrist), spread across it; the thumb is on the near side (-x), opposing them.

    Args:
        kind: ``box`` (half extents), ``ball`` (radius) or ``stick`` (radius, half length;
            ``upright_cylinder`` when it stands on its end).
        spread: lateral spread of the fingers as a fraction of the object's half width.
        height: height of the contacts above the centre [m] (world z).

    Returns:
        ``(points, outward_normals)``, (F, 3) each, in the order of ``fingers``.
    """
    rot = quat_wxyz_to_matrix(quat_wxyz)
    c = np.asarray(center, dtype=np.float64) + np.array([0.0, 0.0, height])
    others = [f for f in fingers if f != "thumb"]
    lat = np.linspace(spread, -spread, len(others)) if len(others) > 1 else np.zeros(1)
    pts, nrm = [], []
    if kind == "box":
        hx, hy, _ = size
        # world directions expressed in the box frame (the box may be rotated about z)
        ex = rot.T @ np.array([1.0, 0.0, 0.0])
        ax = int(np.argmax(np.abs(ex[:2])))  # box axis closest to world x
        sx = np.sign(ex[ax])
        half = (hx, hy)
        lat_ax = 1 - ax
        for f in fingers:
            p = np.zeros(3)
            n = np.zeros(3)
            if f == "thumb":
                p[ax], n[ax] = -sx * half[ax], -sx
            else:
                p[ax], n[ax] = sx * half[ax], sx
                p[lat_ax] = lat[others.index(f)] * half[lat_ax]
            pts.append(c + rot @ p)
            nrm.append(rot @ n)
    elif kind in ("ball", "stick"):
        r = size[0]
        if kind == "stick" and not upright_cylinder:
            raise InputError("a lying stick has no precision-grasp layout; stand it upright")
        for f in fingers:
            if f == "thumb":
                d = np.array([-1.0, 0.0, 0.0])
            else:
                a = 0.9 * lat[others.index(f)]  # angle from the far side [rad]
                d = np.array([np.cos(a), np.sin(a), 0.0])
            pts.append(c + r * d)
            nrm.append(d)
    else:
        raise InputError(f"no grasp layout for object kind {kind!r}")
    return np.array(pts), np.array(nrm)


@dataclass(frozen=True, eq=False)
class GraspPlan:
    """A planned grasp: contact points, the grasp pose and an open pre-grasp pose.

    Attributes:
        fingers: the contacting fingers.
        points, normals: (F, 3) contact points on the surface and the normals pointing from the
            hand into the object, world frame at the object's initial pose.
        q_grasp, q_pregrasp: (27,) hand poses (JOINT_NAMES order).
        residual: (F,) IK distance of each fingertip pad to its target [m].
        closing: (T, 27) a closing motion from ``q_pregrasp`` to ``q_grasp`` (a synthesised
            grasp, ``hand_control.grasp``), played over the closing phase; ``None``: the
            reference interpolates the two poses.
        reaching: (M, 27) a reaching motion ending at ``q_pregrasp``, played over the reaching
            phase (its first frame is the start pose); ``None``: from above, interpolated.
        source: ``"ik"`` (this module) or what made the plan.
    """

    object_name: str
    fingers: tuple[str, ...]
    points: np.ndarray
    normals: np.ndarray
    q_grasp: np.ndarray
    q_pregrasp: np.ndarray
    residual: np.ndarray
    closing: np.ndarray | None = None
    source: str = "ik"
    reaching: np.ndarray | None = None

    def contact_set(self, mu: float) -> ContactSet:
        """The planned contacts with friction ``mu`` (for the feasibility LP)."""
        return ContactSet(self.points, self.normals, mu)


def _tip_points(model: mujoco.MjModel) -> dict[str, tuple[int, np.ndarray, float]]:
    """Finger -> (distal body id, local centre of the distal capsule's end cap, cap radius)."""
    out = {}
    for f in ("thumb", "index", "middle", "ring", "little"):
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{f}_distal")
        if b < 0:
            continue
        geoms = np.nonzero(model.geom_bodyid == b)[0]
        caps = [g for g in geoms if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE]
        if not caps:
            continue
        g = caps[0]
        axis = quat_wxyz_to_matrix(model.geom_quat[g])[:, 2]
        ends = [model.geom_pos[g] + s * model.geom_size[g, 1] * axis for s in (1.0, -1.0)]
        end = max(ends, key=lambda e: float(np.linalg.norm(e)))
        out[f] = (int(b), end, float(model.geom_size[g, 0]))
    return out


def fingertip_ik(model: mujoco.MjModel, targets: dict[str, np.ndarray], q0: np.ndarray,
                 prior: np.ndarray, prior_weight: np.ndarray,
                 palm_target: np.ndarray | None = None, palm_weight: float = 0.3,
                 iterations: int = 300, damping: float = 1e-6,
                 avoid_geoms: Sequence[int] = (), clearance: float = 0.003
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Damped least squares IK of fingertip pad centres (and optionally the palm centre).

    Minimises ``sum_f |p_f(q) - t_f|^2 + w_palm |p_palm(q) - t_palm|^2
    + sum_i w_i (q_i - prior_i)^2`` over the 27 hand DoFs with joint limits, plus a
    collision term that pushes every hand capsule except the contacting fingertips out of the
    geoms ``avoid_geoms`` (the object) to ``clearance``: ``(clearance - dist) n . J``.

    Returns:
        ``(q, residuals)``: the pose (27,) and each fingertip's distance to its target [m].
    """
    d = mujoco.MjData(model)
    qadr = np.array([model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]
                     for n in JOINT_NAMES])
    dadr = np.array([model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]
                     for n in JOINT_NAMES])
    tips = _tip_points(model)
    missing = sorted(set(targets) - set(tips))
    if missing:
        raise InputError(f"no fingertip for {missing}")
    palm_site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "palm_center")
    jacp = np.zeros((3, model.nv))
    q = np.asarray(q0, dtype=np.float64).copy()
    lo, hi = JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1]
    wq = np.asarray(prior_weight, dtype=np.float64)
    names = list(targets)
    tip_bodies = {tips[f][0] for f in names}
    jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in JOINT_NAMES]
    hand_bodies = set(model.jnt_bodyid[jids].tolist())
    hand_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] in hand_bodies
                  and model.geom_bodyid[g] not in tip_bodies]
    fromto = np.zeros(6)

    def residuals() -> tuple[np.ndarray, np.ndarray]:
        rows, errs = [], []
        for f in names:
            b, local, _ = tips[f]
            p = d.xpos[b] + d.xmat[b].reshape(3, 3) @ local
            mujoco.mj_jac(model, d, jacp, None, p, b)
            rows.append(jacp[:, dadr].copy())
            errs.append(targets[f] - p)
        if palm_target is not None and palm_site >= 0:
            # only the height of the palm centre is held (it must stay above the object)
            p = d.site_xpos[palm_site]
            mujoco.mj_jacSite(model, d, jacp, None, palm_site)
            rows.append(palm_weight * jacp[2:3, dadr])
            errs.append(palm_weight * (palm_target[2:3] - p[2:3]))
        for og in avoid_geoms:
            for hg in hand_geoms:
                dist = mujoco.mj_geomDistance(model, d, hg, int(og), clearance, fromto)
                if dist >= clearance:
                    continue
                p_hand, p_obj = fromto[:3].copy(), fromto[3:].copy()
                n = p_obj - p_hand
                nn = np.linalg.norm(n)
                if nn < 1e-9:
                    continue
                n = -n / nn if dist >= 0 else n / nn  # the direction that separates them
                mujoco.mj_jac(model, d, jacp, None, p_hand, int(model.geom_bodyid[hg]))
                rows.append((n @ jacp[:, dadr])[None, :])
                errs.append(np.array([clearance - dist]))
        return np.vstack(rows), np.concatenate(errs)

    for _ in range(iterations):
        d.qpos[qadr] = q
        mujoco.mj_kinematics(model, d)
        mujoco.mj_comPos(model, d)
        jac, err = residuals()
        h = jac.T @ jac + np.diag(wq + damping)
        g = jac.T @ err + wq * (prior - q)
        dq = np.linalg.solve(h, g)
        step = np.linalg.norm(dq)
        if step > 0.2:
            dq *= 0.2 / step
        q = np.clip(q + dq, lo, hi)
        if step < 1e-7:
            break
    d.qpos[qadr] = q
    mujoco.mj_kinematics(model, d)
    res = []
    for f in names:
        b, local, _ = tips[f]
        tip = d.xpos[b] + d.xmat[b].reshape(3, 3) @ local
        res.append(float(np.linalg.norm(targets[f] - tip)))
    return q, np.array(res)


def _prior(root_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A relaxed grasping pose and per-DoF prior weights (root orientation held palm-down)."""
    q = np.zeros(len(JOINT_NAMES))
    w = np.full(len(JOINT_NAMES), 2e-6)
    q[0:3] = root_pos
    w[0:3] = 0.0          # the wrist places itself
    w[3:6] = 1e-5         # palm-down, fingers forward
    for f in ("index", "middle", "ring", "little"):
        q[JOINT_NAMES.index(f"{f}_mcp_flex")] = 0.5
        q[JOINT_NAMES.index(f"{f}_pip_flex")] = 0.8
        q[JOINT_NAMES.index(f"{f}_dip_flex")] = 0.4
    for f in ("ring", "little"):  # not contacting: kept near a light curl, out of the way
        for j in ("mcp_flex", "pip_flex", "dip_flex", "mcp_abd"):
            w[JOINT_NAMES.index(f"{f}_{j}")] = 1e-3
        q[JOINT_NAMES.index(f"{f}_mcp_flex")] = 0.2
        q[JOINT_NAMES.index(f"{f}_pip_flex")] = 0.3
        q[JOINT_NAMES.index(f"{f}_dip_flex")] = 0.2
    q[JOINT_NAMES.index("thumb_tm_abd")] = 0.6
    q[JOINT_NAMES.index("thumb_tm_flex")] = 0.3
    q[JOINT_NAMES.index("thumb_mcp_flex")] = 0.3
    q[JOINT_NAMES.index("thumb_ip_flex")] = 0.2
    return q, w


def plan_grasp(model: mujoco.MjModel, object_name: str, kind: str, size: Sequence[float],
               center: Sequence[float], quat_wxyz: Sequence[float] = (1, 0, 0, 0),
               fingers: Sequence[str] = GRASP_FINGERS, depth: float = 0.003,
               pregrasp_clearance: float = 0.03, palm_clearance: float = 0.012,
               upright_cylinder: bool = False, max_residual: float = 0.006,
               max_grasp_depth_below_top: float = 0.03) -> GraspPlan:
    """Plan a precision grasp of an object resting at ``center`` (see module docstring).

    Args:
        depth: how far the fingertip pads are aimed inside the surface [m].
        pregrasp_clearance: fingertip distance from the surface in the open pre-grasp [m].
        palm_clearance: height of the palm centre above the object's top [m].

    Raises:
        SolverError: a fingertip ends farther than ``max_residual`` from its target.
    """
    top = {"box": size[2] if len(size) > 2 else size[0], "ball": size[0],
           "stick": size[1] if upright_cylinder else size[0]}[kind]
    # tall objects are held near their top (the thumb's reach below the palm is limited)
    # a ball is held a little below its equator, where the contact normals point upwards
    height = max(0.0, top - max_grasp_depth_below_top) if kind != "ball" else -0.25 * size[0]
    points, out_n = surface_contacts(kind, size, center, quat_wxyz, fingers,
                                     upright_cylinder=upright_cylinder, height=height)
    tips = _tip_points(model)
    c = np.asarray(center, dtype=np.float64)
    palm_target = c + np.array([-0.01, 0.0, top + palm_clearance])
    prior, w = _prior(palm_target + np.array([-0.05, 0.0, 0.0]))
    targets = {f: points[i] + out_n[i] * (tips[f][2] - depth) for i, f in enumerate(fingers)}
    obj_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, object_name)
    avoid = np.nonzero(model.geom_bodyid == obj_body)[0] if obj_body >= 0 else ()
    q, res = fingertip_ik(model, targets, prior, prior, w, palm_target=palm_target,
                          avoid_geoms=avoid)
    if res.max() > max_residual:
        raise SolverError(f"grasp IK for {object_name!r} left fingertip residuals "
                          f"{np.round(res * 1e3, 1).tolist()} mm (> {max_residual * 1e3:.1f} mm)")
    # the open pre-grasp: the same wrist, fingertips backed off along the normals
    wpre = w.copy()
    wpre[0:6] = 1e3  # wrist fixed
    pre_t = {f: points[i] + out_n[i] * (tips[f][2] + pregrasp_clearance)
             for i, f in enumerate(fingers)}
    q_pre, _ = fingertip_ik(model, pre_t, q, q, wpre, avoid_geoms=avoid, clearance=0.01)
    return GraspPlan(object_name, tuple(fingers), points, -out_n, q, q_pre, res)
