"""HandPose message <-> 27-DoF pose vector, HandKeypoints <-> 21 keypoints, without importing
any message type.

Works on any object with the fields of ``hand_msgs/HandPose`` (an rclpy message, a rosbags
message read from a bag), so nodes, the report and the bag tools share one conversion.
Articulated joints travel by name; the root (wrist) travels as ``wrist_pose``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.joints import (
    ARTICULATED_JOINTS,
    JOINT_INDEX,
    pose_from_names,
    quat_from_root_angles,
    root_angles_from_quat,
)
from hand_capture.model.keypoints21 import N_KEYPOINTS21, validate_keypoints21

_ART_IDX = np.array([JOINT_INDEX[j] for j in ARTICULATED_JOINTS])

#: hand_msgs/HandPose constants (kept here so the core needs no message import).
HAND_RIGHT, HAND_LEFT = 0, 1
STATUS = {"unknown": 0, "tracking": 1, "recovering": 2, "lost": 3, "ground_truth": 4}


def pose_from_msg(msg: object) -> np.ndarray:
    """The (27,) pose of a HandPose: joints by name (absent ones 0), root from wrist_pose.

    Raises:
        InputError: unknown joint names, mismatched lengths or non-finite values.
    """
    q = pose_from_names(list(msg.joint_names), [float(v) for v in msg.positions])
    p, o = msg.wrist_pose.position, msg.wrist_pose.orientation
    q[0:3] = (p.x, p.y, p.z)
    q[3:6] = root_angles_from_quat(np.array([o.x, o.y, o.z, o.w]))
    return q


def fill_pose_msg(msg: object, pose: np.ndarray, *, side: str = "right",
                  status: str = "tracking", confidence: float = 1.0,
                  source: str = "") -> object:
    """Fill a HandPose ``msg`` (header left to the caller) from a (27,) ``pose``; returns it.

    Args:
        msg: a hand_msgs/HandPose instance.
        pose: (27,) joint values in JOINT_NAMES order [m, rad].
        side: ``"right"`` or ``"left"``.
        status: one of :data:`STATUS`.
        confidence: 0..1.
        source: producer name.
    """
    q = np.asarray(pose, dtype=float)
    msg.handedness = HAND_RIGHT if side == "right" else HAND_LEFT
    msg.joint_names = list(ARTICULATED_JOINTS)
    msg.positions = [float(v) for v in q[_ART_IDX]]
    p = msg.wrist_pose.position
    p.x, p.y, p.z = (float(v) for v in q[0:3])
    o = msg.wrist_pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in quat_from_root_angles(q[3:6]))
    msg.confidence = float(confidence)
    msg.status = STATUS[status]
    msg.source = source
    return msg


# ------------------------------------------------------------------ hand_msgs/HandKeypoints
@dataclass(frozen=True)
class Keypoints21:
    """The content of a hand_msgs/HandKeypoints as arrays (common order, keypoints21.py).

    Attributes:
        points: (21, 3) 3-D keypoints [m] in ``frame_id`` (NaN where unknown), or None when
            the message carries none.
        pixels: (21, 2) image keypoints (u, v) [px], or None.
        scores: (21,) per-keypoint confidence 0..1, or None.
        side: ``"right"`` or ``"left"``.
        status: the HandPose status code (:data:`STATUS`).
        confidence: whole-hand confidence 0..1.
        source: the producer.
    """

    points: np.ndarray | None
    pixels: np.ndarray | None
    scores: np.ndarray | None
    side: str
    status: int
    confidence: float
    source: str


def keypoints_from_msg(msg: object) -> Keypoints21:
    """Arrays of a HandKeypoints (any object with its fields). Values are not range-checked
    (NaN stays NaN: an unknown keypoint); the node-side check is
    :func:`hand_capture.validate.validate_hand_keypoints_msg`.

    Raises:
        InputError: points / pixels / scores whose lengths are not 21 (or empty).
    """
    pts = None
    if len(msg.points):
        if len(msg.points) != N_KEYPOINTS21:
            raise InputError(f"HandKeypoints has {len(msg.points)} points; it must carry "
                             f"{N_KEYPOINTS21} (or none)")
        pts = np.array([(p.x, p.y, p.z) for p in msg.points], dtype=np.float64)
    px = None
    if len(msg.pixels):
        if len(msg.pixels) != 2 * N_KEYPOINTS21:
            raise InputError(f"HandKeypoints has {len(msg.pixels)} pixel values; it must carry "
                             f"{2 * N_KEYPOINTS21} (u, v per keypoint) or none")
        px = np.asarray(msg.pixels, dtype=np.float64).reshape(N_KEYPOINTS21, 2)
    sc = None
    if len(msg.scores):
        if len(msg.scores) != N_KEYPOINTS21:
            raise InputError(f"HandKeypoints has {len(msg.scores)} scores; it must carry "
                             f"{N_KEYPOINTS21} (or none)")
        sc = np.asarray(msg.scores, dtype=np.float64)
    side = "left" if int(msg.handedness) == HAND_LEFT else "right"
    return Keypoints21(pts, px, sc, side, int(msg.status), float(msg.confidence),
                       str(msg.source))


def fill_keypoints_msg(msg: object, points: np.ndarray | None = None,
                       pixels: np.ndarray | None = None, scores: np.ndarray | None = None, *,
                       point_type: Callable[..., object] | None = None, side: str = "right",
                       status: str = "tracking", confidence: float = 1.0,
                       source: str = "") -> object:
    """Fill a HandKeypoints ``msg`` (header left to the caller); returns it.

    Args:
        msg: a hand_msgs/HandKeypoints instance.
        points: (21, 3) keypoints [m] in the common order, or None (sent empty).
        pixels: (21, 2) image keypoints [px], or None.
        scores: (21,) confidences 0..1, or None.
        point_type: the geometry_msgs/Point class (the caller's import; the core imports no
            message type); required with ``points``.
        side, status, confidence, source: as in :func:`fill_pose_msg`.

    Raises:
        InputError: shapes other than (21, 3) / (21, 2) / (21,), points without point_type.
    """
    if points is not None:
        p = validate_keypoints21(points, "points")
        if point_type is None:
            raise InputError("fill_keypoints_msg needs point_type (geometry_msgs/Point) to "
                             "send points")
        msg.points = [point_type(x=float(a), y=float(b), z=float(c)) for a, b, c in p]
    else:
        msg.points = []
    if pixels is not None:
        u = np.asarray(pixels, dtype=np.float64)
        if u.shape != (N_KEYPOINTS21, 2):
            raise InputError(f"pixels must have shape (21, 2), got {u.shape}")
        msg.pixels = [float(v) for v in u.reshape(-1)]
    else:
        msg.pixels = []
    if scores is not None:
        s = np.asarray(scores, dtype=np.float64).reshape(-1)
        if s.shape != (N_KEYPOINTS21,):
            raise InputError(f"scores must have 21 values, got {s.shape}")
        msg.scores = [float(v) for v in s]
    else:
        msg.scores = []
    msg.handedness = HAND_RIGHT if side == "right" else HAND_LEFT
    msg.confidence = float(confidence)
    msg.status = STATUS[status]
    msg.source = source
    return msg
