"""Composite motion control: PD servos + grasp torques that realise a virtual object wrench.

Per control step (seed 000 sec. 5, dissertation 003 sec. III.5):

1. PD servos on every hand DoF, ``tau_pd = kp (q_target - q) - kd qd`` (eq. 8 / III.20).
2. Virtual PD force and torque on the object toward its target pose (eq. 9 / III.22); the
   contacts must supply ``f_v - m g`` (the weight compensated, eq. 9) and ``tau_v``.
3. Contact forces and torsional torques that realise that wrench, inside friction pyramids
   (QP of eq. III.23, or eq. 10 + 11 of seed 000) -- :mod:`hand_control.contact.qp`.
4. Jacobian transpose: ``tau_grasp = sum_k Jp_k^T f_k + Jr_k^T (l_k n_k)`` (eq. 12 / III.21).
5. ``tau = tau_pd + tau_gravity + tau_grasp`` (eq. 13 / III.19).

When the QP finds no solution the step falls back to PD (+ gravity compensation) alone and the
fallback is counted. Everything is arrays in, arrays out: no ROS, no simulator.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_capture.model.joints import JOINT_NAMES
from hand_control.contact.qp import ContactForceQP, ContactForceResult
from hand_control.contact.types import ContactSet, as_finite_array, unchecked
from hand_control.control.gains import CompositeControlConfig, joint_gains
from hand_control.errors import InputError

__all__ = [
    "CompositeController",
    "ControlOutput",
    "ObjectState",
    "ObjectTarget",
    "grasp_torques",
    "object_virtual_wrench",
    "pd_torques",
    "quaternion_error",
]


def _unit_quaternion(name: str, value: Any) -> np.ndarray:
    q = as_finite_array(name, value, (4,))
    norm = float(np.sqrt(q @ q))
    if norm < 1e-9:
        raise InputError(f"{name} must be a non-zero quaternion (w, x, y, z)")
    return q / norm


@dataclass(frozen=True, eq=False)
class ObjectState:
    """State of the grasped object, world frame.

    Attributes:
        position: (3,) centre of mass [m].
        quaternion: (4,) orientation (w, x, y, z); normalised on construction.
        linear_velocity: (3,) velocity of the centre of mass [m/s].
        angular_velocity: (3,) angular velocity, world frame [rad/s].
        mass: [kg], > 0.
    """

    position: np.ndarray
    quaternion: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    mass: float

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "position", as_finite_array("object position", self.position, (3,)))
        set_(self, "quaternion", _unit_quaternion("object quaternion", self.quaternion))
        set_(self, "linear_velocity",
             as_finite_array("object linear velocity", self.linear_velocity, (3,)))
        set_(self, "angular_velocity",
             as_finite_array("object angular velocity", self.angular_velocity, (3,)))
        mass = float(as_finite_array("object mass", self.mass, ()))
        if mass <= 0.0:
            raise InputError(f"object mass must be > 0, got {mass}")
        set_(self, "mass", mass)

    @classmethod
    def trusted(cls, position: np.ndarray, quaternion: np.ndarray, linear_velocity: np.ndarray,
                angular_velocity: np.ndarray, mass: float) -> ObjectState:
        """Without the checks, for arrays a simulator produced: (3,) / unit (4,) float64,
        finite, ``mass > 0`` (the caller vouches; nothing is copied or normalised)."""
        return unchecked(cls, position=position, quaternion=quaternion,
                         linear_velocity=linear_velocity, angular_velocity=angular_velocity,
                         mass=mass)


@dataclass(frozen=True, eq=False)
class ObjectTarget:
    """Target pose of the object's centre of mass, world frame (quaternion w, x, y, z)."""

    position: np.ndarray
    quaternion: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "position", as_finite_array("object target position", self.position, (3,)))
        object.__setattr__(
            self, "quaternion", _unit_quaternion("object target quaternion", self.quaternion))

    @classmethod
    def trusted(cls, position: np.ndarray, quaternion: np.ndarray) -> ObjectTarget:
        """Without the checks: (3,) finite and unit (4,) float64 (the caller vouches)."""
        return unchecked(cls, position=position, quaternion=quaternion)


def quaternion_error(q_target: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame) that turns unit quaternion ``q`` into ``q_target``.

    This is the orientation difference ``o_r_target - o_r`` of eq. (III.22): the rotation
    ``R_target R^T`` as axis * angle, with the angle in [0, pi].
    """
    qt = np.asarray(q_target, dtype=np.float64).tolist()
    return np.array(_quaternion_error(*qt, *np.asarray(q, dtype=np.float64).tolist()))


def _quaternion_error(
    w1: float, x1: float, y1: float, z1: float, w0: float, x0: float, y0: float, z0: float
) -> tuple[float, float, float]:
    """:func:`quaternion_error` on plain floats (a handful of products: numpy costs more)."""
    x0, y0, z0 = -x0, -y0, -z0  # conjugate of q
    # q_target * conj(q)
    w = w1 * w0 - (x1 * x0 + y1 * y0 + z1 * z0)
    x = w1 * x0 + w0 * x1 + (y1 * z0 - z1 * y0)
    y = w1 * y0 + w0 * y1 + (z1 * x0 - x1 * z0)
    z = w1 * z0 + w0 * z1 + (x1 * y0 - y1 * x0)
    if w < 0.0:  # the shorter way round
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    c = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, w) / s  # small-angle limit: 2 v
    return c * x, c * y, c * z


def pd_torques(
    kp: np.ndarray, kd: np.ndarray, q: np.ndarray, qd: np.ndarray, q_target: np.ndarray
) -> np.ndarray:
    """PD servos, ``tau_pd = kp (q_target - q) - kd qd`` (seed 000 eq. 8, eq. III.20)."""
    return kp * (q_target - q) - kd * qd


def object_virtual_wrench(
    config: CompositeControlConfig, state: ObjectState, target: ObjectTarget
) -> tuple[np.ndarray, np.ndarray]:
    """Virtual PD force and torque on the object toward its target pose (eq. 9, eq. III.22).

    Returns ``(f_v, tau_v)`` without the weight: the contacts must apply ``f_v - m g``.
    """
    w = _virtual_wrench(config, state, target, (0.0, 0.0, 0.0))
    return np.array(w[0:3]), np.array(w[3:6])


def _virtual_wrench(
    config: CompositeControlConfig, state: ObjectState, target: ObjectTarget,
    weight: tuple[float, float, float],
) -> list[float]:
    """``f_v - weight`` and ``tau_v`` (eq. 9 / III.22) as six floats (tiny vectors: no numpy)."""
    return _wrench_floats(config, state.position.tolist(), state.quaternion.tolist(),
                          state.linear_velocity.tolist(), state.angular_velocity.tolist(),
                          target.position.tolist(), target.quaternion.tolist(), weight)


def _wrench_floats(
    config: CompositeControlConfig, position: Sequence[float], quaternion: Sequence[float],
    velocity: Sequence[float], omega: Sequence[float], target_position: Sequence[float],
    target_quaternion: Sequence[float], weight: Sequence[float],
) -> list[float]:
    """:func:`_virtual_wrench` on plain floats: the object's position, unit quaternion (w, x,
    y, z), linear and angular velocity (world frame), the target pose and the weight."""
    kp_t, kd_t = config.object_kp_translate, config.object_kd_translate
    kp_r, kd_r = config.object_kp_rotate, config.object_kd_rotate
    px, py, pz = position
    tx, ty, tz = target_position
    vx, vy, vz = velocity
    wx, wy, wz = omega
    ex, ey, ez = _quaternion_error(*target_quaternion, *quaternion)
    gx, gy, gz = weight
    return [kp_t * (tx - px) - kd_t * vx - gx, kp_t * (ty - py) - kd_t * vy - gy,
            kp_t * (tz - pz) - kd_t * vz - gz,
            kp_r * ex - kd_r * wx, kp_r * ey - kd_r * wy, kp_r * ez - kd_r * wz]


def grasp_torques(
    contacts: ContactSet, forces: np.ndarray, torsion: np.ndarray
) -> np.ndarray:
    """Joint torques that make the hand apply ``forces`` and torsional torques on the object.

    ``tau = sum_k Jp_k^T f_k + Jr_k^T (l_k n_k)`` (seed 000 eq. 12, dissertation eq. III.21),
    with ``Jp_k``/``Jr_k`` the translational/rotational Jacobians of the hand at contact k.

    Raises:
        InputError: when the contacts carry no Jacobians or the shapes disagree.
    """
    if contacts.jacp is None or contacts.jacr is None:
        raise InputError("grasp torques need both contact Jacobians (jacp and jacr)")
    k = len(contacts)
    forces = as_finite_array("contact forces", forces, (k, 3))
    torsion = as_finite_array("torsional torques", torsion, (k,))
    return _grasp_torques(contacts, forces, torsion)


def _grasp_torques(contacts: ContactSet, forces: np.ndarray, torsion: np.ndarray) -> np.ndarray:
    """:func:`grasp_torques` without the checks (eq. 12 / III.21).

    ``sum_k Jp_k^T f_k`` is one vector-matrix product over the stacked (3K, nv) Jacobians
    (a reshape, a view for the simulator's Jacobians), likewise the torsion term.
    """
    k3 = 3 * forces.shape[0]
    jacp, jacr = contacts.jacp, contacts.jacr
    tau = forces.reshape(k3).dot(jacp.reshape(k3, jacp.shape[2]))
    tau += (torsion[:, None] * contacts.normals).reshape(k3).dot(jacr.reshape(k3, jacr.shape[2]))
    return tau


@dataclass(frozen=True, eq=False)
class ControlOutput:
    """Torques of one control step and what produced them.

    Attributes:
        tau: (nv,) total joint torques, ``tau_pd + tau_gravity + tau_grasp``.
        tau_pd, tau_gravity, tau_grasp: (nv,) the three terms of eq. (III.19).
        force_target, torque_target: (3,) net wrench asked of the contacts (``f_v - m g``,
            ``tau_v``); zeros when no grasp was attempted.
        qp: the contact-force solution, ``None`` when no grasp was attempted.
        grasp_active: grasp torques were applied this step.
        fallback: a grasp was attempted but the QP found no solution (PD-only step).
    """

    tau: np.ndarray
    tau_pd: np.ndarray
    tau_gravity: np.ndarray
    tau_grasp: np.ndarray
    force_target: np.ndarray
    torque_target: np.ndarray
    qp: ContactForceResult | None
    grasp_active: bool
    fallback: bool


class CompositeController:
    """Composite motion control of the hand (seed 000 eq. 8-13, dissertation eq. III.19-III.23).

    Args:
        config: gains, switches and the contact-force QP's settings (method, weights,
            friction pyramid; :class:`CompositeControlConfig` is the QP's config too).
        joint_names: the hand DoFs, in the order of every joint array (the model's
            vocabulary, ``hand_capture.model.joints``); the object's DoFs are not included.

    Attributes:
        steps: number of :meth:`compute` calls.
        grasp_steps: steps that applied grasp torques.
        fallbacks: steps whose QP failed and fell back to PD only.
    """

    def __init__(
        self,
        config: CompositeControlConfig | None = None,
        joint_names: Sequence[str] = JOINT_NAMES,
    ) -> None:
        self.config = config or CompositeControlConfig()
        self.qp = ContactForceQP(self.config)
        self.joint_names = tuple(joint_names)
        self.kp, self.kd = joint_gains(self.config, self.joint_names)
        self._gravity = np.asarray(self.config.gravity, dtype=np.float64)
        self._g = tuple(float(v) for v in self._gravity)
        self.steps = 0
        self.grasp_steps = 0
        self.fallbacks = 0
        self.unreachable = 0  # grasp steps whose target the contacts could only approach

    @property
    def nv(self) -> int:
        return len(self.joint_names)

    def object_wrench(self, position: Sequence[float], quaternion: Sequence[float],
                      velocity: Sequence[float], omega: Sequence[float],
                      target_position: Sequence[float], target_quaternion: Sequence[float],
                      mass: float) -> list[float]:
        """Step 2: the wrench the contacts must apply, ``f_v - m g`` (weight compensated,
        eq. 9) and ``tau_v`` (eq. III.22), as six floats, from the object's position, unit
        quaternion (w, x, y, z), linear and angular velocity (world frame) [m, m/s, rad/s],
        its target pose and its mass [kg]."""
        gx, gy, gz = self._g
        return _wrench_floats(self.config, position, quaternion, velocity, omega,
                              target_position, target_quaternion,
                              (mass * gx, mass * gy, mass * gz))

    def realise(self, solve: Callable[[], ContactForceResult],
                transpose: Callable[[ContactForceResult], np.ndarray]
                ) -> tuple[np.ndarray | None, ContactForceResult]:
        """Steps 3-4 of a grasp step: ``solve()`` the contact-force QP for the wrench (eq.
        III.23 or eq. 10-11, ``config.method``), then ``transpose(result)`` maps the forces
        and torsional torques to joint torques (eq. 12 / III.21: stacked Jacobians, or
        MuJoCo's ``mj_applyFT`` in the simulator's process). Counts the step, and the
        fallback when the QP finds no solution (``tau_grasp`` is then ``None``).

        An ``"unreachable"`` target (the contacts cannot apply it, e.g. a pull) still has an
        exact optimum: the wrench nearest to the target that the contacts can apply, which
        eq. III.23 minimises for. It is applied, and counted in ``unreachable`` (dropping it
        to PD-only let a grasp slip whenever a tracked target asked for a little pull)."""
        res = solve()
        self.steps += 1
        if not res.found and res.status != "unreachable":
            self.fallbacks += 1
            return None, res
        if not res.found:
            self.unreachable += 1
        self.grasp_steps += 1
        return transpose(res), res

    def compute(
        self,
        q: Any,
        qd: Any,
        q_target: Any,
        obj: ObjectState | None = None,
        target: ObjectTarget | None = None,
        contacts: ContactSet | None = None,
        gravity_torques: Any = None,
        grasp: bool = True,
        check: bool = True,
    ) -> ControlOutput:
        """Joint torques for one step.

        Args:
            q, qd, q_target: (nv,) joint positions, velocities and PD targets.
            obj, target: the object's state and target pose; without them (or without
                contacts) the step is PD only.
            contacts: hand-object contacts with their Jacobians (K may be 0).
            gravity_torques: (nv,) torques that cancel gravity on the hand, ``h(q)`` of
                eq. (III.18); used when ``config.gravity_compensation``.
            grasp: ``False`` drops ``tau_grasp`` (the dissertation does so while closing).
            check: validate the joint arrays and the contacts' Jacobians (the API boundary).
                ``False`` is the simulator's fast path: the caller vouches for (nv,) finite
                float64 arrays and contacts with both Jacobians over the ``nv`` DoFs; the
                equations and the result are the same.

        Raises:
            InputError: NaN/Inf, wrong lengths, or contacts without matching Jacobians.
        """
        nv = len(self.joint_names)  # self.nv without the property call
        if check:
            q = as_finite_array("q", q, (nv,))
            qd = as_finite_array("qd", qd, (nv,))
            q_target = as_finite_array("q_target", q_target, (nv,))
        tau_pd = pd_torques(self.kp, self.kd, q, qd, q_target)
        tau_gravity = None
        if self.config.gravity_compensation and gravity_torques is not None:
            tau_gravity = as_finite_array("gravity torques", gravity_torques, (nv,))
        attempt = (
            grasp and self.config.mode == "composite" and obj is not None
            and target is not None and contacts is not None and len(contacts) > 0
        )
        tau_grasp = None
        force_target = torque_target = None
        qp_result = None
        if attempt:
            if check and (contacts.jacp is None or contacts.jacr is None
                          or contacts.nv != nv):
                raise InputError(
                    f"contacts need both Jacobians (jacp, jacr) over the {nv} hand DoFs; got "
                    f"jacp={'absent' if contacts.jacp is None else contacts.jacp.shape}, "
                    f"jacr={'absent' if contacts.jacr is None else contacts.jacr.shape}"
                )
            wrench = self.object_wrench(obj.position.tolist(), obj.quaternion.tolist(),
                                        obj.linear_velocity.tolist(),
                                        obj.angular_velocity.tolist(),
                                        target.position.tolist(),
                                        target.quaternion.tolist(), obj.mass)
            force_target, torque_target = np.array(wrench[0:3]), np.array(wrench[3:6])
            tau_grasp, qp_result = self.realise(
                lambda: self.qp.solve(contacts, obj.position, force_target, torque_target,
                                      check=check),
                lambda r: _grasp_torques(contacts, r.forces, r.torsion))
        else:
            self.steps += 1
        fallback = attempt and tau_grasp is None
        # eq. (13) / (III.19): tau = tau_pd + tau_gravity + tau_grasp
        if tau_gravity is None:
            tau_gravity = np.zeros(nv)
            tau = tau_pd.copy() if tau_grasp is None else tau_pd + tau_grasp
        else:
            tau = tau_pd + tau_gravity
            if tau_grasp is not None:
                tau += tau_grasp
        if tau_grasp is None:
            tau_grasp = np.zeros(nv)
        if force_target is None:
            force_target = torque_target = np.zeros(3)
        out = object.__new__(ControlOutput)  # the frozen dataclass without its __init__
        out.__dict__.update(
            tau=tau, tau_pd=tau_pd, tau_gravity=tau_gravity, tau_grasp=tau_grasp,
            force_target=force_target, torque_target=torque_target, qp=qp_result,
            grasp_active=attempt and not fallback, fallback=fallback,
        )
        return out
