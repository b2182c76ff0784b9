"""grasp_phase: the teleoperation performance interface (dissertation III.6) as a node.

Thin wrapper around :class:`hand_control.teleop.retarget.PerformanceInterface`.

Topics:
    in   hand/pose (hand_msgs/HandPose): the operator's tracked hand, in the camera optical
         frame (any frame_id but ``world_frame``; mapped to the world by the camera pose) or
         already in ``world_frame``. Lost / unknown poses are skipped.
    in   sim/object_pose (geometry_msgs/PoseStamped, world): the simulated object
    out  control/grasp_phase (hand_msgs/GraspPhase) at every hand pose
    out  control/object_target (geometry_msgs/PoseStamped, world) in manipulation: the object's
         target, rigidly following the operator's (smoothed) wrist
    out  control/hand_target (hand_msgs/HandPose, world): the hand's PD target, the tracked
         hand retargeted onto the scenario's planned grasp while closing and manipulating
         (``grasp_source: synthesis``: onto the grasp synthesised for the object from the
         operator's hand as closing begins, III.6; the synthesis takes a few hundred ms
         once per grasp, the hand poses meanwhile wait in the queue)
    out  diagnostics (1 Hz: phase, rejected inputs per topic)
Inputs pass :mod:`hand_capture.validate` (bad ones are counted and logged); a hand pose stamped
more than ``future_stamp_tolerance`` (1 s) ahead of the node clock is rejected, and the phase
detector restarts its timers when time goes back, so one bad stamp cannot freeze a phase.
Every output keeps the hand pose's stamp (the source image stamp), for per-stage latency.
The camera pose (``camera_position``, ``camera_rotation``: the camera optical frame in the
world, as the synthetic camera takes it) is the mapping from the operator's space to the world.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import GraspPhase, HandPose
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from hand_capture.cameras.transforms import pose_in_world, rotvec_to_matrix
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, HandSuiteError
from hand_capture.model import matrix_to_quat
from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import STATUS, fill_pose_msg
from hand_capture.validate import validate_hand_pose_msg, validate_pose
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import load_scenario
from hand_control.teleop.phases import PhaseConfig
from hand_control.teleop.retarget import InterfaceConfig, PerformanceInterface, object_matrix

#: Statuses of a usable hand pose, by code (the names of posemsg.STATUS, which the output keeps)
_STATUS = {STATUS[name]: name for name in ("tracking", "recovering", "ground_truth")}


@dataclass(frozen=True)
class GraspPhaseNodeConfig:
    """Node parameters besides the interface (``wrist_cutoff``) and phase (``phase.*``) ones."""

    scenario: str = param("lift_box", "scenario file (config/scenarios/<name>.yaml): the "
                          "object and its planned grasp (the same as the sim's)")
    grasp_source: str = param(
        "plan", "plan: the scenario's grasp | synthesis: the grasp synthesised for the object "
        "from the operator's hand as closing begins (dissertation III.6)",
        choices=("plan", "synthesis"))
    camera_position: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), "camera optical centre in the world [m]")
    camera_rotation: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), "camera orientation in the world, rotation vector [rad]")
    world_frame: str = param("world", "frame of the outputs; a hand pose in it is not mapped")

    def __post_init__(self) -> None:
        validate(self)
        for name in ("camera_position", "camera_rotation"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"GraspPhaseNodeConfig.{name} needs 3 values")


class GraspPhaseNode(Node):
    """Publishes grasp phases, the manipulation target and the hand target; module docstring."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("grasp_phase", **kwargs)
        self.cfg = declare_config(self, GraspPhaseNodeConfig)
        phase_cfg = declare_config(self, PhaseConfig, prefix="phase.")
        ui_cfg = declare_config(self, InterfaceConfig)
        spec = load_scenario(self.cfg.scenario)
        runner = LockstepRunner(spec)  # the sim's world and plan
        pose = runner.world.object_pose(runner.obj.name)
        self.object_name = runner.obj.name
        synthesizer = None
        if self.cfg.grasp_source == "synthesis":
            from hand_control.grasp.synthesis import PerformerSynthesizer, primitive_object
            from hand_control.sim.lockstep import scenario_object

            obj = scenario_object(spec) if spec.object_shape else primitive_object(runner.obj)
            synthesizer = PerformerSynthesizer(obj, runner.obj.name)
        self.ui = PerformanceInterface(runner.plan.q_grasp,
                                       object_matrix(pose.position, pose.quaternion),
                                       phase_cfg, ui_cfg,
                                       q_pregrasp=runner.plan.q_pregrasp,
                                       synthesizer=synthesizer, closing=runner.plan.closing)
        self.R_wc = rotvec_to_matrix(np.array(self.cfg.camera_rotation))
        self.t_wc = np.array(self.cfg.camera_position, dtype=float)
        self.object_T: np.ndarray | None = None
        self._object_msg: PoseStamped | None = None
        self.gate = InputGate(self)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_phase = self.create_publisher(GraspPhase, "control/grasp_phase", reliable)
        self.pub_target = self.create_publisher(PoseStamped, "control/object_target", reliable)
        self.pub_hand = self.create_publisher(HandPose, "control/hand_target", reliable)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_subscription(HandPose, "hand/pose", self._on_hand, reliable)
        self.create_subscription(PoseStamped, "sim/object_pose", self._on_object,
                                 qos_profile_sensor_data)
        self.create_timer(1.0, self._diagnostics)
        # rclpy's first log call of a process inspects every loaded module (50-250 ms): done
        # here, not at the first phase change in the middle of a grasp
        self.get_logger().info(f"grasp phases for {self.object_name!r} of scenario "
                               f"{self.cfg.scenario!r}")

    def _on_object(self, msg: PoseStamped) -> None:
        self._object_msg = msg  # converted when a hand pose needs it (hundreds per second)

    def _object_pose(self) -> np.ndarray | None:
        """The latest valid object pose (4, 4), or None."""
        msg, self._object_msg = self._object_msg, None
        if msg is not None:
            p, o = msg.pose.position, msg.pose.orientation
            pose = self.gate.check("sim/object_pose", validate_pose, (p.x, p.y, p.z),
                                   (o.x, o.y, o.z, o.w), what="object pose")
            if pose is not None:
                self.object_T = object_matrix(*pose)
        return self.object_T

    @property
    def rejected(self) -> int:
        """Inputs rejected so far (every topic)."""
        return self.gate.total

    def _on_hand(self, msg: HandPose) -> None:
        q = self.gate.check("hand/pose", validate_hand_pose_msg, msg)
        if q is None or msg.status not in _STATUS or \
                not self.gate.stamp_ok("hand/pose", msg.header.stamp) or \
                self._object_pose() is None:
            return
        try:
            if msg.header.frame_id != self.cfg.world_frame:
                q = pose_in_world(q, self.R_wc, self.t_wc)
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            step = self.ui.update(t, q, self.object_T)
        except HandSuiteError as e:
            self.gate.reject("hand/pose", e)
            return
        up = step.phase
        out = GraspPhase(phase=int(up.phase), object_name=self.object_name)
        out.header = msg.header
        self.pub_phase.publish(out)
        if up.changed:
            self.get_logger().info(f"grasp phase: {up.phase.name.lower()} "
                                   f"(palm-object {up.distance * 100:.1f} cm, grip "
                                   f"{up.grip * 100:.1f} cm)")
        hand = fill_pose_msg(HandPose(), step.hand_target, status=_STATUS[msg.status],
                             confidence=msg.confidence, source="grasp_phase")
        hand.handedness = msg.handedness
        hand.header.stamp = msg.header.stamp
        hand.header.frame_id = self.cfg.world_frame
        self.pub_hand.publish(hand)
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
                              message=self.ui.detector.phase.name.lower())
        values = {"rejected": str(self.rejected), **self.gate.values(),
                  "time_jumps": str(self.ui.detector.time_jumps)}
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    """Entry point of the grasp_phase console script."""
    return run_node(GraspPhaseNode, args)


if __name__ == "__main__":
    sys.exit(main())
