"""The webcam teleop graph runs end to end on the shipped sample video as its camera:
camera (OpenCV, video file) -> rgb_tracker -> retarget (LEAP Hand model, from hand/keypoints)
-> servo bridge (emulated bus), started as a user does (``hand-suite run webcam_teleop``); a
probe node listens."""

from __future__ import annotations

import signal
import time

import numpy as np
import rclpy
from hand_msgs.msg import HandKeypoints, HandPose, JointCommand
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from ros_helpers import hand_suite

from hand_capture.cameras import OpenCVConfig, OpenCVSource
from hand_capture.rgbtrack import RgbTracker
from hand_capture.rgbtrack.sample_video import SAMPLE_VIDEO


def test_mediapipe_tracks_the_shipped_sample_video() -> None:
    src = OpenCVSource(OpenCVConfig(device=SAMPLE_VIDEO, hfov_deg=60.0, realtime=False))
    src.open()
    tracker = RgbTracker()
    good = n = 0
    try:
        for k in range(200):
            f = src.read()
            if f is None:
                break
            if k % 3:
                continue       # every third frame: the tracker's warm start still holds
            r = tracker.process(f.color, f.color_intrinsics, stamp_s=k / 15.0)
            n += 1
            good += r.good
    finally:
        src.close()
        tracker.detector.close()
    assert n >= 50
    assert good >= 0.9 * n, (good, n)


def test_webcam_teleop_graph_drives_the_servos_from_the_video() -> None:
    """The tracked hand reaches the bus: servo goals carry the stamps of the colour
    tracker's hand/keypoints (through the retargeting), and they move (the sample pinches)."""
    graph = hand_suite("run", "webcam_teleop")
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    poses: list[HandPose] = []
    kps: list[HandKeypoints] = []
    goals: list[JointCommand] = []
    try:
        node = rclpy.create_node("webcam_probe", context=ctx)
        node.create_subscription(HandPose, "/hand/pose", poses.append, 50)
        node.create_subscription(HandKeypoints, "/hand/keypoints", kps.append, 50)
        node.create_subscription(JointCommand, "/servo/goal", goals.append,
                                 qos_profile_sensor_data)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)

        def enough() -> bool:
            tracked = {(k.header.stamp.sec, k.header.stamp.nanosec) for k in kps
                       if k.status in (HandPose.STATUS_TRACKING, HandPose.STATUS_RECOVERING)}
            from_tracker = [g for g in goals
                            if (g.header.stamp.sec, g.header.stamp.nanosec) in tracked]
            if len(from_tracker) < 20:
                return False
            pos = np.array([g.positions for g in from_tracker])
            return float(np.ptp(pos, axis=0).max()) > 0.05

        t_end = time.monotonic() + 150.0
        while time.monotonic() < t_end and not enough() and graph.poll() is None:
            ex.spin_once(timeout_sec=0.05)
        ok = enough()
        ex.shutdown()
        node.destroy_node()
    finally:
        ctx.try_shutdown()
        graph.send_signal(signal.SIGINT)
        out, _ = graph.communicate(timeout=60)
    assert graph.returncode == 0, out[-4000:]
    assert ok, (len(kps), len(goals), [k.status for k in kps[-10:]], out[-3000:])
    assert any(p.source == "rgb_tracker" for p in poses)
    assert any(len(k.points) == 21 and len(k.pixels) == 42 for k in kps)
