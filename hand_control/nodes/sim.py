"""sim: the MuJoCo world of a scenario, stepped at 1 ms, driven by joint commands.

Thin wrapper around :class:`hand_control.sim.world.SimWorld` (all logic lives there).

Topics:
    out  sim/joint_states (sensor_msgs/JointState: the hand's joints by model name, position
         [rad or m], velocity), sensor-data QoS, once per tick
    out  sim/object_pose (geometry_msgs/PoseStamped: the object's centre of mass, world)
    out  sim/object_twist (geometry_msgs/TwistStamped: its linear / angular velocity, world)
    out  sim/contacts (hand_msgs/ContactArray: every contact of the step; body1 is the hand
         bone for hand-object contacts; force applied by body1 on body2)
    out  /clock (rosgraph_msgs/Clock) with the simulation time when ``publish_clock``
    out  diagnostics (diagnostic_msgs/DiagnosticArray, 1 Hz: counters)
    in   control/joint_command (hand_msgs/JointCommand: position targets of the servos and
         feed-forward efforts, by joint name; unknown or duplicate names, length mismatches,
         NaN/Inf, positions outside the joint ranges and efforts outside the actuators' force
         limits are rejected, logged and counted, :mod:`hand_capture.validate`). Without a
         command for ``command_timeout`` the servos hold the last targets.
Stamps are simulation time. A divergence of the simulation is logged with its DoF and, by
``on_instability``, stops the node (raise) or resets the episode.
"""

from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped
from hand_msgs.msg import ContactArray, JointCommand
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.qos import newest_command_qos
from hand_capture.nodes.shell import run_node
from hand_capture.validate import validate_joint_command
from hand_control.control import CompositeControlConfig
from hand_control.errors import InputError
from hand_control.nodes.convert import contact_array, set_time
from hand_control.nodes.convert import stamp as _stamp
from hand_control.sim.config import SimConfig, SimNodeConfig
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import load_scenario


class SimNode(Node):
    """Publishes the simulated hand, object and contacts; applies joint commands."""

    def __init__(self, **kwargs) -> None:
        super().__init__("sim", **kwargs)
        self.cfg: SimNodeConfig = declare_config(self, SimNodeConfig)
        self.sim_cfg: SimConfig = declare_config(self, SimConfig)
        # the servos' PD gains (joint_kp, joint_kd: Table 1 = Table III.1 by default) go into
        # the world's MJCF; the controller node declares the same config
        self.gains: CompositeControlConfig = declare_config(self, CompositeControlConfig)
        spec = load_scenario(self.cfg.scenario)
        # the scenario's world, with the hand at the start of its reference motion
        self.runner = LockstepRunner(spec, self.sim_cfg, gains=self.gains)
        self.world = self.runner.world
        self.world.count_saturation = True
        self.object_name = self.runner.obj.name
        self.gate = InputGate(self)
        self._index = {n: i for i, n in enumerate(self.world.joint_names)}
        self.accepted = 0
        self.ticks = 0
        self.pub_js = self.create_publisher(JointState, "sim/joint_states",
                                            qos_profile_sensor_data)
        self.pub_pose = self.create_publisher(PoseStamped, "sim/object_pose",
                                              qos_profile_sensor_data)
        self.pub_twist = self.create_publisher(TwistStamped, "sim/object_twist",
                                               qos_profile_sensor_data)
        self.pub_contacts = self.create_publisher(ContactArray, "sim/contacts",
                                                  qos_profile_sensor_data)
        self.pub_clock = (self.create_publisher(Clock, "/clock", 10)
                          if self.cfg.publish_clock else None)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        # the newest command only: a tick that steps the world for longer than the command
        # period (a loaded CPU) would otherwise leave a backlog that the executor takes one
        # message per wake-up, and the hand would follow commands ever further behind
        self.create_subscription(JointCommand, "control/joint_command", self._on_command,
                                 newest_command_qos())
        dt = self.world.model.opt.timestep * self.cfg.steps_per_tick
        period = dt / self.sim_cfg.real_time_factor if self.sim_cfg.real_time else 1e-4
        self._wall0 = time.perf_counter()
        self._sim0 = self.world.time
        self.create_timer(period, self._tick)
        self.create_timer(1.0, self._diagnostics)
        self.get_logger().info(
            f"scenario {spec.name!r}: object {self.object_name!r}, {self.world.n_hand} hand "
            f"DoFs, step {self.world.model.opt.timestep * 1e3:.1f} ms, "
            f"{'real time' if self.sim_cfg.real_time else 'as fast as possible'}")

    # ----------------------------------------------------------------------------- inputs
    @property
    def rejected(self) -> int:
        """Joint commands rejected so far."""
        return self.gate.total

    def _on_command(self, msg: JointCommand) -> None:
        topic = "control/joint_command"
        w = self.world
        ok = self.gate.check(topic, validate_joint_command, msg.joint_names, msg.positions,
                             msg.velocities, msg.efforts, known=self._index)
        if ok is None:
            return
        names, pos, eff = ok
        try:  # the world refuses efforts outside its actuators' force limits
            w.command_by_name(names, pos, eff)
        except InputError as e:
            self.gate.reject(topic, e)
            return
        self.accepted += 1

    # ------------------------------------------------------------------------------- tick
    def _tick(self) -> None:
        n = self.cfg.steps_per_tick
        if self.sim_cfg.real_time:  # catch up with the wall clock, a bounded number of steps
            behind = ((time.perf_counter() - self._wall0) * self.sim_cfg.real_time_factor
                      - (self.world.time - self._sim0))
            n = int(min(max(behind / self.world.model.opt.timestep, 0), 10 * n))
            if n == 0:
                return
        self.world.step(n)  # SimulationError propagates: run_node reports it and exits 1
        self.ticks += 1
        self.publish_state()

    def publish_state(self) -> None:
        w = self.world
        t = w.time
        q, qd = w.hand_state()
        js = JointState()
        _stamp(js.header, t)
        js.name = list(w.joint_names)
        js.position = q.tolist()
        js.velocity = qd.tolist()
        self.pub_js.publish(js)
        op = w.object_pose(self.object_name)
        ps = PoseStamped()
        _stamp(ps.header, t)
        ps.header.frame_id = self.cfg.frame_id
        ps.pose.position.x, ps.pose.position.y, ps.pose.position.z = op.position.tolist()
        qw, qx, qy, qz = op.quaternion.tolist()
        o = ps.pose.orientation
        o.w, o.x, o.y, o.z = qw, qx, qy, qz
        self.pub_pose.publish(ps)
        tw = TwistStamped()
        tw.header = ps.header
        tw.twist.linear.x, tw.twist.linear.y, tw.twist.linear.z = op.linear_velocity.tolist()
        tw.twist.angular.x, tw.twist.angular.y, tw.twist.angular.z = \
            op.angular_velocity.tolist()
        self.pub_twist.publish(tw)
        self.pub_contacts.publish(contact_array(w.contacts(), t, self.cfg.frame_id))
        if self.pub_clock is not None:
            c = Clock()
            set_time(c.clock, t)
            self.pub_clock.publish(c)

    def _diagnostics(self) -> None:
        w = self.world
        wall = time.perf_counter() - self._wall0
        rtf = (w.time - self._sim0) / max(wall, 1e-9)
        values = {"sim_time": f"{w.time:.3f}", "real_time_factor": f"{rtf:.3f}",
                  "commands_accepted": str(self.accepted), "commands_rejected": str(self.rejected),
                  **self.gate.values(),
                  "command_timed_out": str(w.timed_out), "resets": str(w.resets),
                  "servo_saturated_steps": str(w.saturated_steps)}
        values.update({f"warning_{k}": str(v) for k, v in w.soft_warnings.items()})
        arr = DiagnosticArray()
        _stamp(arr.header, w.time)
        level = DiagnosticStatus.WARN if (self.rejected or w.resets) else DiagnosticStatus.OK
        arr.status = [DiagnosticStatus(level=level, name="sim", message="running",
                                       values=[KeyValue(key=k, value=v)
                                               for k, v in values.items()])]
        self.pub_diag.publish(arr)


def main(args: list[str] | None = None) -> int:
    return run_node(SimNode, args)


if __name__ == "__main__":
    sys.exit(main())
