"""bag_recorder: record topics into a rosbag2 bag (MCAP or sqlite3) with rosbags.

Subscribes to each requested topic as soon as it is discovered, with a QoS compatible with its
publishers (reliable only if every publisher is reliable), receives the serialised messages
without deserialising them and writes them with the middleware's receive time (the node clock
under use_sim_time). It takes them in batches (``batch_period``), which leaves the CPU to the
nodes it records. The bag is made durable
every ``flush_period`` seconds and finished (index, metadata.yaml) on every exit path, after
taking what has arrived but was not taken yet.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass
from datetime import datetime

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.subscription import MessageInfo

from hand_capture.bag import STORAGES, BagWriter, make_qos
from hand_capture.cameras.threads import reuse_freed_memory
from hand_capture.config import param, validate
from hand_capture.errors import BagError
from hand_capture.nodes.msgtypes import message_class
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node

_DRAIN_MAX = 100_000  # most messages taken per topic when the recorder stops


@dataclass(frozen=True)
class RecorderConfig:
    """Parameters of bag_recorder."""

    output: str = param("", "bag directory to create; empty = hand_suite_<date>_<time>")
    storage: str = param("mcap", "storage plugin", choices=STORAGES)
    topics: tuple[str, ...] = param(("hand/pose",), "topics to record (relative names allowed)")
    all_topics: bool = param(False, "record every topic that appears (ignores 'topics')")
    flush_period: float = param(1.0, "seconds between durable flushes [s]", lo=0.0, hi=60.0)
    discovery_period: float = param(0.2, "period of the topic discovery check [s]",
                                    lo=0.01, hi=10.0)
    queue_depth: int = param(100, "subscription queue depth per topic", lo=1, hi=100000)
    batch_period: float = param(
        0.02, "least time between two wake-ups [s]: messages are taken in batches, which "
        "costs far less CPU than a wake-up per message (their receive times come from the "
        "middleware, so batching does not change them; not under use_sim_time)",
        lo=0.0, hi=1.0)

    def __post_init__(self) -> None:
        validate(self)


def _qos_for(node: Node, topic: str, depth: int) -> tuple[QoSProfile, bool, bool]:
    """A subscription QoS matching every current publisher of ``topic``."""
    infos = node.get_publishers_info_by_topic(topic)
    reliable = bool(infos) and all(
        i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
    latched = bool(infos) and all(
        i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
    qos = QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )
    return qos, reliable, latched


class RecorderNode(Node):
    """Records topics to a bag; see the module docstring."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("bag_recorder", **kwargs)
        self.cfg = declare_config(self, RecorderConfig)
        reuse_freed_memory()  # every image / marker array received is a fresh 150-250 KB
        out = self.cfg.output or datetime.now().strftime("hand_suite_%Y%m%d_%H%M%S")
        self.writer = BagWriter(out, storage=self.cfg.storage, flush_period=self.cfg.flush_period)
        self.wanted = {self.resolve_topic_name(t) for t in self.cfg.topics}
        self.subs: dict[str, object] = {}
        self.rejected = 0
        self._sim_time = bool(self.get_parameter("use_sim_time").value)
        # read by LeanExecutor when the node is added (run_node); under sim time the stamps
        # are the node clock's at the callback, so no batching then
        self.min_wake_interval = 0.0 if self._sim_time else self.cfg.batch_period
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_timer(self.cfg.discovery_period, self._discover)
        self.create_timer(self.cfg.flush_period or 1.0, self._flush)
        self.create_timer(1.0, self._diagnostics)
        self._discover()
        self.get_logger().info(
            f"recording {'all topics' if self.cfg.all_topics else sorted(self.wanted)} "
            f"to {self.writer.path} ({self.cfg.storage})")

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if topic in self.subs or not (self.cfg.all_topics or topic in self.wanted):
                continue
            if self.cfg.all_topics and topic in ("/rosout", "/parameter_events"):
                continue
            msgtype = types[0]
            try:
                cls = message_class(msgtype)
                qos, reliable, latched = _qos_for(self, topic, self.cfg.queue_depth)
                self.writer.add_topic(topic, msgtype, [make_qos(reliable, latched)])
            except Exception as e:  # unknown type: skip the topic, keep recording the rest
                self.get_logger().error(f"cannot record {topic} ({msgtype}): {e}")
                self.subs[topic] = None
                continue
            # no QoS event handlers (rclpy's default ones only log incompatible QoS or types,
            # which the QoS and type taken from the publishers rule out): each would be one
            # more entity for the executor to wait on, per topic
            self.subs[topic] = self.create_subscription(
                cls, topic, functools.partial(self._on_message, topic), qos, raw=True,
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
            self.get_logger().info(f"subscribed to {topic} [{msgtype}]")

    def _on_message(self, topic: str, data: bytes, info: MessageInfo) -> None:
        # The middleware's receive time is free of executor scheduling delays; under
        # use_sim_time the node clock (the simulation's /clock) is the time base instead.
        stamp = info.get("received_timestamp", 0) if not self._sim_time else 0
        if stamp <= 0:
            stamp = self.get_clock().now().nanoseconds
        try:
            self.writer.write(topic, stamp, data)
        except BagError as e:
            self.rejected += 1
            self.get_logger().error(f"dropped a message on {topic}: {e}",
                                    throttle_duration_sec=1.0)

    def _flush(self) -> None:
        self.writer.flush()

    def _diagnostics(self) -> None:
        st = DiagnosticStatus(level=DiagnosticStatus.OK, name="bag_recorder",
                              message=f"{self.writer.count} messages",
                              hardware_id=str(self.writer.path))
        st.values = [KeyValue(key="messages", value=str(self.writer.count)),
                     KeyValue(key="bytes", value=str(self.writer.bytes)),
                     KeyValue(key="topics", value=str(len(self.writer.topics))),
                     KeyValue(key="rejected", value=str(self.rejected))]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(arr)

    def _drain(self) -> int:
        """Write what the middleware has received but the executor has not taken yet (a stop
        comes between two batched wake-ups, and later still on a loaded machine); returns the
        number of messages taken."""
        n = 0
        for topic, sub in self.subs.items():
            if sub is None:  # a topic that could not be recorded
                continue
            for _ in range(_DRAIN_MAX):
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, sub.raw)
                except Exception:  # destroyed or failing: the bag comes first
                    break
                if taken is None:
                    break
                self._on_message(topic, taken[0], taken[1])
                n += 1
        return n

    def on_shutdown(self) -> None:
        """Finish the bag (called by run_node on every exit path): write what has arrived,
        then the index and metadata.yaml."""
        if not self.writer.closed:
            self._drain()
        self.writer.close()
        self.get_logger().info(f"wrote {self.writer.count} messages to {self.writer.path}")


def main(args: list[str] | None = None) -> int:
    """Entry point of the bag_recorder console script."""
    return run_node(RecorderNode, args)


if __name__ == "__main__":
    sys.exit(main())
