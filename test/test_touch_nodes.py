"""End to end: a TUIO stream from another process over UDP (127.0.0.1) -> touch_source ->
touch/frame -> touch_encoder -> hand/pose, with the shipped model file."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from hand_msgs.msg import HandPose  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from hand_capture.model.joints import ARTICULATED_JOINTS  # noqa: E402
from hand_capture.nodes.touch_encoder import TouchEncoderNode  # noqa: E402
from hand_capture.nodes.touch_source import TouchSourceNode  # noqa: E402

# A right hand's thumb, index, middle and ring on an iPad-sized surface (normalised TUIO
# coordinates), sliding to the right; then a frame with a NaN cursor (dropped by the parser)
# and one with six cursors (rejected by the encoder).
SENDER = textwrap.dedent("""
    import socket, sys, time
    from hand_capture.touch.tuio import cursor_bundle
    port = int(sys.argv[1])
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    base = [(0.30, 0.62), (0.42, 0.36), (0.55, 0.31), (0.67, 0.37)]
    fseq = 0
    for f in range(40):
        fseq += 1
        cur = {10 + i: (x + 0.002 * f, y) for i, (x, y) in enumerate(base)}
        s.sendto(cursor_bundle(cur, fseq, "pytest@127.0.0.1"), ("127.0.0.1", port))
        time.sleep(0.01)
    fseq += 1
    s.sendto(cursor_bundle({30: (float("nan"), 0.5)}, fseq), ("127.0.0.1", port))
    fseq += 1
    six = {40 + i: (0.1 * (i + 1), 0.4) for i in range(6)}
    s.sendto(cursor_bundle(six, fseq), ("127.0.0.1", port))
    time.sleep(0.05)
    fseq += 1
    s.sendto(cursor_bundle({}, fseq), ("127.0.0.1", port))
""")


@pytest.fixture()
def context():
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    ctx.try_shutdown()


def test_tuio_stream_from_another_process_becomes_hand_poses(context):
    ns = f"/touch_test_{os.getpid()}"
    source = TouchSourceNode(context=context, namespace=ns, parameter_overrides=[
        Parameter("tuio.port", value=0), Parameter("tuio.frame_id", value="ipad")])
    encoder = TouchEncoderNode(context=context, namespace=ns)
    sink = Node("touch_sink", context=context, namespace=ns)
    poses: list[HandPose] = []
    sink.create_subscription(HandPose, "hand/pose", poses.append, 10)
    ex = SingleThreadedExecutor(context=context)
    for n in (source, encoder, sink):
        ex.add_node(n)
    port = source.source.address[1]
    try:
        t_end = time.monotonic() + 3.0  # let the nodes discover each other
        while time.monotonic() < t_end and not encoder.count_publishers(f"{ns}/touch/frame"):
            ex.spin_once(timeout_sec=0.05)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
        sender = subprocess.Popen([sys.executable, "-c", SENDER, str(port)], env=env)

        def finished() -> bool:
            return (sender.poll() is not None and bool(poses)
                    and poses[-1].status == HandPose.STATUS_LOST)

        t_end = time.monotonic() + 20.0
        while time.monotonic() < t_end and not finished():
            ex.spin_once(timeout_sec=0.02)
        assert sender.wait(timeout=10) == 0
    finally:
        ex.shutdown()
        for n in (source, encoder, sink):
            n.destroy_node()
        source.on_shutdown()

    assert len(poses) >= 30  # UDP on loopback and the ROS graph may drop a few, not most
    tracking = [p for p in poses if p.status == HandPose.STATUS_TRACKING]
    assert len(tracking) >= 30
    p = tracking[-1]
    assert p.source == "touch_encoder" and p.header.frame_id == "ipad"
    assert list(p.joint_names) == list(ARTICULATED_JOINTS)
    assert len(p.positions) == 21 and np.isfinite(p.positions).all()
    q = p.wrist_pose.orientation
    assert np.isclose(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2, 1.0)
    # the wrist is above the surface (its z axis points into it) and near the touches
    w = p.wrist_pose.position
    assert -0.15 < w.z < 0.0 and -0.05 < w.x < 0.25 and -0.05 < w.y < 0.25
    # the lifted-all frame keeps the last pose as STATUS_LOST
    assert poses[-1].status == HandPose.STATUS_LOST
    # the six-cursor frame was rejected and counted, the NaN cursor dropped by the parser
    assert encoder.rejected == 1
    assert source.source.stats.bad_coordinates == 1
    # labels were searched when the four contacts appeared, then kept
    assert encoder.relabels == 1


def test_missing_evdev_device_is_logged_and_retried_not_fatal(context):
    from hand_capture.errors import DeviceError

    params = [Parameter("source", value="evdev"),
              Parameter("evdev.device", value="/dev/input/no-such-touchscreen"),
              Parameter("retry_period", value=0.05)]
    node = TouchSourceNode(context=context, namespace=f"/touch_missing_{os.getpid()}",
                           parameter_overrides=params)
    try:
        assert node.source is None and "cannot open" in node.last_error
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(node)
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end and node.errors < 3:
            ex.spin_once(timeout_sec=0.02)
        ex.shutdown()
        assert node.errors >= 3  # reopened on the retry period, still alive
    finally:
        node.destroy_node()
    with pytest.raises(DeviceError, match="no-such-touchscreen"):
        TouchSourceNode(context=context, parameter_overrides=params + [
            Parameter("require_device", value=True)])


def test_parameter_file_builds_every_config():
    import yaml

    from hand_capture.config import from_mapping, load_node_params
    from hand_capture.nodes.touch_source import TouchSourceConfig
    from hand_capture.paths import config_dir
    from hand_capture.touch.encoder import TouchEncoderConfig
    from hand_capture.touch.evdev_mt import EvdevConfig
    from hand_capture.touch.tuio import TuioConfig

    path = config_dir() / "touch.yaml"
    assert load_node_params(TouchEncoderConfig, path, "touch_encoder").encoding == "quadratic"
    src = yaml.safe_load(path.read_text())["touch_source"]["ros__parameters"]
    assert load_node_params(TouchSourceConfig, path, "touch_source").source == src["source"]
    assert from_mapping(TuioConfig, src["tuio"]).port == 3333
    from_mapping(EvdevConfig, src["evdev"])
