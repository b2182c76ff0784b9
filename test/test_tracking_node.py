"""tracker node, in-process rclpy: stamps kept, outputs published, bad input rejected."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from hand_msgs.msg import HandPose
from hand_msgs.msg import HandShape as HandShapeMsg
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message, serialize_message
from ros_helpers import spin_nodes
from sensor_msgs.msg import CameraInfo, Image, JointState
from visualization_msgs.msg import MarkerArray

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.model import ARTICULATED_JOINTS, rest_pose
from hand_capture.nodes.images import camera_info_msg, depth_image_msg, numpy_to_image
from hand_capture.nodes.tracker import TrackerNode


@pytest.fixture(scope="module")
def frame():
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="static"))
    cam.open()
    return cam.render(0.0)


def test_tracker_node_publishes_pose_with_the_image_stamp(rclpy_up, frame, tmp_path):
    node = TrackerNode(parameter_overrides=[Parameter("markers_every", value=1),
                                            Parameter("shape_folder", value=str(tmp_path))])
    io = rclpy.create_node("tracker_test_io")
    got: dict[str, list] = {"pose": [], "joints": [], "markers": [], "debug": []}
    io.create_subscription(HandPose, "hand/pose", got["pose"].append, 10)
    io.create_subscription(JointState, "hand/joint_states", got["joints"].append, 10)
    io.create_subscription(MarkerArray, "hand/markers", got["markers"].append, 10)
    io.create_subscription(Image, "hand/debug_image", got["debug"].append,
                           qos_profile_sensor_data)
    pub_img = io.create_publisher(Image, "camera/depth/image_raw", qos_profile_sensor_data)
    pub_info = io.create_publisher(CameraInfo, "camera/depth/camera_info",
                                   qos_profile_sensor_data)
    intr = frame.depth_intrinsics
    stamps = [Time(sec=1000 + k, nanosec=123456789) for k in range(3)]
    sent = 0
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline and len(got["pose"]) < 2:
        if sent < len(stamps) and (sent == 0 or len(got["pose"]) >= sent):
            pub_info.publish(camera_info_msg(intr, stamps[sent]))
            spin_nodes([node, io], 0.05, lambda: False)
            pub_img.publish(depth_image_msg(frame.depth, stamps[sent], intr.frame_id))
            sent += 1
        spin_nodes([node, io], 0.2, lambda n=sent: len(got["pose"]) >= n)
    spin_nodes([node, io], 1.0, lambda: got["debug"] and got["markers"])
    assert got["pose"], "no hand/pose published"
    msg = got["pose"][0]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) in \
        [(s.sec, s.nanosec) for s in stamps]
    assert msg.header.frame_id == intr.frame_id
    assert list(msg.joint_names) == list(ARTICULATED_JOINTS)
    assert len(msg.positions) == len(ARTICULATED_JOINTS)
    assert msg.status in (HandPose.STATUS_TRACKING, HandPose.STATUS_RECOVERING,
                          HandPose.STATUS_LOST, HandPose.STATUS_UNKNOWN)
    assert 0.0 <= msg.confidence <= 1.0
    assert msg.source == "tracker"
    assert math.isfinite(msg.wrist_pose.position.z) and msg.wrist_pose.position.z > 0.1
    assert got["joints"] and list(got["joints"][0].name) == list(ARTICULATED_JOINTS)
    assert got["joints"][0].header.stamp == msg.header.stamp
    assert got["markers"]
    types = sorted(m.type for m in got["markers"][0].markers)
    assert types == sorted([5, 11])  # LINE_LIST, TRIANGLE_LIST
    assert got["debug"] and got["debug"][0].encoding == "rgb8"
    io.destroy_node()
    node.destroy_node()


def test_serialized_markers_equal_the_message_objects(rclpy_up) -> None:
    """The fast hand/markers path (bytes patched into a serialised template) deserialises to
    exactly the markers the plain path builds, for two poses, stamps and statuses."""
    node = TrackerNode()
    rng = np.random.default_rng(0)
    for k, status in enumerate(("tracking", "lost")):
        pose = rest_pose().copy()
        pose[6:] += rng.normal(0.0, 0.2, 21)
        stamp = Time(sec=1700 + k, nanosec=999 * k)
        fast = deserialize_message(node._markers_bytes(pose, stamp, "cam", status), MarkerArray)
        plain = node._markers(pose, stamp, "cam", status)  # as a subscriber receives it:
        assert fast == deserialize_message(serialize_message(plain), MarkerArray)  # float32
    assert len(fast.markers[0].points) == 3 * len(node.tracker.model.faces)
    node.destroy_node()


def test_tracker_node_rejects_bad_input_without_crashing(rclpy_up, frame):
    node = TrackerNode()
    intr = frame.depth_intrinsics
    img = depth_image_msg(frame.depth, Time(sec=5), intr.frame_id)
    # no camera info yet
    assert node.process(img) is None and node.rejected["no_camera_info"] == 1
    # NaN intrinsics
    info = camera_info_msg(intr)
    k = list(info.k)
    k[0] = float("nan")
    info.k = k
    node._on_info(info)
    assert node.process(img) is None and node.rejected["bad_camera_info"] == 1
    node._on_info(camera_info_msg(intr))
    # wrong encoding
    rgb = numpy_to_image(np.zeros((intr.height, intr.width, 3), np.uint8), "rgb8")
    assert node.process(rgb) is None and node.rejected["bad_encoding"] == 1
    # empty image
    assert node.process(Image(encoding="16UC1")) is None and node.rejected["empty_image"] == 1
    # size that does not match the camera info
    small = depth_image_msg(np.zeros((10, 12), np.uint16))
    assert node.process(small) is None and node.rejected["bad_image"] == 1
    # truncated data
    bad = depth_image_msg(frame.depth)
    bad.data = bad.data[:100]
    assert node.process(bad) is None and node.rejected["bad_image"] == 2
    # a bad shape message is refused, a good one is used
    sm = HandShapeMsg(global_scale=float("nan"))
    node._on_shape(sm)
    assert node.rejected["bad_shape"] == 1
    # the same rejections per topic through the node's InputGate (logged, on diagnostics)
    assert node.gate.rejected == {"camera/depth/image_raw": 4, "hand/shape": 1,
                                  "camera/depth/camera_info": 1}
    sm = HandShapeMsg(global_scale=1.05, alpha=[0.0] * 6, beta=[0.0] * 5, subject_id="x")
    node._on_shape(sm)
    assert node.tracker.model.shape.global_scale == pytest.approx(1.05)
    # and a good frame still goes through
    assert node.process(img) is not None and node.processed == 1
    node._diagnostics()
    node.destroy_node()


def test_tracker_node_drops_frames_when_busy(rclpy_up, frame):
    node = TrackerNode(parameter_overrides=[Parameter("poll_period_s", value=0.002)])
    node._on_info(camera_info_msg(frame.depth_intrinsics))
    for k in range(4):
        node._on_image(depth_image_msg(frame.depth, Time(sec=k)))
    assert node.dropped == 3
    node._process_latest()
    assert node.processed == 1 and node._pending is None
    assert node.last_result is not None
    node.destroy_node()


def test_tracker_node_in_callback_mode_tracks_and_counts_replaced_frames(rclpy_up, frame):
    node = TrackerNode()  # poll_period_s 0: each image is tracked in its callback
    for _ in range(4):  # four frames went by while the tracker was busy ...
        node._on_info(camera_info_msg(frame.depth_intrinsics))
    node._on_image(depth_image_msg(frame.depth, Time(sec=3)))  # ... only the newest is kept
    assert node.processed == 1 and node.last_result is not None
    assert node.dropped == 3
    node.destroy_node()


def test_tracker_node_calibrates_saves_and_reloads_the_shape(rclpy_up, frame, tmp_path):
    params = [Parameter("calibrate_on_start", value=True),
              Parameter("calibration_frames", value=2),
              Parameter("subject_id", value="alice"),
              Parameter("shape_folder", value=str(tmp_path))]
    node = TrackerNode(parameter_overrides=params)
    node._on_info(camera_info_msg(frame.depth_intrinsics))
    for k in range(2):
        assert node.process(depth_image_msg(frame.depth, Time(sec=k))) is not None
    assert (tmp_path / "alice.yaml").exists()
    assert node.shape_msg is not None and node.shape_msg.subject_id == "alice"
    assert len(node.shape_msg.alpha) == 6 and node.shape_msg.residual > 0
    scale = node.tracker.model.shape.global_scale
    node.destroy_node()
    again = TrackerNode(parameter_overrides=[Parameter("subject_id", value="alice"),
                                             Parameter("shape_folder", value=str(tmp_path))])
    assert again.tracker.model.shape.global_scale == pytest.approx(scale)
    again.destroy_node()
