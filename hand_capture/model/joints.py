"""The joint vocabulary of the suite: one declared order, used by every node.

27 degrees of freedom as in the dissertation (ch. II.3.1): 6 for the root (position and
orientation of the wrist), 5 for the thumb (TM 2, MCP 2, IP 1) and 4 for each other finger
(MCP 2, PIP 1, DIP 1). Messages carry joints by name; this order is only the order of arrays
inside the core.

Conventions (shared by the numpy model, the MJCF export and every consumer):

* Hand frame (the palm / root bone), right hand: origin at the wrist joint centre, ``+x``
  distal (towards the middle fingertip), ``+y`` radial (towards the thumb), ``+z`` dorsal (the
  back of the hand); the palm faces ``-z``. The left hand is the mirror image through the
  hand's ``xz`` plane (``y -> -y``), so its thumb lies on ``-y``.
* Root position ``root_tx, root_ty, root_tz`` [m]: wrist position in the parent (world /
  camera) frame.
* Root orientation ``root_rx, root_ry, root_rz`` [rad]: three successive hinge angles about the
  moving ``x``, then ``y``, then ``z`` axes (intrinsic XYZ Euler angles),
  ``R = Rx(rx) @ Ry(ry) @ Rz(rz)``. This is exactly what three MuJoCo hinge joints with axes
  x, y, z declared in that order in one body compute, so the numpy FK and MuJoCo agree to
  round-off. It is *not* a rotation vector; convert with :func:`root_rotation_matrix` and
  :func:`root_angles_from_matrix` (gimbal lock at ``root_ry = +-pi/2``).
* Finger angles [rad]: ``*_flex`` positive = flexion (the segment moves towards the palm),
  ``*_abd`` positive = deviation towards the thumb side (radial) for every finger and both
  hands (for the thumb TM and MCP: away from the index finger / out of the palm, see
  ``hand_capture.model.skeleton``). The zero pose is the flat, slightly spread hand.
* A 2-DoF joint applies its abduction first and its flexion about the abducted axis
  (``R = Rz(abd) @ Ry(flex)`` in the bone's rest frame), the order of the names below.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from hand_capture.errors import InputError

FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")

ROOT_JOINTS: tuple[str, ...] = (
    "root_tx", "root_ty", "root_tz",  # wrist position [m]
    "root_rx", "root_ry", "root_rz",  # wrist orientation, intrinsic XYZ hinge angles [rad]
)

THUMB_JOINTS: tuple[str, ...] = (
    "thumb_tm_abd", "thumb_tm_flex", "thumb_mcp_abd", "thumb_mcp_flex", "thumb_ip_flex",
)


def _finger_joints(finger: str) -> tuple[str, ...]:
    return (f"{finger}_mcp_abd", f"{finger}_mcp_flex", f"{finger}_pip_flex",
            f"{finger}_dip_flex")


FINGER_JOINTS: tuple[str, ...] = THUMB_JOINTS + tuple(
    j for f in FINGERS[1:] for j in _finger_joints(f)
)

#: Every degree of freedom, root first (27).
JOINT_NAMES: tuple[str, ...] = ROOT_JOINTS + FINGER_JOINTS

#: The articulated (hinge) joints that messages carry in joint_names (21).
ARTICULATED_JOINTS: tuple[str, ...] = FINGER_JOINTS

assert len(JOINT_NAMES) == 27 and len(set(JOINT_NAMES)) == 27

N_DOF: int = len(JOINT_NAMES)
JOINT_INDEX: dict[str, int] = {n: i for i, n in enumerate(JOINT_NAMES)}
#: The DoF indices of each finger, thumb to little, in JOINT_NAMES order (5 for the thumb,
#: 4 for each other finger).
FINGER_DOFS: tuple[np.ndarray, ...] = tuple(
    np.array([i for i, n in enumerate(JOINT_NAMES) if n.startswith(f + "_")]) for f in FINGERS
)

# ---------------------------------------------------------------------------------------------
# Anatomical joint limits [deg] (active range of motion), converted to radians below.
#
# Sources:
#  [AAOS] American Academy of Orthopaedic Surgeons, "Joint Motion: Method of Measuring and
#         Recording" (1965), normal ranges: finger MCP flexion 90 deg / hyperextension 45 deg,
#         PIP flexion 100 deg, DIP flexion 90 deg / extension 10 deg; thumb CMC (TM) flexion
#         15 deg, extension 20 deg, abduction 70 deg; thumb MCP flexion 50 deg; thumb IP
#         flexion 80 deg / hyperextension 20 deg.
#  [LWH]  Lin, Wu & Huang, "Modeling the constraints of human hand motion", IEEE Workshop on
#         Human Motion (2000): static limits MCP flexion 0..90, PIP 0..110, DIP 0..90,
#         MCP abduction -15..15 deg.
#  [HUME] Hume et al., "Functional range of motion of the joints of the hand",
#         J. Hand Surg. 15A (1990): active thumb MCP flexion about 56 deg.
#
# Choices: MCP hyperextension is limited to 30 deg (between [LWH]'s 0 and [AAOS]'s 45) so the
# tracker cannot bend fingers backwards into implausible poses; MCP abduction is [LWH]'s +-15
# widened to +-20 deg (+-25 for the little finger) because our zero pose is the anatomical
# neutral and the measured spread between fingers reaches 15-30 deg; PIP uses [LWH]'s 110.
# Our thumb TM axes are not the clinical CMC axes (the zero pose already holds the thumb about
# 35 deg away from the index), so the TM ranges are the [AAOS] arcs (flexion+extension 35,
# abduction 70 deg) re-centred on our zero pose and widened to reach opposition.
# ---------------------------------------------------------------------------------------------
_FINGER_LIMITS_DEG: dict[str, tuple[float, float]] = {
    "mcp_abd": (-20.0, 20.0),   # [LWH] +-15, widened (see above)
    "mcp_flex": (-30.0, 90.0),  # [AAOS] / [LWH]
    "pip_flex": (0.0, 110.0),   # [LWH]
    "dip_flex": (-10.0, 90.0),  # [AAOS]
}
_THUMB_LIMITS_DEG: dict[str, tuple[float, float]] = {
    "thumb_tm_abd": (-20.0, 50.0),    # [AAOS] abduction arc 70, re-centred
    "thumb_tm_flex": (-25.0, 55.0),   # [AAOS] flexion/extension arc, widened for opposition
    "thumb_mcp_abd": (-15.0, 15.0),   # small radial/ulnar play of the thumb MCP
    "thumb_mcp_flex": (-10.0, 60.0),  # [AAOS] 50, [HUME] 56
    "thumb_ip_flex": (-20.0, 80.0),   # [AAOS]
}


def _limits_table() -> np.ndarray:
    lim = np.empty((N_DOF, 2))
    lim[:6] = (-np.inf, np.inf)  # the root is free
    for name, (lo, hi) in _THUMB_LIMITS_DEG.items():
        lim[JOINT_INDEX[name]] = (math.radians(lo), math.radians(hi))
    for finger in FINGERS[1:]:
        for short, (lo, hi) in _FINGER_LIMITS_DEG.items():
            if finger == "little" and short == "mcp_abd":
                lo, hi = -25.0, 20.0  # the little finger abducts further (ulnar)
            lim[JOINT_INDEX[f"{finger}_{short}"]] = (math.radians(lo), math.radians(hi))
    lim.setflags(write=False)
    return lim


#: (27, 2) lower/upper limit per DoF in JOINT_NAMES order [m or rad]; root entries are +-inf.
JOINT_LIMITS: np.ndarray = _limits_table()


def joint_limits_dict() -> dict[str, tuple[float, float]]:
    """The limits by joint name, ``{name: (lo, hi)}`` (root entries are ``(-inf, inf)``)."""
    return {n: (float(JOINT_LIMITS[i, 0]), float(JOINT_LIMITS[i, 1]))
            for i, n in enumerate(JOINT_NAMES)}


# ---------------------------------------------------------------------------------------------
# Pose vectors
# ---------------------------------------------------------------------------------------------
def validate_pose(pose: object, *, name: str = "pose") -> np.ndarray:
    """Return ``pose`` as a float64 array of shape (27,) or (B, 27).

    Raises:
        InputError: wrong length / dimensionality, NaN or Inf (naming the bad joints).
    """
    try:
        q = np.asarray(pose, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name} is not numeric: {e}") from e
    if q.ndim not in (1, 2) or q.shape[-1] != N_DOF:
        raise InputError(f"{name} must have shape (27,) or (B, 27) in JOINT_NAMES order, "
                         f"got {q.shape}")
    if not np.all(np.isfinite(q)):
        bad = np.nonzero(~np.isfinite(q.reshape(-1, N_DOF)).any(axis=0))[0]
        raise InputError(f"{name} has NaN/Inf in {[JOINT_NAMES[i] for i in bad]}")
    return q


def within_limits(pose: object, tol: float = 1e-9) -> np.ndarray:
    """Boolean (27,) or (B, 27): whether each DoF lies inside its limits (+- tol)."""
    q = validate_pose(pose)
    return (q >= JOINT_LIMITS[:, 0] - tol) & (q <= JOINT_LIMITS[:, 1] + tol)


def clamp_to_limits(pose: object) -> np.ndarray:
    """Clip every articulated DoF into :data:`JOINT_LIMITS` (root untouched); returns a copy."""
    q = validate_pose(pose)
    return np.clip(q, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])


def rest_pose() -> np.ndarray:
    """The zero pose (flat hand at the origin), shape (27,)."""
    return np.zeros(N_DOF)


def pose_to_dict(pose: object) -> dict[str, float]:
    """A (27,) pose as ``{joint_name: value}`` in JOINT_NAMES order."""
    q = validate_pose(pose)
    if q.ndim != 1:
        raise InputError(f"pose_to_dict takes one pose (27,), got {q.shape}")
    return {n: float(v) for n, v in zip(JOINT_NAMES, q, strict=True)}


def pose_from_dict(values: Mapping[str, float], default: object | None = None) -> np.ndarray:
    """Build a (27,) pose from ``{joint_name: value}``.

    Joints absent from ``values`` take their value from ``default`` (the zero pose if None).

    Raises:
        InputError: an unknown joint name (the message lists the valid ones), a non-finite value.
    """
    unknown = sorted(set(values) - set(JOINT_NAMES))
    if unknown:
        raise InputError(f"unknown joint name(s) {unknown}; valid names: {list(JOINT_NAMES)}")
    q = rest_pose() if default is None else validate_pose(default, name="default").copy()
    if q.ndim != 1:
        raise InputError("default must be one pose (27,)")
    for n, v in values.items():
        try:
            q[JOINT_INDEX[n]] = float(v)
        except (TypeError, ValueError) as e:
            raise InputError(f"joint {n!r}: value {v!r} is not a number") from e
    return validate_pose(q)


def pose_from_names(names: Iterable[str], positions: Iterable[float],
                    default: object | None = None) -> np.ndarray:
    """Build a (27,) pose from parallel name / value lists (e.g. a JointState or HandPose).

    Raises:
        InputError: different lengths, duplicate or unknown names, non-finite values.
    """
    names = list(names)
    positions = list(positions)
    if len(names) != len(positions):
        raise InputError(f"{len(names)} joint names but {len(positions)} positions")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"duplicate joint name(s) {dup}")
    return pose_from_dict(dict(zip(names, positions, strict=True)), default)


# ---------------------------------------------------------------------------------------------
# Root orientation helpers (intrinsic XYZ hinge angles, see the module docstring)
# ---------------------------------------------------------------------------------------------
def root_rotation_matrix(angles: object) -> np.ndarray:
    """``Rx(rx) @ Ry(ry) @ Rz(rz)`` for angles (..., 3) -> (..., 3, 3)."""
    a = np.asarray(angles, dtype=np.float64)
    cx, cy, cz = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sx, sy, sz = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    r = np.empty(a.shape[:-1] + (3, 3))
    r[..., 0, 0] = cy * cz
    r[..., 0, 1] = -cy * sz
    r[..., 0, 2] = sy
    r[..., 1, 0] = cx * sz + sx * sy * cz
    r[..., 1, 1] = cx * cz - sx * sy * sz
    r[..., 1, 2] = -sx * cy
    r[..., 2, 0] = sx * sz - cx * sy * cz
    r[..., 2, 1] = sx * cz + cx * sy * sz
    r[..., 2, 2] = cx * cy
    return r


def root_angles_from_matrix(rot: object) -> np.ndarray:
    """Inverse of :func:`root_rotation_matrix`: (..., 3, 3) -> (..., 3), ry in [-pi/2, pi/2]."""
    r = np.asarray(rot, dtype=np.float64)
    ry = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    rx = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    rz = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    # At gimbal lock (cos ry ~ 0) rx and rz are coupled: put everything into rx.
    lock = np.abs(r[..., 0, 2]) > 1.0 - 1e-12
    if np.any(lock):
        rx = np.where(lock, np.arctan2(r[..., 2, 1], r[..., 1, 1]), rx)
        rz = np.where(lock, 0.0, rz)
    return np.stack([rx, ry, rz], axis=-1)


def quat_to_matrix(quat_xyzw: object) -> np.ndarray:
    """Unit quaternion (x, y, z, w) (ROS / geometry_msgs order) -> rotation matrix."""
    q = np.asarray(quat_xyzw, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(~np.isfinite(q)) or np.any(n < 1e-12):
        raise InputError(f"invalid quaternion {q}")
    x, y, z, w = np.moveaxis(q / n, -1, 0)
    r = np.empty(q.shape[:-1] + (3, 3))
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - z * w)
    r[..., 0, 2] = 2 * (x * z + y * w)
    r[..., 1, 0] = 2 * (x * y + z * w)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - x * w)
    r[..., 2, 0] = 2 * (x * z - y * w)
    r[..., 2, 1] = 2 * (y * z + x * w)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def quat_wxyz_to_matrix(quat_wxyz: object) -> np.ndarray:
    """Unit quaternion(s) (..., 4) in (w, x, y, z) order (MuJoCo's) -> rotation matrix
    (..., 3, 3)."""
    q = np.asarray(quat_wxyz, dtype=np.float64)
    return quat_to_matrix(q[..., [1, 2, 3, 0]])


def matrix_to_quat(rot: object) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4) in (x, y, z, w) order, w >= 0."""
    r = np.asarray(rot, dtype=np.float64)
    m = r.reshape(-1, 3, 3)
    out = np.empty((m.shape[0], 4))
    for i, a in enumerate(m):
        tr = a[0, 0] + a[1, 1] + a[2, 2]
        if tr > 0:
            s = 2.0 * math.sqrt(tr + 1.0)
            out[i] = ((a[2, 1] - a[1, 2]) / s, (a[0, 2] - a[2, 0]) / s,
                      (a[1, 0] - a[0, 1]) / s, 0.25 * s)
        elif a[0, 0] > a[1, 1] and a[0, 0] > a[2, 2]:
            s = 2.0 * math.sqrt(1.0 + a[0, 0] - a[1, 1] - a[2, 2])
            out[i] = (0.25 * s, (a[0, 1] + a[1, 0]) / s, (a[0, 2] + a[2, 0]) / s,
                      (a[2, 1] - a[1, 2]) / s)
        elif a[1, 1] > a[2, 2]:
            s = 2.0 * math.sqrt(1.0 + a[1, 1] - a[0, 0] - a[2, 2])
            out[i] = ((a[0, 1] + a[1, 0]) / s, 0.25 * s, (a[1, 2] + a[2, 1]) / s,
                      (a[0, 2] - a[2, 0]) / s)
        else:
            s = 2.0 * math.sqrt(1.0 + a[2, 2] - a[0, 0] - a[1, 1])
            out[i] = ((a[0, 2] + a[2, 0]) / s, (a[1, 2] + a[2, 1]) / s, 0.25 * s,
                      (a[1, 0] - a[0, 1]) / s)
    out *= np.where(out[:, 3:] < 0, -1.0, 1.0)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out.reshape(r.shape[:-2] + (4,))


def matrix_to_quat_wxyz(rot: object) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4) in (w, x, y, z) order
    (MuJoCo's), w >= 0: the inverse of :func:`quat_wxyz_to_matrix`."""
    return matrix_to_quat(rot)[..., [3, 0, 1, 2]]


def root_angles_from_quat(quat_xyzw: object) -> np.ndarray:
    """Root hinge angles (rx, ry, rz) of a wrist orientation quaternion (x, y, z, w)."""
    return root_angles_from_matrix(quat_to_matrix(quat_xyzw))


def quat_from_root_angles(angles: object) -> np.ndarray:
    """Wrist orientation quaternion (x, y, z, w) of root hinge angles (rx, ry, rz)."""
    return matrix_to_quat(root_rotation_matrix(angles))


def mirror_pose(pose: object) -> np.ndarray:
    """The pose that places the other hand as the mirror image through the world ``xz`` plane.

    ``HandModel(side='left').forward(mirror_pose(q))`` is the reflection ``y -> -y`` of
    ``HandModel(side='right').forward(q)`` (and vice versa). Finger angles are unchanged; the
    root becomes ``(tx, -ty, tz, -rx, ry, -rz)``.
    """
    q = validate_pose(pose).copy()
    q[..., 1] *= -1.0
    q[..., 3] *= -1.0
    q[..., 5] *= -1.0
    return q
