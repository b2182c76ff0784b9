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

* reaching, releasing: the target is the tracked hand; after a grasp, the fingers first open
  to the plan's pre-grasp with the wrist held where it is, and the wrist then rejoins the
  operator's at the approach's speed (:class:`_ReturnPath`), so the released object is
  neither flung by a jump of the target nor carried off between opening fingers;
* closing: the grasp is fixed where the object rests as closing begins (a grasp that followed
  the object would chase a box the fingers push). The wrist travels from the operator's to
  the plan's at bounded speed and turning rate, first to a pose ``approach_height`` above the
  plan's, then straight down (:class:`_ApproachPath`), with the fingers opening to the plan's
  pre-grasp; after ``settle_time`` (the servoed wrist lags its target) the fingers close onto
  the grasp as the operator's grip closes, progress ``s = (g_open - g) / span`` in [0, 1]
  (``span`` = the detector's ``close_decrease``), no faster than ``close_time``. The
  operator's wrist need not be the plan's;
* manipulation: the controller is told so once the hand's grasp has closed
  (:class:`PerformanceInterface`; until then it still sees closing, PD only). From that
  moment the planned grasp moves rigidly with the operator's wrist,
  ``T_wrist = T_op(t) T_op(t0)^-1 T_plan``, and so does the object's target (the controller
  carries the object with the grasp it was planned for).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from hand_capture.cameras.transforms import matrix_to_rotvec, rotvec_to_matrix
from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model import HandModel, quat_wxyz_to_matrix, root_rotation_matrix
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
    T[:3, :3] = quat_wxyz_to_matrix(quat_wxyz)
    T[:3, 3] = position
    return T


def pose_with_wrist(q: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``q`` with its root replaced by the (4, 4) wrist pose ``T``."""
    out = np.array(q, dtype=np.float64)
    out[0:3] = T[:3, 3]
    out[3:6] = root_angles_from_matrix(T[:3, :3])
    return out


def _smooth(u: float) -> float:
    """Smoothstep of ``u`` in [0, 1]: zero slope at both ends."""
    return u * u * (3 - 2 * u)


def _travel_time(Ta: np.ndarray, Tb: np.ndarray, cfg: InterfaceConfig) -> float:
    """[s] the wrist needs from the (4, 4) pose Ta to Tb at ``approach_speed`` and
    ``approach_turn_rate``, whichever is slower."""
    d = float(np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]))
    ang = float(np.linalg.norm(matrix_to_rotvec(Ta[:3, :3].T @ Tb[:3, :3])))
    return max(d / cfg.approach_speed, ang / cfg.approach_turn_rate)


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
        closing: (T, 27) a closing motion from ``q_pregrasp`` to ``q_grasp`` (a synthesised
            grasp), played as the fingers close; None = a blend of the two.
        approach: how the hand gets from the operator's wrist to the plan's (speeds, the
            height it comes down from, how fast the fingers may close); None = defaults.
    """

    def __init__(self, q_grasp: np.ndarray, object_pose: np.ndarray,
                 model: HandModel | None = None, q_pregrasp: np.ndarray | None = None,
                 closing_span: float | None = None, closing: np.ndarray | None = None,
                 approach: InterfaceConfig | None = None) -> None:
        self.model = model or HandModel()
        self.closing_span = closing_span
        self.approach = approach or InterfaceConfig()
        self.replan(q_grasp, object_pose, q_pregrasp, closing)
        self._phase = Phase.REACHING
        self._grip_open = self.grip_grasp
        self._T_op0: np.ndarray | None = None  # operator's wrist when the grasp closed
        self._path: _ApproachPath | None = None
        self._obj0 = np.array(object_pose, dtype=np.float64)  # object as closing began
        self._q_from = self.q_pregrasp
        self._c, self._t_c = 0.0, 0.0  # how far the fingers have closed, and when [s]
        self._last: np.ndarray | None = None  # the last grasping target (27,)
        self._ret: _ReturnPath | None = None  # the way back to the tracked hand

    def replan(self, q_grasp: np.ndarray, object_pose: np.ndarray,
               q_pregrasp: np.ndarray | None = None, closing: np.ndarray | None = None
               ) -> None:
        """Use another grasp (world, for the object at ``object_pose``): e.g. one synthesised
        for the operator's hand as closing begins (III.6). ``closing``: (T, 27) its closing
        motion from ``q_pregrasp`` to ``q_grasp``, played as the fingers close."""
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

    def _start_in_object(self) -> np.ndarray:
        """(4, 4) the wrist the approach goes to, in the object's frame: the closing motion's
        first wrist, or the plan's."""
        return self._wrist_in_object if self._closing is None else self._closing_wrists[0]

    def _closing_target(self, u: float) -> tuple[np.ndarray, np.ndarray]:
        """The closing motion at fraction ``u`` in [0, 1]: fingers (27,) and wrist (4, 4),
        on the object where it rested as closing began."""
        c = self._closing
        x = min(max(u, 0.0), 1.0) * (len(c) - 1)
        i = min(int(x), len(c) - 2)
        a = x - i
        q = (1 - a) * c[i] + a * c[i + 1]
        return q, self._obj0 @ _blend(self._closing_wrists[i], self._closing_wrists[i + 1], a)

    def progress(self, grip: float) -> float:
        """Closing progress in [0, 1] of the operator's grip size [m]."""
        span = self._grip_open - self.grip_grasp if self.closing_span is None \
            else self.closing_span
        if span <= 1e-6:
            return 1.0
        return float(np.clip((self._grip_open - grip) / span, 0.0, 1.0))

    @property
    def closed(self) -> bool:
        """Whether the hand's target has reached the planned grasp (wrist arrived, fingers
        closed); true when the approach is not paced."""
        return self._path is not None and (not self._path.timed or self._c >= 1.0)

    def _fingers(self, t: float, s: float, arrived: bool) -> float:
        """The fingers' closing from the pre-grasp (0) to the grasp (1) at ``t`` [s]: the
        operator's progress ``s``, not before the wrist has arrived, and no faster than
        ``1 / close_time`` per second (a grip closed while the hand was still on its way does
        not snap the fingers shut)."""
        goal = s if arrived else 0.0
        rate = 1.0 / max(self.approach.close_time, 1e-6)
        self._c = min(max(goal, 0.0), self._c + rate * max(t - self._t_c, 0.0)) \
            if goal > self._c else self._c
        self._t_c = t
        return self._c

    def target(self, q_op: np.ndarray, T_op: np.ndarray, phase: Phase,
               object_pose: np.ndarray, grip: float | None = None,
               t: float | None = None) -> np.ndarray:
        """The hand's PD target (27,) for the tracked pose ``q_op`` (world) in ``phase``.

        Args:
            q_op: (27,) the operator's tracked pose in the world frame.
            T_op: (4, 4) the operator's wrist to use (``q_op``'s, possibly filtered).
            phase: the grasp phase decided for this pose.
            object_pose: (4, 4) the object's current pose.
            grip: ``q_op``'s grip size [m] when the caller has it (else computed).
            t: time of ``q_op`` [s] (paces the approach); None = the approach is instant.
        """
        if grip is None:
            grip = float(grip_size(self.model.joint_positions(q_op)))
        timed = t is not None
        t = float(t) if timed else 0.0
        if phase != self._phase:
            if phase == Phase.CLOSING:
                self._grip_open = max(grip, self.grip_grasp)
                # the grasp goes where the object rests as closing begins, and stays there: a
                # plan that followed the object would chase a box the fingers push (the
                # earlier runaway: pushed 2-3 cm, then dropped)
                self._obj0 = np.array(object_pose, dtype=np.float64)
                T_plan = object_pose @ self._start_in_object()
                # from where the hand is: the tracked hand, or on its way back to it
                q_from = self._tracked(q_op, T_op, t) if self._ret is not None \
                    else pose_with_wrist(q_op, T_op)
                self._ret = None
                self._path = _ApproachPath(pose_matrix(q_from), T_plan, t, self.approach,
                                           timed)
                self._q_from = q_from
                self._c, self._t_c = 0.0, t
            elif phase == Phase.MANIPULATION:
                self._T_op0 = None
                if self._path is None:  # manipulation without closing (a restarted stream)
                    self._obj0 = np.array(object_pose, dtype=np.float64)
                    self._path = _ApproachPath(T_op, object_pose @ self._start_in_object(),
                                               t, self.approach, timed)
            elif phase in (Phase.REACHING, Phase.RELEASING):
                if timed and self._last is not None:
                    # the hand was on the grasp, up to centimetres and tens of degrees off
                    # the operator's wrist: jumping to the tracked hand flung the released
                    # box (7 cm in 0.2 s); open the fingers in place, then rejoin the wrist
                    self._ret = _ReturnPath(self._last, self.q_pregrasp, t, self.approach)
                self._path = None
            self._phase = phase
        if phase in (Phase.CLOSING, Phase.MANIPULATION) and self._path is not None:
            T_w, a = self._path(t)
            arrived = self._path.arrived(t)
            # fingers: the operator's, opening to the plan's pre-grasp as the wrist travels
            q = (1 - a) * self._q_from + a * self.q_pregrasp
            s = self.progress(grip) if phase == Phase.CLOSING else 1.0
            c = self._fingers(t, s, arrived) if timed else s
            if arrived and self._closing is not None:  # a synthesised closing motion
                q, T_w = self._closing_target(c)
            elif arrived:
                q = (1 - c) * self.q_pregrasp + c * self.q_grasp
            if phase == Phase.MANIPULATION and self.closed:
                # moved rigidly with the operator's wrist since the hand's grasp closed: the
                # wrist's drift while the fingers were closing (a tracker's wrist moves as the
                # tracked fingers curl) must not shift the hand off a grasp not yet made
                if self._T_op0 is None:
                    self._T_op0 = T_op
                T_w = T_op @ np.linalg.inv(self._T_op0) @ T_w
            self._last = pose_with_wrist(q, T_w)
            return self._last.copy()
        self._last = None
        return self._tracked(q_op, T_op, t)

    def _tracked(self, q_op: np.ndarray, T_op: np.ndarray, t: float) -> np.ndarray:
        """Reaching, releasing: the tracked hand, or the way back to it after a grasp."""
        if self._ret is None:
            return pose_with_wrist(q_op, T_op)
        q, done = self._ret(q_op, T_op, t)
        if done:
            self._ret = None
        return q


class _ReturnPath:
    """From a grasp back to the tracked hand: first the fingers open to the plan's pre-grasp
    (the closing motion reversed, so they leave the object's surface) within ``close_time``,
    the wrist held where it is (the object is let go in place, whatever the operator's wrist
    does meanwhile); then the wrist rejoins the operator's at the approach's speed and
    turning rate (at least ``min_approach_time``) as the fingers blend into the operator's.
    Call with the tracked pose, the operator's (filtered) wrist and ``t`` [s] -> (the (27,)
    target, whether it is back)."""

    def __init__(self, q_hand: np.ndarray, q_open: np.ndarray, t0: float,
                 cfg: InterfaceConfig) -> None:
        self.q_hand, self.t0, self.cfg = np.array(q_hand, dtype=np.float64), t0, cfg
        self.q_open = np.array(q_open, dtype=np.float64)
        self.T_hand = pose_matrix(self.q_hand)
        self.t_back: float | None = None  # [s], set as the wrist starts back

    def __call__(self, q_op: np.ndarray, T_op: np.ndarray, t: float
                 ) -> tuple[np.ndarray, bool]:
        cfg = self.cfg
        e = t - self.t0
        if e < cfg.close_time:
            a = max(e, 0.0) / cfg.close_time
            return pose_with_wrist((1 - a) * self.q_hand + a * self.q_open, self.T_hand), False
        if self.t_back is None:
            self.t_back = max(_travel_time(self.T_hand, T_op, cfg), cfg.min_approach_time)
        u = min(max((e - cfg.close_time) / self.t_back, 0.0), 1.0)
        s = _smooth(u)
        q = (1 - s) * self.q_open + s * np.asarray(q_op, dtype=np.float64)
        return pose_with_wrist(q, _blend(self.T_hand, T_op, s)), u >= 1.0


class _ApproachPath:
    """The wrist's way from the operator's wrist to the planned one (eq. of a rigid blend,
    :func:`_blend`): first to a via pose ``approach_height`` above the plan's wrist, held there
    ``settle_time`` (the servoed wrist lags its target, most in the turn), then straight down
    onto it, so the open fingers come down beside the object instead of sweeping through it.
    Each leg lasts as long as its distance and angle need at the configured speeds (at least
    ``min_approach_time`` in all). Call with ``t`` [s] -> ((4, 4) wrist, progress of the
    first leg in [0, 1]). The fingers may close ``settle_time`` after the path's end
    (:meth:`arrived`)."""

    def __init__(self, T_from: np.ndarray, T_to: np.ndarray, t0: float,
                 cfg: InterfaceConfig, timed: bool) -> None:
        self.T_from, self.T_to, self.t0 = np.array(T_from), np.array(T_to), t0
        self.T_via = self.T_to.copy()
        self.T_via[2, 3] += cfg.approach_height
        self.t1 = _travel_time(self.T_from, self.T_via, cfg)  # T_via turned as T_to
        self.t2 = cfg.approach_height / cfg.approach_speed
        scale = max(1.0, cfg.min_approach_time / max(self.t1 + self.t2, 1e-9))
        self.t1 *= scale
        self.t2 *= scale
        self.settle = cfg.settle_time
        self.timed = timed

    def arrived(self, t: float) -> bool:
        """Whether the hand may close its fingers at ``t`` [s]."""
        return not self.timed or t - self.t0 >= self.t1 + 2.0 * self.settle + self.t2

    def __call__(self, t: float) -> tuple[np.ndarray, float]:
        if not self.timed:
            return self.T_to.copy(), 1.0
        e = t - self.t0
        if e < self.t1:
            u = e / self.t1
            return _blend(self.T_from, self.T_via, _smooth(u)), u
        e -= self.t1 + self.settle  # held at the via pose while the wrist catches up
        if e < 0.0:
            return self.T_via.copy(), 1.0
        if e < self.t2:
            u = e / self.t2
            return _blend(self.T_via, self.T_to, _smooth(u)), 1.0
        return self.T_to.copy(), 1.0


@dataclass(frozen=True)
class InterfaceConfig:
    """The performance interface besides the phase thresholds."""

    wrist_cutoff: float = param(3.0, "low-pass cutoff of the operator's wrist [Hz]; 0 = off",
                                lo=0.0, hi=100.0)
    synthesis_lead: float = param(
        0.04, "with a grasp synthesiser: the grasp is synthesised once the palm comes within "
        "the closing distance (phase.reach_distance) plus this of the object [m], so it is "
        "ready when closing begins", lo=0.0, hi=0.5)
    approach_speed: float = param(
        0.3, "closing: speed of the hand's wrist on its way from the operator's wrist to the "
        "planned grasp's [m/s]", lo=0.01, hi=5.0)
    approach_turn_rate: float = param(
        3.0, "closing: the wrist's turning rate on that way [rad/s]", lo=0.1, hi=50.0)
    approach_height: float = param(
        0.03, "closing: the wrist comes down onto the planned grasp from this far above [m]",
        lo=0.0, hi=0.3)
    min_approach_time: float = param(
        0.2, "closing: the approach lasts at least this long [s]", lo=0.0, hi=5.0)
    settle_time: float = param(
        0.3, "closing: the fingers start closing this long after the wrist's target has "
        "reached the planned grasp (the servoed wrist lags its target) [s]", lo=0.0, hi=5.0)
    close_time: float = param(
        0.25, "the fingers close from the pre-grasp to the grasp in no less than this [s]",
        lo=0.0, hi=5.0)

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
        self._held = False  # manipulation detected, reported as closing (hand not closed)
        self._T_obj0 = np.eye(4)  # the object in the operator's wrist frame (manipulation)
        self.retarget = GraspRetarget(q_grasp, object_pose, self.model, q_pregrasp,
                                      closing_span=self.detector.cfg.close_decrease,
                                      closing=closing, approach=self.config)
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
        target = self.retarget.target(q, T_op, up.phase, object_pose, grip, t)
        # The operator has grasped; the hand grasps once its paced approach has arrived and
        # its fingers have closed. Until then the controller still sees closing: PD only, no
        # grasp torques (III.5.2 drops the grasp term while closing) and no object target,
        # so the grasp term never pushes on a box the fingers are still closing onto.
        manip = up.phase == Phase.MANIPULATION
        if manip and not self.retarget.closed:
            up = replace(up, phase=Phase.CLOSING, changed=False, object_target=None)
            self._held = True
        elif manip:
            if self._held or up.changed:  # the hand's grasp starts: the object follows the
                # operator's wrist rigidly from here (the detector's rule, from this moment)
                self._T_obj0 = np.linalg.inv(T_op) @ object_pose
                up = replace(up, changed=True)
            up = replace(up, object_target=T_op @ self._T_obj0)
            self._held = False
        else:
            self._held = False
        return InterfaceStep(up, target)
