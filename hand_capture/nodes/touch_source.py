"""touch_source: a multi-touch surface (TUIO over UDP, or a Linux evdev device) -> touch/frame.

Polls its source from a timer and publishes every completed frame as ``hand_msgs/TouchFrame``
(SensorDataQoS), stamped with the node's clock when the frame was read. Parameters:
``source`` ('tuio' or 'evdev'), ``poll_period``, and the source's own under ``tuio.*``
(:class:`~hand_capture.touch.tuio.TuioConfig`) or ``evdev.*``
(:class:`~hand_capture.touch.evdev_mt.EvdevConfig`). A source that cannot be opened (no device,
port in use) is logged with the DeviceError naming it and reopened every ``retry_period``; with
``require_device`` it stops the node instead. Dropped data is counted on ``diagnostics``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hand_msgs.msg import TouchFrame as TouchFrameMsg
from hand_msgs.msg import TouchPoint
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from hand_capture.config import param, validate
from hand_capture.errors import DeviceError
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.touch.evdev_mt import EvdevConfig, EvdevTouchReader
from hand_capture.touch.frame import TouchFrame
from hand_capture.touch.tuio import TuioConfig, TuioReceiver


@dataclass(frozen=True)
class TouchSourceConfig:
    """Parameters of touch_source (the source's own are under tuio.* / evdev.*)."""

    source: str = param("tuio", "where touches come from", choices=("tuio", "evdev"),
                        read_only=True)
    poll_period: float = param(0.002, "period of the source poll [s]", lo=1e-4, hi=1.0)
    require_device: bool = param(False, "true: a source that cannot be opened stops the node; "
                                 "false: it is logged and reopened every retry_period",
                                 read_only=True)
    retry_period: float = param(1.0, "delay between attempts to reopen the source [s]",
                                lo=0.05, hi=60.0)

    def __post_init__(self) -> None:
        validate(self)


def frame_to_msg(frame: TouchFrame, msg: TouchFrameMsg | None = None) -> TouchFrameMsg:
    """A core TouchFrame as a hand_msgs/TouchFrame (header left to the caller)."""
    msg = msg or TouchFrameMsg()
    msg.header.frame_id = frame.frame_id
    msg.width, msg.height = frame.width, frame.height
    msg.points = [TouchPoint(session_id=int(i), x=float(p[0]), y=float(p[1]),
                             in_contact=bool(c))
                  for i, p, c in zip(frame.session_ids, frame.positions, frame.in_contact,
                                     strict=True)]
    return msg


class TouchSourceNode(Node):
    """Publishes touch/frame from a TUIO stream or an evdev device."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("touch_source", **kwargs)
        self.cfg = declare_config(self, TouchSourceConfig)
        if self.cfg.source == "tuio":
            self.src_cfg = declare_config(self, TuioConfig, prefix="tuio.")
        else:
            self.src_cfg = declare_config(self, EvdevConfig, prefix="evdev.")
        self.pub = self.create_publisher(TouchFrameMsg, "touch/frame", qos_profile_sensor_data)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.source: TuioReceiver | EvdevTouchReader | None = None
        self.published = 0
        self.errors = 0
        self._bad_seen = 0  # malformed TUIO datagrams already logged
        self.last_error = ""
        self._next_try = 0.0
        if not self._open() and self.cfg.require_device:
            raise DeviceError(self.last_error)
        self.create_timer(self.cfg.poll_period, self._poll)
        self.create_timer(1.0, self._diagnostics)

    def _open(self) -> bool:
        """Open the source; on failure log it, count it and schedule a retry."""
        try:
            if self.cfg.source == "tuio":
                self.source = TuioReceiver(self.src_cfg)
                host, port = self.source.address
                where = f"udp://{host}:{port}"
            else:
                self.source = EvdevTouchReader(self.src_cfg)
                where = self.source.path
        except DeviceError as e:
            self.source = None
            self.errors += 1
            self.last_error = str(e)
            self._next_try = time.monotonic() + self.cfg.retry_period
            self.get_logger().error(f"{e}; retrying every {self.cfg.retry_period} s",
                                    throttle_duration_sec=10.0)
            return False
        self.last_error = ""
        self._bad_seen = 0
        self.get_logger().info(f"touch source {self.cfg.source} on {where}")
        return True

    def _poll(self) -> None:
        if self.source is None:
            if time.monotonic() >= self._next_try:
                self._open()
            return
        try:
            frames = self.source.poll()
        except DeviceError as e:  # e.g. the device was unplugged: close and reopen later
            self.errors += 1
            self.last_error = str(e)
            self.get_logger().error(str(e))
            self.source.close()
            self.source = None
            self._next_try = time.monotonic() + self.cfg.retry_period
            return
        stats = getattr(self.source, "stats", None)
        if stats is not None and getattr(stats, "bad_datagrams", 0) > self._bad_seen:
            self._bad_seen = stats.bad_datagrams
            self.get_logger().warning(
                f"dropped malformed TUIO datagram(s) ({stats.bad_datagrams} so far), last: "
                f"{stats.last_bad_datagram}", throttle_duration_sec=5.0)
        for frame in frames:
            msg = frame_to_msg(frame)
            msg.header.stamp = self.get_clock().now().to_msg()
            self.pub.publish(msg)
            self.published += 1

    def _diagnostics(self) -> None:
        ok = self.source is not None
        st = DiagnosticStatus(level=DiagnosticStatus.OK if ok else DiagnosticStatus.ERROR,
                              name="touch_source",
                              message=f"{self.published} frames" if ok else self.last_error,
                              hardware_id=self.cfg.source)
        st.values = [KeyValue(key="published", value=str(self.published)),
                     KeyValue(key="errors", value=str(self.errors))]
        if ok:
            st.values += [KeyValue(key=k, value=str(v))
                          for k, v in asdict(self.source.parser.stats).items()
                          if isinstance(v, int)]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(arr)

    def on_shutdown(self) -> None:
        if self.source is not None:
            self.source.close()


def main(args: list[str] | None = None) -> int:
    """Entry point of the touch_source console script."""
    return run_node(TouchSourceNode, args)


if __name__ == "__main__":
    sys.exit(main())
