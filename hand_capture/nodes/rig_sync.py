"""rig_sync: groups the images of a multi-camera rig by stamp and republishes each group.

Thin wrapper around :class:`hand_capture.multiview.sync.FrameSynchronizer`, reading the cameras
from a rig file (:mod:`hand_capture.multiview.rig`).

Topics (``CAM`` = each camera name of the rig, ``STREAM`` = the ``stream`` parameter):
    in   CAM/STREAM/image_raw (sensor_msgs/Image), each camera on its own clock
    out  sync/CAM/STREAM/image_raw: every member of a group, all with the group's common stamp
    out  sync/CAM/STREAM/camera_info (sensor_msgs/CameraInfo): the rig file's calibration, with
         the same stamp
    out  rig/markers (visualization_msgs/MarkerArray, latched): each camera's viewing pyramid
         and name in the rig's world frame, so RViz shows the rig
    out  diagnostics (1 Hz): groups, incomplete groups, dropped, late and overflowing frames,
         worst skew; WARN naming the missing cameras while the rig runs degraded, ERROR when
         fewer than ``min_cameras`` are alive
A timer checks for cameras that stopped, so a dead camera is noticed without new frames.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import CameraInfo, Image
from visualization_msgs.msg import Marker, MarkerArray

from hand_capture.config import param, validate
from hand_capture.errors import HandSuiteError
from hand_capture.multiview.rig import RigCamera, load_rig
from hand_capture.multiview.sync import FrameGroup, FrameSynchronizer, SyncConfig
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node


@dataclass(frozen=True)
class RigSyncNodeConfig:
    """Node parameters besides the synchroniser's (:class:`SyncConfig`)."""

    rig: str = param("studio6", "rig name (config/rigs/NAME.yaml) or path of a rig file",
                     read_only=True)
    stream: str = param("color", "image stream of every camera: CAM/<stream>/image_raw",
                        read_only=True)
    poll_period_s: float = param(0.05, "how often a stopped camera is looked for [s]",
                                 lo=0.005, hi=5.0)

    def __post_init__(self) -> None:
        validate(self)


def _stamp_s(msg: Image) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


class RigSyncNode(Node):
    """Publishes synchronised groups of the rig's images; see the module docstring."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("rig_sync", **kwargs)
        self.cfg = declare_config(self, RigSyncNodeConfig)
        sync_cfg = declare_config(self, SyncConfig)
        self.rig = load_rig(self.cfg.rig)
        self.sync = FrameSynchronizer(self.rig.names, sync_cfg)
        self.rejected = 0
        self._pub_img, self._pub_info = {}, {}
        s = self.cfg.stream
        for cam in self.rig.cameras:
            self._pub_img[cam.name] = self.create_publisher(
                Image, f"sync/{cam.name}/{s}/image_raw", qos_profile_sensor_data)
            self._pub_info[cam.name] = self.create_publisher(
                CameraInfo, f"sync/{cam.name}/{s}/camera_info", qos_profile_sensor_data)
            self.create_subscription(Image, f"{cam.name}/{s}/image_raw",
                                     lambda m, c=cam.name: self._on_image(c, m),
                                     qos_profile_sensor_data)
        self._infos = {c.name: self._info_msg(c) for c in self.rig.cameras}
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_markers = self.create_publisher(MarkerArray, "rig/markers", latched)
        self.pub_markers.publish(self._rig_markers())
        self.create_timer(self.cfg.poll_period_s, self._poll)
        self.create_timer(1.0, self._diagnostics)
        self.get_logger().info(f"synchronising {len(self.rig)} cameras of rig "
                               f"{self.rig.name!r}: {list(self.rig.names)}, tolerance "
                               f"{sync_cfg.tolerance_s * 1e3:.1f} ms")

    @staticmethod
    def _info_msg(cam: RigCamera) -> CameraInfo:
        f = cam.camera_info()
        msg = CameraInfo(width=f["width"], height=f["height"],
                         distortion_model=f["distortion_model"], d=f["d"], k=f["k"], r=f["r"],
                         p=f["p"])
        msg.header.frame_id = f["frame_id"]
        return msg

    def _rig_markers(self) -> MarkerArray:
        """Each camera's viewing pyramid (LINE_LIST) and name (TEXT) in the world frame."""
        out = MarkerArray()
        for i, cam in enumerate(self.rig.cameras):
            lines = Marker(ns="rig_frusta", id=i, type=Marker.LINE_LIST, action=Marker.ADD)
            lines.header.frame_id = self.rig.world_frame
            lines.pose.orientation.w = 1.0
            lines.scale.x = 0.003
            lines.color.r, lines.color.g, lines.color.b, lines.color.a = 0.2, 0.8, 1.0, 1.0
            lines.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
                            for seg in cam.frustum_segments() for p in seg]
            text = Marker(ns="rig_names", id=i, type=Marker.TEXT_VIEW_FACING,
                          action=Marker.ADD, text=cam.name)
            text.header.frame_id = self.rig.world_frame
            text.pose.position.x, text.pose.position.y, text.pose.position.z = (
                float(v) for v in cam.t_wc + np.array([0.0, 0.0, 0.03]))
            text.pose.orientation.w = 1.0
            text.scale.z = 0.03
            text.color.r = text.color.g = text.color.b = text.color.a = 1.0
            out.markers += [lines, text]
        return out

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_image(self, camera: str, msg: Image) -> None:
        try:
            groups = self.sync.push(camera, _stamp_s(msg), msg, self._now())
        except HandSuiteError as e:
            self.rejected += 1
            self.get_logger().warning(f"rejected image: {e}", throttle_duration_sec=1.0)
            return
        self._publish(groups)

    def _poll(self) -> None:
        self._publish(self.sync.poll(self._now()))

    def _publish(self, groups: list[FrameGroup]) -> None:
        for g in groups:
            stamp = Time(nanoseconds=round(g.stamp * 1e9)).to_msg()
            for cam, (_, msg) in g.frames.items():
                msg.header.stamp = stamp
                self._pub_img[cam].publish(msg)
                info = self._infos[cam]
                info.header.stamp = stamp
                self._pub_info[cam].publish(info)

    def _diagnostics(self) -> None:
        st = self.sync.stats
        missing = self.sync.missing(self._now())
        alive = len(self.rig) - len(missing)
        if alive < self.sync.config.min_cameras:
            level, text = DiagnosticStatus.ERROR, f"only {alive} cameras alive; missing: "
        elif missing:
            level, text = DiagnosticStatus.WARN, "degraded; missing: "
        else:
            level, text = DiagnosticStatus.OK, "all cameras"
        if missing:
            text += ", ".join(missing)
        status = DiagnosticStatus(level=level, name="rig_sync", message=text)
        values = {"groups": st.groups, "incomplete": st.incomplete, "dropped": st.dropped,
                  "late": st.late, "overflow": st.overflow, "rejected": self.rejected,
                  "max_skew_ms": round(st.max_skew_s * 1e3, 3),
                  **{f"received.{c}": n for c, n in st.received.items()}}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    """Entry point of the rig_sync console script."""
    return run_node(RigSyncNode, args)


if __name__ == "__main__":
    sys.exit(main())
