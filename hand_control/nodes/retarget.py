"""retarget: the tracked human hand -> the joint angles of a robot hand model.

Thin wrapper around :class:`hand_control.retarget.stream.RetargetStream` (the solver is
:class:`hand_control.retarget.HandRetargeter`; the robot and its points come from a retarget
config, ``config/retarget/<name>.yaml``).

Topics:
    in   hand/pose (hand_msgs/HandPose, ``input: pose``) or hand/keypoints
         (hand_msgs/HandKeypoints, 21 3-D points, ``input: keypoints``), sensor-data QoS
    out  robot/joint_command (hand_msgs/JointCommand, reliable): the robot's joint names and
         positions [rad or m], stamped with the input's stamp (the servo bridge follows it
         with ``source: robot`` and a one-servo-per-joint map, e.g. leap_hand_joints)
    out  diagnostics (1 Hz: frames solved, held by reason, rejected inputs, solve time, tip
         error)
A frame with NaN keypoints, without a hand (status LOST / UNKNOWN), of the other hand (unless
``mirror_other_hand``) or that the solver refuses is counted and holds the last command
(repeated for ``hold_timeout_s``, then nothing is sent: the servo bridge's command timeout
takes over). Inputs pass
:mod:`hand_capture.validate` through the node's :class:`InputGate`.
"""

from __future__ import annotations

import array
import sys
from collections import deque
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hand_msgs.msg import HandKeypoints, HandPose, JointCommand
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from hand_capture.config import param, validate
from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.validate import validate_hand_keypoints_msg, validate_hand_pose_msg
from hand_control.retarget import MODES, HandRetargeter, load_retarget_config
from hand_control.retarget.stream import RetargetStream, StreamOutput


@dataclass(frozen=True)
class RetargetNodeConfig:
    """Parameters of the ``retarget`` node."""

    config: str = param("leap_hand", "retarget config: a path, or a name under "
                        "config/retarget (leap_hand, suite_hand)", read_only=True)
    input: str = param("pose", "the input: pose (hand/pose, HandPose) or keypoints "
                       "(hand/keypoints, HandKeypoints with 3-D points)",
                       choices=("pose", "keypoints"), read_only=True)
    mode: str = param("", "retargeting mode; empty: the config's (position, vector, pinch)",
                      choices=("",) + MODES, read_only=True)
    filter_cutoff_hz: float = param(-1.0, "low-pass cutoff on the output joints [Hz]; 0 = "
                                    "off; -1: the config's", lo=-1.0, hi=500.0,
                                    read_only=True)
    hold_timeout_s: float = param(1.0, "a frame without a usable hand repeats the last "
                                  "command this long after the last good frame [s]",
                                  lo=0.0, hi=60.0, read_only=True)
    mirror_other_hand: bool = param(False, "drive the robot from the other hand than its "
                                    "config's, mirror-imaged (false: such frames are held "
                                    "and counted)", read_only=True)

    def __post_init__(self) -> None:
        validate(self)


class RetargetNode(Node):
    """Publishes robot/joint_command from hand/pose or hand/keypoints (module docstring)."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("retarget", **kwargs)
        self.cfg = declare_config(self, RetargetNodeConfig)
        rcfg = load_retarget_config(self.cfg.config)
        changes: dict[str, object] = {}
        if self.cfg.mode:
            changes["mode"] = self.cfg.mode
        if self.cfg.filter_cutoff_hz >= 0.0:
            changes["filter_cutoff_hz"] = self.cfg.filter_cutoff_hz
        if changes:
            rcfg = rcfg.with_settings(**changes)
        self.stream = RetargetStream(HandRetargeter(rcfg), self.cfg.hold_timeout_s,
                                     mirror_other_hand=self.cfg.mirror_other_hand)
        self.gate = InputGate(self)
        self._names = list(self.stream.joint_names)
        self._solve_ms: deque[float] = deque(maxlen=200)
        self._tip_mm: deque[float] = deque(maxlen=200)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(JointCommand, "robot/joint_command", reliable)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        if self.cfg.input == "pose":
            self.topic = "hand/pose"
            self.create_subscription(HandPose, self.topic, self._on_pose,
                                     qos_profile_sensor_data)
        else:
            self.topic = "hand/keypoints"
            self.create_subscription(HandKeypoints, self.topic, self._on_keypoints,
                                     qos_profile_sensor_data)
        self.create_timer(1.0, self._diagnostics)
        self.get_logger().info(
            f"retargeting {self.topic} onto {rcfg.name!r} ({len(self._names)} joints, mode "
            f"{rcfg.settings.mode}) -> robot/joint_command")

    @staticmethod
    def _t(stamp) -> float:
        return stamp.sec + 1e-9 * stamp.nanosec

    def _on_pose(self, msg: HandPose) -> None:
        t = self._t(msg.header.stamp)
        if not self.gate.stamp_ok(self.topic, msg.header.stamp):
            return
        q = self.gate.check(self.topic, validate_hand_pose_msg, msg)
        side = "left" if msg.handedness == HandPose.HAND_LEFT else "right"
        out = (self.stream.hold("invalid", t, self.gate.last_reason.get(self.topic, ""))
               if q is None else self.stream.pose(q, t, int(msg.status), side))
        self._publish(out, msg.header)

    def _on_keypoints(self, msg: HandKeypoints) -> None:
        t = self._t(msg.header.stamp)
        if not self.gate.stamp_ok(self.topic, msg.header.stamp):
            return
        got = self.gate.check(self.topic, validate_hand_keypoints_msg, msg)
        if got is None:
            out = self.stream.hold("invalid", t, self.gate.last_reason.get(self.topic, ""))
        else:
            pts, side, status = got
            out = self.stream.keypoints(None if status == HandPose.STATUS_LOST else pts, t,
                                        status, side)
        self._publish(out, msg.header)

    def _publish(self, out: StreamOutput, header) -> None:
        if out.q is None:
            return
        if not out.held:
            self._solve_ms.append(out.solve_ms)
            self._tip_mm.append(out.tip_error_mm)
        cmd = JointCommand(joint_names=self._names)
        cmd.header.stamp = header.stamp
        cmd.positions = array.array("d", np.ascontiguousarray(out.q, dtype=np.float64).tobytes())
        self.pub.publish(cmd)

    def _diagnostics(self) -> None:
        values = {k: str(v) for k, v in self.stream.counts().items()}
        values.update(self.gate.values())
        if self._solve_ms:
            values["solve_ms_p50"] = f"{float(np.median(self._solve_ms)):.3f}"
            values["tip_error_mm_mean"] = f"{float(np.nanmean(self._tip_mm)):.2f}"
        if self.stream.last_reason:
            values["last_hold"] = self.stream.last_reason[:200]
        held = self.stream.counts()["held_total"]
        level = DiagnosticStatus.OK if self.stream.solved or not held else DiagnosticStatus.WARN
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(
            level=level, name="retarget", hardware_id=self.stream.rt.config.name,
            message=f"{self.stream.solved} frames retargeted, {held} held",
            values=[KeyValue(key=k, value=v) for k, v in values.items()])]
        self.pub_diag.publish(arr)

    @property
    def rejected(self) -> int:
        return self.gate.total


def main(args: list[str] | None = None) -> int:
    return run_node(RetargetNode, args)


if __name__ == "__main__":
    sys.exit(main())
