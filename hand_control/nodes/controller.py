"""controller: composite motion control of the simulated hand (seed 000 eq. 8-13).

Thin wrapper around :class:`hand_control.control.loop.ControllerCore`. Parameters: the node's
own (:class:`ControllerNodeConfig`) and every gain and QP setting
(:class:`CompositeControlConfig`: ``joint_kp``/``joint_kd`` per row of Table 1 = Table III.1,
``object_kp_translate`` ..., ``method``, ``alpha1`` .. ``alpha4``, ...), from
``config/controller.yaml`` or ``-p name:=value``. The hand's kinematics come from the
scenario's MJCF (:class:`hand_control.sim.kinematics.MujocoKinematics`).

Topics:
    in   sim/joint_states (sensor_msgs/JointState): each message triggers one control step
    in   sim/object_pose (geometry_msgs/PoseStamped), sim/object_twist (TwistStamped)
    in   sim/contacts (hand_msgs/ContactArray; hand-object contacts are used)
    in   hand/pose (hand_msgs/HandPose, world frame) when ``reference: hand_pose``; otherwise
         the scenario's scripted reference at the current (simulation) time. The teleop graph
         remaps it to control/hand_target (the grasp_phase node's retargeted hand); a pose in
         another frame than ``world_frame`` (e.g. a tracker's camera frame) is rejected.
         With ``command_on_reference`` (default) each new hand pose also triggers a step, on
         the newest joint state, so a pose reaches the command without waiting for the next
         joint state.
    in   control/grasp_phase (hand_msgs/GraspPhase) when ``reference: hand_pose``: the grasp
         torques are on in the manipulation phase only (off until a phase arrives)
    in   control/object_target (geometry_msgs/PoseStamped): overrides the object target
    out  control/joint_command (hand_msgs/JointCommand: servo position targets and the grasp
         torques as feed-forward efforts, by joint name), reliable. Its stamp is the stamp of
         the joint state it answers, or with ``reference: hand_pose`` the stamp of the hand
         pose it follows (the source image stamp, for per-stage latency).
    out  control/contact_forces (hand_msgs/ContactArray: the planned contact forces on the
         object, eq. III.23), control/contact_markers (visualization_msgs/MarkerArray: arrows),
         both at ``forces_rate`` (50 Hz)
    out  diagnostics (1 Hz: steps, QP fallbacks, rejected inputs)
A QP without solution or bad input gives a PD-only command (zero efforts), counted and logged;
a non-finite value never reaches a joint.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseStamped, TwistStamped
from hand_msgs.msg import Contact, ContactArray, GraspPhase, HandPose, JointCommand
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState
from visualization_msgs.msg import Marker, MarkerArray

from hand_capture.model.joints import JOINT_NAMES
from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.validate import (
    validate_contacts,
    validate_grasp_phase,
    validate_hand_pose_msg,
    validate_joint_state,
    validate_pose,
    validate_twist,
)
from hand_control.control import CompositeControlConfig, ControllerNodeConfig
from hand_control.errors import InputError
from hand_control.nodes.convert import contacts_from_msg
from hand_control.sim.lockstep import controller_setup
from hand_control.sim.scenario import load_scenario


@dataclass(frozen=True)
class _State:
    """A joint state from the sim with the object state and contacts current at its arrival."""

    t: float  # its stamp [s]
    received: float  # time.monotonic() at arrival [s]
    stamp: object  # its header stamp
    q: np.ndarray  # (n_hand,) [rad]
    qd: np.ndarray  # (n_hand,) [rad/s]
    object_pose: tuple[np.ndarray, ...]  # position, quaternion wxyz, linear, angular velocity
    contacts: tuple  # hand-object contacts: bodies, points, normals, forces, friction


class ControllerNode(Node):
    """Runs :class:`ControllerCore` on every joint state from the simulation."""

    def __init__(self, **kwargs) -> None:
        super().__init__("controller", **kwargs)
        self.cfg: ControllerNodeConfig = declare_config(self, ControllerNodeConfig)
        self.gains: CompositeControlConfig = declare_config(self, CompositeControlConfig)
        spec = load_scenario(self.cfg.scenario)
        # the scenario's model (kinematics, grasp plan, reference); nothing is stepped here
        setup = controller_setup(spec, controller_config=self.cfg, gains=self.gains,
                                 control_period=self.cfg.control_period)
        self.core = setup.core
        self.object_name = setup.obj.name
        self._obj = None
        self._twist = (np.zeros(3), np.zeros(3))
        self._contacts = None
        self._state: _State | None = None  # the newest joint state and what came with it
        self._last_t = -math.inf  # time of the last control step [s]
        self._cmd_names = list(self.core.joint_names)
        self._warned = 0.0
        self.commands = 0
        # every input passes the validation layer: rejections counted per topic, logged
        self.gate = InputGate(self, on_reject=self._count_rejection)
        self._known = frozenset(self.core.joint_names)
        self.create_subscription(JointState, "sim/joint_states", self._on_joint_state,
                                 qos_profile_sensor_data)
        self.create_subscription(PoseStamped, "sim/object_pose", self._on_pose,
                                 qos_profile_sensor_data)
        self.create_subscription(TwistStamped, "sim/object_twist", self._on_twist,
                                 qos_profile_sensor_data)
        self.create_subscription(ContactArray, "sim/contacts", self._on_contacts,
                                 qos_profile_sensor_data)
        self.create_subscription(PoseStamped, "control/object_target", self._on_object_target,
                                 10)
        self._hand_stamp = None  # stamp of the hand pose followed (reference: hand_pose)
        if self.cfg.reference == "hand_pose":
            self.core.grasp_override = False
            # Until the first hand pose comes, hold the hand at the scenario's start and the
            # object where it rests: the scripted reach and lift must not play meanwhile (on a
            # loaded machine the tracker's first pose can come seconds after the sim starts,
            # and the scripted motion, with grasp torques off, knocks the object away).
            start = setup.reference(0.0)
            self.core.hand_target_override = np.array(start.q_target, dtype=np.float64)
            self.core.object_target_override = (np.array(start.object_position, dtype=float),
                                                 np.array(start.object_quaternion, dtype=float))
            self.create_subscription(HandPose, "hand/pose", self._on_hand_pose,
                                     qos_profile_sensor_data)
            self.create_subscription(GraspPhase, "control/grasp_phase", self._on_phase, 10)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_cmd = self.create_publisher(JointCommand, "control/joint_command", reliable)
        self.pub_forces = self.create_publisher(ContactArray, "control/contact_forces", 10)
        self.pub_markers = self.create_publisher(MarkerArray, "control/contact_markers", 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self._last_forces = 0.0
        self.create_timer(1.0, self._diagnostics)

    def _log_throttled(self, text: str) -> None:
        now = time.monotonic()
        if now - self._warned > 1.0:
            self._warned = now
            self.get_logger().warning(text)

    def _count_rejection(self, topic: str) -> None:
        self.core.counters["rejected_inputs"] += 1

    # ----------------------------------------------------------------------------- inputs
    def _on_pose(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        obj = self.gate.check("sim/object_pose", validate_pose, (p.x, p.y, p.z),
                              (o.x, o.y, o.z, o.w), what="object pose")
        if obj is not None:
            self._obj = obj  # position, quaternion wxyz (unit)

    def _on_twist(self, msg: TwistStamped) -> None:
        lin, ang = msg.twist.linear, msg.twist.angular
        tw = self.gate.check("sim/object_twist", validate_twist, (lin.x, lin.y, lin.z),
                             (ang.x, ang.y, ang.z))
        if tw is not None:
            self._twist = tw

    def _on_contacts(self, msg: ContactArray) -> None:
        self._contacts = msg

    def _on_object_target(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        target = self.gate.check("control/object_target", validate_pose, (p.x, p.y, p.z),
                                 (o.x, o.y, o.z, o.w), what="object target")
        if target is not None:
            self.core.object_target_override = target

    def _on_phase(self, msg: GraspPhase) -> None:
        phase = self.gate.check("control/grasp_phase", validate_grasp_phase, msg.phase)
        if phase is not None:
            self.core.grasp_override = phase == GraspPhase.MANIPULATION

    def _on_hand_pose(self, msg: HandPose) -> None:
        if msg.status in (HandPose.STATUS_UNKNOWN, HandPose.STATUS_LOST):
            return
        if msg.header.frame_id != self.cfg.world_frame:
            self.core.counters["rejected_inputs"] += 1
            self._log_throttled(f"hand/pose rejected: frame {msg.header.frame_id!r}, the "
                                f"controller needs {self.cfg.world_frame!r} (map a camera-frame "
                                f"pose through grasp_phase's control/hand_target)")
            return
        # (27,) JOINT_NAMES order, root from wrist_pose
        pose = self.gate.check("hand/pose", validate_hand_pose_msg, msg)
        if pose is None:
            return
        try:
            q = self.core.hand_pose_from_names(JOINT_NAMES, pose)
        except InputError as e:
            self.gate.reject("hand/pose", e)
            return
        self.core.hand_target_override = q
        new = self._hand_stamp != msg.header.stamp
        self._hand_stamp = msg.header.stamp
        if new and self.cfg.command_on_reference:
            self._answer_reference()

    def _on_joint_state(self, msg: JointState) -> None:
        if self._obj is None:
            return
        if self.gate.check("sim/joint_states", validate_joint_state, msg.name, msg.position,
                           msg.velocity, msg.effort, known=self._known) is None:
            return
        try:
            q = self.core.hand_pose_from_names(msg.name, msg.position)
            qd = self.core.hand_pose_from_names(msg.name, msg.velocity)
        except InputError as e:
            self.gate.reject("sim/joint_states", e)
            return
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        bodies, pts, nrm, frc, mu = [], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), \
            np.zeros(0)
        contacts = self._contacts
        if contacts is not None:
            b1, b2, p_, n_, f_, m_ = contacts_from_msg(contacts)
            if self.gate.check("sim/contacts", validate_contacts, p_, n_, f_, m_) is None:
                self._contacts = None  # counted once; the step runs without contacts
                b1 = b2 = []
            hand = self.core.kin.is_hand_body
            sel = [i for i, (a, b) in enumerate(zip(b1, b2, strict=True))
                   if b == self.object_name and hand(a)]
            bodies = [b1[i] for i in sel]
            pts, nrm, frc, mu = p_[sel], n_[sel], f_[sel], m_[sel]
        self._state = _State(t, time.monotonic(), msg.header.stamp, q, qd,
                             (*self._obj, *self._twist), (bodies, pts, nrm, frc, mu))
        self._control(t)

    def _answer_reference(self) -> None:
        """A new hand pose: a control step now, on the newest joint state, at that state's
        time plus the wall time since it came (at most half a control period, so the next
        joint state's step still comes later on the target filter's clock)."""
        s = self._state
        if s is None:
            return
        dt = min(max(time.monotonic() - s.received, 0.0), 0.5 * self.cfg.control_period)
        t = s.t + dt
        if t > self._last_t:
            self._control(t)

    def _control(self, t: float) -> None:
        """One control step at time ``t`` [s] on the stored state; publishes the command."""
        s = self._state
        self._last_t = t
        before = dict(self.core.counters)
        cmd = self.core.step(t, s.q, s.qd, s.object_pose, *s.contacts)
        c = self.core.counters
        if c["qp_fallbacks"] > before["qp_fallbacks"]:
            self._log_throttled(f"contact QP found no solution: PD-only step "
                                f"({c['qp_fallbacks']} so far)")
        elif c["rejected_inputs"] > before["rejected_inputs"]:
            self._log_throttled(f"bad contact/state input: PD-only step "
                                f"({c['rejected_inputs']} so far)")
        out = JointCommand()
        out.header.stamp = s.stamp if self._hand_stamp is None else self._hand_stamp
        out.joint_names = self._cmd_names
        out.positions = cmd.positions.tolist()
        out.efforts = cmd.efforts.tolist()
        self.pub_cmd.publish(out)
        self.commands += 1
        self._publish_forces(s.stamp, cmd)

    def _publish_forces(self, stamp, cmd) -> None:
        now = time.monotonic()
        rate = self.cfg.forces_rate
        if rate > 0 and now - self._last_forces < 1.0 / rate:
            return
        self._last_forces = now
        arr = ContactArray()
        arr.header.stamp = stamp
        arr.header.frame_id = "world"
        for k in range(len(cmd.planned_forces)):
            c = Contact()
            c.body1, c.body2 = cmd.contact_bodies[k], self.object_name
            c.point.x, c.point.y, c.point.z = cmd.contact_points[k].tolist()
            c.normal.x, c.normal.y, c.normal.z = cmd.contact_normals[k].tolist()
            c.force.x, c.force.y, c.force.z = cmd.planned_forces[k].tolist()
            c.torsional_torque = float(cmd.planned_torsion[k])
            arr.contacts.append(c)
        self.pub_forces.publish(arr)
        markers = MarkerArray()
        clear = Marker()
        clear.action = Marker.DELETEALL
        markers.markers.append(clear)
        for k, c in enumerate(arr.contacts):
            m = Marker()
            m.header = arr.header
            m.ns, m.id, m.type, m.action = "planned_contact_forces", k, Marker.ARROW, Marker.ADD
            p0 = np.array([c.point.x, c.point.y, c.point.z])
            f = np.array([c.force.x, c.force.y, c.force.z])
            p1 = p0 + self.cfg.marker_scale * f
            m.points = [Point(x=float(p0[0]), y=float(p0[1]), z=float(p0[2])),
                        Point(x=float(p1[0]), y=float(p1[1]), z=float(p1[2]))]
            m.scale.x, m.scale.y, m.scale.z = 0.002, 0.004, 0.004
            m.color.r, m.color.g, m.color.b, m.color.a = 0.1, 0.8, 0.1, 1.0  # green (Fig. III.5)
            markers.markers.append(m)
        self.pub_markers.publish(markers)

    def _diagnostics(self) -> None:
        c = self.core.counters
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        bad = c["qp_fallbacks"] or c["rejected_inputs"] or c["non_finite_outputs"]
        arr.status = [DiagnosticStatus(
            level=DiagnosticStatus.WARN if bad else DiagnosticStatus.OK, name="controller",
            message="running", values=[KeyValue(key=k, value=str(v))
                                       for k, v in {**c, **self.gate.values()}.items()])]
        self.pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    sys.exit(main())
