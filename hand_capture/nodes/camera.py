"""camera: a real depth/colour camera -> camera/depth/* and camera/color/* (realsense-ros names).

``driver`` selects the source: ``realsense`` (Intel RealSense through the optional
``pyrealsense2``; aligned depth ``16UC1`` [mm] + colour ``rgb8``, parameters under
``realsense.*``) or ``opencv`` (a UVC colour camera or video through ``cv2.VideoCapture``,
parameters under ``opencv.*``). Frames are published, with their CameraInfo, as they arrive
from the device (SensorDataQoS, stamped with the node clock at arrival):

* ``camera/depth/image_raw``, ``camera/depth/camera_info`` (RealSense with depth enabled);
* ``camera/color/image_raw``, ``camera/color/camera_info``.

A capture thread (:class:`~hand_capture.cameras.supervisor.CameraSupervisor`) reads the
device; an unplugged or missing camera is logged, counted and reopened with backoff while the
node keeps running (``require_device: true`` makes a device missing at start-up fatal). A
missing ``pyrealsense2`` stops the node with the ``pip install pyrealsense2`` hint. Status,
counters and device facts go to ``diagnostics`` once a second.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image

from hand_capture.cameras.base import Frame, FrameSource
from hand_capture.cameras.opencv import OpenCVConfig, OpenCVSource
from hand_capture.cameras.realsense import RealSenseConfig, RealSenseSource
from hand_capture.cameras.supervisor import CameraSupervisor
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, DeviceError
from hand_capture.nodes.images import camera_info_msg, depth_image_msg, rgb_image_msg
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node


@dataclass(frozen=True)
class CameraNodeConfig:
    """Parameters of the camera node (the driver's own are under realsense.* / opencv.*)."""

    driver: str = param("realsense", "camera driver", choices=("realsense", "opencv"),
                        read_only=True)
    require_device: bool = param(
        False, "fail at start-up when the device is missing (else keep retrying)",
        read_only=True)
    retry_s: float = param(0.5, "first delay before reopening a lost camera [s]", lo=0.01,
                           hi=60.0)
    max_retry_s: float = param(5.0, "longest delay between reopen attempts [s]", lo=0.01,
                               hi=600.0)
    read_timeout_s: float = param(1.0, "timeout of one frame read [s]", lo=0.01, hi=60.0)
    stale_after_s: float = param(2.0, "no frame for this long = WARN on diagnostics [s]",
                                 lo=0.1, hi=600.0)

    def __post_init__(self) -> None:
        validate(self)
        if self.max_retry_s < self.retry_s:
            raise ConfigError(f"CameraNodeConfig.max_retry_s ({self.max_retry_s}) must be >= "
                              f"retry_s ({self.retry_s})")


class CameraNode(Node):
    """Publishes a real camera's images (module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("camera", **kwargs)
        self.cfg = declare_config(self, CameraNodeConfig)
        self.source: FrameSource
        if self.cfg.driver == "realsense":
            self.source = RealSenseSource(declare_config(self, RealSenseConfig,
                                                         prefix="realsense."))
        else:
            self.source = OpenCVSource(declare_config(self, OpenCVConfig, prefix="opencv."))
        sensor = qos_profile_sensor_data
        self.pub_depth = self.create_publisher(Image, "camera/depth/image_raw", sensor)
        self.pub_depth_info = self.create_publisher(CameraInfo, "camera/depth/camera_info",
                                                    sensor)
        self.pub_color = self.create_publisher(Image, "camera/color/image_raw", sensor)
        self.pub_color_info = self.create_publisher(CameraInfo, "camera/color/camera_info",
                                                    sensor)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.supervisor = CameraSupervisor(
            self.source, retry_s=self.cfg.retry_s, max_retry_s=self.cfg.max_retry_s,
            read_timeout_s=self.cfg.read_timeout_s, log=self._log)
        self.published = 0
        self._diag_count = 0
        self._diag_t = time.monotonic()
        # First attempt in the constructor: a missing driver (or, with require_device, a
        # missing device) stops the node here with the clear message.
        opened = self.supervisor.try_open()
        if not opened and self.cfg.require_device:
            raise self._startup_error()
        self.supervisor.start(self._publish)
        self.create_timer(1.0, self._diagnostics)

    def _startup_error(self) -> Exception:
        return DeviceError(self.supervisor.stats.last_error or "camera not found")

    def _log(self, level: str, message: str) -> None:
        # one call site per severity: rclpy refuses a severity change at one call site
        log = self.get_logger()
        if level == "error":
            log.error(message)
        elif level == "warn":
            log.warning(message)
        else:
            log.info(message)

    def _publish(self, frame: Frame) -> None:
        """Called from the capture thread for every frame."""
        stamp = self.get_clock().now().to_msg()
        if frame.depth is not None and frame.depth_intrinsics is not None:
            fid = frame.depth_intrinsics.frame_id
            self.pub_depth.publish(depth_image_msg(frame.depth, stamp, fid))
            self.pub_depth_info.publish(camera_info_msg(frame.depth_intrinsics, stamp))
        if frame.color is not None and frame.color_intrinsics is not None:
            fid = frame.color_intrinsics.frame_id
            self.pub_color.publish(rgb_image_msg(frame.color, stamp, fid))
            self.pub_color_info.publish(camera_info_msg(frame.color_intrinsics, stamp))
        self.published += 1

    def _diagnostics(self) -> None:
        s = self.supervisor.stats
        now = time.monotonic()
        rate = (self.published - self._diag_count) / max(now - self._diag_t, 1e-9)
        self._diag_count, self._diag_t = self.published, now
        if not s.connected:
            level, msg = DiagnosticStatus.ERROR, f"disconnected: {s.last_error}"
        elif s.last_frame_time is None or now - s.last_frame_time > self.cfg.stale_after_s:
            level, msg = DiagnosticStatus.WARN, "connected but no frames"
        else:
            level, msg = DiagnosticStatus.OK, f"{rate:.1f} Hz"
        st = DiagnosticStatus(level=level, name=f"camera ({self.cfg.driver})", message=msg,
                              hardware_id=self.source.describe().get("serial",
                                                                     self.cfg.driver))
        st.values = [KeyValue(key=k, value=str(v)) for k, v in self.source.describe().items()]
        st.values += [KeyValue(key=k, value=str(v)) for k, v in asdict(s).items()
                      if k != "last_frame_time"]
        st.values += [KeyValue(key="published", value=str(self.published)),
                      KeyValue(key="rate_hz", value=f"{rate:.2f}"),
                      KeyValue(key="nominal_fps", value=f"{self.source.nominal_fps:g}")]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)

    def on_shutdown(self) -> None:
        self.supervisor.stop()


def main(args: list[str] | None = None) -> int:
    """Entry point of the camera console script."""
    return run_node(CameraNode, args)


if __name__ == "__main__":
    sys.exit(main())
