"""The input-validation layer: one check per message type, shared by every node (pure core).

A node extracts the fields of a message (or passes the message itself: any object with the
fields of the ROS type works, as in :mod:`hand_capture.posemsg`) and calls the function of its
type here *before* anything reaches a core object. Each function returns the validated values
or raises :class:`~hand_capture.errors.RejectedInputError` whose text names the field, the bad
value and the valid range with its unit. The node side (:class:`hand_capture.nodes.gate.InputGate`)
counts and logs the rejections per topic and reports them on ``diagnostics``.

Rules, for every type:

* every number finite (no NaN, no +-Inf), every array length matching its names;
* joint names known to the consumer and unique; a HandPose carries every articulated joint;
* physical ranges (:class:`InputLimits`, units in each field): joint angles within the hand
  model's limits widened by ``joint_margin``, positions within ``max_position`` of the origin,
  speeds, efforts and forces below their bounds, quaternions of unit norm;
* enumerations valid (HandPose status and handedness, GraspPhase phase);
* header stamps not in the future beyond ``future_stamp_tolerance`` (:func:`check_stamp`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import RejectedInputError
from hand_capture.model.joints import (
    ARTICULATED_JOINTS,
    JOINT_INDEX,
    JOINT_LIMITS,
    ROOT_JOINTS,
    root_angles_from_quat,
)

__all__ = [
    "GRASP_PHASES",
    "HAND_POSE_STATUS",
    "InputLimits",
    "RejectedInputError",
    "check_stamp",
    "joint_bounds",
    "validate_contacts",
    "validate_grasp_phase",
    "validate_hand_keypoints_msg",
    "validate_hand_pose",
    "validate_hand_pose_msg",
    "validate_joint_command",
    "validate_joint_state",
    "validate_joint_values",
    "validate_pose",
    "validate_touch_frame",
    "validate_twist",
    "validate_camera_info",
    "validate_image_size",
]

#: hand_msgs/HandPose status codes (STATUS_UNKNOWN .. STATUS_GROUND_TRUTH).
HAND_POSE_STATUS = {0: "unknown", 1: "tracking", 2: "recovering", 3: "lost", 4: "ground_truth"}
#: hand_msgs/GraspPhase phase codes.
GRASP_PHASES = {0: "reaching", 1: "closing", 2: "manipulation", 3: "releasing"}
_ROOT_POS = frozenset(ROOT_JOINTS[:3])
_ROOT_ROT = frozenset(ROOT_JOINTS[3:])
_ART_SET = frozenset(ARTICULATED_JOINTS)


@dataclass(frozen=True)
class InputLimits:
    """Physical ranges of the inputs (SI units; one instance shared by a node's checks)."""

    joint_margin: float = param(
        0.35, "articulated joint angles may lie this far outside the hand model's joint "
        "limits [rad] (soft limits in the simulation, tracking noise)", lo=0.0, hi=math.pi)
    max_position: float = param(
        10.0, "largest |coordinate| of a wrist, root joint, object or contact position [m]",
        lo=0.01, hi=1e4)
    max_root_angle: float = param(
        4.0 * math.pi, "largest |root_rx/ry/rz| in a joint state or command [rad]",
        lo=math.pi, hi=1e3)
    max_velocity: float = param(
        200.0, "largest |joint velocity| [rad/s or m/s] (the simulation's divergence "
        "threshold)", lo=0.1, hi=1e5)
    max_effort: float = param(
        500.0, "largest |feed-forward effort| of a joint command [N m or N] (the simulated "
        "hand's strongest actuator gives 150 N; per-actuator limits are the consumer's)",
        lo=0.0, hi=1e6)
    max_linear_speed: float = param(50.0, "largest |object linear velocity| [m/s]",
                                    lo=0.01, hi=1e5)
    max_angular_speed: float = param(500.0, "largest |object angular velocity| [rad/s]",
                                     lo=0.01, hi=1e6)
    max_contact_force: float = param(1e4, "largest |contact force| [N]", lo=0.0, hi=1e9)
    max_friction: float = param(10.0, "largest contact friction coefficient (unitless)",
                                lo=0.0, hi=1e3)
    quat_tolerance: float = param(
        0.1, "a quaternion's norm may differ from 1 by this much (it is then normalised)",
        lo=1e-6, hi=0.9)
    max_surface_size: float = param(10.0, "largest touch surface width / height [m]",
                                    lo=0.01, hi=1e3)
    touch_margin: float = param(
        0.1, "touch positions may lie this fraction of the surface size outside it "
        "(unitless; the TUIO source keeps 0.05)", lo=0.0, hi=1.0)
    max_touch_span: float = param(
        0.3, "largest distance between two touches in contact [m]: one hand spans about "
        "0.25 m from thumb to little finger", lo=0.01, hi=100.0)
    max_touches: int = param(64, "most touch points in one frame", lo=1, hi=10000)
    max_array_length: int = param(512, "most entries in a name / value array", lo=1,
                                  hi=1_000_000)
    future_stamp_tolerance: float = param(
        1.0, "a header stamp may lie this far ahead of the receiving node's clock [s] "
        "(0 = no check)", lo=0.0, hi=1e6)

    def __post_init__(self) -> None:
        validate(self)


DEFAULT_LIMITS = InputLimits()


# ------------------------------------------------------------------------------ primitives
def _reject(text: str) -> RejectedInputError:
    return RejectedInputError(text)


def _array(values: object, what: str, limits: InputLimits) -> np.ndarray:
    """A float64 vector of ``values`` (a message's float64[] field)."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise _reject(f"{what} is not numeric: {e}") from e
    if a.ndim != 1:
        a = a.reshape(-1)
    if a.shape[0] > limits.max_array_length:
        raise _reject(f"{what} has {a.shape[0]} entries (at most {limits.max_array_length})")
    return a


def _finite(a: np.ndarray, what: str, names: Sequence[str] | None = None) -> None:
    if not np.isfinite(a).all():
        bad = np.flatnonzero(~np.isfinite(a))[:5]
        where = [names[i] for i in bad] if names is not None else bad.tolist()
        raise _reject(f"{what} has NaN/Inf at {where}")


def _names(names: Sequence[str], what: str, limits: InputLimits,
           known: Collection[str] | None) -> tuple[str, ...]:
    t = tuple(names)
    if len(t) > limits.max_array_length:
        raise _reject(f"{len(t)} {what} names (at most {limits.max_array_length})")
    if len(set(t)) != len(t):
        seen: set[str] = set()
        dup = sorted({n for n in t if n in seen or seen.add(n)})
        raise _reject(f"duplicate {what} name(s) {dup[:5]}")
    if known is not None:
        unknown = [n for n in t if n not in known]
        if unknown:
            raise _reject(f"unknown {what} name(s) {unknown[:5]}; valid: {sorted(known)[:30]}")
    return t


def _bounded(a: np.ndarray, bound: float, what: str, unit: str,
             names: Sequence[str] | None = None) -> None:
    """Refuse NaN/Inf and values beyond +-``bound`` (one comparison when all is well)."""
    if not (np.abs(a) <= bound).all():  # False for NaN too
        _finite(a, what, names)
        _in_bounds(a, -bound, bound, what, unit, names)


def _same_length(names: Sequence[str], values: np.ndarray, what: str,
                 optional: bool = False) -> None:
    if optional and values.shape[0] == 0:
        return
    if values.shape[0] != len(names):
        raise _reject(f"{len(names)} joint names but {values.shape[0]} {what}")


@functools.lru_cache(maxsize=256)
def joint_bounds(names: tuple[str, ...], limits: InputLimits = DEFAULT_LIMITS
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) arrays of the valid value of each named joint [rad or m]: the model's limits
    widened by ``joint_margin`` for articulated joints, ``+-max_position`` for the root
    position and for names outside the vocabulary, ``+-max_root_angle`` for root angles."""
    lo = np.empty(len(names))
    hi = np.empty(len(names))
    for k, n in enumerate(names):
        if n in _ROOT_ROT:
            lo[k], hi[k] = -limits.max_root_angle, limits.max_root_angle
        elif n in JOINT_INDEX and n not in _ROOT_POS:
            lim = JOINT_LIMITS[JOINT_INDEX[n]]
            lo[k], hi[k] = lim[0] - limits.joint_margin, lim[1] + limits.joint_margin
        else:
            lo[k], hi[k] = -limits.max_position, limits.max_position
    lo.setflags(write=False)
    hi.setflags(write=False)
    return lo, hi


def _joint_unit(name: str) -> str:
    """The unit of a joint's position: m for the root translation and for names outside the
    vocabulary (bounded by ``max_position``), rad for the others."""
    return "rad" if name in JOINT_INDEX and name not in _ROOT_POS else "m"


def _in_bounds(a: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float, what: str,
               unit: str | None, names: Sequence[str] | None = None) -> None:
    """Refuse the first value outside [lo, hi]; ``unit`` None: the joint's own unit."""
    bad = (a < lo) | (a > hi)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        if unit is None:
            unit = _joint_unit(names[k]) if names is not None else ""
        lo_k = float(lo[k]) if isinstance(lo, np.ndarray) else float(lo)
        hi_k = float(hi[k]) if isinstance(hi, np.ndarray) else float(hi)
        who = f" of {names[k]!r}" if names is not None else f"[{k}]"
        raise _reject(f"{what}{who} = {float(a[k]):.6g} {unit} is outside the valid range "
                      f"[{lo_k:.4g}, {hi_k:.4g}] {unit}"
                      + (f" ({int(bad.sum())} values out of range)" if bad.sum() > 1 else ""))


def validate_joint_values(names: Sequence[str], values: Sequence[float],
                          limits: InputLimits = DEFAULT_LIMITS, what: str = "position"
                          ) -> np.ndarray:
    """Finite joint positions within :func:`joint_bounds` (a vector aligned with ``names``).

    Raises:
        RejectedInputError: a length mismatch, NaN/Inf or a value out of its range.
    """
    a = _array(values, what, limits)
    _same_length(names, a, what)
    lo, hi = joint_bounds(tuple(names), limits)
    if not ((a >= lo) & (a <= hi)).all():  # False for NaN too: say which it was
        _finite(a, what, names)
        _in_bounds(a, lo, hi, what, None, names)
    return a


def check_stamp(stamp_s: float, now_s: float, limits: InputLimits = DEFAULT_LIMITS,
                what: str = "header.stamp") -> None:
    """Refuse a stamp more than ``future_stamp_tolerance`` ahead of ``now_s`` [s].

    ``now_s <= 0`` (a simulated clock that has not started) or a tolerance of 0 skip the
    check.

    Raises:
        RejectedInputError: the stamp lies in the future.
    """
    tol = limits.future_stamp_tolerance
    if tol <= 0.0 or now_s <= 0.0:
        return
    if not math.isfinite(stamp_s) or stamp_s - now_s > tol:
        raise _reject(f"{what} {stamp_s:.3f} s lies {stamp_s - now_s:.3f} s in the future of "
                      f"the node clock (tolerance {tol} s)")


# ----------------------------------------------------------------------------- message types
def validate_joint_state(names: Sequence[str], position: Sequence[float],
                         velocity: Sequence[float] = (), effort: Sequence[float] = (), *,
                         known: Collection[str] | None = None,
                         required: Collection[str] = (),
                         limits: InputLimits = DEFAULT_LIMITS
                         ) -> tuple[tuple[str, ...], np.ndarray, np.ndarray | None]:
    """A sensor_msgs/JointState: ``(names, position, velocity or None)``.

    Args:
        known: the consumer's vocabulary (None: any name, ranges of unknown names are
            ``+-max_position``).
        required: names that must be present.

    Raises:
        RejectedInputError: empty, duplicate/unknown/missing names, lengths that do not match
            (velocity and effort may be empty), NaN/Inf, a position outside its joint's range
            [rad or m], a velocity above ``max_velocity`` [rad/s], an effort above
            ``max_effort`` [N m].
    """
    t = _names(names, "joint", limits, known)
    if not t:
        raise _reject("empty joint state (no joint names)")
    missing = [n for n in required if n not in t]
    if missing:
        raise _reject(f"joint(s) {missing[:5]} missing from the joint state")
    pos = validate_joint_values(t, position, limits, "position")
    vel = _array(velocity, "velocity", limits)
    _same_length(t, vel, "velocities", optional=True)
    if vel.shape[0]:
        _bounded(vel, limits.max_velocity, "velocity", "rad/s", t)
    eff = _array(effort, "effort", limits)
    _same_length(t, eff, "efforts", optional=True)
    if eff.shape[0]:
        _bounded(eff, limits.max_effort, "effort", "N m", t)
    return t, pos, (vel if vel.shape[0] else None)


def validate_joint_command(names: Sequence[str], positions: Sequence[float] = (),
                           velocities: Sequence[float] = (), efforts: Sequence[float] = (),
                           *, known: Collection[str] | None = None,
                           effort_limits: tuple[np.ndarray, np.ndarray] | None = None,
                           limits: InputLimits = DEFAULT_LIMITS
                           ) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """A hand_msgs/JointCommand: ``(names, positions, efforts)`` (empty arrays = not
    commanded).

    Args:
        effort_limits: per-name (lo, hi) effort bounds of the consumer's actuators [N m or N],
            aligned with ``names``; default ``+-max_effort``.

    Raises:
        RejectedInputError: no names, duplicate/unknown names, lengths, NaN/Inf, positions outside
            their joint ranges [rad or m], velocities above ``max_velocity`` [rad/s], efforts
            outside the bounds [N m].
    """
    t = _names(names, "joint", limits, known)
    if not t:
        raise _reject("empty joint command (no joint names)")
    pos = _array(positions, "positions", limits)
    _same_length(t, pos, "positions", optional=True)
    if pos.shape[0]:
        pos = validate_joint_values(t, pos, limits, "position")
    vel = _array(velocities, "velocities", limits)
    _same_length(t, vel, "velocities", optional=True)
    if vel.shape[0]:
        _bounded(vel, limits.max_velocity, "velocity", "rad/s", t)
    eff = _array(efforts, "efforts", limits)
    _same_length(t, eff, "efforts", optional=True)
    if eff.shape[0]:
        _finite(eff, "effort", t)
        lo, hi = effort_limits if effort_limits is not None else \
            (-limits.max_effort, limits.max_effort)
        _in_bounds(eff, lo, hi, "effort", "N m", t)
    return t, pos, eff


def validate_hand_pose(names: Sequence[str], positions: Sequence[float],
                       wrist_position: Sequence[float], wrist_quat_xyzw: Sequence[float],
                       status: int, handedness: int = 0, confidence: float = 1.0,
                       limits: InputLimits = DEFAULT_LIMITS) -> np.ndarray:
    """A hand_msgs/HandPose: the (27,) pose in JOINT_NAMES order [m, rad].

    Raises:
        RejectedInputError: a status other than STATUS_UNKNOWN..STATUS_GROUND_TRUTH (0-4), a
            handedness other than 0/1, a confidence outside [0, 1], joint names that are not
            exactly the 21 articulated joints (each once), lengths, NaN/Inf, an angle outside
            its joint's range [rad], a wrist farther than ``max_position`` [m], a wrist
            quaternion whose norm is not 1 within ``quat_tolerance``.
    """
    if int(status) not in HAND_POSE_STATUS:
        raise _reject(f"status {status} is not a HandPose status "
                      f"({', '.join(f'{k}={v}' for k, v in HAND_POSE_STATUS.items())})")
    if int(handedness) not in (0, 1):
        raise _reject(f"handedness {handedness} is neither HAND_RIGHT (0) nor HAND_LEFT (1)")
    if not (math.isfinite(confidence) and 0.0 <= confidence <= 1.0):
        raise _reject(f"confidence {confidence} is outside [0, 1]")
    t = _names(names, "joint", limits, _ART_SET)
    if len(t) != len(ARTICULATED_JOINTS):
        missing = [n for n in ARTICULATED_JOINTS if n not in t]
        raise _reject(f"hand pose without joint(s) {missing[:6]}"
                      + (" (empty pose)" if not t else "")
                      + f"; it must carry all {len(ARTICULATED_JOINTS)} articulated joints")
    vals = validate_joint_values(t, positions, limits, "angle")
    p = _array(wrist_position, "wrist position", limits)
    o = _array(wrist_quat_xyzw, "wrist orientation", limits)
    _finite(p, "wrist position")
    _in_bounds(p, -limits.max_position, limits.max_position, "wrist position", "m")
    quat = _unit_quat(o, "wrist orientation", limits)
    q = np.zeros(len(JOINT_INDEX))
    q[[JOINT_INDEX[n] for n in t]] = vals
    q[0:3] = p
    q[3:6] = root_angles_from_quat(quat)
    return q


def validate_hand_pose_msg(msg: object, limits: InputLimits = DEFAULT_LIMITS) -> np.ndarray:
    """:func:`validate_hand_pose` on any object with the fields of hand_msgs/HandPose."""
    p, o = msg.wrist_pose.position, msg.wrist_pose.orientation
    return validate_hand_pose(msg.joint_names, msg.positions, (p.x, p.y, p.z),
                              (o.x, o.y, o.z, o.w), msg.status, msg.handedness,
                              float(msg.confidence), limits)


def validate_hand_keypoints_msg(msg: object, limits: InputLimits = DEFAULT_LIMITS
                                ) -> tuple[np.ndarray, str, int]:
    """A hand_msgs/HandKeypoints with 3-D points (common 21-keypoint order):
    ``(points (21, 3) [m], side, status)``.

    A frame whose status is STATUS_LOST may carry no points; it is returned with NaN points
    (the consumer holds its last output). Any other frame must carry 21 finite points.

    Raises:
        RejectedInputError: a status outside 0-4, a handedness other than 0/1, a confidence
            outside [0, 1], a point count other than 21, NaN/Inf points (naming the
            keypoints), a coordinate beyond ``max_position`` [m].
    """
    from hand_capture.model.keypoints21 import KEYPOINT21_NAMES, N_KEYPOINTS21

    status, handedness = int(msg.status), int(msg.handedness)
    if status not in HAND_POSE_STATUS:
        raise _reject(f"status {status} is not a HandPose status "
                      f"({', '.join(f'{k}={v}' for k, v in HAND_POSE_STATUS.items())})")
    if handedness not in (0, 1):
        raise _reject(f"handedness {handedness} is neither HAND_RIGHT (0) nor HAND_LEFT (1)")
    conf = float(msg.confidence)
    if not (math.isfinite(conf) and 0.0 <= conf <= 1.0):
        raise _reject(f"confidence {conf} is outside [0, 1]")
    side = "left" if handedness == 1 else "right"
    n = len(msg.points)
    if n == 0 and status == 3:
        return np.full((N_KEYPOINTS21, 3), np.nan), side, status
    if n != N_KEYPOINTS21:
        raise _reject(f"hand keypoints carry {n} 3-D points; {N_KEYPOINTS21} are needed "
                      "(wrist + 4 per finger)")
    pts = np.array([(p.x, p.y, p.z) for p in msg.points], dtype=np.float64)
    if not (np.abs(pts) <= limits.max_position).all():
        bad = ~np.isfinite(pts).all(axis=1)
        if bad.any():
            raise _reject(f"hand keypoints have NaN/Inf at "
                          f"{[KEYPOINT21_NAMES[i] for i in np.flatnonzero(bad)[:5]]}")
        _in_bounds(np.abs(pts).max(axis=1), 0.0, limits.max_position, "keypoint", "m",
                   KEYPOINT21_NAMES)
    return pts, side, status


def _unit_quat(o: np.ndarray, what: str, limits: InputLimits) -> np.ndarray:
    if o.shape != (4,):
        raise _reject(f"{what} needs 4 quaternion components, got {o.shape[0]}")
    _finite(o, what)
    with np.errstate(over="ignore"):  # 1e308 components: an infinite norm, refused below
        n = float(np.sqrt(o @ o))
    if abs(n - 1.0) > limits.quat_tolerance:
        raise _reject(f"{what} quaternion has norm {n:.6g}; it must be 1 within "
                      f"{limits.quat_tolerance}")
    return o / n


def validate_pose(position: Sequence[float], quat_xyzw: Sequence[float],
                  limits: InputLimits = DEFAULT_LIMITS, what: str = "pose"
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A geometry_msgs/Pose (object pose or target): ``(position (3,) [m], quaternion wxyz
    (4,) normalised)``.

    Raises:
        RejectedInputError: NaN/Inf, a coordinate beyond ``max_position`` [m], a quaternion whose
            norm is not 1 within ``quat_tolerance``.
    """
    p = _array(position, f"{what} position", limits)
    if p.shape != (3,):
        raise _reject(f"{what} position needs 3 components, got {p.shape[0]}")
    _finite(p, f"{what} position")
    _in_bounds(p, -limits.max_position, limits.max_position, f"{what} position", "m")
    q = _unit_quat(_array(quat_xyzw, f"{what} orientation", limits), f"{what} orientation",
                   limits)
    return p, np.array([q[3], q[0], q[1], q[2]])


def validate_twist(linear: Sequence[float], angular: Sequence[float],
                   limits: InputLimits = DEFAULT_LIMITS) -> tuple[np.ndarray, np.ndarray]:
    """A geometry_msgs/Twist: ``(linear (3,) [m/s], angular (3,) [rad/s])``.

    Raises:
        RejectedInputError: NaN/Inf, |linear| beyond ``max_linear_speed`` [m/s], |angular| beyond
            ``max_angular_speed`` [rad/s].
    """
    v = _array(linear, "linear velocity", limits)
    w = _array(angular, "angular velocity", limits)
    if v.shape != (3,) or w.shape != (3,):
        raise _reject("a twist needs 3 linear and 3 angular components")
    _finite(v, "linear velocity")
    _finite(w, "angular velocity")
    _in_bounds(v, -limits.max_linear_speed, limits.max_linear_speed, "linear velocity", "m/s")
    _in_bounds(w, -limits.max_angular_speed, limits.max_angular_speed, "angular velocity",
               "rad/s")
    return v, w


def validate_contacts(points: np.ndarray, normals: np.ndarray, forces: np.ndarray,
                      friction: np.ndarray, limits: InputLimits = DEFAULT_LIMITS
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A hand_msgs/ContactArray's (K, 3) points [m], normals, forces [N] and (K,) friction;
    returns them as float64 arrays.

    Raises:
        RejectedInputError: shapes, NaN/Inf, points beyond ``max_position`` [m], normals not of
            unit length (within ``quat_tolerance``; all-zero normals of reported-only contacts
            pass), forces above ``max_contact_force`` [N], friction outside [0,
            ``max_friction``].
    """
    k = len(friction)
    if k > limits.max_array_length:
        raise _reject(f"{k} contacts (at most {limits.max_array_length})")
    for what, a in (("points", points), ("normals", normals), ("forces", forces)):
        if np.shape(a) != (k, 3):
            raise _reject(f"contact {what} have shape {np.shape(a)}, expected ({k}, 3)")
        _finite(np.asarray(a, dtype=np.float64).reshape(-1), f"contact {what}")
    points, normals, forces = (np.asarray(a, dtype=np.float64).reshape(k, 3)
                               for a in (points, normals, forces))
    mu = np.asarray(friction, dtype=np.float64)
    _finite(mu, "contact friction")
    if k == 0:
        return points, normals, forces, mu
    _in_bounds(np.abs(points).max(axis=1), 0.0, limits.max_position, "contact point", "m")
    with np.errstate(over="ignore"):  # huge components: infinite norms, refused below
        n = np.linalg.norm(normals, axis=1)
        f = np.linalg.norm(forces, axis=1)
    bad = (np.abs(n - 1.0) > limits.quat_tolerance) & (n > 0.0)
    if bad.any():
        raise _reject(f"contact normal {int(np.flatnonzero(bad)[0])} has length "
                      f"{float(n[bad][0]):.4g}, not 1")
    _in_bounds(f, 0.0, limits.max_contact_force, "contact force", "N")
    _in_bounds(mu, 0.0, limits.max_friction, "contact friction", "(unitless)")
    return points, normals, forces, mu


def validate_grasp_phase(phase: int) -> int:
    """A hand_msgs/GraspPhase phase code (0-3).

    Raises:
        RejectedInputError: any other value.
    """
    if int(phase) not in GRASP_PHASES:
        raise _reject(f"phase {phase} is not a GraspPhase "
                      f"({', '.join(f'{k}={v}' for k, v in GRASP_PHASES.items())})")
    return int(phase)


def validate_touch_frame(session_ids: Sequence[int], positions: np.ndarray,
                         in_contact: Sequence[bool], width: float, height: float,
                         limits: InputLimits = DEFAULT_LIMITS) -> np.ndarray:
    """A hand_msgs/TouchFrame: the (n, 2) positions [m], checked against the surface size.

    Raises:
        RejectedInputError: a surface size that is not finite in (0, ``max_surface_size``] [m],
            more than ``max_touches`` points, lengths, duplicate session ids, NaN/Inf, a touch
            more than ``touch_margin`` of the surface size outside the surface [m], two touches
            in contact farther apart than ``max_touch_span`` [m].
    """
    w, h = float(width), float(height)
    for name, v in (("width", w), ("height", h)):
        if not (math.isfinite(v) and 0.0 < v <= limits.max_surface_size):
            raise _reject(f"surface {name} {v} m is outside (0, {limits.max_surface_size}] m")
    ids = list(session_ids)
    if len(ids) > limits.max_touches:
        raise _reject(f"{len(ids)} touch points (at most {limits.max_touches})")
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2) if len(ids) else \
        np.zeros((0, 2))
    if pos.shape[0] != len(ids) or len(in_contact) != len(ids):
        raise _reject(f"{len(ids)} session ids, {pos.shape[0]} positions, "
                      f"{len(in_contact)} contact flags")
    if len(set(ids)) != len(ids):
        raise _reject(f"duplicate session ids in {ids[:10]}")
    if len(ids):
        _finite(pos.reshape(-1), "touch positions")
        m = limits.touch_margin
        _in_bounds(pos[:, 0], -m * w, (1 + m) * w, "touch x", "m")
        _in_bounds(pos[:, 1], -m * h, (1 + m) * h, "touch y", "m")
        down = pos[np.asarray(in_contact, dtype=bool)]
        if len(down) > 1:
            span = float(np.sqrt(((down[:, None, :] - down[None, :, :]) ** 2).sum(-1)).max())
            if span > limits.max_touch_span:
                raise _reject(f"touches {span:.3g} m apart: more than one hand spans "
                              f"({limits.max_touch_span} m)")
    return pos


# ------------------------------------------------------------------------------ images
def validate_image_size(width: int, height: int, encoding: str, n_bytes: int,
                        encodings: Collection[str] = ("rgb8", "bgr8")) -> tuple[int, int]:
    """A sensor_msgs/Image's size and encoding before its pixels are touched:
    ``(width, height)``.

    Raises:
        RejectedInputError: an empty image (0 px or no data), an encoding outside
            ``encodings``.
    """
    w, h = int(width), int(height)
    if w <= 0 or h <= 0 or int(n_bytes) == 0:
        raise _reject(f"empty image: {w} x {h} px, {int(n_bytes)} bytes of data")
    if encoding not in encodings:
        raise _reject(f"image encoding {encoding!r} is not one of {sorted(encodings)}")
    return w, h


def validate_camera_info(msg: object, width: int | None = None, height: int | None = None
                         ) -> object:
    """The pinhole of a sensor_msgs/CameraInfo (any object with its fields) as
    :class:`~hand_capture.cameras.base.Intrinsics`, checked against the image it comes with.

    Raises:
        RejectedInputError: a K without 9 finite values, fx or fy <= 0 [px], a size of
            0 px, or a size other than the image's ``width`` x ``height``.
    """
    from hand_capture.cameras.base import Intrinsics

    k = np.asarray(list(msg.k), dtype=np.float64)
    if k.shape != (9,) or not np.isfinite(k).all():
        raise _reject(f"camera_info K must be 9 finite values, got {k.tolist()}")
    if k[0] <= 0 or k[4] <= 0:
        raise _reject(f"camera_info focal lengths fx {k[0]}, fy {k[4]} must be > 0 [px]")
    w, h = int(msg.width), int(msg.height)
    if w <= 0 or h <= 0:
        raise _reject(f"camera_info size {w} x {h} px is empty")
    if width is not None and (w, h) != (int(width), int(height)):
        raise _reject(f"camera_info is for {w} x {h} px, the image is {width} x {height}")
    d = np.asarray(list(msg.d), dtype=np.float64)
    if not np.isfinite(d).all():
        raise _reject(f"camera_info distortion has NaN/Inf: {d.tolist()}")
    return Intrinsics(w, h, float(k[0]), float(k[4]), float(k[2]), float(k[5]),
                      msg.distortion_model or "plumb_bob", tuple(d) or (0.0,) * 5,
                      msg.header.frame_id)
