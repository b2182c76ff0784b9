"""bag_player in-process: rate scaling, --start, /clock, corrupt bags never published."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import rclpy
from hand_msgs.msg import HandPose
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from hand_capture.bag import BagReader, BagWriter
from hand_capture.bag.sample import write_sample_bag
from hand_capture.errors import BagError
from hand_capture.nodes.player import PlayerNode


@pytest.fixture()
def ros():
    rclpy.init()
    yield
    rclpy.shutdown()


def _play(bag: Path, **params: object) -> tuple[PlayerNode, list[float], list[int], float]:
    """Play ``bag``; returns the node, receive times [s] of hand/pose (the middleware's, so
    that a slow executor on a loaded machine does not shift them), /clock stamps [ns], and the
    wall time the playback took [s]."""
    sub = rclpy.create_node("probe")
    times: list[float] = []
    clocks: list[int] = []
    sub.create_subscription(
        HandPose, "/hand/pose",
        lambda m, info: times.append(info.get("received_timestamp", 0) * 1e-9),
        QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE))
    sub.create_subscription(Clock, "/clock",
                            lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), 10)
    overrides = [Parameter("bag", value=str(bag)), Parameter("wait_for_subscribers", value=True),
                 Parameter("topics", value=["/hand/pose"])]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    player = PlayerNode(parameter_overrides=overrides)
    ex = SingleThreadedExecutor()
    ex.add_node(player)
    ex.add_node(sub)
    t0 = time.monotonic()
    ex.spin_until_future_complete(player.done, timeout_sec=30)
    elapsed = time.monotonic() - t0
    deadline = time.monotonic() + 10.0  # take what is still queued (acknowledged, not taken)
    while len(times) < player.published and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)
    ex.spin_once(timeout_sec=0.05)
    player.on_shutdown()
    for n in (player, sub):
        n.destroy_node()
    return player, times, clocks, elapsed


def test_rate_scales_timing_and_clock_follows_bag_time(ros, tmp_path: Path) -> None:
    bag = tmp_path / "s"
    write_sample_bag(bag, duration=2.0, rate=30.0)
    player, times, clocks, _ = _play(bag, rate=2.0)
    assert player.done.result() == 0
    assert len(times) == 60
    span = times[-1] - times[0]
    assert span == pytest.approx((59 / 30) / 2.0, abs=0.1)  # 2x faster than recorded
    r = BagReader(bag)
    assert clocks, "no /clock published"
    assert all(r.start_ns <= c <= r.end_ns + 200_000_000 for c in clocks)
    assert clocks == sorted(clocks)


def test_start_skips_the_beginning(ros, tmp_path: Path) -> None:
    bag = tmp_path / "s"
    write_sample_bag(bag, duration=2.0, rate=30.0)
    player, times, _, _ = _play(bag, start=1.0, rate=4.0)
    assert player.done.result() == 0
    assert len(times) == pytest.approx(30, abs=1)


def test_corrupt_message_stops_playback_before_publishing_it(ros, tmp_path: Path) -> None:
    from rclpy.serialization import serialize_message

    bag = tmp_path / "c"
    w = BagWriter(bag)
    w.add_topic("/hand/pose", "hand_msgs/msg/HandPose")
    for i in range(5):
        w.write("/hand/pose", i * 10_000_000, serialize_message(HandPose(positions=[1.0 * i])))
    w.write("/hand/pose", 60_000_000, b"\x00\x01\x00\x00\xff\xff\xff\x7f")
    w.close()
    player, times, _, _ = _play(bag)
    assert player.done.result() == 1
    assert len(times) == 5


def test_corrupt_first_message_refused_at_start(ros, tmp_path: Path) -> None:
    bag = tmp_path / "c"
    w = BagWriter(bag)
    w.add_topic("/hand/pose", "hand_msgs/msg/HandPose")
    w.write("/hand/pose", 1, b"\x00\x01\x00\x00\xff\xff\xff\x7f")
    w.close()
    with pytest.raises(BagError, match=str(bag)):
        PlayerNode(parameter_overrides=[Parameter("bag", value=str(bag))])


def test_player_holds_its_first_message_until_the_awaited_topic_answers(
        ros, tmp_path: Path) -> None:
    """wait_for_topics: the first message is held (published again and again) and nothing
    else is played until a message arrives on the awaited topic; then the whole bag plays."""
    from std_msgs.msg import String

    bag = tmp_path / "s"
    write_sample_bag(bag, duration=1.0, rate=30.0)
    peer = rclpy.create_node("probe")
    got: list[int] = []
    peer.create_subscription(HandPose, "/hand/pose", lambda m: got.append(1),
                             QoSProfile(depth=500, reliability=ReliabilityPolicy.RELIABLE))
    ready = peer.create_publisher(String, "/probe/ready", 10)
    player = PlayerNode(parameter_overrides=[
        Parameter("bag", value=str(bag)), Parameter("topics", value=["/hand/pose"]),
        Parameter("wait_for_topics", value=["/probe/ready"]), Parameter("hold_rate", value=20.0),
        Parameter("wait_timeout", value=120.0)])
    ex = SingleThreadedExecutor()
    ex.add_node(player)
    ex.add_node(peer)
    try:
        deadline = time.monotonic() + 60.0
        while len(got) < 3 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        assert len(got) >= 3 and player.published == 0  # held, not played
        deadline = time.monotonic() + 60.0
        while not player.done.done() and time.monotonic() < deadline:
            ready.publish(String(data="up"))
            ex.spin_once(timeout_sec=0.05)
        assert player.done.result() == 0
        assert player.published == 30  # the whole bag, after the held first message
    finally:
        player.on_shutdown()
        for n in (player, peer):
            n.destroy_node()
