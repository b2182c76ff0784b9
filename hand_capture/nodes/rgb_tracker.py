"""rgb_tracker: colour images -> hand pose and 21 hand keypoints (hand_capture.rgbtrack).

Subscribes ``camera/color/image_raw`` (``rgb8`` or ``bgr8``) with ``camera/color/camera_info``
(SensorDataQoS), optionally ``camera/depth/image_raw`` (depth aligned to the colour image,
``16UC1`` mm or ``32FC1`` m; used when its stamp is within ``depth_max_age_s`` of the colour
image's) and ``hand/shape`` (the subject's calibrated hand shape: the scale that fixes the
hand's distance in a colour image).

Publishes, stamped with the colour image's time:

* ``hand/pose`` (hand_msgs/HandPose): the fitted pose, status TRACKING / RECOVERING (first
  frame after a loss) / LOST (no hand, or the fit does not explain the keypoints: positions
  then hold the last good pose, never marked as tracking; before the first good frame
  nothing is published here), confidence from the fit residual and the detector's score;
* ``hand/keypoints`` (hand_msgs/HandKeypoints): the detected pixels and the fitted 3-D
  keypoints (common 21 order); a LOST frame carries no 3-D points;
* ``diagnostics``: rates, frames dropped while busy, lost frames by reason, rejected inputs
  (per topic, through :class:`~hand_capture.nodes.gate.InputGate`), stage times.

Frames are never queued: the image subscription keeps one message (depth 1) and is
processed in its callback, so frames that arrive while the tracker is busy replace each other
and are counted as dropped. Parameters: :class:`RgbTrackerNodeConfig`,
:class:`~hand_capture.rgbtrack.tracker.RgbTrackerConfig`, ``detector.*``
(:class:`~hand_capture.rgbtrack.detector.DetectorConfig`) and ``fit.*``
(:class:`~hand_capture.rgbtrack.fit.FitConfig`).
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point
from hand_msgs.msg import HandKeypoints, HandPose
from hand_msgs.msg import HandShape as HandShapeMsg
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.config import param, validate
from hand_capture.errors import HandSuiteError
from hand_capture.model import HandShape
from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.images import image_to_array
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.qos import newest_sensor_qos
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import fill_keypoints_msg, fill_pose_msg
from hand_capture.rgbtrack import (
    DetectorConfig,
    FitConfig,
    RgbTracker,
    RgbTrackerConfig,
    RgbTrackResult,
)
from hand_capture.validate import validate_camera_info, validate_image_size

_IMAGE = "camera/color/image_raw"
_INFO = "camera/color/camera_info"
_DEPTH = "camera/depth/image_raw"


@dataclass(frozen=True)
class RgbTrackerNodeConfig:
    """Node-only parameters of rgb_tracker."""

    use_depth_topic: bool = param(True, "subscribe camera/depth/image_raw (aligned to the "
                                  "colour image) and use it when it is recent",
                                  read_only=True)
    depth_max_age_s: float = param(0.05, "largest stamp difference between a colour image "
                                   "and the depth image used with it [s]", lo=0.0, hi=10.0)
    blas_threads: int = param(1, "BLAS threads of the process", lo=1, hi=256)
    source_name: str = param("rgb_tracker", "the source field of the published messages")

    def __post_init__(self) -> None:
        validate(self)


def _stamp_s(stamp: object) -> float:
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


class RgbTrackerNode(Node):
    """Colour-camera hand tracker (module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("rgb_tracker", **kwargs)
        self.node_cfg = declare_config(self, RgbTrackerNodeConfig)
        limit_blas_threads(self.node_cfg.blas_threads)
        self.cfg = declare_config(self, RgbTrackerConfig)
        det_cfg = declare_config(self, DetectorConfig, prefix="detector.")
        fit_cfg = declare_config(self, FitConfig, prefix="fit.")
        self.tracker = RgbTracker(self.cfg, fit_config=fit_cfg, detector_config=det_cfg)
        self.gate = InputGate(self)
        sensor = qos_profile_sensor_data
        self.create_subscription(Image, _IMAGE, self._on_image, newest_sensor_qos())
        self.create_subscription(CameraInfo, _INFO, self._on_info, sensor)
        if self.node_cfg.use_depth_topic:
            self.create_subscription(Image, _DEPTH, self._on_depth, newest_sensor_qos())
        self.create_subscription(HandShapeMsg, "hand/shape", self._on_shape, 10)
        self.pub_pose = self.create_publisher(HandPose, "hand/pose", 10)
        self.pub_kp = self.create_publisher(HandKeypoints, "hand/keypoints", 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self._info: CameraInfo | None = None
        self._depth: Image | None = None
        self._last_good: np.ndarray | None = None
        self.processed = 0
        self.dropped = 0
        self._infos = self._images = 0
        self.status_count: Counter[str] = Counter()
        self.stage_s: Counter[str] = Counter()
        self.proc_s = 0.0
        self.last_result: RgbTrackResult | None = None
        self._diag_n, self._diag_t = 0, time.monotonic()
        self.create_timer(1.0, self._diagnostics)
        self.get_logger().info(f"rgb_tracker ready: {self.cfg.side} hand, detector "
                               f"{'lite' if det_cfg.model_complexity == 0 else 'full'}")

    # ------------------------------------------------------------------------- inputs
    def _on_info(self, msg: CameraInfo) -> None:
        self._info = msg
        self._infos += 1

    def _on_depth(self, msg: Image) -> None:
        self._depth = msg

    def _on_shape(self, msg: HandShapeMsg) -> None:
        try:
            shape = HandShape.from_msg_fields(msg.global_scale, list(msg.alpha),
                                              list(msg.beta), msg.subject_id)
        except HandSuiteError as e:
            self.gate.reject("hand/shape", e)
            return
        if np.allclose(shape.params, self.tracker.model.shape.params):
            return
        self.tracker.set_shape(shape)
        self.get_logger().info(f"tracking with the shape of {msg.subject_id!r} "
                               f"(s_g {shape.global_scale:.3f})")

    def _on_image(self, msg: Image) -> None:
        # one camera_info comes with every frame: the difference is what the depth-1
        # subscription replaced while the tracker was busy
        self._images += 1
        self.dropped = max(0, self._infos - self._images)
        self.process(msg)

    def _depth_for(self, msg: Image, intr: object) -> np.ndarray | None:
        d = self._depth
        if d is None:
            return None
        if abs(_stamp_s(d.header.stamp) - _stamp_s(msg.header.stamp)) > \
                self.node_cfg.depth_max_age_s:
            return None
        if (d.width, d.height) != (intr.width, intr.height) or d.encoding not in (
                "16UC1", "32FC1", "mono16"):
            self.gate.reject(_DEPTH, f"depth {d.width}x{d.height} {d.encoding!r} is not "
                             f"aligned to the colour image {intr.width}x{intr.height} "
                             "(16UC1 [mm] or 32FC1 [m])")
            self._depth = None
            return None
        try:
            a = image_to_array(d)
        except HandSuiteError as e:
            self.gate.reject(_DEPTH, e)
            self._depth = None
            return None
        return a.astype(np.float32) * 1e-3 if a.dtype == np.uint16 else \
            np.nan_to_num(a.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)

    # ----------------------------------------------------------------------- processing
    def process(self, msg: Image) -> RgbTrackResult | None:
        """Track one colour image message and publish (None when it is rejected)."""
        size = self.gate.check(_IMAGE, validate_image_size, msg.width, msg.height,
                               msg.encoding, len(msg.data))
        if size is None:
            return None
        if self._info is None:
            self.status_count["no_camera_info"] += 1  # a start-up race, not bad input
            return None
        intr = self.gate.check(_INFO, validate_camera_info, self._info, msg.width, msg.height)
        if intr is None:
            return None
        try:
            img = image_to_array(msg)
            if msg.encoding == "bgr8":
                img = img[:, :, ::-1]
            depth = self._depth_for(msg, intr)
            t0 = time.perf_counter()
            res = self.tracker.process(img, intr, stamp_s=_stamp_s(msg.header.stamp),
                                       depth_m=depth)
        except HandSuiteError as e:
            self.gate.reject(_IMAGE, e)
            return None
        self.proc_s += time.perf_counter() - t0
        for k, v in res.timing.items():
            self.stage_s[k] += v
        self.processed += 1
        self.status_count[res.status] += 1
        if res.reason:
            self.status_count[f"lost_{res.reason}"] += 1
        self.last_result = res
        self._publish(msg, res, intr)
        return res

    def _publish(self, img: Image, res: RgbTrackResult, intr: object) -> None:
        stamp = img.header.stamp
        frame_id = img.header.frame_id or intr.frame_id
        name = self.node_cfg.source_name
        if res.good:
            self._last_good = res.pose.copy()
            status, pose, conf = res.status, res.pose, res.confidence
        elif self._last_good is not None:
            status, pose, conf = "lost", self._last_good, 0.0
        else:
            status, pose, conf = "lost", None, 0.0   # no pose to hold yet: none is sent
        if pose is not None:
            msg = HandPose()
            msg.header.stamp = stamp
            msg.header.frame_id = frame_id
            fill_pose_msg(msg, pose, side=self.cfg.side, status=status, confidence=conf,
                          source=name)
            self.pub_pose.publish(msg)
        kp = HandKeypoints()
        kp.header.stamp = stamp
        kp.header.frame_id = frame_id
        det = res.detection
        score = float(det.score) if det is not None else 0.0
        fill_keypoints_msg(
            kp, res.keypoints if res.good else None,
            det.pixels if det is not None else None,
            np.full(21, score) if det is not None else None, point_type=Point,
            side=self.cfg.side, status="lost" if not res.good else res.status,
            confidence=res.confidence if res.good else 0.0, source=name)
        self.pub_kp.publish(kp)

    # ---------------------------------------------------------------------- diagnostics
    def _diagnostics(self) -> None:
        now = time.monotonic()
        rate = (self.processed - self._diag_n) / max(now - self._diag_t, 1e-9)
        self._diag_n, self._diag_t = self.processed, now
        n = max(self.processed, 1)
        good = self.status_count["tracking"] + self.status_count["recovering"]
        level, text = DiagnosticStatus.OK, f"{rate:.1f} Hz"
        if self.processed and good == 0:
            level, text = DiagnosticStatus.WARN, "no hand tracked yet"
        st = DiagnosticStatus(level=level, name="rgb_tracker", message=text,
                              hardware_id="rgb_tracker")
        vals = {"rate_hz": f"{rate:.2f}", "processed": str(self.processed),
                "dropped_busy": str(self.dropped),
                "proc_ms_mean": f"{1e3 * self.proc_s / n:.2f}",
                "last_rms_px": (f"{self.last_result.fit.rms_px:.2f}"
                                if self.last_result and self.last_result.fit else ""),
                "shape_global_scale": f"{self.tracker.model.shape.global_scale:.4f}"}
        vals.update({f"status_{k}": str(v) for k, v in self.status_count.items()})
        vals.update({f"tracker_{k}": str(v) for k, v in self.tracker.counts.items()})
        vals.update({f"{k}_ms_mean": f"{1e3 * v / n:.2f}" for k, v in self.stage_s.items()})
        vals.update(self.gate.values())
        st.values = [KeyValue(key=k, value=v) for k, v in vals.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)

    def on_shutdown(self) -> None:
        self.tracker.detector.close()


def main(args: list[str] | None = None) -> int:
    """Entry point of the rgb_tracker console script."""
    return run_node(RgbTrackerNode, args)


if __name__ == "__main__":
    sys.exit(main())
