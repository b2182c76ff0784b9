"""Full-size depth images reach the tracker (issue 13, transport): 640x480 16UC1 frames at
30 Hz, published with the camera nodes' QoS in one process, arrive at a subscription with
the tracker's image QoS in another, with the DDS environment the graphs give their nodes."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from hand_capture.dds import PROFILE_VARS, dds_environment, profile_file


def test_graphs_hand_every_node_the_shipped_profile() -> None:
    from hand_control.runner import node_environment

    env = dds_environment({})
    assert env[PROFILE_VARS[0]] == str(profile_file())
    assert PROFILE_VARS[1] not in env  # Fast DDS 3's rmw warns about the old name
    # Fast DDS 2 distributions read the old name: both are set
    env = dds_environment({"ROS_DISTRO": "jazzy"})
    assert {env[k] for k in PROFILE_VARS} == {str(profile_file())}
    # a profile the user chose wins
    env = dds_environment({"FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml"})
    assert env[PROFILE_VARS[0]] == "/mine.xml"
    env = node_environment()
    assert env[PROFILE_VARS[0]] and env["PYTHONUNBUFFERED"] == "1"


def test_profile_gives_a_shared_memory_segment_larger_than_a_frame() -> None:
    ns = {"d": "http://www.eprosima.com"}
    root = ET.parse(profile_file()).getroot()
    sizes = [int(e.text) for e in root.iterfind(".//d:transport_descriptor/d:segment_size", ns)]
    assert sizes and min(sizes) >= 8 * 640 * 480 * 2
    part = root.find(".//d:participant[@is_default_profile='true']", ns)
    assert part is not None
    used = {e.text for e in part.iterfind(".//d:userTransports/d:transport_id", ns)}
    shm = {e.findtext("d:transport_id", namespaces=ns)
           for e in root.iterfind(".//d:transport_descriptor", ns)
           if e.findtext("d:type", namespaces=ns) == "SHM"}
    assert shm <= used and shm


def test_640x480_frames_at_30hz_reach_the_tracker_subscription() -> None:
    """The transport loses no frame (fails on the old transport: with Fast DDS defaults the
    message-lost event counted 10 and 21 of 60 frames in two runs, 68-85 % taken). Frames
    the subscriber did not take because its process was not scheduled within a frame period
    (a loaded CPU overwrites the depth-1 queue: 52-58 of 60 taken beside three busy loops on
    two cores) are the tracker's design, not a loss; ``hand-suite bench tracking`` measures
    delivery on an idle machine (99 % target)."""
    from hand_capture.bench._delivery import measure_delivery

    r = measure_delivery(60, 30.0, 640, 480, profile=True, timeout_s=90.0)
    assert r["sent"] == 60, r
    assert r["lost"] == 0, r
    assert r["received"] >= 0.5 * r["sent"], r
