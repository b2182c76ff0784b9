"""touch_encoder: touch/frame -> hand/pose by finger labelling + quadratic encoding.

For every ``hand_msgs/TouchFrame`` it publishes one ``hand_msgs/HandPose`` (same stamp and
frame as the touch frame, ``joint_names`` = the articulated joints, ``wrist_pose`` from the root
degrees of freedom, ``source`` "touch_encoder"). Frames without contact repeat the last pose
with STATUS_LOST. Malformed frames (NaN coordinates, touches off the surface by more than 10 %
of its size, a surface size outside (0, 10] m, more than five contacts: the checks of
:func:`hand_capture.validate.validate_touch_frame` and the encoder's) are rejected, logged and
counted on ``diagnostics``; the graph keeps running. Parameters:
:class:`~hand_capture.touch.encoder.TouchEncoderConfig`.
"""

from __future__ import annotations

import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hand_msgs.msg import HandPose
from hand_msgs.msg import TouchFrame as TouchFrameMsg
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from hand_capture.errors import InputError
from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import fill_pose_msg
from hand_capture.touch.encoder import (
    EncodedPose,
    TouchEncoder,
    TouchEncoderConfig,
    surface_pose,
)
from hand_capture.touch.frame import TouchFrame
from hand_capture.validate import DEFAULT_LIMITS, InputLimits, validate_touch_frame


def frame_from_msg(msg: TouchFrameMsg, limits: InputLimits = DEFAULT_LIMITS) -> TouchFrame:
    """A hand_msgs/TouchFrame as a core TouchFrame, after the validation layer's checks
    (:func:`~hand_capture.validate.validate_touch_frame`; InputError when malformed)."""
    pts = msg.points
    ids, flags = [p.session_id for p in pts], [p.in_contact for p in pts]
    pos = validate_touch_frame(ids, [(p.x, p.y) for p in pts], flags, msg.width, msg.height,
                               limits)
    return TouchFrame(ids, pos, flags, msg.width, msg.height,
                      msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                      msg.header.frame_id)


def pose_to_msg(res: EncodedPose, header: object) -> HandPose:
    """An encoder result as a hand_msgs/HandPose carrying ``header`` (surface frame)."""
    msg = fill_pose_msg(HandPose(), surface_pose(res.pose), side="right", status=res.status,
                        confidence=res.confidence, source="touch_encoder")
    msg.header = header
    return msg


class TouchEncoderNode(Node):
    """Reconstructs hand poses from touch frames at the input rate."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("touch_encoder", **kwargs)
        self.cfg = declare_config(self, TouchEncoderConfig)
        self.core = TouchEncoder(self.cfg)
        self.pub = self.create_publisher(HandPose, "hand/pose", 10)
        self.diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_subscription(TouchFrameMsg, "touch/frame", self._on_frame,
                                 qos_profile_sensor_data)
        self.create_timer(1.0, self._diagnostics)
        self.published = 0
        self.gate = InputGate(self)
        self.relabels = 0
        self.get_logger().info(f"touch encoder: {self.cfg.encoding} encoding, "
                               f"{len(self.core.model.reference_poses)} reference poses")

    @property
    def rejected(self) -> int:
        """Touch frames rejected so far."""
        return self.gate.total

    def _on_frame(self, msg: TouchFrameMsg) -> None:
        try:
            res = self.core.process(frame_from_msg(msg, self.gate.limits))
        except InputError as e:
            self.gate.reject("touch/frame", e)
            return
        if res is None:
            return
        self.relabels += res.relabelled
        self.pub.publish(pose_to_msg(res, msg.header))
        self.published += 1

    def _diagnostics(self) -> None:
        st = DiagnosticStatus(level=DiagnosticStatus.OK if not self.rejected
                              else DiagnosticStatus.WARN,
                              name="touch_encoder", message=f"{self.published} poses",
                              hardware_id=self.cfg.encoding)
        st.values = [KeyValue(key="published", value=str(self.published)),
                     KeyValue(key="rejected", value=str(self.rejected)),
                     KeyValue(key="relabels", value=str(self.relabels))]
        st.values += [KeyValue(key=k, value=v) for k, v in self.gate.values().items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(arr)


def main(args: list[str] | None = None) -> int:
    """Entry point of the touch_encoder console script."""
    return run_node(TouchEncoderNode, args)


if __name__ == "__main__":
    sys.exit(main())
