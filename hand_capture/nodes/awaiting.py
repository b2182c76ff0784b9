"""Wait until a graph's other nodes run: a message has arrived on each of a list of topics.

A source node (the synthetic camera, the bag player) that starts its motion or playback before
the rest of the graph is up loses what it sends first; on a loaded machine the nodes of a graph
come up seconds apart. A publisher alone does not prove its node runs (it may still be setting
up, e.g. the sim building its world), nor a subscriber (a recorder subscribes to everything
early): only a message does. :class:`TopicWaiter` gives each awaited topic that has a publisher
a probe subscription (raw, best effort, so it matches every publisher), records the topics a
message arrived on, and drops the probes when done. Call :meth:`TopicWaiter.poll` from the
node's executor thread (a timer), since it creates subscriptions.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from hand_capture.errors import InputError
from hand_capture.nodes.msgtypes import message_class


class TopicWaiter:
    """Probe ``topics`` of ``node`` until each had a message, or ``timeout`` [s] passed."""

    def __init__(self, node: Node, topics: Sequence[str], timeout: float) -> None:
        self.node = node
        self.topics = list(topics)
        self.timeout = timeout
        self.subs: dict[str, object] = {}  # awaited topic -> its probe subscription
        self.heard: set[str] = set()  # awaited topics a message has arrived on
        self.timed_out = False
        self._created = time.monotonic()

    def missing(self) -> list[str]:
        """Awaited topics without a message so far."""
        return [t for t in self.topics if t not in self.heard]

    def poll(self) -> bool:
        """Probe the topics that got a publisher; True once every topic had a message (or the
        wait timed out, which is logged once). The probes are dropped then."""
        missing = self.missing()
        for t in missing:
            if t not in self.subs:
                self._probe(t)
        if missing and time.monotonic() - self._created > self.timeout:
            self.node.get_logger().warning(f"starting without messages on {missing} "
                                           f"(waited {self.timeout:g} s)")
            self.timed_out = True
            missing = []
        if not missing:
            self.close()
            return True
        return False

    def close(self) -> None:
        """Drop the probe subscriptions."""
        for sub in self.subs.values():
            self.node.destroy_subscription(sub)
        self.subs.clear()

    def _probe(self, topic: str) -> None:
        """Subscribe to an awaited topic once it has a publisher (its type is known then)."""
        infos = self.node.get_publishers_info_by_topic(topic)
        if not infos:
            return
        try:
            cls = message_class(infos[0].topic_type)
        except InputError as e:  # not installed here: its publisher has to do
            self.node.get_logger().warning(f"cannot subscribe to awaited topic {topic}: {e}")
            self.heard.add(topic)
            return
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.subs[topic] = self.node.create_subscription(
            cls, topic, lambda _msg, t=topic: self.heard.add(t), qos, raw=True)
