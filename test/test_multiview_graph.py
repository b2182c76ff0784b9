"""The multiview graph, started as a user does (``hand-suite run multiview``): the shipped
rig capture replayed through rig_sync reaches multiview_tracker, which publishes the hand and
the box."""

from __future__ import annotations

from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import HandPose
from test_graphs_run import _probe_graph


def test_multiview_graph_tracks_the_shipped_rig_capture() -> None:
    topics = {"/hand/pose": HandPose, "/object/pose": PoseStamped}
    counts = _probe_graph(["multiview"], topics, timeout=180.0)
    assert all(counts.values()), counts
