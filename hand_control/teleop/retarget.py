"""Turning the operator's tracked hand into hand targets consistent with the object (III.6).

The dissertation (III.6) notes that tracked fingers miss or penetrate the virtual object, since
the operator performs without it, and that driving the physics-based controller directly with
the tracked closing motion fails. It therefore replaces the tracked *closing* motion by a
grasp synthesised to fit the object (its kinematic synthesis of III.4). Given a
``synthesizer`` (:class:`hand_control.grasp.synthesis.PerformerSynthesizer`), the interface
does that as closing begins: the closing motion synthesised for the object from the
operator's hand (wrist and approach direction as the control term) replaces the plan, and its
closing motion is played as the grip closes. Without one, the grasp is the scenario's plan
(fingertip inverse kinematics onto the object's surface,
:func:`hand_control.sim.grasp.plan_grasp`, or a scenario's synthesised grasp):

* reaching, releasing: the target is the tracked hand;
* closing: the target goes from the tracked hand to the planned grasp (fixed to the object)
  as the operator's grip closes, progress ``s = (g_open - g) / span`` in [0, 1], where ``span``
  is the closing the phase detector needs for a grasp (``close_decrease``), so the target is
  the grasp by the time the grasp is detected. The operator's wrist need not be the plan's (a
  tracked hand reaches as it likes): over the first half of the progress the wrist moves to the
  plan's with the fingers opening to the plan's pre-grasp, over the second half the fingers
  close from the pre-grasp to the grasp, so the fingers do not sweep into the object;
* manipulation: the planned grasp, moved rigidly with the operator's wrist since the phase
  began, ``T_wrist = T_op(t) T_op(t0)^-1 T_plan`` (the same rigid motion the object's target
  follows, so the controller carries the object with the grasp it was planned for).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_capture.cameras.transforms import matrix_to_rotvec, rotvec_to_matrix
from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model import HandModel, quat_to_matrix, root_rotation_matrix
from hand_capture.model.joints import root_angles_from_matrix
from hand_control.teleop.phases import (
    GraspPhaseDetector,
    Phase,
    PhaseConfig,
    PhaseUpdate,
    grip_size,
)

__all__ = ["GraspRetarget", "InterfaceConfig", "InterfaceStep", "PerformanceInterface",
           "WristFilter", "object_matrix", "pose_matrix", "pose_with_wrist"]


def pose_matrix(q: np.ndarray) -> np.ndarray:
    """(4, 4) wrist (root) pose of a 27-D hand pose."""
    T = np.eye(4)
    T[:3, :3] = root_rotation_matrix(q[3:6])
    T[:3, 3] = q[0:3]
    return T


def object_matrix(position: np.ndarray, quat_wxyz: np.ndarray) -> np.ndarray:
    """(4, 4) pose from a position and a quaternion (w, x, y, z)."""
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(np.r_[quat_wxyz[1:], quat_wxyz[0]])
    T[:3, 3] = position
    return T


def pose_with_wrist(q: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``q`` with its root replaced by the (4, 4) wrist pose ``T``."""
    out = np.array(q, dtype=np.float64)
    out[0:3] = T[:3, 3]
    out[3:6] = root_angles_from_matrix(T[:3, :3])
    return out


def _blend(Ta: np.ndarray, Tb: np.ndarray, s: float) -> np.ndarray:
    """Rigid interpolation from Ta (s = 0) to Tb (s = 1): lerp + rotation-vector slerp."""
    T = np.eye(4)
    T[:3, 3] = (1 - s) * Ta[:3, 3] + s * Tb[:3, 3]
    T[:3, :3] = Ta[:3, :3] @ rotvec_to_matrix(s * matrix_to_rotvec(Ta[:3, :3].T @ Tb[:3, :3]))
    return T


class WristFilter:
    """First-order low-pass of a rigid pose (position lerp, rotation-vector slerp).

    Tracking jitter of a few millimetres and degrees per frame, passed to the servos of a
    simulated hand holding an object, shakes the object out of the grasp; the phase detector
    and the retargeting both smooth the operator's wrist with this filter (same input, same
    output). ``cutoff``: -3 dB frequency [Hz]; 0 = no filtering.
    """

    def __init__(self, cutoff: float = 3.0) -> None:
        self.cutoff = float(cutoff)
        self._T: np.ndarray | None = None
        self._t = 0.0

    def reset(self) -> None:
        self._T = None

    def __call__(self, t: float, T: np.ndarray) -> np.ndarray:
        """The filtered (4, 4) pose after the sample ``T`` at time ``t`` [s]."""
        if self._T is None or self.cutoff <= 0 or t <= self._t:
            self._T, self._t = np.array(T, dtype=np.float64), t
            return self._T.copy()
        a = 1.0 - float(np.exp(-2.0 * np.pi * self.cutoff * (t - self._t)))
        self._T, self._t = _blend(self._T, T, a), t
        return self._T.copy()


class GraspRetarget:
    """Hand targets from tracked world-frame poses and grasp phases (module docstring).

    Args:
        q_grasp: (27,) planned grasp, world frame, for the object at ``object_pose``.
        object_pose: (4, 4) the object's pose the grasp was planned for.
        model: the hand model whose keypoints measure the grip size.
        q_pregrasp: (27,) the plan's open pre-grasp (same wrist); None = the grasp itself.
        closing_span: the operator's grip closing [m] that completes the progress; None =
            from the open grip down to the planned grasp's grip.
    """

    def __init__(self, q_grasp: np.ndarray, object_pose: np.ndarray,
                 model: HandModel | None = None, q_pregrasp: np.ndarray | None = None,
                 closing_span: float | None = None, closing: np.ndarray | None = None
                 ) -> None:
        self.model = model or HandModel()
        self.closing_span = closing_span
        self.replan(q_grasp, object_pose, q_pregrasp, closing)
        self._phase = Phase.REACHING
        self._grip_open = self.grip_grasp
        self._T_op0 = np.eye(4)
        self._T_plan0 = np.eye(4)

    def replan(self, q_grasp: np.ndarray, object_pose: np.ndarray,
               q_pregrasp: np.ndarray | None = None, closing: np.ndarray | None = None
               ) -> None:
        """Use another grasp (world, for the object at ``object_pose``): e.g. one synthesised
        for the operator's hand as closing begins (III.6). ``closing``: (T, 27) its closing
        motion from ``q_pregrasp`` to ``q_grasp``, played as the operator's grip closes."""
        self.q_grasp = np.array(q_grasp, dtype=np.float64)
        self.q_pregrasp = self.q_grasp if q_pregrasp is None \
            else np.array(q_pregrasp, dtype=np.float64)
        inv = np.linalg.inv(object_pose)
        # the planned wrists in the object's frame: the grasp stays fixed to the object
        self._wrist_in_object = inv @ pose_matrix(self.q_grasp)
        self._closing = None if closing is None else np.array(closing, dtype=np.float64)
        if self._closing is not None:
            self.q_pregrasp = self._closing[0].copy()
            self._closing_wrists = np.array([inv @ pose_matrix(q) for q in self._closing])
        self.grip_grasp = float(grip_size(self.model.joint_positions(self.q_grasp)))

    def _closing_target(self, u: float, object_pose: np.ndarray) -> np.ndarray:
        """The closing motion at fraction ``u``, its wrists following the object."""
        c = self._closing
        x = min(max(u, 0.0), 1.0) * (len(c) - 1)
        i = min(int(x), len(c) - 2)
        a = x - i
        q = (1 - a) * c[i] + a * c[i + 1]
        T = _blend(self._closing_wrists[i], self._closing_wrists[i + 1], a)
        return pose_with_wrist(q, object_pose @ T)

    def progress(self, grip: float) -> float:
        """Closing progress in [0, 1] of the operator's grip size [m]."""
        span = self._grip_open - self.grip_grasp if self.closing_span is None \
            else self.closing_span
        if span <= 1e-6:
            return 1.0
        return float(np.clip((self._grip_open - grip) / span, 0.0, 1.0))

    def target(self, q_op: np.ndarray, T_op: np.ndarray, phase: Phase,
               object_pose: np.ndarray, grip: float | None = None) -> np.ndarray:
        """The hand's PD target (27,) for the tracked pose ``q_op`` (world) in ``phase``.

        Args:
            q_op: (27,) the operator's tracked pose in the world frame.
            T_op: (4, 4) the operator's wrist to use (``q_op``'s, possibly filtered).
            phase: the grasp phase decided for this pose.
            object_pose: (4, 4) the object's current pose.
            grip: ``q_op``'s grip size [m] when the caller has it (else computed).
        """
        if grip is None:
            grip = float(grip_size(self.model.joint_positions(q_op)))
        T_plan = object_pose @ self._wrist_in_object
        if phase != self._phase:
            if phase == Phase.CLOSING:
                self._grip_open = max(grip, self.grip_grasp)
            elif phase == Phase.MANIPULATION:
                self._T_op0, self._T_plan0 = T_op, T_plan
            self._phase = phase
        if phase == Phase.CLOSING:
            s = self.progress(grip)
            if self._closing is not None:  # a closing motion: to its start, then play it
                T_start = object_pose @ self._closing_wrists[0]
                if s < 0.5:
                    u = 2.0 * s
                    q = (1 - u) * np.asarray(q_op, dtype=np.float64) + u * self.q_pregrasp
                    return pose_with_wrist(q, _blend(T_op, T_start, u))
                return self._closing_target(2.0 * s - 1.0, object_pose)
            if s < 0.5:  # wrist to the plan's, fingers to the open pre-grasp
                u = 2.0 * s
                q = (1 - u) * np.asarray(q_op, dtype=np.float64) + u * self.q_pregrasp
                return pose_with_wrist(q, _blend(T_op, T_plan, u))
            u = 2.0 * s - 1.0  # then the fingers close onto the grasp
            return pose_with_wrist((1 - u) * self.q_pregrasp + u * self.q_grasp, T_plan)
        if phase == Phase.MANIPULATION:
            return pose_with_wrist(self.q_grasp,
                                   T_op @ np.linalg.inv(self._T_op0) @ self._T_plan0)
        return pose_with_wrist(q_op, T_op)


@dataclass(frozen=True)
class InterfaceConfig:
    """The performance interface besides the phase thresholds."""

    wrist_cutoff: float = param(3.0, "low-pass cutoff of the operator's wrist [Hz]; 0 = off",
                                lo=0.0, hi=100.0)
    synthesis_lead: float = param(
        0.04, "with a grasp synthesiser: the grasp is synthesised once the palm comes within "
        "the closing distance (phase.reach_distance) plus this of the object [m], so it is "
        "ready when closing begins", lo=0.0, hi=0.5)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class InterfaceStep:
    """One update of the performance interface."""

    phase: PhaseUpdate          # phase, object target (manipulation), grip, distance
    hand_target: np.ndarray     # (27,) world-frame PD target of the hand


class PerformanceInterface:
    """The teleoperation performance interface of III.6, as one object.

    Per tracked hand pose (world frame): smooth the wrist (:class:`WristFilter`), decide the
    grasp phase (:class:`GraspPhaseDetector`; the object's target follows the smoothed wrist in
    manipulation) and retarget the hand onto the planned grasp (:class:`GraspRetarget`).

    Args:
        q_grasp: (27,) the planned grasp (world) for the object at ``object_pose`` (4, 4).
        q_pregrasp: (27,) the plan's open pre-grasp (see :class:`GraspRetarget`).
        synthesizer: ``(recent tracked poses (n, 27) world, object pose (4, 4)) -> plan or
            None``, called once per approach as the palm comes within ``reach_distance +
            synthesis_lead`` of the object (or as closing begins): the grasp synthesised for
            the object from the operator's hand (III.6;
            ``hand_control.grasp.synthesis.PerformerSynthesizer``) replaces the given one (a
            plan with ``q_grasp``, ``q_pregrasp``, ``closing``).
        closing: (T, 27) the given grasp's closing motion (world), if it has one.
    """

    def __init__(self, q_grasp: np.ndarray, object_pose: np.ndarray,
                 phase_config: PhaseConfig | None = None,
                 config: InterfaceConfig | None = None, model: HandModel | None = None,
                 q_pregrasp: np.ndarray | None = None,
                 synthesizer: Callable[[np.ndarray, np.ndarray], Any] | None = None,
                 closing: np.ndarray | None = None) -> None:
        self.config = config or InterfaceConfig()
        self.model = model or HandModel()
        self.detector = GraspPhaseDetector(phase_config)
        self.filter = WristFilter(self.config.wrist_cutoff)
        # the progress completes with the closing the detector needs to see a grasp
        self.retarget = GraspRetarget(q_grasp, object_pose, self.model, q_pregrasp,
                                      closing_span=self.detector.cfg.close_decrease,
                                      closing=closing)
        self.synthesizer = synthesizer
        self._recent: deque[np.ndarray] = deque(maxlen=15)
        self._last_phase = Phase.REACHING
        self._planned = False
        self.synthesized = 0  # grasps synthesised for the operator's hand

    def update(self, t: float, q_op: np.ndarray, object_pose: np.ndarray) -> InterfaceStep:
        """Advance with the operator's pose ``q_op`` (27,) at ``t`` [s] and the object's pose.

        Raises:
            InputError: non-finite or wrongly shaped input.
        """
        q = np.asarray(q_op, dtype=np.float64)
        if q.shape != (27,) or not np.isfinite(q).all():
            raise InputError("the hand pose must be 27 finite values")
        T_op = self.filter(t, pose_matrix(q))
        kp = self.model.joint_positions(q)
        grip = float(grip_size(kp))
        up = self.detector.update(t, kp, T_op, object_pose, raw_grip=grip)
        self._recent.append(pose_with_wrist(q, T_op))
        if self.synthesizer is not None:
            if up.phase == Phase.REACHING and self._last_phase != Phase.REACHING:
                self._planned = False  # a new approach: a new grasp
            near = up.distance < self.detector.cfg.reach_distance + self.config.synthesis_lead
            if not self._planned and (up.phase == Phase.CLOSING or (
                    up.phase == Phase.REACHING and near)):
                # III.6: the closing motion synthesised for the object from the operator's
                # hand, as the hand comes near (ready when closing begins)
                self._planned = True
                plan = self.synthesizer(np.array(self._recent), object_pose)
                if plan is not None:
                    self.retarget.replan(plan.q_grasp, object_pose, plan.q_pregrasp,
                                         plan.closing)
                    self.synthesized += 1
        self._last_phase = up.phase
        return InterfaceStep(up, self.retarget.target(q, T_op, up.phase, object_pose, grip))
