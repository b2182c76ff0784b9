"""grasp_phase node: hand poses and the object pose in; phases, the manipulation target and the
world-frame hand target out, with the hand pose's stamp."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import GraspPhase, HandPose
from rclpy.parameter import Parameter

from hand_capture.model import JOINT_INDEX, HandModel, rest_pose
from hand_capture.posemsg import fill_pose_msg
from hand_control.nodes.grasp_phase import GraspPhaseNode

FLEX = [j for j in JOINT_INDEX if j.endswith(("_mcp_flex", "_pip_flex", "_dip_flex"))
        and not j.startswith("thumb")]


def _hand(close: float, k: int) -> HandPose:
    q = rest_pose().copy()
    for j in FLEX:
        q[JOINT_INDEX[j]] = close
    msg = fill_pose_msg(HandPose(), q, status="tracking")
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k // 30, (k % 30) * 33_000_000
    return msg


def test_phases_and_target_follow_the_hand(ros) -> None:
    peer, add, spin_until = ros
    # camera 1 m above the world origin looking down (x stays, y and z flip)
    add(GraspPhaseNode(parameter_overrides=[
        Parameter("scenario", value="lift_box"),
        Parameter("camera_position", value=[0.0, 0.0, 1.0]),
        Parameter("camera_rotation", value=[np.pi, 0.0, 0.0])]))
    phases: list[GraspPhase] = []
    targets: list[PoseStamped] = []
    hands: list[HandPose] = []
    peer.create_subscription(HandPose, "control/hand_target", hands.append, 50)
    peer.create_subscription(GraspPhase, "control/grasp_phase", phases.append, 50)
    peer.create_subscription(PoseStamped, "control/object_target", targets.append, 50)
    pub_hand = peer.create_publisher(HandPose, "hand/pose", 50)
    pub_obj = peer.create_publisher(PoseStamped, "sim/object_pose", 10)
    kp = HandModel().forward(rest_pose()).joint_positions  # camera frame
    palm = kp[[0, 5, 9, 13, 17]].mean(axis=0)
    obj = PoseStamped()  # at the palm centre, in the world
    obj.pose.position.x, obj.pose.position.y, obj.pose.position.z = (
        float(palm[0]), float(-palm[1]), float(1.0 - palm[2]))
    obj.pose.orientation.w = 1.0
    assert spin_until(lambda: pub_hand.get_subscription_count() > 0, 10.0)
    # ... held closed while the hand's paced approach reaches the planned grasp and closes it
    seq = [0.0] * 5 + list(np.linspace(0.0, 0.8, 10)) + [0.8] * 150
    sent = 0

    def tick() -> None:
        nonlocal sent
        pub_obj.publish(obj)
        if sent < len(seq):
            pub_hand.publish(_hand(seq[sent], sent))
            sent += 1

    assert spin_until(lambda: targets and phases[-1].phase == GraspPhase.MANIPULATION, 20.0,
                      tick=tick), [p.phase for p in phases]
    assert phases[0].phase in (GraspPhase.REACHING, GraspPhase.CLOSING)
    assert phases[-1].object_name == "box"
    last = phases[-1].header.stamp
    assert (last.sec, last.nanosec) != (0, 0)  # the hand pose's stamp, not a new one
    assert targets[-1].pose.position.x == pytest.approx(obj.pose.position.x, abs=1e-6)
    assert targets[-1].pose.position.z == pytest.approx(obj.pose.position.z, abs=1e-6)
    # the hand target is in the world: the wrist mapped through the camera pose
    assert hands and hands[0].header.frame_id == "world"
    assert hands[0].wrist_pose.position.z == pytest.approx(1.0 - rest_pose()[2], abs=1e-6)
    assert (hands[-1].header.stamp.sec, hands[-1].header.stamp.nanosec) == (last.sec,
                                                                            last.nanosec)
