"""camera and synthetic_camera nodes, spun in-process with rclpy (behaviour checks, loose
timing bands only), plus the numpy <-> Image/CameraInfo conversions."""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from hand_msgs.msg import HandPose
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from ros_helpers import spin_nodes
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image

from hand_capture.cameras.base import DriverNotInstalledError, Intrinsics
from hand_capture.errors import DeviceError, InputError
from hand_capture.model.joints import ARTICULATED_JOINTS
from hand_capture.nodes.camera import CameraNode
from hand_capture.nodes.images import (
    camera_info_msg,
    depth_image_msg,
    image_to_array,
    intrinsics_from_msg,
    numpy_to_image,
    rgb_image_msg,
)
from hand_capture.nodes.synthetic_camera import SyntheticCameraNode

TOPICS = {"camera/depth/image_raw": Image, "camera/depth/camera_info": CameraInfo,
          "camera/color/image_raw": Image, "camera/color/camera_info": CameraInfo}


class _Listener:
    def __init__(self, topics=TOPICS, truth=True):
        self.node = rclpy.create_node("camera_test_listener")
        self.got: dict[str, list] = {t: [] for t in topics}
        for name, typ in topics.items():
            self.node.create_subscription(typ, name, lambda m, n=name: self.got[n].append(m),
                                          qos_profile_sensor_data)
        if truth:
            self.got["hand/pose_truth"] = []
            self.node.create_subscription(HandPose, "hand/pose_truth",
                                          self.got["hand/pose_truth"].append, 10)
        self.got["diagnostics"] = []
        self.node.create_subscription(DiagnosticArray, "diagnostics",
                                      self.got["diagnostics"].append, 10)


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def test_synthetic_camera_node_publishes_at_its_rate_with_consistent_info(rclpy_up):
    fps = 20.0
    cam = SyntheticCameraNode(parameter_overrides=[
        Parameter("fps", value=fps), Parameter("width", value=160),
        Parameter("height", value=120), Parameter("clip", value="fist"),
        Parameter("noise.flying_prob", value=0.5)])
    lis = _Listener()
    spin_nodes([cam, lis.node], 0.5)  # discovery
    for v in lis.got.values():
        v.clear()
    t0 = time.monotonic()
    spin_nodes([cam, lis.node], 1.5)
    dt = time.monotonic() - t0
    n = len(lis.got["camera/depth/image_raw"])
    # behaviour check of the timer configuration: a loose band, no tight timing assert
    assert 0.5 * fps * dt <= n <= 1.3 * fps * dt + 2, (n, dt)
    for topic in TOPICS:
        assert len(lis.got[topic]) >= 0.5 * fps * dt, topic
    depth = lis.got["camera/depth/image_raw"][-1]
    info = lis.got["camera/depth/camera_info"][-1]
    assert depth.encoding == "16UC1" and (depth.width, depth.height) == (160, 120)
    d = image_to_array(depth)
    assert d.dtype == np.uint16 and d.shape == (120, 160) and (d > 0).sum() > 200
    color = image_to_array(lis.got["camera/color/image_raw"][-1])
    assert color.shape == (120, 160, 3) and lis.got["camera/color/image_raw"][-1].encoding \
        == "rgb8"
    intr = intrinsics_from_msg(info)
    assert intr == cam.intr
    assert (info.width, info.height) == (160, 120)
    assert info.header.frame_id == depth.header.frame_id == "camera_depth_optical_frame"
    assert list(info.p) == [intr.fx, 0, intr.cx, 0, 0, intr.fy, intr.cy, 0, 0, 0, 1, 0]
    cinfo = lis.got["camera/color/camera_info"][-1]
    assert list(cinfo.k) == list(info.k)
    # the ground truth carries the image's stamp, the joint names and the wrist pose
    truth = lis.got["hand/pose_truth"]
    assert truth
    stamps = {_stamp(m) for m in lis.got["camera/depth/image_raw"]}
    assert sum(_stamp(t) in stamps for t in truth) >= len(truth) - 2
    m = truth[-1]
    assert m.status == HandPose.STATUS_GROUND_TRUTH and m.source == "synthetic_camera"
    assert list(m.joint_names) == list(ARTICULATED_JOINTS) and len(m.positions) == 21
    assert m.handedness == HandPose.HAND_RIGHT
    assert 0.3 < m.wrist_pose.position.z < 0.6
    q = m.wrist_pose.orientation
    assert q.x**2 + q.y**2 + q.z**2 + q.w**2 == pytest.approx(1.0)
    spin_nodes([cam, lis.node], 1.2, until=lambda: bool(lis.got["diagnostics"]))
    st = lis.got["diagnostics"][-1].status[0]
    assert st.name == "synthetic_camera"
    assert {kv.key for kv in st.values} >= {"published", "dropped", "rate_hz"}
    cam.destroy_node()
    lis.node.destroy_node()


def test_synthetic_camera_node_follows_sim_time(rclpy_up):
    cam = SyntheticCameraNode(parameter_overrides=[
        Parameter("use_sim_time", value=True), Parameter("fps", value=10.0),
        Parameter("width", value=80), Parameter("height", value=60)])
    lis = _Listener(topics={"camera/depth/image_raw": Image})
    clock_pub = lis.node.create_publisher(Clock, "/clock", 10)
    spin_nodes([cam, lis.node], 0.6)
    assert not lis.got["camera/depth/image_raw"]  # no /clock yet: time stands still
    sent = []
    for k in range(40):  # 2 s of sim time at 20 Hz
        t_ns = 100 * 10**9 + k * 50_000_000
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 10**9)
        clock_pub.publish(msg)
        sent.append(t_ns)
        spin_nodes([cam, lis.node], 0.03)
    spin_nodes([cam, lis.node], 0.3)
    stamps = [_stamp(m) for m in lis.got["camera/depth/image_raw"]]
    assert stamps, "no frames under sim time"
    assert all(min(sent) <= s <= max(sent) for s in stamps)  # stamped with the sim clock
    assert len(stamps) <= 2 * 10 + 3  # about 10 Hz of 2 s sim time, not wall time
    cam.destroy_node()
    lis.node.destroy_node()


def test_camera_node_missing_devices_give_clear_errors(rclpy_up, monkeypatch):
    with pytest.raises(DeviceError, match="index 57"):
        CameraNode(parameter_overrides=[Parameter("driver", value="opencv"),
                                        Parameter("opencv.device", value="57"),
                                        Parameter("require_device", value=True)])
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)
    with pytest.raises(DriverNotInstalledError, match="pip install pyrealsense2"):
        CameraNode(parameter_overrides=[Parameter("driver", value="realsense")])
    # without require_device the node keeps running, retries and reports the error
    node = CameraNode(parameter_overrides=[Parameter("driver", value="opencv"),
                                           Parameter("opencv.device", value="57"),
                                           Parameter("retry_s", value=0.05),
                                           Parameter("max_retry_s", value=0.1)])
    lis = _Listener(topics={}, truth=False)
    spin_nodes([node, lis.node], 2.5, until=lambda: bool(lis.got["diagnostics"]))
    node.on_shutdown()
    assert node.supervisor.stats.open_failures >= 2
    st = lis.got["diagnostics"][-1].status[0]
    assert st.level == DiagnosticStatus.ERROR and "index 57" in st.message
    node.destroy_node()
    lis.node.destroy_node()


def test_camera_node_streams_a_uvc_source_and_survives_its_end(rclpy_up, tmp_path):
    path = tmp_path / "cam.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    for k in range(10):
        w.write(np.full((48, 64, 3), 20 * k, np.uint8))
    w.release()
    node = CameraNode(parameter_overrides=[
        Parameter("driver", value="opencv"), Parameter("opencv.device", value=str(path)),
        Parameter("opencv.failures_to_disconnect", value=1),
        Parameter("retry_s", value=0.05), Parameter("max_retry_s", value=0.05)])
    lis = _Listener(topics={"camera/color/image_raw": Image,
                            "camera/color/camera_info": CameraInfo}, truth=False)
    spin_nodes([node, lis.node], 3.0,
          until=lambda: node.supervisor.stats.reconnects >= 1
          and len(lis.got["camera/color/image_raw"]) >= 5)
    node.on_shutdown()
    imgs = lis.got["camera/color/image_raw"]
    assert len(imgs) >= 5 and imgs[0].encoding == "rgb8" and imgs[0].width == 64
    assert lis.got["camera/color/camera_info"][0].header.frame_id == \
        "camera_color_optical_frame"
    # the end of the video is handled like an unplugged camera: reopened, node alive
    assert node.supervisor.stats.read_errors >= 1 and node.supervisor.stats.reconnects >= 1
    node.destroy_node()
    lis.node.destroy_node()


def test_image_and_camera_info_conversions_round_trip():
    d = (np.arange(12, dtype=np.uint16) * 1000).reshape(3, 4)
    m = depth_image_msg(d, frame_id="f")
    assert (m.step, m.encoding, m.is_bigendian) == (8, "16UC1", 0)
    assert np.array_equal(image_to_array(m), d)
    rgb = np.random.default_rng(0).integers(0, 255, (3, 4, 3), dtype=np.uint8)
    assert np.array_equal(image_to_array(rgb_image_msg(rgb)), rgb)
    # padded rows and big-endian data from other drivers
    m.step = 10
    m.data = bytes(b"".join(d[i].astype(">u2").tobytes() + b"\0\0" for i in range(3)))
    m.is_bigendian = 1
    assert np.array_equal(image_to_array(m), d)
    with pytest.raises(InputError, match="encoding"):
        numpy_to_image(d, "yuv422")
    with pytest.raises(InputError, match="16UC1"):
        depth_image_msg(d.astype(np.float32))
    m.data = bytes(5)
    with pytest.raises(InputError, match="do not hold"):
        image_to_array(m)
    intr = Intrinsics(640, 480, 600.0, 601.0, 320.5, 240.5, distortion=(0.1, 0, 0, 0, 0),
                      frame_id="cam")
    assert intrinsics_from_msg(camera_info_msg(intr)) == intr


def test_synthetic_camera_holds_the_motion_until_awaited_topics_carry_messages(rclpy_up):
    """wait_for_topics: a publisher alone (a node still setting up) does not start the
    motion; the first message on every awaited topic does, start_delay_s later, and the
    probes are dropped."""
    from std_msgs.msg import String

    cam = SyntheticCameraNode(parameter_overrides=[
        Parameter("fps", value=30.0), Parameter("width", value=80),
        Parameter("height", value=60), Parameter("clip", value="fist"),
        Parameter("render_color", value=False),
        Parameter("wait_for_topics", value=["probe/a", "probe/b"]),
        Parameter("start_delay_s", value=0.3)])
    peer = rclpy.create_node("camera_wait_peer")
    spin_nodes([cam, peer], 0.3)
    assert cam._start_ns is None  # no publishers yet
    pub_a = peer.create_publisher(String, "probe/a", 10)
    pub_b = peer.create_publisher(String, "probe/b", 10)
    spin_nodes([cam, peer], 0.5, until=lambda: len(cam._waiter.subs) == 2)
    assert set(cam._waiter.subs) == {"probe/a", "probe/b"}
    spin_nodes([cam, peer], 0.3)
    assert cam._start_ns is None  # publishers, but no message
    for _ in range(3):
        pub_a.publish(String(data="up"))
        spin_nodes([cam, peer], 0.1)
    assert cam._start_ns is None and cam._waiter.heard == {"probe/a"}  # b has said nothing
    pub_b.publish(String(data="up"))
    t_heard = time.monotonic()
    spin_nodes([cam, peer], 2.0, until=lambda: cam._start_ns is not None)
    assert cam._start_ns is not None
    assert time.monotonic() - t_heard >= 0.3  # start_delay_s after the last first message
    assert not cam._waiter.subs and cam.count_subscribers("probe/a") == 0
    cam.destroy_node()
    peer.destroy_node()
