"""synthetic_camera: renders the hand model as an RGB-D camera -> camera/* and hand/pose_truth.

A timer at ``fps`` (on the node clock, so ``use_sim_time`` is honoured) renders the motion at
the time elapsed since the first tick and publishes, all with the same stamp:

* ``camera/depth/image_raw`` (``16UC1``, mm) and ``camera/depth/camera_info``;
* ``camera/color/image_raw`` (``rgb8``) and ``camera/color/camera_info`` (same pinhole);
* ``hand/pose_truth`` (hand_msgs/HandPose, ``STATUS_GROUND_TRUTH``): the articulated joints
  by name and the wrist pose (root DoF) in the camera optical frame;
* optionally ``camera/hand_mask/image_raw`` (``mono8``, 255 = hand) with ``publish_mask``.

Images use SensorDataQoS; the ground truth is reliable (benchmarks must not lose it).
Parameters: :class:`~hand_capture.cameras.synthetic.SyntheticCameraConfig` (resolution,
intrinsics, fps, clip / pose_file, shape_seed, noise_seed, ...) and the noise model under
``noise.*`` (:class:`~hand_capture.cameras.noise.DepthNoiseConfig`). Dropped frames
(``noise.frame_drop_prob``) publish nothing and are counted on ``diagnostics``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hand_msgs.msg import HandPose
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.task import Future
from sensor_msgs.msg import CameraInfo, Image

from hand_capture.cameras.noise import DepthNoiseConfig
from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.cameras.threads import limit_blas_threads, reuse_freed_memory
from hand_capture.config import param, validate
from hand_capture.nodes.awaiting import TopicWaiter
from hand_capture.nodes.images import (
    camera_info_msg,
    depth_image_msg,
    numpy_to_image,
    rgb_image_msg,
)
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import fill_pose_msg


@dataclass(frozen=True)
class SyntheticNodeConfig:
    """Node-only parameters of synthetic_camera."""

    publish_mask: bool = param(False, "also publish camera/hand_mask/image_raw (mono8)")
    blas_threads: int = param(1, "BLAS threads of the process (1 avoids oversubscription)",
                              lo=1, hi=256)
    wait_for_topics: tuple[str, ...] = param(
        (), "hold the motion's first pose (publishing it) until a message has arrived on each "
        "of these topics, i.e. the graph's other nodes are up and running; then start the "
        "motion")
    wait_timeout_s: float = param(60.0, "start the motion anyway after waiting this long [s]",
                                  lo=0.0)
    start_delay_s: float = param(
        0.0, "with wait_for_topics: hold the first pose this much longer once every awaited "
        "topic has a message, so that the graph's late subscriptions (a recorder's) have "
        "settled when the motion starts [s]", lo=0.0, hi=60.0)
    end_after_s: float = param(
        -1.0, "with loop false: end the node this long after the motion's last pose [s] (a "
        "graph whose camera is required then stops, e.g. the README's main job); "
        "negative = keep publishing the last pose", lo=-1.0)

    def __post_init__(self) -> None:
        validate(self)


class SyntheticCameraNode(Node):
    """Publishes rendered depth/colour images and the true hand pose (module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("synthetic_camera", **kwargs)
        self.node_cfg = declare_config(self, SyntheticNodeConfig)
        limit_blas_threads(self.node_cfg.blas_threads)
        reuse_freed_memory()  # the frame's image-sized buffers, every frame
        self.cfg = declare_config(self, SyntheticCameraConfig)
        self.noise_cfg = declare_config(self, DepthNoiseConfig, prefix="noise.")
        self.camera = SyntheticCamera(self.cfg, self.noise_cfg)
        self.camera.open()
        self.intr = self.camera.intrinsics
        sensor = qos_profile_sensor_data
        self.pub_depth = self.create_publisher(Image, "camera/depth/image_raw", sensor)
        self.pub_depth_info = self.create_publisher(CameraInfo, "camera/depth/camera_info",
                                                    sensor)
        self.pub_color = self.create_publisher(Image, "camera/color/image_raw", sensor) \
            if self.cfg.render_color else None
        self.pub_color_info = self.create_publisher(
            CameraInfo, "camera/color/camera_info", sensor) if self.cfg.render_color else None
        self.pub_mask = self.create_publisher(Image, "camera/hand_mask/image_raw", sensor) \
            if self.node_cfg.publish_mask else None
        self.pub_truth = self.create_publisher(HandPose, "hand/pose_truth", 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self._info = camera_info_msg(self.intr)  # reused: only the stamp changes
        self._start_ns: int | None = None
        self._waiter = TopicWaiter(self, self.node_cfg.wait_for_topics,
                                   self.node_cfg.wait_timeout_s)
        self._wait_logged: list[str] = []
        self._ready_t: float | None = None  # time.monotonic() when all of them had one [s]
        self._wait_log_t = -1e9
        self.done: Future = Future()
        self._end_t = (self.camera.motion.duration + self.node_cfg.end_after_s
                       if not self.cfg.loop and self.node_cfg.end_after_s >= 0 else None)
        self.published = 0
        self.render_s = 0.0
        self._diag_count = 0
        self._diag_t = time.monotonic()
        self.create_timer(1.0 / self.cfg.fps, self._tick)
        self.create_timer(1.0, self._diagnostics)
        d = self.camera.describe()
        self.get_logger().info(
            f"synthetic camera {d['resolution']} @ {d['fps']} Hz, motion {d['motion']}, "
            f"{d['side']} hand, shape seed {d['shape_seed']}, noise "
            f"{'on' if self.noise_cfg.enabled else 'off'}")

    def _waiting(self) -> bool:
        """Whether the motion still waits for ``wait_for_topics`` (logs what it waits for):
        until a message has arrived on each (:class:`~hand_capture.nodes.awaiting.TopicWaiter`),
        then ``start_delay_s`` more."""
        if not self.node_cfg.wait_for_topics:
            return False
        now = time.monotonic()
        if self._ready_t is None:
            if not self._waiter.poll():
                # throttled here: rclpy's own throttling inspects the caller's stack (about
                # 1 ms) on every call, i.e. on every tick while the graph starts
                missing = self._waiter.missing()
                if missing != self._wait_logged or now - self._wait_log_t >= 5.0:
                    self._wait_logged, self._wait_log_t = missing, now
                    self.get_logger().info(f"holding the first pose until messages arrive on "
                                           f"{missing}")
                return True
            self._ready_t = now
            self.get_logger().info(
                f"a message has arrived on every awaited topic: motion starts in "
                f"{self.node_cfg.start_delay_s:g} s")
        return now - self._ready_t < self.node_cfg.start_delay_s

    def _tick(self) -> None:
        now = self.get_clock().now()
        if self._start_ns is None and self._waiting():
            self._publish(self.camera.frame_at(0.0, stamp_s=now.nanoseconds * 1e-9), now)
            return
        if self._start_ns is None:
            self._start_ns = now.nanoseconds
        t = (now.nanoseconds - self._start_ns) * 1e-9
        if self._end_t is not None and t * self.cfg.speed > self._end_t:
            if not self.done.done():
                self.get_logger().info(f"end of the motion ({self.published} frames)")
                self.done.set_result(0)
            return
        t0 = time.perf_counter()
        frame = self.camera.frame_at(t, stamp_s=now.nanoseconds * 1e-9)
        self.render_s += time.perf_counter() - t0
        self._publish(frame, now)

    def _publish(self, frame, now) -> None:
        if frame is None:  # dropped by the noise model
            return
        stamp = now.to_msg()
        fid = self.intr.frame_id
        self.pub_depth.publish(depth_image_msg(frame.depth, stamp, fid))
        self._info.header.stamp = stamp
        self.pub_depth_info.publish(self._info)
        if self.pub_color is not None and frame.color is not None:
            self.pub_color.publish(rgb_image_msg(frame.color, stamp, fid))
            self.pub_color_info.publish(self._info)
        if self.pub_mask is not None:
            mask = (frame.silhouette.astype(np.uint8) * 255)
            self.pub_mask.publish(numpy_to_image(mask, "mono8", stamp, fid))
        truth = fill_pose_msg(HandPose(), frame.pose, side=self.cfg.side,
                              status="ground_truth", source="synthetic_camera")
        truth.header.frame_id = fid
        truth.header.stamp = stamp
        self.pub_truth.publish(truth)
        self.published += 1

    def _diagnostics(self) -> None:
        now = time.monotonic()
        rate = (self.published - self._diag_count) / max(now - self._diag_t, 1e-9)
        self._diag_count, self._diag_t = self.published, now
        ticks = self.published + self.camera.dropped_frames
        mean_ms = 1e3 * self.render_s / ticks if ticks else 0.0
        level = DiagnosticStatus.OK
        msg = f"{rate:.1f} Hz"
        if mean_ms > 1e3 / self.cfg.fps:
            level, msg = DiagnosticStatus.WARN, f"rendering ({mean_ms:.1f} ms) slower than fps"
        st = DiagnosticStatus(level=level, name="synthetic_camera", message=msg,
                              hardware_id="synthetic")
        st.values = [KeyValue(key=k, value=v) for k, v in self.camera.describe().items()]
        st.values += [KeyValue(key="published", value=str(self.published)),
                      KeyValue(key="dropped", value=str(self.camera.dropped_frames)),
                      KeyValue(key="rate_hz", value=f"{rate:.2f}"),
                      KeyValue(key="render_ms_mean", value=f"{mean_ms:.2f}")]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)

    def on_shutdown(self) -> None:
        self.camera.close()


def main(args: list[str] | None = None) -> int:
    """Entry point of the synthetic_camera console script."""
    return run_node(SyntheticCameraNode, args)


if __name__ == "__main__":
    sys.exit(main())
