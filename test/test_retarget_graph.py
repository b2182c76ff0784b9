"""The retarget graph, started as a user does (``hand-suite run retarget``): the tracked hand
becomes robot/joint_command and the servo bridge writes goals from it."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from hand_msgs.msg import HandPose, JointCommand
from sensor_msgs.msg import JointState
from test_graphs_run import _probe_graph


def test_retarget_graph_drives_the_servos_from_the_tracked_hand() -> None:
    topics = {"/hand/pose": HandPose, "/robot/joint_command": JointCommand,
              "/servo/goal": JointCommand, "/servo/joint_states": JointState,
              "/diagnostics": DiagnosticArray}
    counts = _probe_graph(["retarget"], topics, timeout=120.0)
    assert all(counts.values()), counts
