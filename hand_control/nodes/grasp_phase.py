"""grasp_phase: the teleoperation performance interface (dissertation III.6) as a node.

Subscribes to the tracked hand (``hand/pose``, camera frame) and the simulated object
(``sim/object_pose``, world frame); publishes the phase on ``control/grasp_phase`` at every hand
pose and, during manipulation, the object's target pose (rigidly following the wrist) on
``control/object_target``. Both keep the hand pose's stamp (the source image stamp).
The camera's pose in the world is a parameter.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import GraspPhase, HandPose
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model import HandModel, matrix_to_quat, quat_to_matrix, root_rotation_matrix
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import pose_from_msg
from hand_control.teleop.phases import GraspPhaseDetector, PhaseConfig


@dataclass(frozen=True)
class GraspPhaseNodeConfig:
    """Node parameters besides the detector thresholds (``phase.*``)."""

    camera_pose: tuple[float, ...] = param(
        (0.0, -0.45, 0.35, -2.2, 0.0, 0.0),
        "camera optical frame in the world: x, y, z [m], then rx, ry, rz root-style angles [rad]")
    object_name: str = param("object", "name reported in GraspPhase.object_name")
    world_frame: str = param("world", "frame of control/object_target")

    def __post_init__(self) -> None:
        validate(self)


def _transform(xyz: object, angles: object) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = root_rotation_matrix(np.asarray(angles, dtype=float))
    T[:3, 3] = np.asarray(xyz, dtype=float)
    return T


class GraspPhaseNode(Node):
    """Publishes grasp phases and the manipulation target; see the module docstring."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("grasp_phase", **kwargs)
        self.cfg = declare_config(self, GraspPhaseNodeConfig)
        if len(self.cfg.camera_pose) != 6:
            raise InputError("camera_pose needs 6 values: x, y, z, rx, ry, rz")
        self.detector = GraspPhaseDetector(declare_config(self, PhaseConfig, prefix="phase."))
        self.model = HandModel()
        self.T_world_cam = _transform(self.cfg.camera_pose[:3], self.cfg.camera_pose[3:])
        self.object_T: np.ndarray | None = None
        self.rejected = 0
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_phase = self.create_publisher(GraspPhase, "control/grasp_phase", reliable)
        self.pub_target = self.create_publisher(PoseStamped, "control/object_target", reliable)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_subscription(HandPose, "hand/pose", self._on_hand, reliable)
        self.create_subscription(PoseStamped, "sim/object_pose", self._on_object, 10)
        self.create_timer(1.0, self._diagnostics)

    def _on_object(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(np.array([o.x, o.y, o.z, o.w]))
        T[:3, 3] = (p.x, p.y, p.z)
        self.object_T = T

    def _on_hand(self, msg: HandPose) -> None:
        if self.object_T is None or msg.status not in (HandPose.STATUS_TRACKING,
                                                       HandPose.STATUS_GROUND_TRUTH):
            return
        try:
            q = pose_from_msg(msg)
            kp_cam = self.model.forward(q).joint_positions
            kp = kp_cam @ self.T_world_cam[:3, :3].T + self.T_world_cam[:3, 3]
            wrist = self.T_world_cam @ _transform(q[:3], q[3:6])
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            up = self.detector.update(t, kp, wrist, self.object_T)
        except InputError as e:
            self.rejected += 1
            self.get_logger().warning(f"rejected hand pose: {e}", throttle_duration_sec=1.0)
            return
        out = GraspPhase(phase=int(up.phase), object_name=self.cfg.object_name)
        out.header = msg.header
        self.pub_phase.publish(out)
        if up.changed:
            self.get_logger().info(f"grasp phase: {up.phase.name.lower()}")
        if up.object_target is not None:
            tgt = PoseStamped()
            tgt.header.stamp = msg.header.stamp
            tgt.header.frame_id = self.cfg.world_frame
            tp, to = tgt.pose.position, tgt.pose.orientation
            tp.x, tp.y, tp.z = (float(v) for v in up.object_target[:3, 3])
            to.x, to.y, to.z, to.w = (float(v) for v in matrix_to_quat(up.object_target[:3, :3]))
            self.pub_target.publish(tgt)

    def _diagnostics(self) -> None:
        st = DiagnosticStatus(level=DiagnosticStatus.OK, name="grasp_phase",
                              message=self.detector.phase.name.lower())
        st.values = [KeyValue(key="rejected", value=str(self.rejected))]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    """Entry point of the grasp_phase console script."""
    return run_node(GraspPhaseNode, args)


if __name__ == "__main__":
    sys.exit(main())
