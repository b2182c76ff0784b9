"""Grasp synthesis for a given object (dissertation III.4): closing, reaching, manipulation.

Closing phase (III.4.1.2-III.4.1.4): minimise eq. (III.4)

    w_p E_p + w_c E_c + w_k E_k + w_d E_d + w_q E_q

over the deformable model's parameters (alpha, gamma) of a grip mode and the approach
direction (the yaw of the III.3 object frame about z), by particle swarm optimisation
initialised from the model's Gaussian mixture prior. The particle evaluation is vectorised:
the swarm's motions at a few frames go through one batched FK, and every hand capsule point is
looked up in the object's signed distance field at once. The dynamic feasibility LP
(III.10-III.16, with the hand's joint torque limits through the contact Jacobians) then runs
on the last generation, best first; the best feasible particle's grasping pose is refined by
inverse kinematics that pulls each contact point onto the object's surface, and the closing
motion is bent smoothly onto the refined pose.

Reaching (III.4.2): the database's reaching segment nearest to the boundary poses, edited by
the Laplacian least squares of eq. (III.17) to start at the initial pose and end at the first
closing frame. Manipulation (III.4.3): the object's path from the database's nearest
manipulation example edited the same way to the initial and target positions, the hand moving
rigidly with the object.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.joints import JOINT_LIMITS, N_DOF
from hand_capture.model.mjcf import (
    ROOT_FORCE_LIMIT,
    ROOT_TORQUE_LIMIT,
    finger_torque_limits,
)
from hand_capture.model.skeleton import BONE_DOF_MASK, BONE_NAMES
from hand_control.contact.feasibility import dynamic_feasibility
from hand_control.contact.types import ContactSet
from hand_control.errors import InputError, SolverError
from hand_control.grasp.objects import GraspObject
from hand_control.grasp.pso import PSOConfig, pso
from hand_control.grasp.terms import (
    ContactPoints,
    EnergyWeights,
    HandGeometry,
    collision_term,
    contact_distance_term,
    grasp_quality_terms,
    rot_z,
)

__all__ = ["GraspControl", "SynthesisConfig", "SynthesisResult", "laplacian_edit",
           "manipulation_path", "reaching_motion", "synthesize"]

GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass(frozen=True)
class SynthesisConfig:
    """Settings of the closing-phase synthesis."""

    particles: int = param(24, "PSO swarm size per grip mode", lo=2, hi=4096)
    iterations: int = param(12, "PSO generations", lo=0, hi=1000)
    modes_kept: int = param(1, "without a grip mode: the swarm runs on the modes whose "
                            "prior samples score best (one generation each), this many, then "
                            "on the next ones while none is feasible", lo=1, hi=20)
    max_modes: int = param(3, "at most this many grip modes get a swarm per run", lo=1,
                           hi=20)
    eval_frames: int = param(5, "closing frames checked for collisions (the last included)",
                             lo=1, hi=200)
    yaw_range: float = param(1.0, "approach directions within +- this of the preferred one "
                             "[rad]", lo=0.0, hi=math.pi)
    contact_threshold: float = param(
        0.008, "a contact point within this of the surface can push on it (feasibility LP) "
        "[m]", lo=0.0, hi=0.05)
    grasp_depth: float = param(0.003, "the refined contacts aim this far inside the surface "
                               "(the servos' squeeze) [m]", lo=0.0, hi=0.01)
    refine_iterations: int = param(20, "IK refinement steps (0 = none)", lo=0, hi=500)
    max_lp: int = param(8, "feasibility LPs tried on the last generation, best first",
                        lo=1, hi=4096)
    retries: int = param(1, "runs of the swarm again when no particle is feasible", lo=0,
                         hi=10)
    torque_limits: bool = param(True, "the feasibility LP bounds the forces by the joint "
                                "torque limits")
    patch_radius: float = param(
        0.0, "each contact a patch of 4 points this far around it in the feasibility LP "
        "(III.4.1.3: the soft fingertip's contact torque) [m]; 0 = point contacts (with 4 mm "
        "patches the LP admitted two-finger pinches of a ball and a torus that then slipped "
        "in the simulation)", lo=0.0, hi=0.02)
    friction_margin: float = param(
        0.7, "the friction cone term (III.9) and the feasibility LP use this fraction of the "
        "object's friction (a grasp that holds only at the cone's edge slips in practice)",
        lo=0.05, hi=1.0)
    seed: int = param(0, "random seed of the swarm")
    reaching_frames: int = param(30, "frames of the synthesised reaching motion (0 = none)",
                                 lo=0, hi=1000)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True, eq=False)
class GraspControl:
    """The user's control input (the E_c term of eq. III.4).

    Attributes:
        grip_mode: the grip mode to use (``None``: every model given competes).
        contact_targets: finger -> desired contact point in the object's body frame [m].
        performer: (n, 27) the performer's tracked closing motion in the object's body frame
            (III.6); E_c is then its difference from the synthesised motion.
        approach_yaw: preferred direction from the hand to the object in the body frame [rad].
        performer_mode: ``motion``: E_c compares the whole closing motion with the performer's
            (resampled; squared wrist distance [cm] + squared finger angles [rad]);
            ``onset``: only the closing motion's first wrist with the performer's latest one
            [cm] (online, as closing begins: the rest of the closing is yet to come).
    """

    grip_mode: str | None = None
    contact_targets: Mapping[str, Sequence[float]] = field(default_factory=dict)
    performer: np.ndarray | None = None
    approach_yaw: float = 0.0
    performer_mode: str = "motion"

    def __post_init__(self) -> None:
        if self.performer_mode not in ("motion", "onset"):
            raise InputError(f"performer_mode must be 'motion' or 'onset', got "
                             f"{self.performer_mode!r}")


@dataclass(frozen=True, eq=False)
class SynthesisResult:
    """A synthesised closing motion.

    Attributes:
        grip_mode, params (n_params,), yaw: the chosen model, its parameters and the yaw of
            the III.3 object frame in the object's body frame [rad] (the approach direction).
        motion: (T, 27) the closing motion (last frame refined onto the surface) in the III.3
            object frame.
        contact_bones: the contacting bones; contact_points (C, 3) their closest surface
            points and contact_normals (C, 3) the inward normals there, body frame;
            in_contact (C,) within ``contact_threshold`` of the surface; residual (C,) the
            contact points' distance to the surface after refinement [m].
        cost, terms: eq. (III.4) and its terms at the chosen particle (before refinement).
        feasible, status: the feasibility LP's verdict; lp_tried: particles it tested.
        synth_ms, pso_ms, lp_ms, ik_ms: wall time [ms]; cpu_ms: the process's CPU time
            [ms] (what the wall time is on an idle core).
    """

    grip_mode: str
    params: np.ndarray
    yaw: float
    motion: np.ndarray
    contact_bones: tuple[str, ...]
    contact_points: np.ndarray
    contact_normals: np.ndarray
    in_contact: np.ndarray
    residual: np.ndarray
    cost: float
    terms: dict[str, float]
    feasible: bool
    status: str
    lp_tried: int
    synth_ms: float
    pso_ms: float
    lp_ms: float
    ik_ms: float
    reaching: np.ndarray | None = None
    cpu_ms: float = float("nan")

    @property
    def grasp_pose(self) -> np.ndarray:
        return self.motion[-1]

    def world_motion(self, position: Sequence[float], yaw: float) -> np.ndarray:
        """The closing motion in the world, for the object's centre of mass at ``position``
        and its body turned by ``yaw`` about z [rad]."""
        from hand_control.grasp.database import from_object_frame

        return from_object_frame(self.motion, position, yaw + self.yaw)

    def grasp_plan(self, object_name: str, position: Sequence[float], yaw: float) -> object:
        """The grasp as the simulation's :class:`~hand_control.sim.grasp.GraspPlan` (the
        scenarios' reference plays the closing motion, then holds the grasping pose)."""
        from hand_control.grasp.database import from_object_frame
        from hand_control.sim.grasp import GraspPlan

        wm = self.world_motion(position, yaw)
        pts, nrm = self.world_contacts(position, yaw)
        reach = None
        if self.reaching is not None:
            reach = from_object_frame(self.reaching, position, yaw + self.yaw)
        return GraspPlan(object_name, self.contact_bones, pts, nrm, wm[-1].copy(),
                         wm[0].copy(), self.residual.copy(), closing=wm, source="synthesis",
                         reaching=reach)

    def world_contacts(self, position: Sequence[float], yaw: float
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Contact points and inward normals in the world (C, 3) each."""
        r = rot_z(np.float64(yaw))
        return (self.contact_points @ r.T + np.asarray(position, dtype=np.float64),
                self.contact_normals @ r.T)


# --------------------------------------------------------------------------- contact Jacobian
def _torque_limits() -> np.ndarray:
    lim = finger_torque_limits()
    lim[0:3], lim[3:6] = ROOT_FORCE_LIMIT, ROOT_TORQUE_LIMIT
    return lim


class _Evaluator:
    """Eq. (III.4) for a whole swarm of one grip mode (see the module docstring)."""

    def __init__(self, model: object, obj: GraspObject, geometry: HandGeometry,
                 contacts: ContactPoints, weights: EnergyWeights, control: GraspControl,
                 eval_frames: int, mu: float) -> None:
        self.model, self.obj, self.geo, self.contacts = model, obj, geometry, contacts
        self.w, self.control = weights, control
        self.mu = mu
        self.n = int(model.n_params)
        self.frames = eval_frames
        self.floor = -obj.bottom
        self.finger_of = [b.split("_")[0] for b in contacts.names]
        tgt = control.contact_targets or {}
        bad = [f for f in tgt if f not in self.finger_of]
        if bad:
            raise InputError(f"contact targets for fingers {bad}, which grip mode "
                             f"{model.grip_mode!r} does not use ({sorted(set(self.finger_of))})")
        self.tgt_idx = [self.finger_of.index(f) for f in tgt]
        self.tgt = np.array([tgt[f] for f in tgt], dtype=np.float64).reshape(-1, 3)
        self.perf = None
        if control.performer is not None:
            perf = np.asarray(control.performer, dtype=np.float64)
            if perf.ndim != 2 or perf.shape[1] != N_DOF or len(perf) < 2 \
                    or not np.isfinite(perf).all():
                raise InputError(f"performer motion must be finite (n >= 2, {N_DOF}), got "
                                 f"{perf.shape}")
            s = np.linspace(0, len(perf) - 1, eval_frames)
            i0 = np.minimum(np.floor(s).astype(int), len(perf) - 2)
            f = (s - i0)[:, None]
            self.perf = (1 - f) * perf[i0] + f * perf[i0 + 1]
            if control.performer_mode == "onset":
                self.perf = perf[-1:]

    def frames_of(self, params: np.ndarray) -> np.ndarray:
        """(P, F, 27) the decoded closing motions (eq. III.3) at F evenly spaced instants of
        their own duration (the last one the grasping pose), object frame: the warp (III.2)
        maps each instant to canonical time, where eq. (III.1) is evaluated at the two
        neighbouring frames only."""
        m = self.model
        na = m.n_alpha
        h = m.warp(params)  # (P, T)
        t = h.shape[1]
        s = np.linspace(0.0, 1.0, self.frames)[None, :] * h[:, -1:]  # (P, F)
        k = (h[:, None, :] <= s[:, :, None]).sum(axis=-1) - 1  # h[k] <= s < h[k + 1]
        i0 = np.clip(k, 0, t - 2)
        rows = np.arange(len(params))[:, None]
        h0, h1 = h[rows, i0], h[rows, i0 + 1]
        a = np.clip((s - h0) / np.maximum(h1 - h0, 1e-12), 0.0, 1.0)[..., None]
        alpha = params[:, :na]
        pb = m.p_basis  # (T, 27, M)
        c0 = m.p0[i0] + np.einsum("pfdm,pm->pfd", pb[i0], alpha)  # eq. (III.1)
        c1 = m.p0[i0 + 1] + np.einsum("pfdm,pm->pfd", pb[i0 + 1], alpha)
        return (1 - a) * c0 + a * c1

    def __call__(self, x: np.ndarray, parts: bool = False
                 ) -> np.ndarray | tuple[np.ndarray, dict[str, np.ndarray]]:
        params, yaw = x[:, :self.n], x[:, self.n]
        q = self.frames_of(params)
        rot, pos = self.geo.frames(q)  # (P, F, 16, ...)
        rt = rot_z(yaw).transpose(0, 2, 1)  # object frame -> body frame (row vectors)
        caps = HandGeometry.points(rot, pos, self.geo.bones, self.geo.local)
        p_, f_, s_ = caps.shape[:3]
        caps = np.matmul(caps.reshape(p_, f_ * s_, 3), rt).reshape(p_, f_, s_, 3)
        con = HandGeometry.points(rot[:, -1], pos[:, -1], self.contacts.bones,
                                  self.contacts.local)
        con = np.matmul(con, rt)
        w = self.w
        e_k = collision_term(self.obj.sdf, caps, self.geo.radii, self.floor,
                             w.penetration_penalty, w.penetration_tolerance)  # III.6-7
        e_d = contact_distance_term(self.obj.sdf, con)  # III.8
        eg1, eg2 = grasp_quality_terms(self.obj.sdf, con, self.contacts.is_thumb,
                                       self.mu)  # III.9
        e_q = w.w1 * eg1 + w.w2 * eg2
        e_p = np.asarray(self.model.neg_log_prior(params), dtype=np.float64)  # III.5
        e_c = np.zeros(len(x))
        if len(self.tgt_idx):
            e_c += 1e3 * np.linalg.norm(con[:, self.tgt_idx] - self.tgt, axis=-1).sum(-1)
        if self.perf is not None and self.control.performer_mode == "onset":
            root = np.matmul(q[:, 0:1, 0:3], rt)[:, 0]
            e_c += np.linalg.norm(root - self.perf[0, 0:3], axis=-1) / 0.01  # [cm]
        elif self.perf is not None:
            root = np.matmul(q[..., 0:3], rt)
            d_root = np.linalg.norm(root - self.perf[None, :, 0:3], axis=-1) / 0.01  # [cm]
            d_fing = np.linalg.norm(q[..., 6:] - self.perf[None, :, 6:], axis=-1)  # [rad]
            e_c += (d_root ** 2 + d_fing ** 2).mean(axis=-1)
        total = w.w_p * e_p + w.w_c * e_c + w.w_k * e_k + w.w_d * e_d + w.w_q * e_q  # III.4
        if parts:
            return total, {"E_p": e_p, "E_c": e_c, "E_k": e_k, "E_d": e_d, "E_g1": eg1,
                           "E_g2": eg2}
        return total


def _contact_jacobian(geo: HandGeometry, q: np.ndarray, contacts: ContactPoints,
                      r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contact points (C, 3) and their Jacobians (C, 3, 27) for pose ``q`` (object frame),
    both rotated by ``r`` into the body frame."""
    model = geo.model
    rot, pos = model._fk(q[None])
    axes, anchors = model._dof_axes(q[None], rot, pos)
    p = HandGeometry.points(rot[0], pos[0], contacts.bones, contacts.local)  # (C, 3)
    jac = np.cross(axes[0][None], p[:, None, :] - anchors[0][None])  # (C, 27, 3)
    jac[:, 0:3] = axes[0][None, 0:3]
    jac *= BONE_DOF_MASK[contacts.bones][:, :, None]
    return p @ r.T, np.einsum("ij,cdj->cid", r, jac)


def contact_patches(points: np.ndarray, normals: np.ndarray, radius: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Each contact (K, 3) as a patch of four points ``radius`` around it in its tangent
    plane (III.4.1.3), with its normal: (4K, 3) points and normals, patch-major."""
    n = np.asarray(normals, dtype=np.float64)
    a = np.where(np.abs(n[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]),
                 np.array([[1.0, 0.0, 0.0]]))
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    c = np.asarray(points, dtype=np.float64)
    pts = np.concatenate([c + radius * t1, c - radius * t1, c + radius * t2, c - radius * t2])
    return pts, np.tile(n, (4, 1))


def _feasibility(obj: GraspObject, geo: HandGeometry, contacts: ContactPoints, q: np.ndarray,
                 yaw: float, cfg: SynthesisConfig, tau_max: np.ndarray
                 ) -> tuple[bool, str, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (III.10)-(III.16) for the grasping pose ``q``: the contacts within reach of the
    surface push along the inward normals there; with ``patch_radius`` each contact is a
    patch of four points around it in the tangent plane (III.4.1.3: the soft finger's contact
    torques), all with the contact's Jacobian."""
    p, jac = _contact_jacobian(geo, q, contacts, rot_z(np.float64(yaw)))
    surf, n_out, d = obj.sdf.closest(p)
    near = np.abs(d) <= cfg.contact_threshold
    if near.sum() < 2:
        return False, "too_few_contacts", surf, -n_out, near
    pts, nrm, jp = surf[near], -n_out[near], jac[near]
    if cfg.patch_radius > 0:
        pts, nrm = contact_patches(pts, nrm, cfg.patch_radius)
        jp = np.tile(jp, (4, 1, 1))
    cs = ContactSet(pts, nrm, obj.friction * cfg.friction_margin,
                    jacp=jp if cfg.torque_limits else None)
    res = dynamic_feasibility(cs, obj.mass, np.zeros(3), GRAVITY,
                              torque_limits=tau_max if cfg.torque_limits else None)
    return bool(res.feasible), res.status, surf, -n_out, near


def refine_grasp(obj: GraspObject, geo: HandGeometry, contacts: ContactPoints, q: np.ndarray,
                 yaw: float, depth: float, iterations: int, damping: float = 1e-4
                 ) -> tuple[np.ndarray, np.ndarray]:
    """IK refinement (III.4.1.4): damped Gauss-Newton on the finger joints of the contacting
    fingers and the wrist, pulling each contact point to its closest surface point moved
    ``depth`` inside; joint limits kept. Returns the pose (27,) and the contact points'
    distances to the surface (C,) [m]."""
    q = q.copy()
    r = rot_z(np.float64(yaw))
    lo, hi = JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1]
    free = BONE_DOF_MASK[contacts.bones].any(axis=0)
    # the wrist moves little (it carries the other fingers): a stiffer prior
    prior = np.where(np.arange(N_DOF) < 6, 1e-2, 1e-4)
    for _ in range(iterations):
        p, jac = _contact_jacobian(geo, q, contacts, r)
        surf, n_out, d = obj.sdf.closest(p)
        err = (surf - depth * n_out - p).reshape(-1)
        j = jac.reshape(-1, N_DOF)[:, free]
        h = j.T @ j + np.diag(prior[free] + damping)
        dq = np.linalg.solve(h, j.T @ err)
        step = np.linalg.norm(dq)
        if step > 0.2:
            dq *= 0.2 / step
        q[free] = np.clip(q[free] + dq, lo[free], hi[free])
        if step < 1e-6:
            break
    p, _ = _contact_jacobian(geo, q, contacts, r)
    return q, np.abs(obj.sdf(p))


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def model_contacts(model: object) -> ContactPoints:
    """The grip mode's contact points (the model's annotations; its fingertips otherwise)."""
    c = getattr(model, "contacts", ())
    if c:
        return ContactPoints.from_names([b for b, _ in c], np.array([p for _, p in c]))
    from hand_control.grasp.database import GRIP_CONTACT_FINGERS

    return ContactPoints.fingertips(GRIP_CONTACT_FINGERS[model.grip_mode])


def synthesize(obj: GraspObject, models: Mapping[str, object],
               control: GraspControl | None = None, config: SynthesisConfig | None = None,
               weights: EnergyWeights | None = None, geometry: HandGeometry | None = None,
               records: Sequence[object] = ()) -> SynthesisResult:
    """Synthesise the closing motion for ``obj`` (module docstring).

    Args:
        models: grip mode -> closing model (``load_grasp_models()``).
        control: grip mode / contact targets / performer (E_c); default: any grip mode.
        weights: eq. (III.4) weights (zero one for the ablations of Fig. III.9).
        records: the grasp database, for the reaching phase (III.4.2).

    Raises:
        InputError: an unknown grip mode, or no models.
        SolverError: the swarm found no grasp at all (a NaN everywhere).
    """
    t0 = time.perf_counter()
    c0 = time.process_time()
    control = control or GraspControl()
    cfg = config or SynthesisConfig()
    weights = weights or EnergyWeights()
    geo = geometry or HandGeometry()
    if not models:
        raise InputError("no closing models given (hand-suite train grasps builds them)")
    if control.grip_mode is not None:
        if control.grip_mode not in models:
            raise InputError(f"unknown grip mode {control.grip_mode!r}; valid: "
                             f"{', '.join(models)}")
        modes = [control.grip_mode]
    else:
        modes = list(models)
    rng = np.random.default_rng(cfg.seed)
    tau = _torque_limits()
    pso_cfg = PSOConfig(particles=cfg.particles, iterations=cfg.iterations)
    best: tuple | None = None
    pso_s = lp_s = 0.0
    tried = 0
    setups = {}
    for mode in modes:
        model = models[mode]
        contacts = model_contacts(model)
        ev = _Evaluator(model, obj, geo, contacts, weights, control, cfg.eval_frames,
                        obj.friction * cfg.friction_margin)
        lo_p, hi_p = model.bounds(3.0)
        lo = np.r_[lo_p, control.approach_yaw - cfg.yaw_range]
        hi = np.r_[hi_p, control.approach_yaw + cfg.yaw_range]
        setups[mode] = (model, contacts, ev, lo, hi)
    if len(modes) > 1:  # screening: one generation from each mode's prior
        t1 = time.perf_counter()
        score = {}
        for mode in modes:
            model, _, ev, lo, hi = setups[mode]
            x0 = np.c_[model.sample(cfg.particles, rng),
                       rng.uniform(lo[-1], hi[-1], cfg.particles)]
            score[mode] = float(np.min(ev(x0)))
        modes = sorted(modes, key=score.__getitem__)
        pso_s += time.perf_counter() - t1
    for _attempt in range(cfg.retries + 1):
        for k, mode in enumerate(modes):
            if k >= cfg.max_modes or (k >= cfg.modes_kept and best is not None and best[3]):
                break
            model, contacts, ev, lo, hi = setups[mode]
            init = np.c_[model.sample(cfg.particles, rng),
                         rng.uniform(lo[-1], hi[-1], cfg.particles)]  # from the prior
            t1 = time.perf_counter()
            res = pso(ev, init, lo, hi, pso_cfg, rng)
            pso_s += time.perf_counter() - t1
            # the last generation and the particles' bests, best first (III.4.1.4)
            xs = np.vstack([res.positions, res.personal_best])
            cs = np.r_[res.costs, res.personal_cost]
            order = np.argsort(cs)
            t1 = time.perf_counter()
            seen = 0
            for i in order:
                if not np.isfinite(cs[i]) or seen >= cfg.max_lp:
                    break
                seen += 1
                x = xs[i]
                q = model.final_pose(x[:ev.n])
                ok, status, *_ = _feasibility(obj, geo, contacts, q, float(x[-1]), cfg, tau)
                if ok or best is None or (not best[3] and cs[i] < best[1]):
                    cand = (mode, float(cs[i]), x.copy(), ok, status, ev, contacts)
                    if best is None or (ok and not best[3]) or (ok == best[3]
                                                                and cs[i] < best[1]):
                        best = cand
                if ok:
                    break
            tried += seen
            lp_s += time.perf_counter() - t1
        if best is not None and best[3]:
            break
    if best is None:
        raise SolverError(f"grasp synthesis for {obj.name!r}: every particle's cost was NaN")
    mode, cost, x, ok, status, ev, contacts = best
    model = models[mode]
    params, yaw = x[:ev.n], float(x[-1])
    _, terms = ev(x[None], parts=True)
    motion = np.asarray(model.decode(params), dtype=np.float64)
    t1 = time.perf_counter()
    q_ref, residual = (refine_grasp(obj, geo, contacts, motion[-1], yaw, cfg.grasp_depth,
                                    cfg.refine_iterations)
                       if cfg.refine_iterations else (motion[-1], np.zeros(len(contacts.bones))))
    # bend the closing motion onto the refined grasping pose
    ramp = _smoothstep(np.linspace(0.0, 1.0, len(motion)))[:, None]
    motion = motion + ramp * (q_ref - motion[-1])[None]
    ik_s = time.perf_counter() - t1
    reach = None
    if cfg.reaching_frames:
        t1 = time.perf_counter()
        reach = safe_reaching(obj, geo, motion, yaw, records, cfg.reaching_frames)
        ik_s += time.perf_counter() - t1
    ok2, status2, surf, n_in, near = _feasibility(obj, geo, contacts, q_ref, yaw, cfg, tau)
    if ok and not ok2:  # the refinement moved the contacts: keep the swarm's verdict's reason
        status2 = f"{status2} after refinement"
    return SynthesisResult(
        grip_mode=mode, params=params, yaw=yaw, motion=motion, contact_bones=contacts.names,
        contact_points=surf, contact_normals=n_in, in_contact=near, residual=residual,
        cost=cost, terms={k: float(v[0]) for k, v in terms.items()}, feasible=bool(ok2),
        status=status2 if not ok2 else "optimal", lp_tried=tried,
        synth_ms=(time.perf_counter() - t0) * 1e3, pso_ms=pso_s * 1e3, lp_ms=lp_s * 1e3,
        ik_ms=ik_s * 1e3, reaching=reach, cpu_ms=(time.process_time() - c0) * 1e3)


# ----------------------------------------------------------------------- reaching, manipulation
def laplacian_edit(example: np.ndarray, start: np.ndarray, end: np.ndarray,
                   after_end: np.ndarray | None = None, w1: float = 10.0, w2: float = 0.01
                   ) -> np.ndarray:
    """Eq. (III.17): the motion (N, D) closest to ``example`` in its 1D Laplacian coordinates
    (the second differences) that starts at ``start`` and ends at ``end`` (weight ``w1``),
    with a smooth transition into ``after_end`` (the frame after the end, weight ``w2``).
    Each DoF is an independent linear least-squares problem with one matrix."""
    ex = np.asarray(example, dtype=np.float64)
    n = ex.shape[0]
    if n < 3:
        raise InputError(f"laplacian_edit: the example needs >= 3 frames, got {n}")
    lap = np.zeros((n - 2, n))
    for i in range(n - 2):
        lap[i, i:i + 3] = (1.0, -2.0, 1.0)
    rows = [lap, math.sqrt(w1) * np.eye(n)[[0]], math.sqrt(w1) * np.eye(n)[[n - 1]]]
    rhs = [lap @ ex, math.sqrt(w1) * np.asarray(start)[None], math.sqrt(w1)
           * np.asarray(end)[None]]
    if after_end is not None:
        # q_{N+1} + q_{N-1} - 2 q_N: q_{N+1} is given, so the row acts on q_{N-1} and q_N
        row = np.zeros((1, n))
        row[0, n - 2], row[0, n - 1] = 1.0, -2.0
        rows.append(math.sqrt(w2) * row)
        rhs.append(-math.sqrt(w2) * np.asarray(after_end)[None])
    a = np.vstack(rows)
    b = np.vstack(rhs)
    return np.linalg.lstsq(a, b, rcond=None)[0]


def reaching_motion(records: Sequence[object], q_init: np.ndarray, closing: np.ndarray,
                    frames: int | None = None) -> np.ndarray:
    """Reaching phase (III.4.2) in the object frame: the database reaching segment whose end
    points are nearest to ``q_init`` and the first closing frame, edited by eq. (III.17).

    Args:
        records: GraspRecords (motions in the object frame; reaching = before ``phases[0]``).
        q_init: (27,) the hand's initial pose, object frame.
        closing: (T, 27) the synthesised closing motion, object frame.
    """
    q0 = np.asarray(q_init, dtype=np.float64)
    best, best_d = None, math.inf
    for r in records:
        seg = r.motion[:r.phases[0] + 1]
        if len(seg) < 3:
            continue
        d = np.linalg.norm(seg[0] - q0) + np.linalg.norm(seg[-1] - closing[0])
        if d < best_d:
            best, best_d = seg, d
    if best is None:  # no example: a straight line (what the dissertation improves on)
        n = frames or 30
        s = _smoothstep(np.linspace(0, 1, n))[:, None]
        return (1 - s) * q0 + s * closing[0]
    if frames:
        idx = np.linspace(0, len(best) - 1, frames)
        best = np.array([np.interp(idx, np.arange(len(best)), best[:, j])
                         for j in range(N_DOF)]).T
    after = closing[1] if len(closing) > 1 else None
    return laplacian_edit(best, q0, closing[0], after)


def manipulation_path(records: Sequence[object], start: np.ndarray, target: np.ndarray,
                      frames: int = 50) -> np.ndarray:
    """Manipulation phase (III.4.3): the object's centre path (frames, 3) from ``start`` to
    ``target`` [m]: the database's manipulation example with the nearest displacement (the
    wrist's path after the grasp, which holds the object rigidly), resampled and edited by
    eq. (III.17) to the new end points. The hand follows it rigidly."""
    start = np.asarray(start, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    want = target - start
    best, best_d = None, math.inf
    for r in records:
        seg = r.motion[r.phases[1] - 1:, 0:3]
        if len(seg) < 3:
            continue
        d = float(np.linalg.norm((seg[-1] - seg[0]) - want))
        if d < best_d:
            best, best_d = seg - seg[0], d
    if best is None:
        s = _smoothstep(np.linspace(0, 1, frames))[:, None]
        return start + s * want
    idx = np.linspace(0, len(best) - 1, frames)
    ex = np.array([np.interp(idx, np.arange(len(best)), best[:, j]) for j in range(3)]).T
    return laplacian_edit(ex + start, start, target)


#: start of the reaching motion relative to the first closing frame, object frame (x from the
#: hand to the object): (back, up) [m], tried in order until the path is collision free
REACH_STARTS: tuple[tuple[float, float], ...] = (
    (0.0, 0.06), (0.03, 0.05), (0.05, 0.035), (0.07, 0.02), (0.09, 0.012))


def safe_reaching(obj: GraspObject, geo: HandGeometry, closing: np.ndarray, yaw: float,
                  records: Sequence[object], frames: int = 30) -> np.ndarray:
    """Reaching (III.4.2) to the first closing frame, object frame: from the first start of
    :data:`REACH_STARTS` (the grip opened) whose reaching path (:func:`reaching_motion`, the
    database's nearest example edited by eq. III.17) keeps the hand out of the object and
    the table (checked through the signed distance field)."""
    r = rot_z(np.float64(yaw)).T
    fingers = [i for i in range(11, N_DOF)]  # index .. little: open the grip
    best, best_hits = None, math.inf
    for back, up in REACH_STARTS:
        q0 = closing[0].copy()
        q0[0:3] += np.array([-back, 0.0, up])
        q0[fingers] *= 0.5
        q0 = np.clip(q0, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])
        path = reaching_motion(records, q0, closing, frames)
        check = path[np.linspace(0, len(path) - 1, min(len(path), 12)).astype(int)]
        rot, pos = geo.frames(check)
        pts = HandGeometry.points(rot, pos, geo.bones, geo.local) @ r
        hits = float(collision_term(obj.sdf, pts[None], geo.radii, -obj.bottom)[0])
        if hits < best_hits:
            best, best_hits = path, hits
        if hits == 0.0:
            break
    return best


def with_weights(weights: EnergyWeights, ablation: str) -> EnergyWeights:
    """Fig. III.9's ablations: ``no_collision`` (w_k = 0), ``no_polygon`` (w1 = 0),
    ``no_cone`` (w2 = 0); ``full``: unchanged."""
    changes = {"full": {}, "no_collision": {"w_k": 0.0}, "no_polygon": {"w1": 0.0},
               "no_cone": {"w2": 0.0}}
    if ablation not in changes:
        raise InputError(f"unknown ablation {ablation!r}; valid: {sorted(changes)}")
    return replace(weights, **changes[ablation])


def bone_finger(bone: str) -> str:
    """The finger of a bone name (``palm`` for the palm)."""
    return bone.split("_")[0] if bone in BONE_NAMES else bone


# ------------------------------------------------------------------------ in a simulated world
#: where the simulated hand starts (the MJCF export's default root position), for the
#: preferred approach direction
HAND_HOME_XY = (0.0, 0.0)
_MODELS: dict[str, dict] = {}


def grasp_models() -> dict:
    """The shipped closing models (loaded once per process)."""
    if "shipped" not in _MODELS:
        from hand_control.grasp.database import load_grasp_models

        _MODELS["shipped"] = load_grasp_models()
    return _MODELS["shipped"]


def grasp_records() -> list:
    """The shipped grasp database (loaded once per process; empty when missing)."""
    if "records" not in _MODELS:
        from hand_control.grasp.database import load_grasp_database

        try:
            _MODELS["records"] = load_grasp_database()
        except InputError:
            _MODELS["records"] = []
    return _MODELS["records"]


def body_yaw(quat_wxyz: Sequence[float]) -> float:
    """Yaw [rad] of a body whose z axis points up (0 for any other orientation: the
    scenarios' upright cylinder, symmetric about its axis)."""
    w, x, y, z = (float(v) for v in quat_wxyz)
    zz = 1.0 - 2.0 * (x * x + y * y)
    if zz < 0.99:
        return 0.0
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def plan_in_world(obj: GraspObject, object_name: str, position: Sequence[float],
                  quat_wxyz: Sequence[float], grip_mode: str | None = None,
                  config: SynthesisConfig | None = None, weights: EnergyWeights | None = None,
                  models: Mapping[str, object] | None = None,
                  geometry: HandGeometry | None = None) -> tuple[object, SynthesisResult]:
    """Synthesise a grasp of ``obj`` resting at ``position`` (its centre of mass) with
    orientation ``quat_wxyz``, approached from the hand's home side; returns the simulation's
    GraspPlan and the synthesis result."""
    yaw = body_yaw(quat_wxyz)
    p = np.asarray(position, dtype=np.float64)
    approach = math.atan2(p[1] - HAND_HOME_XY[1], p[0] - HAND_HOME_XY[0]) - yaw
    control = GraspControl(grip_mode=grip_mode or None,
                           approach_yaw=math.atan2(math.sin(approach), math.cos(approach)))
    res = synthesize(obj, models if models is not None else grasp_models(), control, config,
                     weights, geometry or _geometry(), grasp_records())
    return res.grasp_plan(object_name, p, yaw), res


_GEOMETRY: list[HandGeometry] = []


def _geometry() -> HandGeometry:
    if not _GEOMETRY:
        _GEOMETRY.append(HandGeometry())
    return _GEOMETRY[0]


def primitive_object(obj: object) -> GraspObject:
    """The GraspObject of a scenario's box / ball / upright-cylinder MJCF object."""
    from hand_control.grasp.objects import make_object

    kind = {"box": "box", "ball": "sphere", "stick": "cylinder"}.get(obj.kind)
    if kind is None:
        raise InputError(f"no grasp object for MJCF kind {obj.kind!r}")
    return make_object(kind, tuple(obj.size), obj.mass, obj.friction, name=obj.name)


def synthesize_for_world(spec: object, obj: object, grasp_object: GraspObject | None,
                         position: Sequence[float], quat_wxyz: Sequence[float]) -> object:
    """The GraspPlan of a scenario with ``grasp_source: synthesis`` (lockstep, nodes).

    Raises:
        SolverError: no dynamically feasible grasp was found.
    """
    g = grasp_object or primitive_object(obj)
    plan, res = plan_in_world(g, obj.name, position, quat_wxyz, spec.grip_mode or None,
                              SynthesisConfig(grasp_depth=spec.grasp_depth))
    if not res.feasible:
        raise SolverError(f"scenario {spec.name}: no dynamically feasible grasp of "
                          f"{obj.name!r} found ({res.status}, grip {res.grip_mode})")
    return plan


class PerformerSynthesizer:
    """The performance interface's grasp (III.6): as the operator's closing begins, the closing
    motion synthesised for the object from the operator's hand (its wrist and approach
    direction in the object's frame as E_c), instead of a grasp planned beforehand.

    Call it with the operator's recent world-frame poses (n, 27) and the object's pose (4, 4)
    (its body origin at the centre of mass, z up); returns a GraspPlan (world, with the
    closing motion) or ``None`` when no dynamically feasible grasp was found.
    """

    def __init__(self, obj: GraspObject, object_name: str = "object",
                 models: Mapping[str, object] | None = None,
                 config: SynthesisConfig | None = None, grip_mode: str | None = None) -> None:
        self.obj, self.name = obj, object_name
        self.models = models if models is not None else grasp_models()
        # online, inside the closing phase: no reaching motion, no second run (the tracked
        # poses wait while it runs; a smaller swarm found no feasible grasp of teleop_stone)
        self.config = config or SynthesisConfig(retries=0, reaching_frames=0)
        self.grip_mode = grip_mode
        self.last: SynthesisResult | None = None

    def __call__(self, poses: np.ndarray, object_pose: np.ndarray) -> object | None:
        from hand_control.grasp.database import to_object_frame

        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != N_DOF or not np.isfinite(poses).all():
            raise InputError(f"performer poses must be finite (n, {N_DOF})")
        com = np.asarray(object_pose, dtype=np.float64)[:3, 3]
        rot = np.asarray(object_pose, dtype=np.float64)[:3, :3]
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        perf = to_object_frame(poses, com, yaw)  # the object's body frame
        wrist = perf[-1, 0:3]
        control = GraspControl(grip_mode=self.grip_mode, performer=np.vstack([perf, perf[-1:]]),
                               approach_yaw=math.atan2(-wrist[1], -wrist[0]),
                               performer_mode="onset")
        self.last = synthesize(self.obj, self.models, control, self.config,
                               geometry=_geometry())
        if not self.last.feasible:
            return None
        return self.last.grasp_plan(self.name, com, yaw)
