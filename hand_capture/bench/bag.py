"""``hand-suite bench bag``: record and replay throughput of 640x480 depth images.

Three measurements in one process over the same ROS 2 middleware (Fast DDS), reliable QoS:

* baseline: a plain rclpy publisher -> subscriber (no bag);
* record: the same publisher -> bag_recorder's node (raw subscription -> MCAP writer);
* replay: bag_player's node at maximum rate -> a plain subscriber.

Each figure is the message count over the time from the first publish to the last message
handled. ROS imports are local to :func:`run` so importing this module loads no rclpy.
"""

from __future__ import annotations

import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from hand_capture.bench import print_table

WIDTH, HEIGHT = 640, 480


def _depth_image(i: int):  # -> sensor_msgs.msg.Image
    from sensor_msgs.msg import Image

    depth = np.full((HEIGHT, WIDTH), 600 + i % 100, dtype=np.uint16)
    msg = Image(height=HEIGHT, width=WIDTH, encoding="16UC1", is_bigendian=0, step=WIDTH * 2)
    msg.data = depth.tobytes()
    msg.header.frame_id = "camera_depth_optical_frame"
    return msg


class _Counter:
    def __init__(self, n: int) -> None:
        self.n, self.count, self.t_last = n, 0, 0.0
        self.done = threading.Event()

    def __call__(self, _msg: object) -> None:
        self.count += 1
        self.t_last = time.perf_counter()
        if self.count >= self.n:
            self.done.set()


def _spin_in_thread(executor):  # -> threading.Thread
    t = threading.Thread(target=executor.spin, daemon=True)
    t.start()
    return t


def _publish_all(pub, msgs: list, wait_for, timeout: float = 120.0) -> float:
    """Publish every message; return the time of the first publish [perf_counter s]."""
    deadline = time.monotonic() + 10.0
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.3)  # reliable connection settles
    t0 = time.perf_counter()
    for m in msgs:
        pub.publish(m)
    wait_for(timeout)
    return t0


def run(quick: bool = False) -> dict:
    """Measure; returns the figures for the last-line JSON."""
    import rclpy
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from hand_capture.nodes.player import PlayerNode
    from hand_capture.nodes.recorder import RecorderNode

    n = 60 if quick else 300
    msgs = [_depth_image(i) for i in range(n)]
    mb = len(msgs[0].data) / 1e6
    qos = QoSProfile(depth=n, reliability=ReliabilityPolicy.RELIABLE)
    tmp = Path(tempfile.mkdtemp(prefix="bench_bag_"))
    rows, fig = [], {}
    rclpy.init()
    try:
        # 1. baseline: plain publisher -> subscriber
        ex = MultiThreadedExecutor(num_threads=2)
        pub_node = rclpy.create_node("bench_pub")
        sub_node = rclpy.create_node("bench_sub")
        pub = pub_node.create_publisher(Image, "bench/depth", qos)
        c = _Counter(n)
        sub_node.create_subscription(Image, "bench/depth", c, qos)
        ex.add_node(pub_node)
        ex.add_node(sub_node)
        _spin_in_thread(ex)
        t0 = _publish_all(pub, msgs, c.done.wait)
        base = c.count / max(c.t_last - t0, 1e-9)
        ex.remove_node(sub_node)
        sub_node.destroy_node()
        rows.append(("baseline pub->sub", c.count, base, base * mb))

        # 2. record: publisher -> recorder node (raw) -> MCAP
        bag = tmp / "rec"
        rec = RecorderNode(parameter_overrides=[
            Parameter("output", value=str(bag)), Parameter("topics", value=["/bench/depth"]),
            Parameter("queue_depth", value=n), Parameter("discovery_period", value=0.05)])
        ex.add_node(rec)
        done = threading.Event()

        def wait_written(timeout: float) -> None:
            deadline = time.monotonic() + timeout
            while rec.writer.count < n and time.monotonic() < deadline:
                time.sleep(0.001)
            done.set()

        t0 = _publish_all(pub, msgs, wait_written)
        t_rec = time.perf_counter() - t0
        recorded = rec.writer.count
        ex.remove_node(rec)
        rec.on_shutdown()
        rec.destroy_node()
        rec_rate = recorded / t_rec
        rows.append(("record (recorder node)", recorded, rec_rate, rec_rate * mb))

        # 3. replay: player node at maximum rate -> subscriber
        sub_node = rclpy.create_node("bench_sub2")
        c2 = _Counter(recorded)
        sub_node.create_subscription(Image, "bench/depth", c2, qos)
        ex.add_node(sub_node)
        t0 = time.perf_counter()
        player = PlayerNode(parameter_overrides=[
            Parameter("bag", value=str(bag)), Parameter("rate", value=1000.0),
            Parameter("wait_for_subscribers", value=True), Parameter("clock_rate", value=0.0)])
        ex.add_node(player)
        c2.done.wait(120.0)
        first = player._t0[0] if player._t0 else t0  # wall time of the first publish
        first_perf = time.perf_counter() - (time.monotonic() - first)
        rep_rate = c2.count / max(c2.t_last - first_perf, 1e-9)
        rows.append(("replay (player node)", c2.count, rep_rate, rep_rate * mb))
        player.on_shutdown()
        ex.shutdown()
        for nd in (player, sub_node, pub_node):
            nd.destroy_node()
    finally:
        rclpy.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    print_table(f"bag throughput, {n} depth images 640x480 16UC1 ({mb:.3f} MB each)",
                ["path", "messages", "msgs/s", "MB/s"], rows)
    fig = {
        "msgs_per_s": rec_rate, "mb_per_s": rec_rate * mb,
        "replay_msgs_per_s": rep_rate, "replay_mb_per_s": rep_rate * mb,
        "baseline_msgs_per_s": base, "record_vs_baseline": rec_rate / base,
        "replay_vs_baseline": rep_rate / base, "messages": n,
        "recorded": recorded, "replayed": c2.count,
    }
    return fig
