"""HandPose <-> pose vector: one conversion for nodes, bags and the report."""

from __future__ import annotations

import numpy as np
import pytest
from hand_msgs.msg import HandPose

from hand_capture.bag.typestore import default_typestore
from hand_capture.errors import InputError
from hand_capture.model import JOINT_LIMITS
from hand_capture.posemsg import fill_pose_msg, pose_from_msg


def _random_pose(seed: int) -> np.ndarray:
    lo, hi = np.asarray(JOINT_LIMITS).T  # (27, 2) -> two (27,)
    rng = np.random.default_rng(seed)
    q = rng.uniform(np.maximum(lo, -1.0), np.minimum(hi, 1.0))
    q[:3] = rng.uniform(-0.3, 0.3, 3)
    q[3:6] = rng.uniform(-1.0, 1.0, 3)
    return q


def test_round_trip_through_an_rclpy_message() -> None:
    q = _random_pose(1)
    msg = fill_pose_msg(HandPose(), q, status="recovering", confidence=0.5, source="t")
    assert msg.status == HandPose.STATUS_RECOVERING
    np.testing.assert_allclose(pose_from_msg(msg), q, atol=1e-12)


def test_round_trip_through_a_bag_message() -> None:
    from rclpy.serialization import serialize_message

    q = _random_pose(2)
    data = serialize_message(fill_pose_msg(HandPose(), q))
    m = default_typestore().deserialize_cdr(data, "hand_msgs/msg/HandPose")
    np.testing.assert_allclose(pose_from_msg(m), q, atol=1e-12)


def test_unknown_joint_is_refused() -> None:
    msg = HandPose(joint_names=["index_mcp_flex", "sixth_finger"], positions=[0.1, 0.2])
    with pytest.raises(InputError, match="sixth_finger"):
        pose_from_msg(msg)
