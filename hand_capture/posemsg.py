"""HandPose message <-> 27-DoF pose vector, without importing any message type.

Works on any object with the fields of ``hand_msgs/HandPose`` (an rclpy message, a rosbags
message read from a bag), so nodes, the report and the bag tools share one conversion.
Articulated joints travel by name; the root (wrist) travels as ``wrist_pose``.
"""

from __future__ import annotations

import numpy as np

from hand_capture.model.joints import (
    ARTICULATED_JOINTS,
    JOINT_INDEX,
    pose_from_names,
    quat_from_root_angles,
    root_angles_from_quat,
)

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
