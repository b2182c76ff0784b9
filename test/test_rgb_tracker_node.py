"""rgb_tracker node, in-process rclpy: outputs with the image stamp, LOST without a hand,
bad input (NaN CameraInfo, empty image) counted and rejected without crashing."""

from __future__ import annotations

import math

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from hand_msgs.msg import HandKeypoints, HandPose
from hand_msgs.msg import HandShape as HandShapeMsg
from ros_helpers import spin_nodes

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.model import ARTICULATED_JOINTS, sample_shape
from hand_capture.nodes.images import camera_info_msg, depth_image_msg, rgb_image_msg
from hand_capture.nodes.rgb_tracker import RgbTrackerNode


@pytest.fixture(scope="module")
def frames():
    cam = SyntheticCamera(SyntheticCameraConfig(width=640, height=480, hfov_deg=60.0,
                                                clip="pinch"))
    cam.open()
    return [cam.render(t) for t in (1.0, 1.1, 1.2)]


def test_rgb_tracker_publishes_pose_and_keypoints_with_the_image_stamp(rclpy_up, frames):
    node = RgbTrackerNode()
    io = rclpy.create_node("rgb_tracker_test_io")
    poses: list[HandPose] = []
    kps: list[HandKeypoints] = []
    io.create_subscription(HandPose, "hand/pose", poses.append, 10)
    io.create_subscription(HandKeypoints, "hand/keypoints", kps.append, 10)
    intr = frames[0].color_intrinsics
    stamps = [Time(sec=2000, nanosec=5000 + 33_000_000 * k) for k in range(len(frames))]
    node._on_info(camera_info_msg(intr, stamps[0]))
    results = [node.process(rgb_image_msg(f.color, s, intr.frame_id))
               for f, s in zip(frames, stamps, strict=True)]
    spin_nodes([node, io], 10.0, lambda: len(poses) >= 3 and len(kps) >= 3)
    assert [r.status for r in results] == ["recovering", "tracking", "tracking"]
    assert len(poses) == 3 and len(kps) == 3
    for msg, kp, s, f in zip(poses, kps, stamps, frames, strict=True):
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (s.sec, s.nanosec)
        assert kp.header.stamp == msg.header.stamp
        assert msg.header.frame_id == intr.frame_id
        assert list(msg.joint_names) == list(ARTICULATED_JOINTS)
        assert msg.status in (HandPose.STATUS_TRACKING, HandPose.STATUS_RECOVERING)
        assert 0.0 < msg.confidence <= 1.0 and msg.source == "rgb_tracker"
        # the wrist where the renderer put it, within the detector's accuracy
        wp = msg.wrist_pose.position
        assert math.dist((wp.x, wp.y, wp.z), f.pose[:3]) < 0.06
        assert len(kp.points) == 21 and len(kp.pixels) == 42 and len(kp.scores) == 21
        assert kp.status == msg.status
    node.destroy_node()
    io.destroy_node()


def test_rgb_tracker_without_a_hand_is_lost_and_never_tracking(rclpy_up, frames):
    node = RgbTrackerNode()
    io = rclpy.create_node("rgb_tracker_test_io2")
    poses: list[HandPose] = []
    kps: list[HandKeypoints] = []
    io.create_subscription(HandPose, "hand/pose", poses.append, 10)
    io.create_subscription(HandKeypoints, "hand/keypoints", kps.append, 10)
    intr = frames[0].color_intrinsics
    node._on_info(camera_info_msg(intr, Time(sec=1)))
    empty = np.full((480, 640, 3), 50, np.uint8)
    node.process(rgb_image_msg(frames[0].color, Time(sec=1), intr.frame_id))
    for k in range(2, 4):
        res = node.process(rgb_image_msg(empty, Time(sec=k), intr.frame_id))
        assert res.status == "lost" and res.reason == "no_hand"
    spin_nodes([node, io], 10.0, lambda: len(poses) >= 3 and len(kps) >= 3)
    assert [p.status for p in poses] == [HandPose.STATUS_RECOVERING, HandPose.STATUS_LOST,
                                         HandPose.STATUS_LOST]
    # a lost frame holds the last good pose, with zero confidence, and no 3-D keypoints
    assert poses[1].positions == poses[0].positions and poses[1].confidence == 0.0
    assert [k.status for k in kps[1:]] == [HandPose.STATUS_LOST] * 2
    assert all(len(k.points) == 0 for k in kps[1:])
    assert node.status_count["lost_no_hand"] == 2
    assert node.tracker.counts["lost_no_hand"] == 2
    node.destroy_node()
    io.destroy_node()


def test_rgb_tracker_counts_bad_camera_info_and_empty_images(rclpy_up, frames):
    node = RgbTrackerNode()
    intr = frames[0].color_intrinsics
    img = rgb_image_msg(frames[0].color, Time(sec=3), intr.frame_id)
    assert node.process(img) is None and node.status_count["no_camera_info"] == 1
    info = camera_info_msg(intr, Time(sec=3))
    bad = list(info.k)
    bad[0] = float("nan")
    info.k = bad
    node._on_info(info)
    assert node.process(img) is None
    assert node.gate.rejected["camera/color/camera_info"] == 1
    assert "finite" in node.gate.last_reason["camera/color/camera_info"]
    node._on_info(camera_info_msg(intr, Time(sec=3)))
    empty = rgb_image_msg(frames[0].color, Time(sec=3), intr.frame_id)
    empty.width = empty.height = 0
    empty.data = []
    assert node.process(empty) is None
    mono = rgb_image_msg(frames[0].color, Time(sec=3), intr.frame_id)
    mono.encoding = "16UC1"
    assert node.process(mono) is None
    assert node.gate.rejected["camera/color/image_raw"] == 2
    wrong_size = camera_info_msg(frames[0].color_intrinsics.__class__.from_fov(320, 240, 60.0),
                                 Time(sec=3))
    node._on_info(wrong_size)
    assert node.process(img) is None
    assert node.gate.rejected["camera/color/camera_info"] == 2
    assert node.processed == 0            # nothing reached the tracker
    node._on_info(camera_info_msg(intr, Time(sec=3)))
    assert node.process(img) is not None  # and the node still works
    node.destroy_node()


def test_rgb_tracker_uses_aligned_depth_and_the_calibrated_shape(rclpy_up, frames):
    """A depth image with the colour image's stamp joins the fit (wrong-size hand: the
    depth keeps the wrist at its distance); one with another stamp is not used; a
    hand/shape message replaces the model's shape."""
    node = RgbTrackerNode()
    intr = frames[0].color_intrinsics
    node._on_info(camera_info_msg(intr, Time(sec=7)))
    shape = sample_shape(3)
    msg = HandShapeMsg()
    for k, v in shape.to_msg_fields().items():
        setattr(msg, k, v)
    msg.global_scale = 1.15     # the hand in the images is the default one (scale 1)
    node._on_shape(msg)
    assert node.tracker.model.shape.global_scale == 1.15
    f = frames[0]
    node._on_depth(depth_image_msg(f.depth, Time(sec=7, nanosec=900_000_000)))
    stale = node.process(rgb_image_msg(f.color, Time(sec=7), intr.frame_id))
    assert stale.good and stale.fit.depth_used == 0
    node.tracker.reset()
    node._on_depth(depth_image_msg(f.depth, Time(sec=8)))
    fresh = node.process(rgb_image_msg(f.color, Time(sec=8), intr.frame_id))
    assert fresh.good and fresh.fit.depth_used >= 10
    # colour only, the larger model sits further away; the depth keeps it near the truth
    assert abs(fresh.pose[2] - f.pose[2]) < abs(stale.pose[2] - f.pose[2])
    assert abs(fresh.pose[2] - f.pose[2]) < 0.03
    bad = HandShapeMsg()
    bad.global_scale = float("nan")
    node._on_shape(bad)
    assert node.gate.rejected["hand/shape"] == 1
    node.destroy_node()


def test_rgb_tracker_keeps_only_the_newest_image(rclpy_up):
    """Frames are dropped, not queued, while the tracker is busy: the image subscriptions
    hold one message (SensorDataQoS otherwise: best effort)."""
    from rclpy.qos import ReliabilityPolicy

    node = RgbTrackerNode()
    subs = {s.topic_name.lstrip("/"): s.qos_profile for s in node.subscriptions}
    for topic in ("camera/color/image_raw", "camera/depth/image_raw"):
        assert subs[topic].depth == 1, topic
        assert subs[topic].reliability == ReliabilityPolicy.BEST_EFFORT
    node.destroy_node()
