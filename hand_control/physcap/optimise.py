"""Sampling-based control optimisation of a capture (seed 000 sec. 6).

Every ``step`` (0.05 s) each saved sample spawns new ones: target poses of the hand (the PD
servos' set points, eq. 8) and of the object (the virtual wrench's target, eq. 9) drawn
uniformly in hypercubes around the reference frame, or, with contact-based sampling, around
seed poses made consistent with a sampled contact configuration (:mod:`.contacts`). The
composite controller (eq. 8-13, :class:`~hand_control.control.ControllerCore` on the live
MuJoCo state) advances the simulation over the step; the new frame's energy is eq. 2 without
images: the mean squared 3-D keypoint error, the object's position and orientation errors and
a penalty on hand-object penetration; a capture with multi-view images adds eq. (3)'s image
term (:mod:`.images`). :func:`~.selection.sampling_optimise` keeps the samples
(sec. 6's selection) and returns the lowest-energy chain.

A sample's simulation restarts from its parent's full integration state
(``mj_getState(mjSTATE_INTEGRATION)``: positions, velocities, controls, applied forces, warm
start), so :func:`replay_control` reproduces an optimised motion exactly from its control.
The composite controller runs in Python at every control update, so the samples are simulated
by ``n_threads`` threads, each with its own ``MjData`` and controller (MuJoCo releases the
GIL while stepping); ``mujoco.rollout``, which runs open-loop control sequences, cannot call
the controller between steps.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from hand_capture.model.hand import HandModel
from hand_capture.model.skeleton import BONE_NAMES, N_KEYPOINTS
from hand_control.control import ControllerCore, ControllerNodeConfig
from hand_control.errors import SimulationError
from hand_control.physcap.capture import (
    Capture,
    CapturedObject,
    CaptureError,
    PhysCapConfig,
    PhysCapResult,
)
from hand_control.physcap.contacts import ContactIK, contact_configurations
from hand_control.physcap.selection import sampling_optimise
from hand_control.physcap.world import OBJECT_NAME, build_capture_world
from hand_control.sim.kinematics import MujocoKinematics

__all__ = ["Segment", "SegmentSimulator", "frame_costs", "optimise", "quat_angle",
           "replay_control", "resample_capture"]

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_HAND_MODEL: HandModel | None = None


def _hand_model() -> HandModel:
    global _HAND_MODEL
    if _HAND_MODEL is None:
        _HAND_MODEL = HandModel()
    return _HAND_MODEL


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (..., 4) quaternions w, x, y, z."""
    w1, x1, y1, z1 = np.moveaxis(np.asarray(a, float), -1, 0)
    w2, x2, y2, z2 = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    axis=-1)


def rotvec_quat(v: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 4) unit quaternions."""
    v = np.asarray(v, float)
    a = np.linalg.norm(v, axis=-1, keepdims=True)
    s = np.where(a > 1e-12, np.sin(a / 2) / np.maximum(a, 1e-12), 0.5)
    return np.concatenate([np.cos(a / 2), s * v], axis=-1)


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] between (..., 4) unit quaternions."""
    dot = np.abs((np.asarray(a, float) * np.asarray(b, float)).sum(axis=-1))
    return 2.0 * np.arccos(np.minimum(1.0, dot))


def resample_capture(c: Capture, step: float) -> tuple[np.ndarray, ...]:
    """The capture on a ``step`` grid from its first frame: ``(times (T,), hand_q (T, 27),
    object_pose (T, 7), keypoints (T, K, 3) or None)`` (linear; quaternions nlerp). A capture
    already on the grid is returned as it is."""
    dt = np.diff(c.times)
    if np.abs(dt - step).max() < 1e-6:
        return c.times, c.hand_q, c.object_pose, c.keypoints
    n = int(math.floor(c.duration / step + 1e-6)) + 1
    t = c.times[0] + step * np.arange(n)

    def lerp(a: np.ndarray) -> np.ndarray:
        flat = a.reshape(a.shape[0], -1)
        out = np.stack([np.interp(t, c.times, flat[:, j]) for j in range(flat.shape[1])], 1)
        return out.reshape((n,) + a.shape[1:])

    quat = c.object_pose[:, 3:7].copy()
    for i in range(1, len(quat)):  # one hemisphere before interpolating
        if quat[i] @ quat[i - 1] < 0:
            quat[i] = -quat[i]
    pose = lerp(np.concatenate([c.object_pose[:, 0:3], quat], axis=1))
    pose[:, 3:7] /= np.linalg.norm(pose[:, 3:7], axis=1, keepdims=True)
    kp = None if c.keypoints is None else lerp(c.keypoints)
    return t, lerp(c.hand_q), pose, kp


def smooth_reference(x: np.ndarray, half: int) -> np.ndarray:
    """Centred moving average of (T, D) rows over ``2 half + 1`` frames (fewer at the
    ends); quaternion columns 3:7 of a (T, 7) pose are renormalised by the caller."""
    if half <= 0:
        return x.copy()
    c = np.cumsum(np.vstack([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    t = x.shape[0]
    lo = np.clip(np.arange(t) - half, 0, t)
    hi = np.clip(np.arange(t) + half + 1, 0, t)
    return (c[hi] - c[lo]) / (hi - lo)[:, None]


def frame_costs(config: PhysCapConfig, hand_q: np.ndarray, object_pose: np.ndarray,
                penetration: np.ndarray, kp_obs: np.ndarray, obj_obs: np.ndarray
                ) -> np.ndarray:
    """Energy of N simulated frames against one observed frame (eq. 2 without images).

    ``E = w_kp mean_k |x_k - x_k^obs|^2 + w_pos |p - p^obs|^2 + w_rot angle(q, q^obs)^2
    + w_pen max(0, penetration - 2 mm)^2``.

    Args:
        hand_q: (N, 27) simulated hand poses; object_pose: (N, 7).
        penetration: (N,) deepest hand-object penetration [m] (>= 0).
        kp_obs: (21, 3) observed keypoints; obj_obs: (7,) observed object pose.
    """
    kp = _hand_model().joint_positions(hand_q)  # (N, 21, 3)
    e_kp = ((kp - kp_obs[None]) ** 2).sum(axis=-1).mean(axis=-1)
    e_pos = ((object_pose[:, 0:3] - obj_obs[None, 0:3]) ** 2).sum(axis=-1)
    e_rot = quat_angle(object_pose[:, 3:7], obj_obs[None, 3:7]) ** 2
    pen = np.maximum(0.0, penetration - 0.002) ** 2
    return (config.w_keypoint * e_kp + config.w_object_pos * e_pos
            + config.w_object_rot * e_rot + config.w_penetration * pen)


class _Targets:
    """The controller's reference during one step: the sample's targets (a
    :class:`~hand_control.control.kinematics.ControlReference`)."""

    phase = "manipulation"
    grasp = True

    def __init__(self) -> None:
        self.q_target = np.zeros(27)
        self.object_position = np.zeros(3)
        self.object_quaternion = np.array([1.0, 0.0, 0.0, 0.0])

    def __call__(self, t: float) -> _Targets:
        return self

    def is_finite(self) -> bool:
        return True


@dataclass(eq=False)
class Segment:
    """The outcome of simulating one step: the end state and what it shows."""

    state: np.ndarray       # integration state (mj_getState)
    hand_q: np.ndarray      # (27,)
    object_pose: np.ndarray  # (7,)
    wrench: np.ndarray      # (6,) mean virtual wrench over the step
    penetration: float      # deepest hand-object penetration at the end [m]
    ok: bool                # False: the simulation diverged
    q_offset: np.ndarray | None = None  # (27,) this step's hand target - reference


class SegmentSimulator:
    """One MuJoCo world of a capture with its composite controller: simulates a step from a
    given state under given hand and object targets (:meth:`run`).

    Args:
        obj: the object; hand_q (27,), object_pose (7,): the initial state (at rest).
        config: timestep, control rate and control mode.
    """

    def __init__(self, obj: CapturedObject, hand_q: np.ndarray, object_pose: np.ndarray,
                 config: PhysCapConfig) -> None:
        self.config = config
        self.world, gains = build_capture_world(obj, hand_q, object_pose, config.timestep,
                                                config.control)
        w = self.world
        m = w.model
        self.m, self.d = m, w.data
        o = w.objects[OBJECT_NAME]
        self.body = int(o["body"])
        self.obj_adr = int(o["qpos"])
        self.obj_geoms = np.asarray(o["geoms"], dtype=np.int64)
        self.ref = _Targets()
        self.core = ControllerCore(
            MujocoKinematics(w), self.ref, obj.mass, ControllerNodeConfig(), gains,
            object_inertia=float(m.body_inertia[self.body].min()),
            control_period=config.control_every * config.timestep)
        self.views = w.object_state_views(OBJECT_NAME)
        # the contact QP warm-starts from its last active set: cleared at the start of every
        # step, so that a step's outcome depends only on its state and control (a replay
        # reproduces the optimised motion bit for bit, whatever was simulated before)
        self._qp_warm = getattr(self.core.controller.qp, "_passive", None)
        self.hand_geom = np.zeros(m.ngeom, dtype=bool)
        hand_bodies = {int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n))
                       for n in BONE_NAMES}
        self.hand_geom[[g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in hand_bodies]] \
            = True
        self.obj_geom = np.zeros(m.ngeom, dtype=bool)
        self.obj_geom[self.obj_geoms] = True
        self.state_size = mujoco.mj_stateSize(m, _STATE)
        self.initial_state = self.get_state()

    def get_state(self) -> np.ndarray:
        buf = np.empty(self.state_size)
        mujoco.mj_getState(self.m, self.d, buf, _STATE)
        return buf

    def _penetration(self) -> float:
        d = self.d
        if d.ncon == 0:
            return 0.0
        g = d.contact.geom
        pair = (self.hand_geom[g[:, 0]] & self.obj_geom[g[:, 1]]) | \
            (self.hand_geom[g[:, 1]] & self.obj_geom[g[:, 0]])
        if not pair.any():
            return 0.0
        return float(max(0.0, -d.contact.dist[pair].min()))

    def run(self, state: np.ndarray, q_target: np.ndarray, object_target: np.ndarray,
            n_steps: int) -> Segment:
        """Simulate ``n_steps`` physics steps from ``state`` with the hand's PD targets
        ``q_target`` (27,) and the object's target pose ``object_target`` (7,)."""
        m, d, w, core = self.m, self.d, self.world, self.core
        mujoco.mj_setState(m, d, state, _STATE)
        mujoco.mj_forward(m, d)
        if self._qp_warm is not None:
            self._qp_warm.clear()
        self.ref.q_target = q_target
        self.ref.object_position = object_target[0:3]
        self.ref.object_quaternion = object_target[3:7]
        every = self.config.control_every
        q, qd = d.qpos[0:27], d.qvel[0:27]
        wrench = np.zeros(6)
        n_w = 0
        ok = True
        try:
            for i in range(n_steps):
                if i % every == 0:
                    cmd = core.step_world(d.time, w, self.body, q, qd, self.views)
                    if cmd.pd_only:
                        w.set_targets(cmd.positions)
                    else:
                        w.set_command(cmd.positions, cmd.efforts, check=False)
                        out = core.last_output
                        if out is not None:
                            wrench[0:3] += out.force_target
                            wrench[3:6] += out.torque_target
                            n_w += 1
                w.step()
        except SimulationError:
            ok = False
        if n_w:
            wrench /= n_w
        obj = d.qpos[self.obj_adr:self.obj_adr + 7].copy()
        hand = d.qpos[0:27].copy()
        if not (ok and np.isfinite(obj).all() and np.isfinite(hand).all()):
            return Segment(state, np.full(27, np.nan), np.full(7, np.nan), wrench, 0.0, False)
        return Segment(self.get_state(), hand, obj, wrench, self._penetration(), True)


class _Search:
    """The callbacks of :func:`sampling_optimise` for one capture."""

    def __init__(self, obj: CapturedObject, ref_q: np.ndarray, ref_obj: np.ndarray,
                 kp_obs: np.ndarray, config: PhysCapConfig, images: Any = None) -> None:
        self.config = config
        self.images = images  # CaptureImages or None: eq. (3)'s image term added per frame
        self.ref_q, self.ref_obj, self.kp_obs = ref_q, ref_obj, kp_obs
        # the sampling centres: the reference, smoothed (cost: the reference as it is)
        self.centre_q = smooth_reference(ref_q, config.smoothing)
        po = ref_obj.copy()
        for i in range(1, len(po)):  # one quaternion hemisphere before averaging
            if po[i, 3:7] @ po[i - 1, 3:7] < 0:
                po[i, 3:7] *= -1.0
        po = smooth_reference(po, config.smoothing)
        po[:, 3:7] /= np.linalg.norm(po[:, 3:7], axis=1, keepdims=True)
        # servo lag: the wrist's centres lead by `lead` frames of the reference's velocity
        self.centre_q[1:, 0:3] += config.lead * np.diff(self.centre_q[:, 0:3], axis=0)
        po[1:, 0:3] += config.object_lead * np.diff(po[:, 0:3], axis=0)
        self.centre_obj = po
        self.sims = [SegmentSimulator(obj, ref_q[0], ref_obj[0], config)
                     for _ in range(config.n_threads)]
        s0 = self.sims[0]
        self.n_steps = int(round(config.step / config.timestep))
        self.ik = ContactIK(s0.m, s0.obj_adr, s0.obj_geoms, config.contact_depth,
                            config.contact_clearance)
        c = config
        self.width = np.r_[np.full(3, c.root_pos_width), np.full(3, c.root_rot_width),
                           np.full(21, c.finger_width)]
        self.pool = ThreadPoolExecutor(c.n_threads) if c.n_threads > 1 else None
        self.contact_log: list[int] = []

    def initial(self) -> tuple[Segment, float]:
        s = self.sims[0]
        seg = Segment(s.initial_state, self.ref_q[0].copy(), self.ref_obj[0].copy(),
                      np.zeros(6), 0.0, True)
        cost = frame_costs(self.config, seg.hand_q[None], seg.object_pose[None],
                           np.zeros(1), self.kp_obs[0], self.ref_obj[0])[0]
        if self.images is not None:
            cost += self.images.energies(0, seg.hand_q[None], seg.object_pose[None])[0]
        return seg, float(cost)

    def centres(self, step: int, n: int, rng: np.random.Generator,
                parents: list[Segment], parent_idx: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """(n, 27) hypercube centres and (n,) width scales: the reference frame, contact
        seeds (sec. 6) or, for ``carry_fraction`` of the samples, the reference plus the
        parent's own correction of the previous step (half width)."""
        q_ref = self.centre_q[step + 1]
        out = np.tile(q_ref, (n, 1))
        scale = np.ones(n)
        carry = rng.random(n) < self.config.carry_fraction
        for i in np.flatnonzero(carry):
            off = parents[parent_idx[i]].q_offset
            if off is not None:
                out[i] += off
                scale[i] = 0.5
        if self.config.sampling != "contact":
            return out, scale
        self.ik.set_object(self.centre_obj[step + 1])
        cc = contact_configurations(self.ik.distances(q_ref), self.config.contact_threshold,
                                    self.config.max_contacts)
        self.contact_log.append(int(cc.bones.size))
        if cc.bones.size == 0:
            return out, scale
        seeds, _ = self.ik.seeds(q_ref, cc)
        use = (rng.random(n) < self.config.seed_fraction) & ~carry
        pick = rng.choice(len(seeds), size=n, p=cc.probabilities)
        out[use] = seeds[pick[use]]
        return out, scale

    def propose(self, step: int, parents: list[Segment], parent_idx: np.ndarray,
                rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
        n = parent_idx.size
        c = self.config
        centre, scale = self.centres(step, n, rng, parents, parent_idx)
        q = centre + rng.uniform(-1.0, 1.0, (n, 27)) * self.width * scale[:, None]
        obj = np.tile(self.centre_obj[step + 1], (n, 1))
        obj[:, 0:3] += rng.uniform(-1.0, 1.0, (n, 3)) * c.object_pos_width
        rv = rng.uniform(-1.0, 1.0, (n, 3)) * c.object_rot_width
        obj[:, 3:7] = quat_mul(rotvec_quat(rv), obj[:, 3:7])
        return [(q[i], obj[i]) for i in range(n)]

    def simulate(self, step: int, parents: list[Segment], parent_idx: np.ndarray,
                 controls: list[tuple[np.ndarray, np.ndarray]]
                 ) -> tuple[list[Segment], np.ndarray, list[Any]]:
        n = len(controls)

        def work(k: int, lo: int, hi: int) -> list[Segment]:
            sim = self.sims[k]
            return [sim.run(parents[parent_idx[i]].state, controls[i][0], controls[i][1],
                            self.n_steps) for i in range(lo, hi)]

        if self.pool is None:
            segs = work(0, 0, n)
        else:
            t = len(self.sims)
            bounds = np.linspace(0, n, t + 1).astype(int)
            futs = [self.pool.submit(work, k, int(bounds[k]), int(bounds[k + 1]))
                    for k in range(t)]
            segs = [s for f in futs for s in f.result()]
        q_ref = self.centre_q[step + 1]
        for s, c in zip(segs, controls, strict=True):
            s.q_offset = c[0] - q_ref
        ok = np.array([s.ok for s in segs])
        costs = np.full(n, np.inf)
        if ok.any():
            idx = np.flatnonzero(ok)
            costs[idx] = frame_costs(
                self.config, np.array([segs[i].hand_q for i in idx]),
                np.array([segs[i].object_pose for i in idx]),
                np.array([segs[i].penetration for i in idx]), self.kp_obs[step + 1],
                self.ref_obj[step + 1])
            if self.images is not None:  # eq. (3) against the frame's observed views
                costs[idx] += self.images.energies(
                    step + 1, np.array([segs[i].hand_q for i in idx]),
                    np.array([segs[i].object_pose for i in idx]))
        return segs, costs, [None] * n

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


def _goal_figures(config: PhysCapConfig, obj_sim: np.ndarray, obj_ref: np.ndarray
                  ) -> tuple[bool, bool, float]:
    """(reached_goal, dropped, final error [m]) of a simulated object trajectory against the
    reference one: the goal is the reference's last position; dropped when, after the
    reference has lifted the object by 2 cm, the simulated one is ``drop_tolerance`` lower."""
    final = float(np.linalg.norm(obj_sim[-1, 0:3] - obj_ref[-1, 0:3]))
    lifted = obj_ref[:, 2] > obj_ref[0, 2] + 0.02
    drop = bool(np.any(lifted & (obj_sim[:, 2] < obj_ref[:, 2] - config.drop_tolerance))) \
        or not np.isfinite(obj_sim).all()
    return final < config.success_tolerance, drop, final


def optimise(capture: Capture, config: PhysCapConfig, progress: Any = None,
             images: Any = None) -> PhysCapResult:
    """:func:`hand_control.physcap.capture.optimise_capture` (see there)."""
    times, ref_q, ref_obj, kp = resample_capture(capture, config.step)
    if images is not None and (images.n_frames != len(times) or times is not capture.times):
        raise CaptureError(f"capture {capture.name!r}: its images need one group per frame on "
                           f"the {config.step} s step grid ({len(times)} frames); got "
                           f"{images.n_frames} for a capture of {capture.n_frames} frames")
    if kp is not None and kp.shape[1] != N_KEYPOINTS:
        raise CaptureError(f"capture {capture.name!r}: the cost compares the model's "
                           f"{N_KEYPOINTS} keypoints (KEYPOINT_NAMES), the capture has "
                           f"{kp.shape[1]}")
    if len(times) < 2:
        raise CaptureError(f"capture {capture.name!r} is shorter than one step "
                           f"({config.step} s)")
    kp_obs = _hand_model().joint_positions(ref_q) if kp is None else kp
    search = _Search(capture.obj, ref_q, ref_obj, kp_obs, config, images)
    try:
        seg0, cost0 = search.initial()
        rng = np.random.default_rng(config.seed)
        path = sampling_optimise(seg0, cost0, len(times) - 1, search.propose, search.simulate,
                                 config.n_samples, config.n_keep, rng, progress)
    finally:
        search.close()
    segs: list[Segment] = path.states
    hand = np.array([s.hand_q for s in segs])
    obj = np.array([s.object_pose for s in segs])
    ctl = path.controls[1:]
    reached, dropped, final = _goal_figures(config, obj, ref_obj)
    return PhysCapResult(
        name=capture.name, times=times, hand_q=hand, object_pose=obj, reference_q=ref_q,
        reference_object=ref_obj, targets=np.array([c[0] for c in ctl]).reshape(-1, 27),
        object_targets=np.array([c[1] for c in ctl]).reshape(-1, 7),
        virtual_forces=np.array([s.wrench for s in segs[1:]]).reshape(-1, 6),
        costs=path.costs, frame_seconds=path.step_seconds, success=reached and not dropped,
        reached_goal=reached, dropped=dropped, final_error_m=final, config=config,
        obj=capture.obj,
        extras={"potential_contacts_mean": float(np.mean(search.contact_log))
                if search.contact_log else 0.0})


def replay_control(obj: CapturedObject, hand_q0: np.ndarray, object_pose0: np.ndarray,
                   targets: np.ndarray, object_targets: np.ndarray, config: PhysCapConfig,
                   mass: float | None = None, friction: float | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate a control: from the initial state (hand ``hand_q0`` (27,), object
    ``object_pose0`` (7,), at rest) apply each step's hand targets ``targets`` (S, 27) and
    object targets ``object_targets`` (S, 7) with the composite controller, as the optimiser
    did (the same result for the same inputs). ``mass`` / ``friction`` override the object's.

    Returns:
        ``(hand_q (S + 1, 27), object_pose (S + 1, 7), ok (S + 1,))``; after a divergence
        the rest is NaN and ``ok`` False.
    """
    if mass is not None or friction is not None:
        obj = CapturedObject(obj.kind, obj.size, obj.mass if mass is None else mass,
                             obj.friction if friction is None else friction, obj.mesh)
    sim = SegmentSimulator(obj, hand_q0, object_pose0, config)
    n = int(round(config.step / config.timestep))
    hand = [np.asarray(hand_q0, float)]
    pose = [sim.d.qpos[sim.obj_adr:sim.obj_adr + 7].copy()]
    ok = [True]
    state = sim.initial_state
    for qt, ot in zip(np.asarray(targets, float), np.asarray(object_targets, float),
                      strict=True):
        if not ok[-1]:
            hand.append(np.full(27, np.nan))
            pose.append(np.full(7, np.nan))
            ok.append(False)
            continue
        seg = sim.run(state, qt, ot, n)
        state = seg.state
        hand.append(seg.hand_q)
        pose.append(seg.object_pose)
        ok.append(seg.ok)
    return np.array(hand), np.array(pose), np.array(ok)
