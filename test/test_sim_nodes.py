"""The sim and controller nodes in-process: topics published, commands applied by name,
unknown names rejected and counted, and the closed loop over topics lifts the box."""

from __future__ import annotations

import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, TwistStamped
from hand_msgs.msg import ContactArray, JointCommand
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from hand_control.nodes.controller import ControllerNode
from hand_control.nodes.sim import SimNode


def _collect(peer, topics: dict) -> dict[str, list]:
    got: dict[str, list] = {t: [] for t in topics}
    for topic, msgtype in topics.items():
        peer.create_subscription(msgtype, topic, got[topic].append, 50)
    return got


def test_sim_node_publishes_every_topic_and_rejects_unknown_joint_names(ros) -> None:
    peer, add, spin_until = ros
    sim = add(SimNode(parameter_overrides=[Parameter("scenario", value="lift_box"),
                                           Parameter("real_time", value=False)]))
    from rclpy.qos import qos_profile_sensor_data

    got = {t: [] for t in ("sim/joint_states", "sim/object_pose", "sim/object_twist",
                           "sim/contacts", "/clock")}
    for topic, msgtype in (("sim/joint_states", JointState), ("sim/object_pose", PoseStamped),
                           ("sim/object_twist", TwistStamped), ("sim/contacts", ContactArray)):
        peer.create_subscription(msgtype, topic, got[topic].append, qos_profile_sensor_data)
    peer.create_subscription(Clock, "/clock", got["/clock"].append, 10)
    assert spin_until(lambda: all(len(v) >= 3 for v in got.values()), 20.0), \
        {k: len(v) for k, v in got.items()}
    js = got["sim/joint_states"][-1]
    assert list(js.name) == list(sim.world.joint_names) and len(js.position) == 27
    assert len(js.velocity) == 27
    assert got["/clock"][-1].clock.sec * 1e9 + got["/clock"][-1].clock.nanosec > 0
    contacts = got["sim/contacts"][-1]
    assert any(c.body1 == "table" and c.body2 == "box" for c in contacts.contacts)
    assert got["sim/object_pose"][-1].header.frame_id == "world"

    pub = peer.create_publisher(JointCommand, "control/joint_command", 10)
    bad = JointCommand(joint_names=["index_pip_flex", "bogus"], positions=[0.5, 0.1])
    good = JointCommand(joint_names=["index_pip_flex"], positions=[0.7])
    deadline = time.monotonic() + 10
    while sim.rejected == 0 and time.monotonic() < deadline:
        pub.publish(bad)
        spin_until(lambda: sim.rejected > 0, 0.2)
    assert sim.rejected >= 1
    k = sim.world.joint_names.index("index_pip_flex")
    assert sim.world.target[k] != 0.5
    pub.publish(good)
    assert spin_until(lambda: sim.world.target[k] == 0.7, 5.0)


def test_controller_node_closes_the_loop_over_topics(ros) -> None:
    peer, add, spin_until = ros
    sim = add(SimNode(parameter_overrides=[Parameter("scenario", value="lift_box"),
                                           Parameter("real_time", value=False),
                                           Parameter("command_timeout", value=1.0)]))
    ctrl = add(ControllerNode(parameter_overrides=[Parameter("scenario", value="lift_box")]))
    got = _collect(peer, {"control/joint_command": JointCommand,
                          "control/contact_forces": ContactArray,
                          "control/contact_markers": MarkerArray})
    # the sim runs as fast as the loop allows; wait until it is past the closing phase
    z0 = sim.world.object_pose("box").position[2]
    assert spin_until(lambda: sim.world.time > 2.5, 60.0), sim.world.time
    assert len(got["control/joint_command"]) > 100
    cmd = got["control/joint_command"][-1]
    assert list(cmd.joint_names) == list(sim.world.joint_names)
    assert any(abs(e) > 1e-3 for e in cmd.efforts)  # grasp torques are on
    assert sim.accepted > 100 and sim.rejected == 0
    assert any(len(m.contacts) for m in got["control/contact_forces"])
    assert got["control/contact_markers"]
    assert ctrl.core.counters["non_finite_outputs"] == 0
    # lifting started at 1.3 s: the box is up by most of the reference's 10 cm by 2.5 s
    assert sim.world.object_pose("box").position[2] - z0 > 0.05


def test_teleop_controller_holds_the_start_until_the_first_hand_pose(ros) -> None:
    """reference: hand_pose: before any hand pose (a slow tracker on a loaded machine) the
    hand holds the scenario's start and the object stays put; the scripted reach and lift
    (which, with grasp torques off, knocks the box away) must not play."""
    peer, add, spin_until = ros
    sim = add(SimNode(parameter_overrides=[Parameter("scenario", value="lift_box"),
                                           Parameter("real_time", value=False),
                                           Parameter("command_timeout", value=1.0)]))
    ctrl = add(ControllerNode(parameter_overrides=[
        Parameter("scenario", value="lift_box"), Parameter("reference", value="hand_pose")]))
    p0 = sim.world.object_pose("box").position.copy()
    q0 = ctrl.core.reference(0.0).q_target[:3].copy()
    # the scripted reference has reached, closed and lifted by 2.5 s
    assert spin_until(lambda: sim.world.time > 2.5, 180.0), sim.world.time
    assert ctrl.commands > 10
    assert np.linalg.norm(sim.world.object_pose("box").position - p0) < 0.005
    q = sim.world.hand_state()[0]
    assert np.linalg.norm(q[:3] - q0) < 0.01  # the wrist stayed at the start


@pytest.mark.parametrize("answer", [True, False])
def test_controller_answers_a_new_hand_pose_without_waiting_for_a_joint_state(
        ros, answer: bool) -> None:
    """reference: hand_pose: with ``command_on_reference`` a new hand pose gets its command
    (carrying the pose's stamp) at once, computed on the newest joint state; without it, only
    the next joint state's step carries it."""
    from hand_msgs.msg import HandPose
    from rclpy.qos import qos_profile_sensor_data

    from hand_capture.model import rest_pose
    from hand_capture.posemsg import fill_pose_msg

    peer, add, spin_until = ros
    ctrl = add(ControllerNode(parameter_overrides=[
        Parameter("scenario", value="lift_box"), Parameter("reference", value="hand_pose"),
        Parameter("command_on_reference", value=answer)]))
    got = _collect(peer, {"control/joint_command": JointCommand})
    qos = qos_profile_sensor_data
    pub_obj = peer.create_publisher(PoseStamped, "sim/object_pose", qos)
    pub_js = peer.create_publisher(JointState, "sim/joint_states", qos)
    pub_hand = peer.create_publisher(HandPose, "hand/pose", qos)
    names = list(ctrl.core.joint_names)
    obj = PoseStamped()
    obj.header.frame_id = "world"
    obj.pose.orientation.w = 1.0
    js = JointState(name=names, position=[0.0] * len(names), velocity=[0.0] * len(names))
    js.header.stamp.sec = 5
    assert spin_until(lambda: ctrl._obj is not None, 10.0, tick=lambda: pub_obj.publish(obj))
    assert spin_until(lambda: got["control/joint_command"], 10.0,
                      tick=lambda: pub_js.publish(js))
    hand = fill_pose_msg(HandPose(), rest_pose(), status="tracking")
    hand.header.frame_id = "world"
    hand.header.stamp.sec = 76
    # the topic reaches the controller ...
    assert spin_until(lambda: ctrl._hand_stamp is not None, 10.0,
                      tick=lambda: pub_hand.publish(hand))

    def carried() -> bool:
        return any(c.header.stamp.sec == 77 for c in got["control/joint_command"])

    # ... and a new pose is answered inside its own callback, or not at all (no timing: a
    # joint state still in flight cannot blur this)
    hand.header.stamp.sec = 77
    js.header.stamp.sec = 6  # a fresh joint state just before (answers on a stale one stop)
    ctrl._on_joint_state(js)
    before = ctrl.commands
    ctrl._on_hand_pose(hand)
    assert (ctrl.commands == before + 1) == answer
    if not answer:  # the next joint state's step carries it
        js.header.stamp.sec = 7
        ctrl._on_joint_state(js)
        assert ctrl.commands == before + 1
    assert spin_until(carried, 10.0)  # and the command on the topic carries the pose's stamp
