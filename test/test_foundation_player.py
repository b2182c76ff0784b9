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


def test_rate_scales_timing_and_clock_follows_bag_time(rclpy_up, tmp_path: Path) -> None:
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


def test_start_skips_the_beginning(rclpy_up, tmp_path: Path) -> None:
    bag = tmp_path / "s"
    write_sample_bag(bag, duration=2.0, rate=30.0)
    player, times, _, _ = _play(bag, start=1.0, rate=4.0)
    assert player.done.result() == 0
    assert len(times) == pytest.approx(30, abs=1)


def test_corrupt_message_stops_playback_before_publishing_it(rclpy_up, tmp_path: Path) -> None:
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


def test_corrupt_first_message_refused_at_start(rclpy_up, tmp_path: Path) -> None:
    bag = tmp_path / "c"
    w = BagWriter(bag)
    w.add_topic("/hand/pose", "hand_msgs/msg/HandPose")
    w.write("/hand/pose", 1, b"\x00\x01\x00\x00\xff\xff\xff\x7f")
    w.close()
    with pytest.raises(BagError, match=str(bag)):
        PlayerNode(parameter_overrides=[Parameter("bag", value=str(bag))])


def test_mcap_without_qos_metadata_is_played(rclpy_up, tmp_path: Path) -> None:
    """Issue #20 item 10: an MCAP file from the mcap tools (no QoS metadata, channels not
    repeated in the summary) was refused as a 'truncated bag'."""
    from mcap.writer import Writer
    from rclpy.serialization import serialize_message

    f = tmp_path / "ext.mcap"
    with f.open("wb") as fh:
        w = Writer(fh, repeat_channels=False)
        w.start(profile="ros2", library="mcap-tools")
        sid = w.register_schema(name="hand_msgs/msg/HandPose", encoding="ros2msg",
                                data=b"")  # definition taken from the suite's store
        cid = w.register_channel(topic="/hand/pose", message_encoding="cdr", schema_id=sid)
        for k in range(5):
            data = serialize_message(HandPose(positions=[0.1 * k]))
            w.add_message(cid, log_time=(k + 1) * 10_000_000, data=data,
                          publish_time=(k + 1) * 10_000_000)
        w.finish()
    got: list[float] = []
    probe = rclpy.create_node("probe")
    probe.create_subscription(HandPose, "/hand/pose", lambda m: got.append(m.positions[0]),
                              QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    player = PlayerNode(parameter_overrides=[Parameter("bag", value=str(f)),
                                             Parameter("wait_for_subscribers", value=True)])
    ex = SingleThreadedExecutor()
    for n in (player, probe):
        ex.add_node(n)
    try:
        ex.spin_until_future_complete(player.done, timeout_sec=30)
        assert player.done.result() == 0
        deadline = time.monotonic() + 10.0
        while len(got) < 5 and time.monotonic() < deadline:  # the last ones still queued
            ex.spin_once(timeout_sec=0.1)
        assert got == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    finally:
        player.on_shutdown()
        for n in (player, probe):
            n.destroy_node()


def test_latched_topic_is_replayed_transient_local(rclpy_up, tmp_path: Path) -> None:
    """Issue #20 item 10: hand/shape (recorded transient local) reaches a subscriber that
    joins after the player published it."""
    from hand_msgs.msg import HandShape
    from rclpy.qos import DurabilityPolicy
    from rclpy.serialization import serialize_message

    from hand_capture.bag import make_qos

    bag = tmp_path / "latched"
    w = BagWriter(bag)
    w.add_topic("/hand/shape", "hand_msgs/msg/HandShape", [make_qos(True, True, depth=1)])
    w.write("/hand/shape", 1_000, serialize_message(HandShape(global_scale=1.07)))
    w.close()
    player = PlayerNode(parameter_overrides=[Parameter("bag", value=str(bag)),
                                             Parameter("clock_rate", value=0.0)])
    ex = SingleThreadedExecutor()
    ex.add_node(player)
    late = rclpy.create_node("late_subscriber")
    try:
        ex.spin_until_future_complete(player.done, timeout_sec=30)
        assert player.done.result() == 0 and player.published == 1
        got: list[float] = []
        late.create_subscription(
            HandShape, "/hand/shape", lambda m: got.append(m.global_scale),
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        ex.add_node(late)
        deadline = time.monotonic() + 20.0
        while not got and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.1)
        assert got and got[0] == pytest.approx(1.07)
    finally:
        player.on_shutdown()
        player.destroy_node()
        late.destroy_node()


def test_damaged_bag_given_to_play_is_one_line(tmp_path: Path) -> None:
    """Issue #20 items 6 and 9: a bit-flipped bag is refused by play before anything is
    published, with one line naming the damage (no traceback)."""
    import os
    import subprocess
    import sys

    bag = tmp_path / "s"
    write_sample_bag(bag, duration=0.5)
    f = bag / "s.mcap"
    data = bytearray(f.read_bytes())
    data[len(data) // 3] ^= 0x10
    f.write_bytes(bytes(data))
    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-m", "hand_control.cli", "play", str(bag)],
                       capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(root)})
    assert p.returncode != 0
    assert "Traceback" not in p.stderr + p.stdout, p.stderr
    errors = [ln for ln in p.stderr.splitlines() if "error" in ln]
    assert len(errors) == 1 and "CRC mismatch" in errors[0] and "s.mcap" in errors[0], p.stderr


def test_player_holds_its_first_message_until_the_awaited_topic_answers(
        rclpy_up, tmp_path: Path) -> None:
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
