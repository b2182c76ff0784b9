"""The sample capture: reproducible, small, and it replays through the bag player."""

from __future__ import annotations

from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from hand_capture.bag import BagReader, default_typestore
from hand_capture.cameras.synthetic import SyntheticCameraConfig
from hand_capture.nodes.capture import SAMPLE_CAPTURE, TOPICS, write_capture
from hand_capture.nodes.images import image_to_array
from hand_capture.nodes.player import PlayerNode
from hand_capture.posemsg import pose_from_msg


def test_capture_is_reproducible_and_stamps_truth_with_the_image(tmp_path: Path) -> None:
    cfg = SyntheticCameraConfig(clip="fist", fps=10.0, width=80, height=60)
    a = write_capture(tmp_path / "a", cfg, seconds=0.3)
    b = write_capture(tmp_path / "b", cfg, seconds=0.3)
    assert a.frames == 3 and a.messages == 3 * len(TOPICS)
    store = default_typestore()

    def canonical(path: Path) -> list[tuple]:
        # Messages sharing a receive time may come in any topic order, and rclpy leaves CDR
        # alignment padding uninitialised: compare canonical re-serialisations per topic.
        return sorted((m.topic, m.timestamp_ns, bytes(store.serialize_cdr(
            store.deserialize_cdr(m.data, m.msgtype), m.msgtype)))
            for m in BagReader(path).messages())

    assert canonical(a.path) == canonical(b.path)
    r = BagReader(a.path)
    by_topic: dict[str, list] = {}
    for m in r.messages():
        by_topic.setdefault(m.topic, []).append(r.check(m))
    for depth, truth in zip(by_topic["/camera/depth/image_raw"], by_topic["/hand/pose_truth"],
                            strict=True):
        assert depth.header.stamp == truth.header.stamp
        assert depth.encoding == "16UC1" and (depth.width, depth.height) == (80, 60)
        assert pose_from_msg(truth).shape == (27,)


def test_shipped_sample_capture_is_small_and_replays() -> None:
    assert SAMPLE_CAPTURE.is_dir(), "regenerate with: hand-suite capture"
    size = sum(f.stat().st_size for f in SAMPLE_CAPTURE.iterdir())
    assert size <= 5_000_000
    expected = BagReader(SAMPLE_CAPTURE).message_count
    rclpy.init()
    try:
        got: list[Image] = []
        sub = rclpy.create_node("probe")
        sub.create_subscription(Image, "/camera/depth/image_raw", got.append,
                                QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        player = PlayerNode(parameter_overrides=[
            Parameter("bag", value=str(SAMPLE_CAPTURE)), Parameter("rate", value=5.0),
            Parameter("wait_for_subscribers", value=True),
            Parameter("topics", value=["/camera/depth/image_raw"])])
        ex = SingleThreadedExecutor()
        ex.add_node(player)
        ex.add_node(sub)
        ex.spin_until_future_complete(player.done, timeout_sec=30)
        ex.spin_once(timeout_sec=0.5)
        assert player.done.result() == 0
        assert len(got) == expected // len(TOPICS)
        assert image_to_array(got[0]).max() > 0  # the hand is in view
        player.on_shutdown()
        player.destroy_node()
        sub.destroy_node()
    finally:
        rclpy.shutdown()
