"""Delivery of full-size depth images between two processes (issue 13, transport).

A publisher process sends ``n`` 16UC1 images (640x480 by default) at ``rate_hz`` with the
camera nodes' QoS (SensorDataQoS); a subscriber process takes them with the tracker's image
QoS (:func:`hand_capture.nodes.tracker.depth_image_qos`) and counts the distinct frames
it takes. A frame it does not take was either lost in transport (it never reached the
reader: the rmw's message-lost event counts it) or overwritten in the reader's depth-1 queue
by the next one before the subscriber's process ran (a loaded CPU: by design, the tracker
wants the latest frame). Both processes get the environment the graph runner and the
launch files give nodes (:func:`hand_capture.dds.dds_environment`: the shipped Fast DDS
profile), or the bare environment for comparison.

Protocol: the publisher waits until it sees the subscriber, then sends warm-up frames until
the subscriber acknowledges one on a reliable topic (both ends matched), then the ``n``
measured frames (``frame_id`` ``m<i>``), then a reliable "done"; the subscriber waits for
"done" (and a short drain) and prints one JSON line.

Run as ``python -m hand_capture.bench._delivery {pub,sub} ...`` (the children); use
:func:`measure_delivery` from code.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

__all__ = ["measure_delivery"]

_TOPIC = "camera/depth/image_raw"


def measure_delivery(n: int = 90, rate_hz: float = 30.0, width: int = 640, height: int = 480,
                     *, profile: bool = True, timeout_s: float = 60.0) -> dict:
    """Share of ``n`` frames published at ``rate_hz`` that reach the tracker's subscription.

    Args:
        n: measured frames.
        rate_hz: publishing rate [Hz].
        width, height: image size [px] (16UC1).
        profile: True: the graphs' DDS environment (shipped Fast DDS profile); False: the
            environment as it is (Fast DDS defaults, unless the caller set a profile).
        timeout_s: overall limit [s].

    Returns:
        ``{"sent", "received", "delivery", "lost", "warmup_s", "bytes"}``: ``received`` the
        measured frames the subscription took, ``delivery`` their share (NaN when the two
        ends never matched), ``lost`` the samples the transport lost over the whole run,
        warm-up frames included (the message-lost event's total count).
    """
    from hand_capture.dds import dds_environment

    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if profile:
        env = dds_environment(env)
    else:
        for k in ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
            env.pop(k, None)
    tag = f"delivery_{os.getpid()}_{time.monotonic_ns() % 10 ** 9}"
    common = ["--tag", tag, "--n", str(n), "--rate", str(rate_hz), "--width", str(width),
              "--height", str(height), "--timeout", str(timeout_s)]
    cmd = [sys.executable, "-m", "hand_capture.bench._delivery"]
    sub = subprocess.Popen(cmd + ["sub"] + common, env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    pub = subprocess.Popen(cmd + ["pub"] + common, env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        out, err = sub.communicate(timeout=timeout_s + 15)
        pub.communicate(timeout=timeout_s + 15)
    finally:
        for p in (sub, pub):
            if p.poll() is None:
                p.kill()
                p.wait()
    lines = [ln for ln in out.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"delivery subscriber gave no result (rc {sub.returncode}): "
                           f"{err[-2000:]}")
    return json.loads(lines[-1])


def _ack_qos():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _pub(a: argparse.Namespace) -> int:
    import numpy as np
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node(f"{a.tag}_pub")
    pub = node.create_publisher(Image, f"{a.tag}/{_TOPIC}", qos_profile_sensor_data)
    done = node.create_publisher(String, f"{a.tag}/done", _ack_qos())
    acked = []
    node.create_subscription(String, f"{a.tag}/ack", lambda m: acked.append(m.data),
                             _ack_qos())
    msg = Image(height=a.height, width=a.width, encoding="16UC1", is_bigendian=0,
                step=2 * a.width)
    img = (np.arange(a.width * a.height, dtype=np.uint32) % 4000 + 300).astype(np.uint16)
    msg.data = img.tobytes()
    period = 1.0 / a.rate
    t_end = time.monotonic() + a.timeout
    while pub.get_subscription_count() < 1 and time.monotonic() < t_end:
        rclpy.spin_once(node, timeout_sec=0.05)
    i = 0
    nxt = time.monotonic()
    while not acked and time.monotonic() < t_end:  # warm-up until the subscriber has one
        msg.header.frame_id = f"w{i}"
        pub.publish(msg)
        i += 1
        nxt += period
        while time.monotonic() < nxt:
            rclpy.spin_once(node, timeout_sec=max(0.0, nxt - time.monotonic()))
    nxt = time.monotonic()
    for k in range(a.n if acked else 0):
        msg.header.frame_id = f"m{k}"
        msg.header.stamp = node.get_clock().now().to_msg()
        pub.publish(msg)
        nxt += period
        while time.monotonic() < nxt:
            rclpy.spin_once(node, timeout_sec=max(0.0, nxt - time.monotonic()))
    done.publish(String(data=str(a.n if acked else 0)))
    t_done = time.monotonic() + 5.0   # let the reliable "done" get out
    while done.get_subscription_count() and time.monotonic() < t_done:
        rclpy.spin_once(node, timeout_sec=0.05)
        if acked and acked[-1] == "bye":
            break
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def _sub(a: argparse.Namespace) -> int:
    import rclpy
    from rclpy.event_handler import SubscriptionEventCallbacks
    from sensor_msgs.msg import Image
    from std_msgs.msg import String

    from hand_capture.nodes.tracker import depth_image_qos

    rclpy.init()
    node = rclpy.create_node(f"{a.tag}_sub")
    ack = node.create_publisher(String, f"{a.tag}/ack", _ack_qos())
    got: set[str] = set()
    state = {"warm": None, "done": None, "t0": time.monotonic()}

    def on_image(m: Image) -> None:
        fid = m.header.frame_id
        if fid.startswith("w") and state["warm"] is None:
            state["warm"] = time.monotonic() - state["t0"]
            ack.publish(String(data="warm"))
        elif fid.startswith("m") and len(m.data) == 2 * a.width * a.height:
            got.add(fid)

    lost = {"n": 0}

    def on_lost(info) -> None:  # samples that never reached the reader (sequence gaps)
        lost["n"] = max(lost["n"], int(info.total_count))

    events = SubscriptionEventCallbacks(message_lost=on_lost)
    node.create_subscription(Image, f"{a.tag}/{_TOPIC}", on_image, depth_image_qos(),
                             event_callbacks=events)
    node.create_subscription(String, f"{a.tag}/done",
                             lambda m: state.update(done=(int(m.data), time.monotonic())),
                             _ack_qos())
    t_end = time.monotonic() + a.timeout
    while time.monotonic() < t_end:
        rclpy.spin_once(node, timeout_sec=0.05)
        d = state["done"]
        if d is not None and time.monotonic() - d[1] > 0.3:
            break
    ack.publish(String(data="bye"))
    sent = state["done"][0] if state["done"] is not None else 0
    t_ack = time.monotonic() + 1.0
    while time.monotonic() < t_ack and ack.get_subscription_count():
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps({"sent": sent, "received": len(got),
                      "delivery": len(got) / sent if sent else float("nan"), "lost": lost["n"],
                      "warmup_s": state["warm"], "bytes": 2 * a.width * a.height}),
          flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("role", choices=("pub", "sub"))
    ap.add_argument("--tag", required=True)
    ap.add_argument("--n", type=int, default=90)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--timeout", type=float, default=60.0)
    a = ap.parse_args(argv)
    return _pub(a) if a.role == "pub" else _sub(a)


if __name__ == "__main__":
    raise SystemExit(main())
