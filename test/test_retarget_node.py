"""The retarget stream (pure core) and node: commands out of good frames; NaN keypoints, no
hand, the other hand hold the last command and are counted."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point
from hand_msgs.msg import HandKeypoints, HandPose, JointCommand
from rclpy.parameter import Parameter

from hand_capture.cameras.motion import builtin_clip
from hand_capture.model import JOINT_INDEX
from hand_capture.model.keypoints21 import keypoints21
from hand_capture.posemsg import fill_keypoints_msg, fill_pose_msg
from hand_control.retarget import HandRetargeter
from hand_control.retarget.stream import RetargetStream


@pytest.fixture(scope="module")
def leap() -> HandRetargeter:
    return HandRetargeter("leap_hand")


def test_stream_holds_the_last_command_on_bad_frames_and_counts_them(leap) -> None:
    s = RetargetStream(HandRetargeter(leap.config, leap.robot), hold_timeout_s=0.5)
    kp = keypoints21(None, builtin_clip("pinch").sample(1.8))
    assert s.hold("no_hand", 0.0).q is None  # nothing to hold yet
    good = s.keypoints(kp, 1.0)
    assert good.q is not None and not good.held
    bad = kp.copy()
    bad[12] = np.nan
    for out in (s.keypoints(bad, 1.1), s.keypoints(kp, 1.2, status=3),
                s.keypoints(kp, 1.25, side="left"), s.pose(None, 1.3)):
        assert out.held
        np.testing.assert_array_equal(out.q, good.q)
    assert s.counts() == {"solved": 1, "held_total": 5, "held/invalid": 2,
                          "held/no_hand": 2, "held/other_hand": 1, "held/solver": 0}
    assert s.keypoints(bad, 1.6).q is None  # past hold_timeout_s: nothing is sent
    assert s.pose(builtin_clip("fist").sample(1.5), 2.0).q is not None  # a pose works too


def _kp_msg(points, k: int, status: str = "tracking") -> HandKeypoints:
    msg = fill_keypoints_msg(HandKeypoints(), points, point_type=Point, status=status)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k // 30, (k % 30) * 33_000_000
    return msg


def test_node_retargets_keypoints_and_holds_on_nan_and_lost(ros) -> None:
    from hand_control.nodes.retarget import RetargetNode

    peer, add, spin_until = ros
    node = add(RetargetNode(parameter_overrides=[Parameter("input", value="keypoints"),
                                                 Parameter("config", value="leap_hand")]))
    cmds: list[JointCommand] = []
    diags: list[DiagnosticArray] = []
    peer.create_subscription(JointCommand, "robot/joint_command", cmds.append, 50)
    peer.create_subscription(DiagnosticArray, "diagnostics", diags.append, 50)
    pub = peer.create_publisher(HandKeypoints, "hand/keypoints", 50)
    assert spin_until(lambda: pub.get_subscription_count() > 0, 10.0)
    clip = builtin_clip("pinch")
    kp = keypoints21(None, clip.sample(1.8))
    pub.publish(_kp_msg(kp, 0))
    assert spin_until(lambda: len(cmds) == 1, 10.0)
    assert list(cmds[0].joint_names) == list(node.stream.joint_names)
    assert (cmds[0].header.stamp.sec, cmds[0].header.stamp.nanosec) == (100, 0)
    bad = kp.copy()
    bad[8] = np.nan
    pub.publish(_kp_msg(bad, 1))
    pub.publish(_kp_msg(None, 2, status="lost"))
    assert spin_until(lambda: len(cmds) == 3, 10.0)
    assert list(cmds[1].positions) == list(cmds[0].positions) == list(cmds[2].positions)
    counts = node.stream.counts()
    assert counts["held/invalid"] == 1 and counts["held/no_hand"] == 1
    assert node.gate.rejected["hand/keypoints"] == 1  # the NaN frame, logged by the gate
    pub.publish(_kp_msg(keypoints21(None, builtin_clip("fist").sample(1.5)), 3))
    assert spin_until(lambda: len(cmds) == 4, 10.0)
    assert list(cmds[3].positions) != list(cmds[0].positions)

    def diag_values() -> dict[str, str]:
        for arr in reversed(diags):
            for st in arr.status:
                if st.name == "retarget":
                    return {kv.key: kv.value for kv in st.values}
        return {}

    assert spin_until(lambda: diag_values().get("solved") == "2", 10.0), diag_values()
    v = diag_values()
    assert v["held/invalid"] == "1" and v["held/no_hand"] == "1"
    assert v["rejected/hand/keypoints"] == "1" and float(v["solve_ms_p50"]) > 0


def test_node_follows_hand_poses(ros) -> None:
    from hand_control.nodes.retarget import RetargetNode

    peer, add, spin_until = ros
    node = add(RetargetNode(parameter_overrides=[Parameter("config", value="suite_hand")]))
    cmds: list[JointCommand] = []
    peer.create_subscription(JointCommand, "robot/joint_command", cmds.append, 50)
    pub = peer.create_publisher(HandPose, "hand/pose", 50)
    assert spin_until(lambda: pub.get_subscription_count() > 0, 10.0)
    q = builtin_clip("pinch").sample(1.8)
    msg = fill_pose_msg(HandPose(), q)
    msg.header.stamp.sec = 50
    pub.publish(msg)
    assert spin_until(lambda: len(cmds) == 1, 10.0)
    got = dict(zip(cmds[0].joint_names, cmds[0].positions, strict=True))
    # the suite hand onto itself: the finger joints come back (tips within 1 mm)
    assert node.stream.solved == 1
    assert abs(got["index_pip_flex"] - q[JOINT_INDEX["index_pip_flex"]]) < 0.05


def test_stream_mirrors_the_other_hand_when_asked(leap) -> None:
    from hand_capture.model import mirror_pose

    q = builtin_clip("pinch").sample(1.8)
    right = keypoints21(None, q, "right")
    left = keypoints21(None, mirror_pose(q), "left")  # the same hand, mirrored
    want = RetargetStream(HandRetargeter(leap.config, leap.robot)).keypoints(right, 0.0).q
    s = RetargetStream(HandRetargeter(leap.config, leap.robot), mirror_other_hand=True)
    got = s.keypoints(left, 0.0, side="left")
    assert not got.held and s.counts()["held/other_hand"] == 0
    np.testing.assert_allclose(got.q, want, atol=1e-6)
