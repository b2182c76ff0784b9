"""bag_player: replay a rosbag2 bag with its recorded timing, publishing /clock.

Messages are published in receive-time order at the recorded pace scaled by ``rate``; every
payload is checked (deserialised) before it is published, so a corrupt record stops playback
with an error naming the file and is never sent. ``/clock`` carries the bag time at
``clock_rate`` Hz so nodes with ``use_sim_time`` follow the recording. When the bag ends the node
exits 0 (or starts over with ``loop``).

QoS: every topic is republished reliable (a reliable publisher serves reliable and best-effort
subscribers alike) with the recorded durability: a topic recorded transient-local (latched, e.g.
``hand/shape``) is republished transient-local with the recorded depth, so a subscriber that
joins late still gets it. A topic without recorded QoS (MCAP files from the ``mcap`` tools) is
played reliable and volatile, with a note in the log.

Start-up of a graph (``wait_for_topics``): until a message has arrived on each awaited topic
(the downstream nodes run; :class:`~hand_capture.nodes.awaiting.TopicWaiter`), the player holds
the bag's first message of every played topic, publishing it ``hold_rate`` times a second, as a
camera shows its first frame, so that the chain can answer; playback starts ``start_delay``
seconds after. The nodes of a graph come up seconds apart on a loaded machine, so a fixed delay
is not enough.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from hand_capture.bag import BagReader
from hand_capture.config import param, validate
from hand_capture.errors import BagError, ConfigError
from hand_capture.nodes.awaiting import TopicWaiter
from hand_capture.nodes.msgtypes import message_class
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.paths import resolve_path

_SPIN_WAIT = 0.002  # below this remaining time [s], busy-wait for precise timing


@dataclass(frozen=True)
class PlayerConfig:
    """Parameters of bag_player."""

    bag: str = param("", "bag directory to play (relative: from the working directory, "
                     "else the suite's share folder, e.g. data/sample_capture)")
    rate: float = param(1.0, "playback speed factor (1.0 = recorded pace)", lo=0.01, hi=1000.0)
    loop: bool = param(False, "start over when the bag ends")
    start: float = param(0.0, "seconds into the bag to start from [s]", lo=0.0)
    clock_rate: float = param(100.0, "rate of /clock messages [Hz]; 0 = no /clock",
                              lo=0.0, hi=1000.0)
    topics: tuple[str, ...] = param((), "topics to play; empty = all")
    wait_for_subscribers: bool = param(
        False, "wait until every played topic has a subscriber before starting")
    wait_timeout: float = param(10.0, "longest wait for subscribers [s]", lo=0.0, hi=600.0)
    start_delay: float = param(0.0, "pause after start-up (after the wait) before the first "
                               "message [s]", lo=0.0, hi=60.0)
    wait_for_topics: tuple[str, ...] = param(
        (), "hold the first message of every played topic (published hold_rate times a "
        "second) until a message has arrived on each of these topics, i.e. the graph's other "
        "nodes run; at most wait_timeout")
    hold_rate: float = param(5.0, "rate of the held first messages while waiting [Hz]",
                             lo=0.1, hi=100.0)

    def __post_init__(self) -> None:
        validate(self)
        if not self.bag:
            raise ConfigError("PlayerConfig.bag: a bag directory is required")


class PlayerNode(Node):
    """Replays a bag; see the module docstring."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("bag_player", **kwargs)
        self.cfg = declare_config(self, PlayerConfig)
        self.reader = BagReader(resolve_path(self.cfg.bag))
        wanted = {self.resolve_topic_name(t) for t in self.cfg.topics}
        self.pubs = {}
        for topic, msgtype in self.reader.topics.items():
            if wanted and topic not in wanted:
                continue
            qos = self._replay_qos(topic)
            self.pubs[topic] = self.create_publisher(message_class(msgtype), topic, qos)
        self.clock_pub = (self.create_publisher(Clock, "/clock", 10)
                          if self.cfg.clock_rate > 0 else None)
        self._first: dict[str, bytes] = {}  # topic -> its first message (held while waiting)
        self._warm_up()
        self._chain_ready = threading.Event()
        self._waiter = (TopicWaiter(self, self.cfg.wait_for_topics, self.cfg.wait_timeout)
                        if self.cfg.wait_for_topics else None)
        if self._waiter is not None:  # probes are made in the executor's thread
            self._wait_timer = self.create_timer(0.05, self._poll_waiter)
        self.done: Future = Future()
        self.published = 0
        self._stop = threading.Event()
        self._bag_now_ns: int | None = None
        self._t0: tuple[float, int] | None = None  # (wall monotonic [s], bag time [ns])
        if self.clock_pub is not None:
            self.create_timer(1.0 / self.cfg.clock_rate, self._publish_clock)
        # The playback thread shares the GIL with the executor; a short switch interval
        # (default 5 ms) keeps it from waiting behind the executor at a message's due time.
        sys.setswitchinterval(min(sys.getswitchinterval(), 0.0005))
        self._thread = threading.Thread(target=self._run, name="bag_player", daemon=True)
        self._thread.start()
        self.get_logger().info(
            f"playing {self.cfg.bag}: {self.reader.message_count} messages on "
            f"{len(self.pubs)} topics, {self.reader.duration_s:.2f} s at rate {self.cfg.rate}")

    def _replay_qos(self, topic: str) -> QoSProfile:
        """Reliable, with the recorded durability (see the module docstring)."""
        from rosbags.interfaces import QosDurability

        offered = self.reader.qos(topic)
        if not offered:
            self.get_logger().info(f"{topic}: no QoS recorded in the bag; playing it reliable, "
                                   f"volatile")
            latched = False
        else:
            latched = all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offered)
        if latched:
            depth = max(1, max(int(q.depth) for q in offered))
            return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
        return QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

    def _warm_up(self) -> None:
        """Check the first message of every topic before playing.

        The first deserialisation of a type generates its decoder (tens of ms); doing it here
        keeps that out of the timed playback, and a bag whose first records are corrupt is
        refused before anything is published.
        """
        pending = set(self.pubs)
        for msg in self.reader.messages():
            if msg.topic in pending:
                self.reader.check(msg)
                self._first[msg.topic] = msg.data
                pending.discard(msg.topic)
                if not pending:
                    break

    def _wait_subscribers(self) -> None:
        deadline = time.monotonic() + self.cfg.wait_timeout
        while not self._stop.is_set() and time.monotonic() < deadline:
            if all(p.get_subscription_count() > 0 for p in self.pubs.values()):
                return
            self._stop.wait(0.02)
        missing = [t for t, p in self.pubs.items() if p.get_subscription_count() == 0]
        if missing:
            self.get_logger().warning(f"starting without subscribers on {missing}")

    def _poll_waiter(self) -> None:
        if self._waiter.poll():
            self._wait_timer.cancel()
            self._chain_ready.set()
            self.get_logger().info(
                f"a message has arrived on every awaited topic: playing in "
                f"{self.cfg.start_delay:g} s")

    def _hold_first(self) -> None:
        """Publish the first messages until the awaited topics answered (or a stop)."""
        self.get_logger().info(f"holding the first messages until messages arrive on "
                               f"{list(self.cfg.wait_for_topics)}")
        while not self._stop.is_set() and not self._chain_ready.is_set():
            for topic, data in self._first.items():
                self.pubs[topic].publish(data)
            self._chain_ready.wait(1.0 / self.cfg.hold_rate)

    def _sleep_until(self, wall: float) -> bool:
        """Wait until monotonic time ``wall`` [s]; False if asked to stop."""
        while True:
            remaining = wall - time.monotonic()
            if self._stop.is_set():
                return False
            if remaining <= 0:
                return True
            if remaining > _SPIN_WAIT:
                self._stop.wait(remaining - _SPIN_WAIT)

    def _play_once(self) -> None:
        start_ns = self.reader.start_ns + int(self.cfg.start * 1e9)
        t0: tuple[float, int] | None = None
        for msg in self.reader.messages(start_ns=start_ns if self.cfg.start > 0 else None):
            pub = self.pubs.get(msg.topic)
            if pub is None:
                continue
            if t0 is None:
                t0 = (time.monotonic(), msg.timestamp_ns)
                self._t0 = t0
            target = t0[0] + (msg.timestamp_ns - t0[1]) * 1e-9 / self.cfg.rate
            if not self._sleep_until(target):
                return
            self.reader.check(msg)  # raises BagError on a corrupt payload: never published
            pub.publish(msg.data)
            self.published += 1

    def _run(self) -> None:
        code = 0
        try:
            if self.cfg.wait_for_subscribers:
                self._wait_subscribers()
            if self._waiter is not None:
                self._hold_first()
            if self.cfg.start_delay > 0:
                self._stop.wait(self.cfg.start_delay)
            while not self._stop.is_set():
                self._play_once()
                if not self.cfg.loop:
                    break
        except BagError as e:
            self.get_logger().error(str(e))
            code = 1
        for pub in self.pubs.values():  # let reliable subscribers receive the last messages
            pub.wait_for_all_acked(Duration(seconds=2.0))
        self.get_logger().info(f"published {self.published} messages")
        if not self.done.done():
            self.done.set_result(code)

    def _publish_clock(self) -> None:
        if self._t0 is None:
            return
        wall0, bag0 = self._t0
        now_ns = bag0 + int((time.monotonic() - wall0) * self.cfg.rate * 1e9)
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(now_ns, 1_000_000_000)
        self.clock_pub.publish(msg)

    def on_shutdown(self) -> None:
        """Stop the playback thread and close the bag."""
        self._stop.set()
        self._chain_ready.set()
        self._thread.join(timeout=2.0)
        self.reader.close()


def main(args: list[str] | None = None) -> int:
    """Entry point of the bag_player console script."""
    return run_node(PlayerNode, args)


if __name__ == "__main__":
    sys.exit(main())
