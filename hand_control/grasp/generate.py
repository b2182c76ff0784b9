"""Build the grasp database with the suite's own tools (the Vicon database of III.3 is not
available; see :mod:`hand_control.grasp.database`).

One demonstration (:func:`demonstrate`):

1. an object (box, ball or upright cylinder) of random size, mass and friction, at a random
   place on the table, and a random approach heading of the hand;
2. the grip mode's contact layout on the object's surface: the thumb on the near side, the
   mode's other fingers spread over the far side (random spread, height, thumb offset);
3. the grasping pose by fingertip IK onto that layout (``hand_control.sim.grasp.fingertip_ik``)
   with a grip-mode posture prior (fingers that do not touch the object are curled or held out
   of the way), the open pre-grasp by IK with the fingertips backed off along the normals;
4. a human-like closing motion: every finger closes on its own randomised timeline (lag,
   speed profile), under a random global time warp, so that DTW has real warps to register;
   reaching from above, and manipulation (lift 10 cm, hold) by the scenario reference;
5. the check: the composite controller executes it in MuJoCo; the demonstration is kept only
   when the object rose at least 80 % of the lift and is still up at the end; the contacts at
   the grasping pose (end of the settle phase) are read from the simulation;
6. the motion, sampled at ``fps``, is stored in the object frame of III.3.

Everything is drawn from ``numpy.random.default_rng((seed, mode index, attempt))``: the same
seed gives the same database.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.joints import JOINT_INDEX, JOINT_LIMITS, JOINT_NAMES, N_DOF
from hand_control.errors import HandSuiteError
from hand_control.grasp.database import (
    GRIP_CONTACT_FINGERS,
    GRIP_MODES,
    GraspRecord,
    object_frame_yaw,
    to_object_frame,
)
from hand_control.sim.grasp import GraspPlan, _tip_points, fingertip_ik
from hand_control.sim.lockstep import LockstepRunner, build_world
from hand_control.sim.scenario import PHASES, Reference, RefSample, ScenarioSpec

__all__ = ["GenConfig", "TimedReference", "build_database", "demonstrate"]

_FINGER_GROUPS = ("thumb", "index", "middle", "ring", "little")


@dataclass(frozen=True)
class GenConfig:
    """How the database is generated."""

    demos_per_mode: int = param(12, "demonstrations kept per grip mode", lo=3, hi=200)
    max_attempts: int = param(60, "attempts per grip mode (failed checks are dropped)",
                              lo=3, hi=1000)
    seed: int = param(0, "random seed (same seed, same database)", lo=0)
    fps: float = param(100.0, "frame rate of the stored motions [Hz]", lo=10.0, hi=1000.0)
    control_every: int = param(1, "physics steps per control step in the check", lo=1, hi=10)
    lift_height: float = param(0.10, "lift of the manipulation phase [m]", lo=0.02, hi=0.3)
    min_lift_fraction: float = param(0.8, "kept when the object rose this part of the lift",
                                     lo=0.1, hi=1.0)

    def __post_init__(self) -> None:
        validate(self)


# ---- objects and contact layouts ---------------------------------------------------------
def _object_for(mode: str, rng: np.random.Generator
                ) -> tuple[str, tuple[float, ...], float, float]:
    """(kind, size, mass, friction) of a random object suited to the grip mode: the more
    fingers touch it, the wider it is (about 15 mm of surface per finger)."""
    n_others = len(GRIP_CONTACT_FINGERS[mode]) - 1
    kinds = {"spherical": ("ball", "cylinder"), "power": ("cylinder", "box", "ball")}.get(
        mode, ("box", "ball", "cylinder"))
    kind = kinds[int(rng.integers(len(kinds)))]
    width = 0.015 * n_others  # the far side's span the fingers need [m]
    if kind == "box":
        hy = max(0.5 * width + rng.uniform(0.0, 0.008), rng.uniform(0.015, 0.025))
        # the thumb reaches about 5 cm across: wide boxes are thin
        hx = rng.uniform(0.012, 0.02) if n_others >= 3 else rng.uniform(0.014, 0.026)
        size = (hx, hy, rng.uniform(0.015, 0.04))
    elif kind == "ball":  # the fingers wrap around round objects
        r0 = 0.018 if n_others == 1 else 0.022
        size = (rng.uniform(r0, r0 + 0.009),)
    else:
        r0 = 0.013 if n_others == 1 else 0.018
        size = (rng.uniform(r0, r0 + 0.01), rng.uniform(0.03, 0.065))
    mass = (rng.uniform(0.03, 0.12) if n_others == 1 else rng.uniform(0.05, 0.3)
            if n_others == 2 else rng.uniform(0.04, 0.2))
    return kind, tuple(float(s) for s in size), float(mass), float(rng.uniform(0.7, 1.0))


def _top(kind: str, size: tuple[float, ...]) -> float:
    return {"box": size[-1], "ball": size[0], "cylinder": size[-1]}[kind]


def _far_side(kind: str, size: tuple[float, ...], lateral: float, h: float, yaw: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """A surface point on the far side of the approach frame (turned by ``yaw``) at lateral
    offset ``lateral`` [m] (arc length on round objects) and height ``h``, with its outward
    normal (object-centred world axes). A box is approached square to a face (the heading
    snaps to the face nearest to it)."""
    if kind == "box":
        face = int(round(yaw / (math.pi / 2)))
        fyaw = face * math.pi / 2
        ax = face % 2  # 0: the x faces, 1: the y faces
        half, lat_half = size[ax], size[1 - ax]
        lat = float(np.clip(lateral, -lat_half + 0.004, lat_half - 0.004))
        local = np.array([half, lat, h])
        return _rz(fyaw) @ local, _rz(fyaw) @ np.array([1.0, 0.0, 0.0])
    r = size[0]
    ring = math.sqrt(max(r * r - h * h, 0.0)) if kind == "ball" else r
    a = yaw + float(np.clip(lateral / max(ring, 1e-3), -1.4, 1.4))
    d = np.array([math.cos(a), math.sin(a), 0.0])
    p = ring * d + np.array([0.0, 0.0, h])
    return p, (p / r if kind == "ball" else d)


def grip_layout(mode: str, kind: str, size: tuple[float, ...], yaw: float,
                rng: np.random.Generator) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """The grip mode's contact points and outward normals, object-centred world axes.

    In the approach frame (turned by ``yaw`` about z) the mode's fingers other than the
    thumb are spread over the far side (``+x``), index towards ``+y`` (the thumb's side of a
    right hand approaching palm down), about 15 mm apart; the thumb is on the near side,
    opposing their centroid.
    """
    fingers = GRIP_CONTACT_FINGERS[mode]
    others = [f for f in fingers if f != "thumb"]
    top = _top(kind, size)
    many = len(fingers) >= 4  # the short little finger and the thumb reach less far down
    if kind == "ball":
        h = -size[0] * (rng.uniform(0.1, 0.25) if many else rng.uniform(0.1, 0.35))
    elif mode == "power":
        h = max(-top + 0.008, top - rng.uniform(0.03, 0.045))
    else:
        h = max(-top + 0.008, top - (rng.uniform(0.01, 0.02) if many
                                      else rng.uniform(0.012, 0.03)))
    gap = rng.uniform(0.014, 0.017) * (1.2 if mode == "spherical" else 1.0)
    off = rng.uniform(-0.004, 0.004)
    lats = [off + gap * ((len(others) - 1) / 2.0 - k) for k in range(len(others))]
    pts, nrm = [], []
    for lat in lats:
        p, n = _far_side(kind, size, lat, h, yaw)
        pts.append(p)
        nrm.append(n)
    # the thumb opposes the fingers' centroid, through the object's axis
    c = np.mean(pts, axis=0)
    th = math.atan2(-c[1], -c[0]) + rng.uniform(-0.1, 0.1)
    if kind == "box":
        p, n = _far_side(kind, size, -np.mean(lats), h, yaw + math.pi)
    else:
        p, n = _far_side(kind, size, 0.0, h, th)
    return tuple(fingers), np.array([p] + pts), np.array([n] + nrm)


# ---- poses -------------------------------------------------------------------------------
def _mode_prior(mode: str, root_pos: np.ndarray, yaw: float, rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray]:
    """A posture prior and per-DoF weights for the IK of one grip mode: fingers that do not
    touch the object curl (lightly, or fully for pinches) and are held there."""
    q = np.zeros(N_DOF)
    w = np.full(N_DOF, 2e-6)
    q[0:3] = root_pos
    w[0:3] = 0.0
    q[5] = yaw  # palm down, fingers along the approach heading
    w[3:6] = 1e-5
    touching = set(GRIP_CONTACT_FINGERS[mode])
    for f in ("index", "middle", "ring", "little"):
        j = {k: JOINT_INDEX[f"{f}_{k}"] for k in ("mcp_abd", "mcp_flex", "pip_flex",
                                                  "dip_flex")}
        if f in touching:
            q[j["mcp_flex"]], q[j["pip_flex"]], q[j["dip_flex"]] = 0.5, 0.8, 0.4
            continue
        order = ("index", "middle", "ring", "little")
        beyond = all(order.index(f) > order.index(t) for t in touching if t != "thumb")
        # ulnar of every touching finger: curled into the palm; else held out over the top
        curl = rng.uniform(0.9, 1.3) if beyond else rng.uniform(-0.15, 0.05)
        q[j["mcp_flex"]], q[j["pip_flex"]], q[j["dip_flex"]] = curl, max(1.2 * curl, 0.05), \
            max(0.6 * curl, 0.05)
        for k in j.values():
            w[k] = 1e-3
    q[JOINT_INDEX["thumb_tm_abd"]] = 0.6
    q[JOINT_INDEX["thumb_tm_flex"]] = 0.3
    q[JOINT_INDEX["thumb_mcp_flex"]] = 0.3
    q[JOINT_INDEX["thumb_ip_flex"]] = 0.2
    return q, w


def _rz(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def plan_mode_grasp(model: mujoco.MjModel, object_name: str, mode: str, kind: str,
                    size: tuple[float, ...], center: np.ndarray, yaw: float,
                    rng: np.random.Generator, depth: float = 0.003,
                    max_residual: float = 0.006) -> GraspPlan | None:
    """The grasp and pre-grasp poses of one grip mode by fingertip IK (None: IK missed)."""
    fingers, pts, nrm = grip_layout(mode, kind, size, yaw, rng)
    pts = pts + center
    tips = _tip_points(model)
    top = _top(kind, size)
    many = len(GRIP_CONTACT_FINGERS[mode]) >= 4
    palm_clear = (rng.uniform(0.002, 0.008) if mode == "power" else
                  rng.uniform(0.004, 0.012) if many else rng.uniform(0.01, 0.02))
    if many:  # four or five fingertips on one object: a few mm more slack for the short
        # fingers, and a firmer squeeze (what one finger falls short, the others hold)
        max_residual += 0.002
        depth += 0.002
    palm_target = center + _rz(yaw) @ np.array([-0.01, 0.0, top + palm_clear])
    prior, w = _mode_prior(mode, palm_target + _rz(yaw) @ np.array([-0.05, 0.0, 0.0]), yaw,
                           rng)
    # the PD squeeze grows with the aim depth: the thumb, alone against the others, aims
    # deeper so that the squeeze on the two sides balances (the object is not pushed away)
    n_others = len(fingers) - 1
    dep = {f: depth * (1.0 + 0.25 * (n_others - 1) if f == "thumb" else 1.0)
           for f in fingers}
    obj_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, object_name)
    avoid = np.nonzero(model.geom_bodyid == obj_body)[0]
    # the little finger is short: with five fingers the other four place the hand, then it
    # closes onto its point as far as it reaches (its own IK, the rest of the hand held)
    main = [i for i, f in enumerate(fingers) if not (f == "little" and len(fingers) == 5)]
    late = [i for i in range(len(fingers)) if i not in main]
    targets = {fingers[i]: pts[i] + nrm[i] * (tips[fingers[i]][2] - dep[fingers[i]])
               for i in main}
    q, res = fingertip_ik(model, targets, prior, prior, w, palm_target=palm_target,
                          avoid_geoms=avoid, iterations=150)
    # where a fingertip fell short (the hand's reach), its target moves to the surface point
    # nearest to where it got, and the IK runs again from there
    for _ in range(4):
        if res.max() <= max_residual:
            break
        tip_pos = _tip_positions(model, q, tips, fingers)
        for i in main:
            f = fingers[i]
            pts[i], nrm[i] = _closest_surface(kind, size, tip_pos[i] - center)
            pts[i] += center
            targets[f] = pts[i] + nrm[i] * (tips[f][2] - dep[f])
        q, res = fingertip_ik(model, targets, q, prior, w, palm_target=palm_target,
                              avoid_geoms=avoid, iterations=80)
    if res.max() > max_residual:
        return None
    res_all = np.zeros(len(fingers))
    res_all[main] = res
    for i in late:
        f = fingers[i]
        wl = np.full(N_DOF, 1e3)
        for j, n in enumerate(JOINT_NAMES):
            if n.startswith(f):
                wl[j] = 2e-6
        tip = _tip_positions(model, q, tips, (f,))[0]
        pts[i], nrm[i] = _closest_surface(kind, size, tip - center)
        pts[i] += center
        q, r = fingertip_ik(model, {f: pts[i] + nrm[i] * (tips[f][2] - dep[f])}, q, q, wl,
                            avoid_geoms=avoid, iterations=80)
        res_all[i] = r[0]
    res = res_all
    wpre = w.copy()
    wpre[0:6] = 1e3  # the wrist stays; the fingers open
    clear = rng.uniform(0.02, 0.035)
    pre_t = {f: pts[i] + nrm[i] * (tips[f][2] + clear) for i, f in enumerate(fingers)}
    q_pre, _ = fingertip_ik(model, pre_t, q, q, wpre, avoid_geoms=avoid, clearance=0.01,
                            iterations=150)
    return GraspPlan(object_name, fingers, pts, -nrm, q, q_pre, res)


def _tip_positions(model: mujoco.MjModel, q: np.ndarray, tips: dict, fingers: tuple[str, ...]
                   ) -> np.ndarray:
    """World positions (F, 3) of the fingertip pad centres at pose ``q``."""
    d = mujoco.MjData(model)
    for i, n in enumerate(JOINT_NAMES):
        d.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]] = q[i]
    mujoco.mj_kinematics(model, d)
    out = []
    for f in fingers:
        b, local, _ = tips[f]
        out.append(d.xpos[b] + d.xmat[b].reshape(3, 3) @ local)
    return np.array(out)


def _closest_surface(kind: str, size: tuple[float, ...], p: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The surface point nearest to ``p`` (object-centred, world axes; the object upright and
    axis-aligned) and its outward normal."""
    if kind == "ball":
        n = p / max(float(np.linalg.norm(p)), 1e-9)
        return n * size[0], n
    if kind == "cylinder":
        r, hh = size
        radial = np.array([p[0], p[1], 0.0])
        n = radial / max(float(np.linalg.norm(radial)), 1e-9)
        return n * r + np.array([0.0, 0.0, float(np.clip(p[2], -hh, hh))]), n
    half = np.asarray(size, dtype=np.float64)
    q = np.clip(p, -half, half)
    gap = half - np.abs(q)
    ax = int(np.argmin(gap[:2]))  # the side face nearest to the point
    n = np.zeros(3)
    n[ax] = 1.0 if p[ax] >= 0 else -1.0
    q[ax] = n[ax] * half[ax]
    return q, n


# ---- human-like timing -------------------------------------------------------------------
def _smooth(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def closing_profile(plan: GraspPlan, rng: np.random.Generator
                    ) -> Callable[[np.ndarray], np.ndarray]:
    """A closing motion ``u in [0, 1] -> (N, 27)`` from the pre-grasp to the grasp: a random
    global time warp (an exponential ramp) and, per finger, a random lag and speed shape, so
    that every demonstration has its own, monotonic, timing."""
    k = rng.uniform(-2.0, 2.0)
    group = np.zeros(N_DOF, dtype=np.int64)
    for i, n in enumerate(JOINT_NAMES[6:], start=6):
        group[i] = 1 + _FINGER_GROUPS.index(n.split("_")[0])
    lag = np.r_[0.0, rng.uniform(0.0, 0.25, len(_FINGER_GROUPS))][group]
    power = np.r_[1.0, rng.uniform(0.7, 1.5, len(_FINGER_GROUPS))][group]
    q0, q1 = plan.q_pregrasp.copy(), plan.q_grasp.copy()

    def motion(u: np.ndarray) -> np.ndarray:
        u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
        g = u if abs(k) < 1e-6 else np.expm1(k * u) / math.expm1(k)  # global warp
        x = np.clip((g[:, None] - lag) / (1.0 - lag), 0.0, 1.0) ** power
        s = _smooth(x)
        return q0 + s * (q1 - q0)

    return motion


class TimedReference(Reference):
    """The scenario reference with its own start pose and closing motion (``closing(u)``,
    u = the closing phase's progress in [0, 1])."""

    def __init__(self, spec: ScenarioSpec, plan: GraspPlan, object_position: np.ndarray,
                 object_quaternion: np.ndarray, start: np.ndarray,
                 closing: Callable[[np.ndarray], np.ndarray]) -> None:
        super().__init__(spec, plan, object_position, object_quaternion)
        self.q_start = np.asarray(start, dtype=np.float64).copy()
        self._closing = closing

    def _sample_many(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        q, pos, quat, phase, grasp = super()._sample_many(t)
        q = q.copy()
        c = phase == PHASES.index("closing")
        if c.any():
            q[c] = self._closing((t[c] - self.t_close0) / self.spec.t_close)
        q.setflags(write=False)
        return q, pos, quat, phase, grasp

    def _sample(self, t: float) -> RefSample:
        r = super()._sample(t)
        if r.phase != "closing":
            return r
        q = self._closing(np.array([(t - self.t_close0) / self.spec.t_close]))[0]
        return RefSample(r.phase, q, r.object_position, r.object_quaternion, r.grasp)


# ---- one demonstration -------------------------------------------------------------------
def _palm_center(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    d = mujoco.MjData(model)
    for i, n in enumerate(JOINT_NAMES):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)
        d.qpos[model.jnt_qposadr[j]] = q[i]
    mujoco.mj_kinematics(model, d)
    return d.site_xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "palm_center")].copy()


def demonstrate(mode: str, rng: np.random.Generator, config: GenConfig | None = None,
                why: list[str] | None = None) -> GraspRecord | None:
    """One checked demonstration of ``mode`` (None when the IK missed or the check failed;
    the reason is appended to ``why``)."""
    why = [] if why is None else why
    cfg = config or GenConfig()
    kind, size, mass, mu = _object_for(mode, rng)
    xy = (0.12 + rng.uniform(-0.02, 0.02), rng.uniform(-0.03, 0.03))
    yaw = float(rng.uniform(-0.4, 0.4))
    t_reach, t_close = float(rng.uniform(0.35, 0.6)), float(rng.uniform(0.35, 0.75))
    spec = ScenarioSpec(name=f"demo_{mode}", object_kind=kind, object_size=size,
                        object_mass=mass, object_friction=mu, object_xy=xy, t_reach=t_reach,
                        t_close=t_close, t_settle=0.3, t_lift=0.8, t_carry=0.0, t_hold=0.6,
                        lift_height=cfg.lift_height, carry_offset=(0.0, 0.0, 0.0))
    world, obj, _ = build_world(spec)
    pose = world.object_pose(obj.name)
    center = pose.position.copy()
    plan = plan_mode_grasp(world.model, obj.name, mode, kind, size, center, yaw, rng)
    if plan is None:
        why.append("ik")
        return None
    start = plan.q_pregrasp.copy()
    start[0:3] += _rz(yaw) @ np.array([-rng.uniform(0.0, 0.02), 0.0, rng.uniform(0.05, 0.09)])
    for f in _FINGER_GROUPS[1:]:  # the grip opens while reaching (III.3.2)
        for k in ("mcp_flex", "pip_flex", "dip_flex"):
            start[JOINT_INDEX[f"{f}_{k}"]] *= rng.uniform(0.2, 0.6)
    start = np.clip(start, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])
    closing = closing_profile(plan, rng)
    try:
        runner = LockstepRunner(spec, control_every=cfg.control_every, plan=plan)
        ref = TimedReference(spec, plan, pose.position, pose.quaternion, start, closing)
        runner.reference = runner.core.reference = ref
        w = runner.world
        w.set_initial_state(ref.initial_pose)
        w.set_command(ref.initial_pose, np.zeros(w.n_hand))
        ref.precompute(w.model.opt.timestep, t0=w.time)
        w.reset()
        dt = w.model.opt.timestep
        n = int(round(ref.t_end / dt))
        i_grasp = int(round(ref.t_lift0 / dt)) - 1
        cf = None
        z0 = float(w.object_pose(obj.name).position[2])
        z_max = z0
        for i in range(n):
            if i % runner.control_every == 0:
                runner.control_step(w.data.time)
            w.step()
            if i == i_grasp:
                cf = w.contacts(obj.name, forces=False)
                op = w.object_pose(obj.name)
                o_pos, o_rot = op.position.copy(), _quat_matrix(op.quaternion)
                bone_x = w.data.xpos.copy()
                bone_r = w.data.xmat.copy().reshape(-1, 3, 3)
            if i % 50 == 0:
                z_max = max(z_max, float(w.object_pose(obj.name).position[2]))
        z_end = float(w.object_pose(obj.name).position[2])
    except HandSuiteError as e:
        why.append(f"sim: {type(e).__name__}")
        return None
    lift = z_end - z0
    if cf is None or len(cf) == 0 or lift < cfg.min_lift_fraction * cfg.lift_height:
        why.append(f"not lifted ({lift * 1e3:.0f} mm, peak {(z_max - z0) * 1e3:.0f} mm, "
                   f"{0 if cf is None else len(cf)} contacts at the grasp)")
        return None
    # the annotation must show the grip: the thumb and most of the mode's fingers touching
    touching = {world.model.body(b).name.split("_")[0] for b in cf.body1_id.tolist()}
    grip = set(plan.fingers)
    if "thumb" not in touching or len(grip & touching) < max(2, len(grip) - 2):
        why.append("grip not touching")
        return None
    # the object frame of III.3: CoM at rest, z up, x from the palm centre to the object
    fyaw = object_frame_yaw(_palm_center(world.model, plan.q_grasp), center)
    times = np.arange(int(math.floor(ref.t_end * cfg.fps)) + 1) / cfg.fps
    motion_w = np.array([ref(float(t)).q_target for t in times])
    motion = to_object_frame(motion_w, center, fyaw)
    phases = (int(round(ref.t_close0 * cfg.fps)), int(round(ref.t_settle0 * cfg.fps)) + 1)
    rz = _rz(fyaw)
    q0 = _quat_matrix(pose.quaternion)
    contacts, local = [], []
    for b, p in zip(cf.body1_id.tolist(), cf.points, strict=True):
        name = world.model.body(b).name
        p_obj = rz.T @ (q0 @ (o_rot.T @ (p - o_pos)))  # as if the object were at rest
        p_loc = bone_r[b].T @ (p - bone_x[b])
        contacts.append((name, tuple(float(v) for v in p_obj)))
        local.append((name, tuple(float(v) for v in p_loc)))
    return GraspRecord(mode, kind, size, mass, motion, phases, tuple(contacts), tuple(local),
                       mu, (float(center[0]), float(center[1]), fyaw), lift * 1e3, cfg.fps,
                       {"approach_yaw": yaw, "t_close": t_close, "t_reach": t_reach,
                        "z_max_mm": (z_max - z0) * 1e3})


def _quat_matrix(wxyz: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(wxyz, dtype=np.float64))
    return m.reshape(3, 3)


def build_database(config: GenConfig | None = None, modes: tuple[str, ...] = GRIP_MODES,
                   progress: Callable[[str], None] | None = None,
                   reasons: dict[str, list[str]] | None = None
                   ) -> tuple[list[GraspRecord], dict[str, tuple[int, int]]]:
    """Demonstrations of every grip mode: ``(records, {mode: (kept, attempts)})``; why each
    rejected attempt was rejected goes to ``reasons[mode]``."""
    reasons = {} if reasons is None else reasons
    cfg = config or GenConfig()
    records: list[GraspRecord] = []
    stats: dict[str, tuple[int, int]] = {}
    for mi, mode in enumerate(GRIP_MODES):
        if mode not in modes:
            continue
        kept = attempts = 0
        while kept < cfg.demos_per_mode and attempts < cfg.max_attempts:
            rng = np.random.default_rng((cfg.seed, mi, attempts))
            attempts += 1
            rec = demonstrate(mode, rng, cfg, why=reasons.setdefault(mode, []))
            if rec is not None:
                records.append(rec)
                kept += 1
        stats[mode] = (kept, attempts)
        if progress:
            progress(f"{mode}: kept {kept} of {attempts}")
    return records, stats
