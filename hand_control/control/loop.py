"""The controller side of the sim <-> controller loop, as arrays (what the controller node wraps).

:class:`ControllerCore` holds the composite controller (one :class:`CompositeControlConfig`:
every gain and QP setting), a reference motion and the hand's kinematics behind a small
interface (:class:`~hand_control.control.kinematics.HandKinematics`: contact Jacobians from
joint positions, the hand's limits). Each :meth:`ControllerCore.step` maps

    joint state + object state + contacts + time  ->  servo targets + feed-forward efforts

:meth:`ControllerCore.step_world` is the same step for a controller in the simulator's process
(the lockstep loop): it reads the contacts from a
:class:`~hand_control.control.kinematics.LiveContacts` world and lets it apply the Jacobian
transpose, with the same equations (:meth:`CompositeController.object_wrench` and
:meth:`CompositeController.realise`) and results up to rounding. Nothing here imports the
simulator.

Failures never reach a joint: a QP without solution, bad input or a non-finite result gives a
PD-only command (zero efforts), counted in :attr:`ControllerCore.counters`; efforts are
clipped to the actuators' limits and position targets to the joints' (counted as
``saturated``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from hand_capture.config import param, validate
from hand_control.contact import ContactSet
from hand_control.contact.qp import ContactForceResult
from hand_control.control.composite import (
    CompositeController,
    ControlOutput,
    ObjectState,
    ObjectTarget,
    pd_torques,
)
from hand_control.control.gains import CompositeControlConfig
from hand_control.control.kinematics import (
    ControlReference,
    HandKinematics,
    LiveContacts,
    ReferenceSample,
)
from hand_control.errors import HandSuiteError, InputError

__all__ = ["Command", "ControllerCore", "ControllerNodeConfig"]


@dataclass(frozen=True)
class ControllerNodeConfig:
    """The controller node's own settings (scenario, reference, rates); the gains and QP
    settings are :class:`CompositeControlConfig`'s (the node declares both)."""

    scenario: str = param("lift_box", "scenario file (config/scenarios/<name>.yaml): object, "
                          "grasp and reference motion")
    reference: str = param(
        "scripted", "hand target: 'scripted' (the scenario's reference at the current time) or "
        "'hand_pose' (hand/pose from a tracker; the object target then comes from "
        "control/object_target)", choices=("scripted", "hand_pose"))
    state_timeout: float = param(0.2, "inputs older than this [s] are ignored", lo=0.0)
    forces_rate: float = param(
        50.0, "rate of control/contact_forces and control/contact_markers [Hz] (they are for "
        "RViz and recording; 0 = every control step)", lo=0.0)
    marker_scale: float = param(0.01, "arrow length per newton in control/contact_markers "
                                "[m/N]", lo=0.0)
    world_frame: str = param("world", "frame of the simulation; hand/pose targets must be in "
                             "it (reference: hand_pose)")
    control_period: float = param(
        0.004, "period of the joint states that trigger the control steps [s] (the sim's "
        "timestep x steps_per_tick); caps the object's rotational gains for stability",
        lo=1e-4, hi=0.1)
    target_cutoff: float = param(
        4.0, "low-pass cutoff of hand and object targets that come from outside (hand/pose, "
        "control/object_target) [Hz]: tracked poses arrive at 10-30 Hz, and each step of the "
        "target jerks the hand and shakes a held object loose; 0 = use them as they come",
        lo=0.0)
    command_on_reference: bool = param(
        True, "reference: hand_pose: a new hand pose is answered at once, by a control step "
        "on the newest joint state, instead of at the next joint state (up to one "
        "control_period later)")

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True, eq=False)
class Command:
    """One controller output: servo targets and feed-forward efforts by joint name."""

    joint_names: tuple[str, ...]
    positions: np.ndarray
    efforts: np.ndarray
    phase: str
    planned_forces: np.ndarray      # (K, 3) on the object [N] (empty when none)
    planned_torsion: np.ndarray     # (K,)
    contact_points: np.ndarray      # (K, 3)
    contact_normals: np.ndarray     # (K, 3)
    contact_bodies: tuple[str, ...]
    pd_only: bool                   # no grasp torques this step (by design or fallback)


class ControllerCore:
    """Composite controller + scenario reference + hand kinematics (see module docstring)."""

    def __init__(self, kinematics: HandKinematics, reference: ControlReference,
                 object_mass: float, config: ControllerNodeConfig | None = None,
                 gains: CompositeControlConfig | None = None, object_inertia: float = 0.0,
                 control_period: float = 0.001) -> None:
        """
        Args:
            kinematics: the hand's kinematics and limits (e.g. the sim's
                :class:`~hand_control.sim.kinematics.MujocoKinematics`).
            reference: the reference motion (hand targets, object target, phases).
            object_mass: the grasped object's mass [kg].
            config: the node's settings (reference source, target filter).
            gains: every gain and QP setting (defaults: the papers' tables; the simulation
                cancels gravity on the hand, so ``gravity_compensation`` is not used here).
            object_inertia: the object's smallest principal inertia [kg m^2] (caps the
                rotational object gains, see below); 0 = no cap.
            control_period: time between control steps [s].
        """
        self.config = config or ControllerNodeConfig()
        self.gains = gains or CompositeControlConfig()
        self.kin = kinematics
        self.reference = reference
        self.object_mass = float(object_mass)
        # Virtual object servo (eq. III.22, gains of Table III.1). Its damping is explicit at
        # the control period: for small objects kd_rot * dt / I exceeds the explicit-Euler
        # limit (a 50 g ball: 0.5 * 1e-3 / 2.5e-5 = 20) and the virtual torque oscillates and
        # throws the object. The rotational gains are therefore capped at
        # kd <= 0.5 I / dt and kp <= 0.25 I / dt^2 (no change for the tables' 1 kg objects).
        kd_rot, kp_rot = self.gains.object_kd_rotate, self.gains.object_kp_rotate
        if object_inertia > 0:
            kd_rot = min(kd_rot, 0.5 * object_inertia / control_period)
            kp_rot = min(kp_rot, 0.25 * object_inertia / control_period**2)
        self.object_rot_gains = (kp_rot, kd_rot)
        self.controller = CompositeController(
            replace(self.gains, gravity_compensation=False, object_kp_rotate=kp_rot,
                    object_kd_rotate=kd_rot),
            joint_names=kinematics.joint_names)
        self.joint_names = tuple(kinematics.joint_names)
        n = len(self.joint_names)
        lim = np.asarray(kinematics.effort_limits, dtype=np.float64)
        plim = np.asarray(kinematics.position_limits, dtype=np.float64)
        if lim.shape != (n,) or plim.shape != (n, 2) or np.isnan(lim).any() \
                or np.isnan(plim).any() or (lim < 0).any():
            raise InputError(f"kinematics limits need shapes ({n},) and ({n}, 2), no NaN")
        self._effort_hi = lim
        self._effort_lo = -lim
        self._ones = np.ones(n)
        self._pos_lo, self._pos_hi = plim[:, 0].copy(), plim[:, 1].copy()
        self._no_gravity = not self.controller.config.gravity_compensation
        self._composite = self.controller.config.mode == "composite"
        self._reference_finite = bool(reference.is_finite())
        self._zeros = np.zeros(len(self.joint_names))  # read-only use: finiteness checks
        self._zeros.setflags(write=False)
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        self.counters = {"steps": 0, "qp_fallbacks": 0, "rejected_inputs": 0,
                         "non_finite_outputs": 0, "saturated": 0}
        self._live: tuple | None = None  # see last_output
        self._last_output: ControlOutput | None = None
        self.object_target_override: tuple[np.ndarray, np.ndarray] | None = None
        self.hand_target_override: np.ndarray | None = None
        # grasp torques on/off from outside (teleoperation: on in the manipulation phase of
        # the grasp-phase detector); None = the scenario reference's phases
        self.grasp_override: bool | None = None
        self._filtered: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None

    def needs_contacts(self, t: float) -> bool:
        """Whether the step at ``t`` uses contacts (composite mode, grasp torques on)."""
        return self.controller.config.mode == "composite" and self._grasp_on(self.reference(t))

    def _grasp_on(self, ref: ReferenceSample) -> bool:
        """Grasp torques on: ``grasp_override`` when set, else the reference's phase."""
        return ref.grasp if self.grasp_override is None else self.grasp_override

    def _low_pass(self, t: float, q: np.ndarray, pos: np.ndarray, quat: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First-order low-pass (``target_cutoff``) of the hand and object targets at time
        ``t`` [s]: joint values and position lerp, quaternion nlerp (same hemisphere)."""
        f = self._filtered
        if f is None or t <= f[0]:
            self._filtered = (t, np.array(q, float), np.array(pos, float), np.array(quat, float))
            return self._filtered[1:]
        a = 1.0 - math.exp(-2.0 * math.pi * self.config.target_cutoff * (t - f[0]))
        quat = np.asarray(quat, float)
        if float(quat @ f[3]) < 0.0:
            quat = -quat
        qq = f[3] + a * (quat - f[3])
        self._filtered = (t, f[1] + a * (np.asarray(q, float) - f[1]),
                          f[2] + a * (np.asarray(pos, float) - f[2]), qq / np.linalg.norm(qq))
        return self._filtered[1:]

    def hand_pose_from_names(self, names: Sequence[str], positions: Sequence[float],
                             default: np.ndarray | None = None) -> np.ndarray:
        """A (n_hand,) vector from name/value lists; unknown names raise InputError."""
        q = np.zeros(len(self.joint_names)) if default is None else default.copy()
        if len(names) != len(positions):
            raise InputError(f"{len(names)} names but {len(positions)} values")
        for n, v in zip(names, positions, strict=True):
            i = self._index.get(n)
            if i is None:
                raise InputError(f"unknown joint {n!r}")
            q[i] = v
        if not np.isfinite(q).all():
            raise InputError("non-finite joint values")
        return q

    def step(self, t: float, q: np.ndarray, qd: np.ndarray, object_pose: tuple[np.ndarray, ...],
             contact_bodies: Sequence[str], contact_points: np.ndarray,
             contact_normals: np.ndarray, contact_forces: np.ndarray,
             contact_friction: np.ndarray, contact_set: ContactSet | None = None,
             trusted: bool = False) -> Command:
        """One control step.

        Args:
            t: time [s] on the reference's clock (simulation time).
            q, qd: (n_hand,) hand joint positions / velocities (``joint_names`` order).
            object_pose: ``(position, quaternion wxyz, linear velocity, angular velocity)``.
            contact_*: hand-object contacts (hand = body 1), world frame.
            contact_set: contacts with Jacobians already computed (lockstep path).
            trusted: the inputs come straight from a :class:`SimWorld` in this process
                (finite float64 arrays of the right shapes, unit quaternion): the controller
                skips its input checks (same equations, same result). The output is still
                checked for NaN/Inf.
        """
        self.counters["steps"] += 1
        ref = self.reference(t)
        q_target, obj_pos, obj_quat = self._targets(t, ref)
        effort = None
        k = len(contact_bodies)
        forces = torsion = None
        if self._grasp_on(ref) and self.controller.config.mode == "composite" and k > 0:
            try:
                if contact_set is None:
                    self.kin.update(q)
                    jp, jr = self.kin.jacobians(contact_bodies, contact_points)
                    contact_set = ContactSet(contact_points, contact_normals,
                                             contact_friction, forces=contact_forces,
                                             jacp=jp, jacr=jr)
                if trusted and self.object_target_override is None:
                    obj = ObjectState.trusted(object_pose[0], object_pose[1], object_pose[2],
                                              object_pose[3], self.object_mass)
                    target = ObjectTarget.trusted(obj_pos, obj_quat)
                else:
                    obj = ObjectState(object_pose[0], object_pose[1], object_pose[2],
                                      object_pose[3], self.object_mass)
                    target = ObjectTarget(obj_pos, obj_quat)
                out = self.controller.compute(q, qd, q_target, obj, target, contact_set,
                                              grasp=True, check=not trusted)
                self.last_output = out
                if out.fallback:
                    self.counters["qp_fallbacks"] += 1
                else:  # tau_gravity is zero here (gravity compensated inside MuJoCo);
                    # the command's own array (clipped in place by _command)
                    effort = out.tau_grasp.copy() if self._no_gravity else \
                        out.tau_grasp + out.tau_gravity
                    forces, torsion = out.qp.forces, out.qp.torsion
            except HandSuiteError:
                self.counters["rejected_inputs"] += 1
        if effort is not None and not trusted:
            contact_points = np.asarray(contact_points).reshape(-1, 3)
            contact_normals = np.asarray(contact_normals).reshape(-1, 3)
            contact_bodies = tuple(contact_bodies)
        # trusted: (K, 3) arrays and a tuple of names from SimWorld.contacts, as they are
        return self._command(q, q_target, effort, ref.phase, forces, torsion, contact_points,
                             contact_normals, contact_bodies)

    def step_world(self, t: float, world: LiveContacts, object_body: int, q: np.ndarray,
                   qd: np.ndarray, object_views: tuple[np.ndarray, ...]) -> Command:
        """One control step on the live state of a :class:`SimWorld` in this process (the
        lockstep loop): what :meth:`step` computes with ``trusted=True`` and the world's
        contacts, without its intermediate objects.

        The contacts come from :meth:`SimWorld.object_contacts`, the contact forces from the
        QP on their arrays (:meth:`ContactForceQP.solve_arrays`, method ``dissertation``; seed
        000's eq. 10 needs the simulator's contact forces: use :meth:`step`), and the
        Jacobian-transpose map of eq. (12) / (III.21) from MuJoCo (``mj_applyFT`` on the
        current state: :meth:`SimWorld.wrench_torques` with each contact's wrench about the
        object's centre of mass) instead of stacked contact Jacobians: the same torques up to
        rounding (the order of the sums).

        Args:
            t: simulation time [s].
            world: the simulated world; its ``data`` holds the state of this step.
            object_body: the grasped object's body id.
            q, qd: (n_hand,) live views (or copies) of the hand's joint positions / velocities.
            object_views: :meth:`SimWorld.object_state_views` of the object.
        """
        counters = self.counters
        counters["steps"] += 1
        ref = self.reference(t)
        if self.hand_target_override is None and self.object_target_override is None:
            q_target, obj_pos, obj_quat = ref.q_target, ref.object_position, \
                ref.object_quaternion
        else:
            q_target, obj_pos, obj_quat = self._targets(t, ref)
        # the scenario's reference is finite when its inputs are (a validated spec, a finite
        # grasp plan and start pose: see __init__): then only a hand target from outside is
        # checked with the output
        trusted = self._reference_finite and self.hand_target_override is None
        grasp = ref.grasp if self.grasp_override is None else self.grasp_override
        if not (grasp and self._composite):
            return self._command(q, q_target, None, ref.phase, None, None, None, None, (),
                                 trusted)
        k, points, normals, mu, hand = world.object_contacts(object_body)
        effort = forces = torsion = None
        if k:
            try:
                effort, forces, torsion = self._grasp_world(
                    world, q, qd, q_target, obj_pos, obj_quat, object_views, points, normals,
                    mu, hand)
            except HandSuiteError:
                counters["rejected_inputs"] += 1
        if effort is None:
            return self._command(q, q_target, None, ref.phase, forces, torsion, None, None, (),
                                 trusted)
        return self._command(q, q_target, effort, ref.phase, forces, torsion, points, normals,
                             world.hand_body_names(hand), trusted)

    def _grasp_world(self, world: LiveContacts, q: np.ndarray, qd: np.ndarray,
                     q_target: np.ndarray, obj_pos: np.ndarray, obj_quat: np.ndarray,
                     object_views: tuple[np.ndarray, ...], points: np.ndarray,
                     normals: np.ndarray, mu: np.ndarray, hand: list[int]
                     ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """The grasp part of :meth:`step_world`: the controller's own steps 2-4
        (:meth:`CompositeController.object_wrench`, :meth:`CompositeController.realise`) on
        the world's contact arrays, eq. (12) evaluated by the world. ``(tau_grasp, forces,
        torsion)``, all ``None`` when the QP finds no solution (counted as a fallback)."""
        ctrl = self.controller
        pos, quat, vel, omega_body, rot = object_views
        omega = rot.dot(omega_body)  # angular velocity, world frame
        if self.object_target_override is None:
            # the simulator's state and the reference (as step(trusted=True)): floats as they
            # are
            w6 = ctrl.object_wrench(pos.tolist(), quat.tolist(), vel.tolist(), omega.tolist(),
                                    obj_pos.tolist(), obj_quat.tolist(), self.object_mass)
        else:  # a target from outside: checked and normalised, as step() does
            obj = ObjectState(pos, quat, vel, omega, self.object_mass)
            target = ObjectTarget(obj_pos, obj_quat)
            w6 = ctrl.object_wrench(obj.position.tolist(), obj.quaternion.tolist(),
                                    obj.linear_velocity.tolist(), obj.angular_velocity.tolist(),
                                    target.position.tolist(), target.quaternion.tolist(),
                                    self.object_mass)

        def transpose(res: ContactForceResult) -> np.ndarray:
            # eq. (12) / (III.21): tau_grasp = sum_k Jp_k^T f_k + Jr_k^T (l_k n_k); tau_gravity
            # is zero here (gravity compensated inside the simulator)
            if res.contact_wrench is not None:  # each contact's wrench about the object's com
                return world.wrench_torques(hand, pos, res.contact_wrench)
            return world.contact_torques(hand, points, res.forces, res.torsion, normals)

        tau, res = ctrl.realise(lambda: ctrl.qp.solve_arrays(points, normals, mu, pos, w6),
                                transpose)
        # the ingredients of last_output (built when asked for; q, qd may be live views)
        self._live = (q.copy(), qd.copy(), q_target, w6, res, tau)
        if tau is None:
            self.counters["qp_fallbacks"] += 1
            return None, None, None
        return tau, res.forces, res.torsion

    @property
    def last_output(self) -> ControlOutput | None:
        """The controller's :class:`ControlOutput` of the last step that attempted a grasp
        (for diagnostics)."""
        live = self._live
        if live is not None:  # a step_world: the output from its ingredients, once
            self._live = None
            self._last_output = self._live_output(*live)
        return self._last_output

    @last_output.setter
    def last_output(self, out: ControlOutput | None) -> None:
        self._live = None
        self._last_output = out

    def _live_output(self, q: np.ndarray, qd: np.ndarray, q_target: np.ndarray,
                     wrench: list[float], res: ContactForceResult,
                     tau: np.ndarray | None) -> ControlOutput:
        """What :meth:`CompositeController.compute` returns for a :meth:`step_world`."""
        ctrl = self.controller
        tau_pd = pd_torques(ctrl.kp, ctrl.kd, q, qd, np.asarray(q_target, dtype=np.float64))
        found = tau is not None
        tau_grasp = tau if found else np.zeros(len(q))
        return ControlOutput(tau=tau_pd + tau_grasp if found else tau_pd.copy(), tau_pd=tau_pd,
                             tau_gravity=np.zeros(len(q)), tau_grasp=tau_grasp,
                             force_target=np.array(wrench[0:3]),
                             torque_target=np.array(wrench[3:6]), qp=res, grasp_active=found,
                             fallback=not found)

    def _targets(self, t: float, ref: ReferenceSample
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The hand target and the object's target pose at ``t``: the reference's, or the
        overrides (low-passed, ``target_cutoff``)."""
        q_target = ref.q_target if self.hand_target_override is None else \
            self.hand_target_override
        obj_pos, obj_quat = ref.object_position, ref.object_quaternion
        if self.object_target_override is not None:
            obj_pos, obj_quat = self.object_target_override
        if self.config.target_cutoff > 0 and (self.hand_target_override is not None
                                              or self.object_target_override is not None):
            q_target, obj_pos, obj_quat = self._low_pass(t, q_target, obj_pos, obj_quat)
        return q_target, obj_pos, obj_quat

    def _command(self, q: np.ndarray, q_target: np.ndarray, effort: np.ndarray | None,
                 phase: str, forces: np.ndarray | None, torsion: np.ndarray | None,
                 points: np.ndarray | None, normals: np.ndarray | None,
                 bodies: tuple[str, ...], trusted_target: bool = False) -> Command:
        """The step's :class:`Command`: PD only (zero efforts) without grasp torques or when
        an output is not finite (counted), else the grasp torques with their contacts.
        Efforts beyond the actuators' limits and targets beyond the joints' are clipped
        (counted as ``saturated``): whatever the inputs, the command is finite and within
        the hand's limits. ``trusted_target``: ``q_target`` is known to be finite."""
        pd_only = effort is None
        # the command's own copy (of a float64 array: its copy method, the quicker call)
        q_target = q_target.copy() if type(q_target) is np.ndarray and \
            q_target.dtype == _F64 else np.array(q_target, dtype=np.float64)
        zeros = self._zeros
        if not ((pd_only or effort.dot(zeros) == 0.0)
                and (trusted_target or q_target.dot(zeros) == 0.0)):
            self.counters["non_finite_outputs"] += 1
            q = np.asarray(q, dtype=np.float64)
            hold = np.where(np.isfinite(q), q, 0.0) if q.shape == q_target.shape else 0.0
            q_target = np.where(np.isfinite(q_target), q_target, hold)
            pd_only = True
        # q_target is the command's own copy: clipped in place
        if trusted_target:  # a scenario reference: within the limits up to round-off (not counted)
            _clip(q_target, self._pos_lo, self._pos_hi, out=q_target)
            saturated = False
        else:
            clipped = _clip(q_target, self._pos_lo, self._pos_hi)
            # counted beyond round-off (IK grasp poses sit on the joint limits)
            saturated = bool(np.abs(clipped - q_target).max() > _POS_TOL)
            q_target = clipped
        if not pd_only:  # the efforts (this step's own array) clipped in place; a clipped
            # entry changes their sum (two BLAS dots: cheaper than a comparison per entry)
            ones = self._ones
            before = effort.dot(ones)
            _clip(effort, self._effort_lo, self._effort_hi, out=effort)
            if effort.dot(ones) != before:
                saturated = True
        if saturated:
            self.counters["saturated"] += 1
        cmd = object.__new__(Command)  # the frozen dataclass without its __init__
        if pd_only:
            cmd.__dict__.update(
                joint_names=self.joint_names, positions=q_target,
                efforts=np.zeros(len(self.joint_names)), phase=phase,
                planned_forces=_EMPTY3 if forces is None else forces,
                planned_torsion=_EMPTY if torsion is None else torsion,
                contact_points=_EMPTY3, contact_normals=_EMPTY3, contact_bodies=(),
                pd_only=True)
        else:
            cmd.__dict__.update(
                joint_names=self.joint_names, positions=q_target, efforts=effort, phase=phase,
                planned_forces=forces, planned_torsion=torsion, contact_points=points,
                contact_normals=normals, contact_bodies=bodies, pd_only=False)
        return cmd


_F64 = np.dtype(np.float64)
_POS_TOL = 1e-6  # [rad or m] a clipped target further off than this counts as saturated
try:  # numpy's clip ufunc (one call); min(max(x, lo), hi) elementwise
    from numpy._core.umath import clip as _clip
except ImportError:  # pragma: no cover - numpy < 2
    def _clip(x: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              out: np.ndarray | None = None) -> np.ndarray:
        return np.minimum(np.maximum(x, lo), hi, out=out)
# the empty arrays of a PD-only command (read-only: shared by every such command)
_EMPTY3 = np.zeros((0, 3))
_EMPTY = np.zeros(0)
_EMPTY3.setflags(write=False)
_EMPTY.setflags(write=False)


def _all_finite(x: np.ndarray) -> bool:
    """``np.isfinite(x).all()`` for a float vector in one BLAS call: ``x . 0`` is 0 when every
    entry is finite and NaN as soon as one is NaN or +-Inf (IEEE 754: Inf * 0 = NaN)."""
    return x.dot(np.zeros(x.shape[0])) == 0.0
