"""hand_msgs travel intact between processes over ROS 2 (Fast DDS)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import time

import rclpy
from geometry_msgs.msg import Point, Vector3
from hand_msgs.msg import Contact, ContactArray, HandPose
from rclpy.qos import QoSProfile, ReliabilityPolicy

LISTENER = textwrap.dedent("""
    import json, sys
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from hand_msgs.msg import HandPose, ContactArray
    rclpy.init()
    node = rclpy.create_node("listener")
    got = {}
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    def on_pose(m):
        got["pose"] = {"names": list(m.joint_names), "q": list(m.positions),
                       "z": m.wrist_pose.position.z, "status": m.status,
                       "conf": m.confidence, "stamp": [m.header.stamp.sec,
                       m.header.stamp.nanosec], "frame": m.header.frame_id}
    def on_contacts(m):
        got["contacts"] = [{"b1": c.body1, "b2": c.body2, "p": [c.point.x, c.point.y,
                            c.point.z], "f": [c.force.x, c.force.y, c.force.z],
                            "tau": c.torsional_torque, "mu": c.friction} for c in m.contacts]
    node.create_subscription(HandPose, "hand/pose", on_pose, qos)
    node.create_subscription(ContactArray, "sim/contacts", on_contacts, qos)
    print("ready", flush=True)
    while rclpy.ok() and len(got) < 2:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps(got), flush=True)
    rclpy.shutdown()
""")


def test_hand_pose_and_contacts_cross_processes() -> None:
    child = subprocess.Popen([sys.executable, "-c", LISTENER], stdout=subprocess.PIPE,
                             text=True)
    assert child.stdout.readline().strip() == "ready"
    rclpy.init()
    node = rclpy.create_node("talker")
    try:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        pub_pose = node.create_publisher(HandPose, "hand/pose", qos)
        pub_c = node.create_publisher(ContactArray, "sim/contacts", qos)
        pose = HandPose(joint_names=["index_mcp_flex", "thumb_ip_flex"], positions=[0.5, -0.25],
                        confidence=0.75, status=HandPose.STATUS_TRACKING, source="test")
        pose.header.frame_id = "camera_depth_optical_frame"
        pose.header.stamp.sec, pose.header.stamp.nanosec = 12, 345
        pose.wrist_pose.position.z = 0.42
        contacts = ContactArray(contacts=[Contact(
            body1="index_distal", body2="box", point=Point(x=0.1, y=0.2, z=0.3),
            normal=Vector3(z=1.0), force=Vector3(x=1.5, y=-2.0, z=3.25),
            torsional_torque=0.01, friction=0.8)])
        deadline = time.monotonic() + 20.0
        while child.poll() is None and time.monotonic() < deadline:
            pub_pose.publish(pose)
            pub_c.publish(contacts)
            rclpy.spin_once(node, timeout_sec=0.05)
        out, _ = child.communicate(timeout=5)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        if child.poll() is None:
            child.kill()
    got = json.loads(out.strip().splitlines()[-1])
    assert got["pose"] == {"names": ["index_mcp_flex", "thumb_ip_flex"], "q": [0.5, -0.25],
                           "z": 0.42, "status": HandPose.STATUS_TRACKING, "conf": 0.75,
                           "stamp": [12, 345], "frame": "camera_depth_optical_frame"}
    assert got["contacts"] == [{"b1": "index_distal", "b2": "box", "p": [0.1, 0.2, 0.3],
                                "f": [1.5, -2.0, 3.25], "tau": 0.01, "mu": 0.8}]
