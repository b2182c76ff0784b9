"""The sim_grasp and touch graphs, started as a user does (``hand-suite run``), publish every
topic of their part of the contract; a probe node in this process listens."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import textwrap
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import ContactArray, HandPose, JointCommand, TouchFrame
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from ros_helpers import hand_suite
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

SENDER = textwrap.dedent("""
    import socket, sys, time
    from hand_capture.touch.tuio import cursor_bundle
    port = int(sys.argv[1])
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    base = [(0.30, 0.62), (0.42, 0.36), (0.55, 0.31), (0.67, 0.37)]
    for f in range(1500):  # until the test stops it (30 s at most)
        cur = {10 + i: (x + 0.0005 * (f % 100), y) for i, (x, y) in enumerate(base)}
        s.sendto(cursor_bundle(cur, f + 1, "pytest@127.0.0.1"), ("127.0.0.1", port))
        time.sleep(0.02)
""")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _probe_graph(args: list[str], topics: dict[str, type], timeout: float = 90.0,
                 side: list[str] | None = None) -> dict[str, int]:
    """Run ``hand-suite run *args``, count messages per topic until each has one (or the
    timeout), stop the graph with SIGINT; returns the counts (and asserts a clean exit)."""
    graph = hand_suite("run", *args)
    helper = None
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    counts = dict.fromkeys(topics, 0)
    try:
        node = rclpy.create_node("graph_probe", context=ctx)
        for name, typ in topics.items():
            def cb(_msg, name=name) -> None:
                counts[name] += 1
            node.create_subscription(typ, name, cb, qos_profile_sensor_data)
        if side is not None:
            env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
            helper = subprocess.Popen([sys.executable, "-c", *side], env=env)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end and not all(counts.values()) and graph.poll() is None:
            ex.spin_once(timeout_sec=0.05)
        ex.shutdown()
        node.destroy_node()
    finally:
        ctx.try_shutdown()
        if helper is not None:
            helper.kill()
            helper.wait()
        graph.send_signal(signal.SIGINT)
        out, _ = graph.communicate(timeout=30)
    assert graph.returncode == 0, out[-4000:]
    return counts


def test_sim_grasp_graph_publishes_its_topics() -> None:
    topics = {"/sim/joint_states": JointState, "/sim/object_pose": PoseStamped,
              "/sim/contacts": ContactArray, "/control/joint_command": JointCommand,
              "/control/contact_forces": ContactArray, "/clock": Clock,
              "/diagnostics": DiagnosticArray}
    counts = _probe_graph(["sim_grasp"], topics)
    assert all(counts.values()), counts


def test_touch_graph_turns_a_tuio_stream_into_servo_goals() -> None:
    port = _free_udp_port()
    topics = {"/touch/frame": TouchFrame, "/hand/pose": HandPose,
              "/servo/joint_states": JointState, "/servo/goal": JointCommand,
              "/diagnostics": DiagnosticArray}
    counts = _probe_graph(["touch", "-p", f"touch_source.tuio.port:={port}"], topics,
                          side=[SENDER, str(port)])
    assert all(counts.values()), counts
