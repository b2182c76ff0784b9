"""tracker: depth images -> hand pose (hybrid tracking, dissertation ch. II.5).

Subscribes ``camera/depth/image_raw`` (``16UC1`` mm, or ``32FC1`` m) and
``camera/depth/camera_info`` (SensorDataQoS), and ``hand/shape`` (a calibrated
hand_msgs/HandShape to track with). The same node runs on a live camera and on a replayed bag:
every output carries the stamp of the depth image it was computed from.

Publishes:

* ``hand/pose`` (hand_msgs/HandPose): ARTICULATED_JOINTS by name, wrist_pose, status
  (TRACKING / RECOVERING after a loss / LOST with the last good pose / UNKNOWN before the
  first estimate) and a confidence from the depth error of eq. II.19;
* ``hand/joint_states`` (sensor_msgs/JointState);
* ``hand/markers`` (visualization_msgs/MarkerArray): the skinned hand (TRIANGLE_LIST) and the
  skeleton (LINE_LIST), every ``markers_every`` frames;
* ``hand/debug_image`` (``rgb8``): the depth image, the segmented hand and the skeleton;
* ``hand/shape`` (latched) after an automatic calibration (``calibrate_on_start``), which is
  also saved under ``shape_folder`` as ``<subject_id>.yaml`` and loaded from there on the next
  start;
* ``diagnostics``: rates, dropped and rejected frames (by reason), stage times (wall clock)
  and the CPU time per frame, the share of frames that ran the regression (below 1 with
  ``regress_every`` > 1, the teleop graph's cheaper setting), the share of frames whose
  segment lost a background plane (a table or wall behind the hand, ``plane_removal``).

Frames are never queued: the image callback keeps only the latest image and a short timer
processes it, so a slow frame drops the ones that arrived meanwhile (counted). Parameters:
:class:`TrackerNodeConfig` and :class:`~hand_capture.tracking.config.TrackerConfig` (every
weight and threshold of the tracker).
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import dataclass

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point
from hand_msgs.msg import HandPose
from hand_msgs.msg import HandShape as HandShapeMsg
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sensor_msgs.msg import CameraInfo, Image, JointState
from visualization_msgs.msg import Marker, MarkerArray

from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.config import param, validate
from hand_capture.errors import HandSuiteError
from hand_capture.model import ARTICULATED_JOINTS, JOINT_INDEX, HandModel, HandShape
from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.images import image_to_array, intrinsics_from_msg, rgb_image_msg
from hand_capture.nodes.markers import SerializedMarkers
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.qos import newest_sensor_qos
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import fill_pose_msg
from hand_capture.tracking.calibration import (
    CALIBRATION_POSES,
    calibrate,
    load_shape,
    save_shape,
    shape_path,
)
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import (
    HybridTracker,
    TrackResult,
    load_regressor,
    model_path,
    regressor_files,
)

_ART_IDX = np.array([JOINT_INDEX[j] for j in ARTICULATED_JOINTS])
_IMAGE = "camera/depth/image_raw"
#: skeleton segments between keypoints (KEYPOINT_NAMES indices)
_BONES = [(0, 1), (0, 5), (0, 9), (0, 13), (0, 17), (5, 9), (9, 13), (13, 17)] + [
    (b + k, b + k + 1) for b in (1, 5, 9, 13, 17) for k in range(3)]


def depth_image_qos() -> QoSProfile:
    """QoS of the tracker's depth-image subscription.

    Depth 1, keep-last: the executor takes one queued message per subscription per cycle,
    so a deeper queue would hand the tracker stale frames after every slow frame.
    """
    return newest_sensor_qos()


@dataclass(frozen=True)
class TrackerNodeConfig:
    """Node-only parameters of the tracker."""

    subject_id: str = param("", "subject whose calibrated shape is loaded / saved")
    shape_folder: str = param("~/.hand_suite/shapes", "folder of the per-subject shapes")
    calibrate_on_start: bool = param(False, "fit the subject's shape from the first frames "
                                     "(hand held flat towards the camera)")
    calibration_frames: int = param(3, "frames used by the automatic calibration", lo=1,
                                    hi=30)
    markers_every: int = param(3, "publish hand/markers every n-th frame (0 = never)", lo=0)
    debug_image_every: int = param(1, "publish hand/debug_image every n-th frame (0 = never)",
                                   lo=0)
    poll_period_s: float = param(
        0.0, "period of a timer that processes the latest image [s]; 0 = process each image "
        "in its callback (the subscription keeps one, the newest, while the tracker is busy; "
        "no wake-ups without a frame)", lo=0.0, hi=1.0)
    blas_threads: int = param(1, "BLAS threads of the process", lo=1, hi=256)

    def __post_init__(self) -> None:
        validate(self)


class TrackerNode(Node):
    """Hybrid depth hand tracker (module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("tracker", **kwargs)
        self.node_cfg = declare_config(self, TrackerNodeConfig)
        limit_blas_threads(self.node_cfg.blas_threads)
        self.cfg = declare_config(self, TrackerConfig)
        log = self.get_logger()
        regressor = load_regressor(self.cfg)
        if regressor is not None:
            log.info("regressor: " + " + ".join(str(p) for p in regressor_files(self.cfg)))
        elif self.cfg.mode != "icp":
            log.warning(f"no regressor model at {model_path(self.cfg)}: tracking without "
                        f"regression (train one with `hand-suite train tracker`)")
        self.tracker = HybridTracker(HandModel(side=self.cfg.side), self.cfg, regressor)
        self.shape_msg: HandShapeMsg | None = None
        nc = self.node_cfg
        if nc.subject_id:
            try:
                if shape_path(nc.shape_folder, nc.subject_id).exists():
                    self._use_shape(load_shape(nc.shape_folder, nc.subject_id), float("nan"))
                    log.info(f"loaded the shape of subject {nc.subject_id!r}")
            except HandSuiteError as e:
                log.error(f"cannot load the shape of {nc.subject_id!r}: {e}")
        self._calib: list[tuple[np.ndarray, object]] | None = [] if nc.calibrate_on_start \
            else None

        sensor = qos_profile_sensor_data
        self.create_subscription(Image, "camera/depth/image_raw", self._on_image,
                                 depth_image_qos())
        self.create_subscription(CameraInfo, "camera/depth/camera_info", self._on_info, sensor)
        self.create_subscription(HandShapeMsg, "hand/shape", self._on_shape, 10)
        self.pub_pose = self.create_publisher(HandPose, "hand/pose", 10)
        self.pub_joints = self.create_publisher(JointState, "hand/joint_states", 10)
        self.pub_markers = self.create_publisher(MarkerArray, "hand/markers", 10)
        self.pub_debug = self.create_publisher(Image, "hand/debug_image", sensor)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub_shape = self.create_publisher(HandShapeMsg, "hand/shape", latched)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)

        self._pending: Image | None = None
        self._marker_tpl: SerializedMarkers | None = None
        self._marker_key: tuple[str, int, int] | None = None
        self._info: CameraInfo | None = None
        self.processed = 0
        self.dropped = 0
        self.rejected: Counter[str] = Counter()
        self.gate = InputGate(self)  # rejections per topic, logged (diagnostics)
        self.status_count: Counter[str] = Counter()
        self.proc_s = 0.0
        self.cpu_s = 0.0
        self.regressed = 0
        self.background_plane = 0   # frames whose segment lost a background plane
        self.stage_s: Counter[str] = Counter()
        self.last_result: TrackResult | None = None
        self._diag_n, self._diag_t = 0, time.monotonic()
        self._in_callback = nc.poll_period_s == 0.0
        self._infos = self._images = 0
        if not self._in_callback:
            self.create_timer(nc.poll_period_s, self._process_latest)
        self.create_timer(1.0, self._diagnostics)
        log.info(f"tracker ready: mode {self.cfg.mode}, {self.cfg.side} hand, regressor "
                 f"{'loaded' if regressor else 'none'}")

    # ---------------------------------------------------------------------------- inputs
    def _on_image(self, msg: Image) -> None:
        if self._in_callback:
            # frames the subscription replaced while the tracker was busy: one camera_info
            # comes with every frame
            self._images += 1
            self.dropped = max(0, self._infos - self._images)
            self.process(msg)
            return
        if self._pending is not None:
            self.dropped += 1  # keep only the latest frame
        self._pending = msg

    def _on_info(self, msg: CameraInfo) -> None:
        self._info = msg
        self._infos += 1

    def _on_shape(self, msg: HandShapeMsg) -> None:
        try:
            shape = HandShape.from_msg_fields(msg.global_scale, list(msg.alpha),
                                              list(msg.beta), msg.subject_id)
        except HandSuiteError as e:
            self._reject("bad_shape", "hand/shape", e)
            return
        if np.allclose(shape.params, self.tracker.model.shape.params):
            return  # our own calibration coming back, or a repeat
        self._use_shape(shape, float(msg.residual) * 1e3)
        self.get_logger().info(f"tracking with the shape of {msg.subject_id!r} "
                               f"(s_g {shape.global_scale:.3f})")

    def _use_shape(self, shape: HandShape, residual_mm: float) -> None:
        self.tracker.set_shape(shape)
        m = HandShapeMsg()
        m.header.stamp = self.get_clock().now().to_msg()
        for k, v in shape.to_msg_fields().items():
            setattr(m, k, v)
        m.handedness = HandPose.HAND_RIGHT if self.cfg.side == "right" else HandPose.HAND_LEFT
        m.residual = float(residual_mm * 1e-3) if np.isfinite(residual_mm) else 0.0
        self.shape_msg = m

    def _reject(self, reason: str, topic: str, text: object) -> None:
        """Count a rejected input by reason (diagnostics ``rejected_<reason>``) and through
        the node's :class:`InputGate` (per topic, logged at most once a second)."""
        self.rejected[reason] += 1
        self.gate.reject(topic, f"{reason}: {text}")

    # ------------------------------------------------------------------------ processing
    def _process_latest(self) -> None:
        msg = self._pending
        if msg is None:
            return
        self._pending = None
        self.process(msg)

    def process(self, msg: Image) -> TrackResult | None:
        """Track one depth image message and publish the results (None if rejected)."""
        if msg.width == 0 or msg.height == 0 or len(msg.data) == 0:
            self._reject("empty_image", _IMAGE, f"{msg.width} x {msg.height}, "
                         f"{len(msg.data)} bytes")
            return None
        if msg.encoding not in ("16UC1", "32FC1", "mono16"):
            self._reject("bad_encoding", _IMAGE, f"encoding {msg.encoding!r} (16UC1, 32FC1 "
                         "or mono16)")
            return None
        if self._info is None:
            self.rejected["no_camera_info"] += 1  # a start-up race, not bad input
            return None
        try:
            intr = intrinsics_from_msg(self._info)
        except (HandSuiteError, ValueError, IndexError) as e:
            self._reject("bad_camera_info", "camera/depth/camera_info", e)
            return None
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            depth = image_to_array(msg)
            if self._calib is not None:
                self._calibration_step(depth, intr)
            res = self.tracker.process(depth, intr)
        except HandSuiteError as e:
            self._reject("bad_image", _IMAGE, e)
            return None
        self._account(t0, c0, res.timing, res.regressed)
        self.background_plane += int(res.background_plane)
        self.processed += 1
        self.status_count[res.status] += 1
        self.last_result = res
        self._publish(msg, res, intr)
        # a regression the frame deferred (defer_regression): after its pose is out
        t1, c1 = time.perf_counter(), time.process_time()
        deferred = self.tracker.run_deferred()
        if deferred is not None:
            self._account(t1, c1, deferred, True)
        return res

    def _account(self, t0: float, c0: float, timing: dict[str, float], regressed: bool
                 ) -> None:
        """Add work begun at wall time t0 and CPU time c0 [s] to the diagnostics' totals."""
        self.proc_s += time.perf_counter() - t0
        self.cpu_s += time.process_time() - c0
        self.regressed += int(regressed)
        for k, v in timing.items():
            self.stage_s[k] += v

    def _calibration_step(self, depth: np.ndarray, intr: object) -> None:
        from hand_capture.tracking.preprocess import segment_hand

        obs = segment_hand(depth, intr, self.cfg)
        if len(obs.points) < 200:
            return
        self._calib.append((np.array(depth, copy=True), intr))
        n = self.node_cfg.calibration_frames
        if len(self._calib) < n:
            return
        frames, self._calib = self._calib, None
        flat = CALIBRATION_POSES["flat"]
        sid = self.node_cfg.subject_id or "subject"
        res = calibrate(frames, [flat] * len(frames), HandModel(side=self.cfg.side), self.cfg,
                        subject_id=sid)
        if not res.ok:  # an untrusted fit is neither used nor saved
            self.get_logger().warning(f"calibration of {sid!r} {res.status}; keeping the "
                                      f"current shape")
            return
        self._use_shape(res.shape, res.residual_mm)
        self.tracker.set_calibration(res)   # tau of eq. II.19 follows the fit
        if self.node_cfg.subject_id:
            p = save_shape(res.shape, self.node_cfg.shape_folder, sid, self.cfg.side,
                           res.residual_mm)
            self.get_logger().info(f"calibrated {sid!r}: s_g {res.shape.global_scale:.3f}, "
                                   f"residual {res.residual_mm:.1f} mm, saved {p}")
        if self.shape_msg is not None:
            self.pub_shape.publish(self.shape_msg)

    def _publish(self, img: Image, res: TrackResult, intr: object) -> None:
        stamp = img.header.stamp
        frame_id = img.header.frame_id or (self._info.header.frame_id if self._info else "")
        status = {"tracking": "tracking", "recovering": "recovering"}.get(res.status, "lost")
        pose = res.pose
        if status == "lost":
            if res.last_good is None:
                status, pose = "unknown", res.pose
            else:
                pose = res.last_good
        msg = HandPose()
        msg.header.stamp = stamp
        msg.header.frame_id = frame_id
        fill_pose_msg(msg, pose, side=self.cfg.side, status=status,
                      confidence=res.confidence if status != "unknown" else 0.0,
                      source="tracker")
        self.pub_pose.publish(msg)
        js = JointState()
        js.header.stamp = stamp
        js.header.frame_id = frame_id
        js.name = list(ARTICULATED_JOINTS)
        js.position = [float(v) for v in pose[_ART_IDX]]
        self.pub_joints.publish(js)
        n = self.processed
        me, de = self.node_cfg.markers_every, self.node_cfg.debug_image_every
        if me and n % me == 1 % me:
            self.pub_markers.publish(self._markers_bytes(pose, stamp, frame_id, status))
        if de and n % de == 1 % de:
            self.pub_debug.publish(rgb_image_msg(self._debug_image(res, pose, intr), stamp,
                                                 frame_id))

    # ----------------------------------------------------------------------- rendering
    def _marker_template(self, frame_id: str, n_mesh: int, n_skel: int) -> MarkerArray:
        """The two markers (skinned mesh, skeleton) with placeholder points."""
        mesh = Marker()
        mesh.header.frame_id = frame_id
        mesh.ns, mesh.id, mesh.type, mesh.action = "hand_mesh", 0, Marker.TRIANGLE_LIST, 0
        mesh.pose.orientation.w = 1.0
        mesh.scale.x = mesh.scale.y = mesh.scale.z = 1.0
        skel = Marker()
        skel.header.frame_id = frame_id
        skel.ns, skel.id, skel.type, skel.action = "hand_skeleton", 1, Marker.LINE_LIST, 0
        skel.pose.orientation.w = 1.0
        skel.scale.x = 0.003
        mesh.points = [Point() for _ in range(n_mesh)]
        skel.points = [Point() for _ in range(n_skel)]
        return MarkerArray(markers=[mesh, skel])

    def _marker_content(self, pose: np.ndarray, status: str
                        ) -> tuple[list[tuple[float, ...]], list[np.ndarray]]:
        """Colours and points of the mesh and skeleton markers for ``pose``."""
        model = self.tracker.model
        fk = model.forward(pose)
        good = status in ("tracking", "recovering")
        mesh_color = (0.9, 0.7, 0.6, 0.8) if good else (0.6, 0.6, 0.6, 0.8)
        tri = fk.vertices[model.faces.reshape(-1)]
        kp = fk.joint_positions
        skel = kp[np.array(_BONES).reshape(-1)]
        return [mesh_color, (0.0, 1.0, 0.0, 1.0)], [tri, skel]

    def _markers(self, pose: np.ndarray, stamp: object, frame_id: str, status: str
                 ) -> MarkerArray:
        """hand/markers as message objects (the plain path; see :meth:`_markers_bytes`)."""
        colors, points = self._marker_content(pose, status)
        arr = self._marker_template(frame_id, 0, 0)
        for m, c, pts in zip(arr.markers, colors, points, strict=True):
            m.header.stamp = stamp
            m.color.r, m.color.g, m.color.b, m.color.a = c
            m.points = [Point(x=x, y=y, z=z) for x, y, z in pts.tolist()]
        return arr

    def _markers_bytes(self, pose: np.ndarray, stamp: object, frame_id: str, status: str
                       ) -> bytes:
        """hand/markers serialised straight from the arrays (:class:`SerializedMarkers`)."""
        colors, points = self._marker_content(pose, status)
        key = (frame_id, len(points[0]), len(points[1]))
        if self._marker_key != key:
            self._marker_tpl = SerializedMarkers(self._marker_template(*key))
            self._marker_key = key
        return self._marker_tpl.serialize(stamp, colors, points)

    def _debug_image(self, res: TrackResult, pose: np.ndarray, intr: object) -> np.ndarray:
        obs = res.observation
        H, W = intr.height, intr.width
        if obs is not None and obs.mask.shape == (H, W):
            d = obs.depth_m
            img = np.zeros((H, W, 3), np.uint8)
            if obs.found:
                z = d[obs.mask]
                lo, hi = float(z.min()), float(z.max()) + 1e-6
                g = (255 * (1 - (d - lo) / (hi - lo))).clip(0, 255).astype(np.uint8)
                img[obs.mask] = np.stack([g[obs.mask] // 2, g[obs.mask], g[obs.mask] // 2], 1)
        else:
            img = np.zeros((H, W, 3), np.uint8)
        kp = self.tracker.model.joint_positions(pose)
        z = np.maximum(kp[:, 2], 1e-3)
        uv = np.stack([intr.fx * kp[:, 0] / z + intr.cx, intr.fy * kp[:, 1] / z + intr.cy], 1)
        if np.all(np.isfinite(uv)) and np.all(np.abs(uv) < 1e5):
            col = (255, 80, 80) if res.success else (255, 200, 0)
            for a, b in _BONES:
                cv2.line(img, tuple(int(v) for v in uv[a]), tuple(int(v) for v in uv[b]), col, 1)
        return img

    # ---------------------------------------------------------------------- diagnostics
    def _diagnostics(self) -> None:
        now = time.monotonic()
        rate = (self.processed - self._diag_n) / max(now - self._diag_t, 1e-9)
        self._diag_n, self._diag_t = self.processed, now
        n = max(self.processed, 1)
        level = DiagnosticStatus.OK
        text = f"{rate:.1f} Hz"
        if self.processed and self.status_count["tracking"] + self.status_count[
                "recovering"] == 0:
            level, text = DiagnosticStatus.WARN, "no successful frame yet"
        st = DiagnosticStatus(level=level, name="tracker", message=text, hardware_id="tracker")
        vals = {"rate_hz": f"{rate:.2f}", "processed": str(self.processed),
                "dropped_busy": str(self.dropped), "rejected": str(sum(self.rejected.values())),
                "proc_ms_mean": f"{1e3 * self.proc_s / n:.2f}",
                "cpu_ms_mean": f"{1e3 * self.cpu_s / n:.2f}",
                "regressed_share": f"{self.regressed / n:.2f}",
                "background_plane_share": f"{self.background_plane / n:.2f}",
                "mode": self.cfg.mode,
                "last_cost_mm": f"{self.last_result.cost:.2f}" if self.last_result else "",
                "shape_global_scale": f"{self.tracker.model.shape.global_scale:.4f}"}
        vals.update({f"rejected_{k}": str(v) for k, v in self.rejected.items()})
        vals.update(self.gate.values())
        vals.update({f"status_{k}": str(v) for k, v in self.status_count.items()})
        vals.update({f"{k}_ms_mean": f"{1e3 * v / n:.2f}" for k, v in self.stage_s.items()})
        st.values = [KeyValue(key=k, value=v) for k, v in vals.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    """Entry point of the tracker console script."""
    return run_node(TrackerNode, args)


if __name__ == "__main__":
    sys.exit(main())
