"""servo_bridge: a lifecycle node that drives a DYNAMIXEL hand from the tracked, simulated or
commanded hand.

Thin wrapper around :class:`hand_control.dynamixel.bridge.ServoBridge` (all logic lives there).

Topics:
    in   hand/pose (hand_msgs/HandPose, source: tracked) or
         sim/joint_states (sensor_msgs/JointState, source: simulated), sensor-data QoS, or
         control/joint_command (hand_msgs/JointCommand, source: commanded; the controller's
         position targets, reliable), or
         robot/joint_command (hand_msgs/JointCommand, source: robot; the retargeting node's
         robot joints, reliable; with a servo map of joint_vocabulary: robot)
    out  servo/joint_states (sensor_msgs/JointState: servo angle [rad], velocity [rad/s],
         effort = motor current [A]; only servos read cleanly in that cycle)
    out  servo/goal (hand_msgs/JointCommand: the goals [rad] written to the bus in a cycle,
         stamped with the stamp of the input they come from, for per-stage latency)
    out  diagnostics (diagnostic_msgs/DiagnosticArray: bus state, loop rate, per-servo
         temperature, voltage, current, hardware error bits)
Cycles (sync read, then sync write of the goals) run when a new input arrives (at most about
    ``control_rate_hz``), and at ``control_rate_hz`` while no input comes.
Parameters: those of :class:`BridgeConfig`; ``goal_current_scale`` (grip strength in
    current-based position mode) may change while running, the others are read-only.
Service:
    ~/reboot (std_srvs/Trigger): reboot servos with a hardware error, or recover from a bus
         ERROR: the port is closed and opened again (a replugged USB adapter works), every
         servo pinged and set up, positions re-read before torque comes back on, and the node
         activated again.
Lifecycle: configure = open the port, ping and check every servo, write modes and limits;
    activate = torque on (after a good read, goal := present position; after a bus ERROR the
    port is reopened first); deactivate = torque off; cleanup/shutdown/error = torque off and
    close. A bus ERROR (``max_comm_failures`` failed cycles: adapter pulled, servo dead) takes
    the node from active to inactive with torque off, logs why, and diagnostics keep saying
    it until ``~/reboot`` or an activate recovers. With ``autostart: true`` (default) the
    node configures and activates itself. ``on_shutdown()``, which ``run_node`` calls on every
    exit path (Ctrl-C, SIGTERM, exception), switches torque off.
"""

from __future__ import annotations

import array
import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hand_msgs.msg import HandPose, JointCommand
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from hand_capture.nodes.gate import InputGate
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.qos import newest_command_qos, newest_sensor_qos
from hand_capture.nodes.shell import run_node
from hand_capture.validate import (
    validate_hand_pose_msg,
    validate_joint_command,
    validate_joint_state,
)
from hand_control.dynamixel.bridge import BridgeConfig, BridgeState, ServoBridge
from hand_control.errors import HandSuiteError

_SUCCESS = TransitionCallbackReturn.SUCCESS
_FAILURE = TransitionCallbackReturn.FAILURE


class ServoBridgeNode(LifecycleNode):
    """Lifecycle node wrapping :class:`ServoBridge`."""

    def __init__(self, **kwargs) -> None:
        super().__init__("servo_bridge", **kwargs)
        self.config: BridgeConfig = declare_config(self, BridgeConfig)
        self.core: ServoBridge | None = None
        self._last_error = ""
        self.gate = InputGate(self)  # rejected inputs, counted per topic (diagnostics)
        self._state_pub = None
        self._goal_pub = None
        self._input_stamp = None  # header stamp of the last accepted input
        self._sub = None
        self._srv = None
        self._control_timer = None
        self._timer_periods = 1.0  # the control timer's period in control periods
        self._last_cycle = 0.0  # time.monotonic() of the last control cycle [s]
        self._last_input = 0.0  # time.monotonic() of the last accepted input [s]
        self._pending = False  # a new input waits for its cycle (the timer is set for it)
        # messages reused every cycle (publish serialises them at once); names set once
        self._goal_msg: JointCommand | None = None
        self._state_msg: JointState | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._diag_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self._diag_timer = self.create_timer(1.0 / self.config.diagnostics_rate_hz,
                                             self._publish_diagnostics)
        self._retry_timer = None
        if self.config.autostart and not self._autostart() and self.config.autostart_retry_s:
            self._retry_timer = self.create_timer(self.config.autostart_retry_s,
                                                  self._retry_autostart)

    def _autostart(self) -> bool:
        """Configure (unless configured) and activate; whether the node is active. A failed
        activation (e.g. the first reads timing out on a loaded machine) is retried as a
        failed configure is: it leaves the node inactive with torque off."""
        if self._state_machine.current_state[1] == "unconfigured" \
                and self.trigger_configure() != _SUCCESS:
            return False
        return self.trigger_activate() == _SUCCESS

    def _retry_autostart(self) -> None:
        self.get_logger().info(f"retrying configure / activate (every "
                               f"{self.config.autostart_retry_s} s)", throttle_duration_sec=30.0)
        if self._autostart() and self._retry_timer is not None:
            self.destroy_timer(self._retry_timer)
            self._retry_timer = None

    # ------------------------------------------------------------------------ transitions
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.core = ServoBridge(self.config, logger=self.get_logger())
            self.core.set_goal_current_scale(self.get_parameter("goal_current_scale").value)
            self.core.configure()
        except HandSuiteError as e:
            self._last_error = str(e)
            self.get_logger().error(f"configure failed: {e}")
            if self.core is not None:
                self.core.close()
            self.core = None
            return _FAILURE
        self._state_pub = self.create_lifecycle_publisher(JointState, "servo/joint_states", 10)
        self._goal_pub = self.create_lifecycle_publisher(JointCommand, "servo/goal", 10)
        # every source the newest input only: a goal from a backlog is stale when it reaches
        # the motors (the executor takes one queued message per wake-up)
        if self.config.source == "tracked":
            self._sub = self.create_subscription(HandPose, "hand/pose", self._on_pose,
                                                 newest_sensor_qos())
        elif self.config.source == "commanded":
            self._sub = self.create_subscription(JointCommand, "control/joint_command",
                                                 self._on_command, newest_command_qos())
        elif self.config.source == "robot":
            self._sub = self.create_subscription(
                JointCommand, "robot/joint_command",
                lambda m: self._on_command(m, "robot/joint_command"), newest_command_qos())
        else:
            self._sub = self.create_subscription(JointState, "sim/joint_states",
                                                 self._on_joint_state, newest_sensor_qos())
        self._srv = self.create_service(Trigger, "~/reboot", self._on_reboot)
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.core.activate()
        except HandSuiteError as e:
            self._last_error = str(e)
            self.get_logger().error(f"activate failed: {e}")
            return _FAILURE
        self._control_timer = self.create_timer(1.0 / self.config.control_rate_hz,
                                                self._on_timer)
        self._timer_periods = 1.0
        self._pending = False
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_control()
        if self.core is not None:
            self.core.deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return super().on_cleanup(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return _SUCCESS

    def on_shutdown(self, state: LifecycleState | None = None) -> TransitionCallbackReturn:
        """Torque off and close; the lifecycle shutdown transition and ``run_node`` call it.

        From ``run_node`` (``state`` None) the subscription, service and publishers are left
        to ``destroy_node``, whose time ``run_node`` bounds: a DDS call here could hang in
        Fast DDS (README "Networking and safety") where nothing may cut the hook short."""
        if state is None:
            self._release_servos()
        else:
            self._teardown()
        return _SUCCESS

    def _stop_control(self) -> None:
        if self._control_timer is not None:
            self.destroy_timer(self._control_timer)
            self._control_timer = None

    def _release_servos(self) -> None:
        """No more control cycles; torque off, then close the port."""
        self._stop_control()
        if self.core is not None:
            self.core.close()

    def _teardown(self) -> None:
        self._release_servos()
        for ent, destroy in ((self._sub, self.destroy_subscription),
                             (self._srv, self.destroy_service)):
            if ent is not None:
                destroy(ent)
        for pub in (self._state_pub, self._goal_pub):
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
        self._sub = self._srv = self._state_pub = self._goal_pub = None
        self._goal_msg = self._state_msg = None

    # ---------------------------------------------------------------------------- callbacks
    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        # the only parameter that may change while running (the others are read-only)
        for p in params:
            if p.name == "goal_current_scale" and self.core is not None:
                self.core.set_goal_current_scale(float(p.value))
        return SetParametersResult(successful=True)

    def _on_pose(self, msg: HandPose) -> None:
        if self.core is None or self.gate.check("hand/pose", validate_hand_pose_msg,
                                                msg) is None:
            return
        valid = msg.status not in (HandPose.STATUS_UNKNOWN, HandPose.STATUS_LOST)
        hand = "left" if msg.handedness == HandPose.HAND_LEFT else "right"
        if self.core.handle_pose(msg.joint_names, msg.positions, handedness=hand,
                                 valid=valid):
            self._accepted(msg.header.stamp)

    def _on_joint_state(self, msg: JointState) -> None:
        if self.core is None or self.gate.check(
                "sim/joint_states", validate_joint_state, msg.name, msg.position,
                msg.velocity, msg.effort) is None:
            return
        if self.core.handle_joint_state(msg.name, msg.position):
            self._accepted(msg.header.stamp)

    def _on_command(self, msg: JointCommand, topic: str = "control/joint_command") -> None:
        if self.core is None or self.gate.check(
                topic, validate_joint_command, msg.joint_names,
                msg.positions, msg.velocities, msg.efforts) is None:
            return
        if not len(msg.positions):  # efforts only: no position targets for the servos
            return
        if self.core.handle_joint_state(msg.joint_names, msg.positions):
            self._accepted(msg.header.stamp)

    def _accepted(self, stamp) -> None:
        """A new input: run the cycle now rather than at the next tick, unless a cycle ran
        less than 0.9 of a period ago (the bus sees at most about ``control_rate_hz``). An
        input with a new stamp (new information from the source, e.g. a controller's answer
        to a new camera frame) waits at most until a quarter period after the last cycle."""
        new = stamp != self._input_stamp
        self._input_stamp = stamp
        now = time.monotonic()
        self._last_input = now
        if self._control_timer is None:
            return
        rate = self.config.control_rate_hz
        gap = (0.25 if new else 0.9) / rate
        since = now - self._last_cycle
        if since >= gap:
            self._on_control()
            # the fixed-rate cycle is only for times without input: it is due 1.5 periods
            # after this cycle, so inputs at about the control rate never wake the node twice
            self._set_timer_period(1.5)
        elif new:  # its cycle when the quarter period is over, not at the next fixed cycle
            self._pending = True
            self._set_timer_period((gap - since) * rate)

    def _on_timer(self) -> None:
        """A pending new input's cycle, or the fixed-rate cycle while no input drives the
        cycles (none for 1.5 periods)."""
        if self._pending:
            self._on_control()
            self._set_timer_period(1.5)
            return
        if time.monotonic() - self._last_input >= 1.5 / self.config.control_rate_hz:
            self._set_timer_period(1.0)
            self._on_control()

    def _set_timer_period(self, periods: float) -> None:
        """The control timer's next call ``periods`` control periods from now, and every
        ``periods`` after that until this is called again (the timer's period is only set
        when ``periods`` changes)."""
        timer = self._control_timer
        if timer is None:
            return
        if periods != self._timer_periods:
            self._timer_periods = periods
            timer.timer_period_ns = int(round(periods * 1e9 / self.config.control_rate_hz))
            timer.reset()
        elif periods != 1.0:
            timer.reset()

    def _on_control(self) -> None:
        self._last_cycle = time.monotonic()
        self._pending = False  # this cycle writes the newest input
        r = self.core.step() if self.core is not None else None
        if self.core is not None and self.core.state is BridgeState.ERROR:
            self._on_bus_error()
            return
        if r is None or self._state_pub is None:
            return
        if r.written and self._input_stamp is not None:
            goal = self._goal_msg
            if goal is None:
                goal = self._goal_msg = JointCommand(joint_names=list(self.core.names))
            goal.positions = _doubles(r.goal)
            goal.header.stamp = self._input_stamp
            self._goal_pub.publish(goal)
        if not r.fresh.any():
            return
        if r.fresh.all():  # the usual cycle: every servo read, the names of last time
            msg = self._state_msg
            if msg is None:
                msg = self._state_msg = JointState(name=list(self.core.names))
            pos, vel, cur = r.position, r.velocity, r.current
        else:
            idx = r.fresh.nonzero()[0]
            msg = JointState(name=[self.core.names[k] for k in idx])
            pos, vel, cur = r.position[idx], r.velocity[idx], r.current[idx]
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.position = _doubles(pos)
        msg.velocity = _doubles(vel)
        msg.effort = _doubles(cur)
        self._state_pub.publish(msg)

    def _lifecycle_state(self) -> str:
        return self._state_machine.current_state[1]

    def _on_bus_error(self) -> None:
        """The bridge entered its ERROR state (torque-off attempted): the lifecycle follows
        (active -> inactive), so managers and ``get_state`` see it, and the log says why."""
        self._last_error = self.core.error_reason
        self.get_logger().error(
            f"servo bus ERROR: {self.core.error_reason}; lifecycle: active -> inactive, torque "
            f"off. Fix the bus (replug the adapter, power the servos), then call ~/reboot or "
            f"activate: the port is reopened and every servo checked")
        if self._lifecycle_state() == "active":
            self.trigger_deactivate()

    def _on_reboot(self, request: Trigger.Request, response: Trigger.Response):
        if self.core is None:
            response.success, response.message = False, "not configured"
            return response
        ok, msg = self.core.reboot()
        if ok and self._lifecycle_state() == "inactive" and self._last_error:
            # deactivated by a bus ERROR, now recovered: back to active
            if self.trigger_activate() == _SUCCESS:
                self._last_error = ""
                msg += "; node active again"
            else:
                ok, msg = False, f"{msg}; activate failed: {self._last_error}"
        response.success, response.message = ok, msg
        return response

    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        if self.core is None:
            arr.status = [DiagnosticStatus(
                level=DiagnosticStatus.WARN, name="servo_bridge: bus",
                message=f"not configured{': ' + self._last_error if self._last_error else ''}",
                hardware_id=self.config.port)]
        else:
            for i, r in enumerate(self.core.diagnostics()):
                values = {**r.values, **self.gate.values()} if i == 0 else r.values
                arr.status.append(DiagnosticStatus(
                    level=bytes((r.level,)), name=r.name, message=r.message,
                    hardware_id=r.hardware_id,
                    values=[KeyValue(key=k, value=v) for k, v in values.items()]))
        self._diag_pub.publish(arr)


def _doubles(a) -> array.array:
    """A float64[] message field from a numpy array: one copy, no per-element checks."""
    return array.array("d", np.ascontiguousarray(a, dtype=np.float64).tobytes())


def main(args: list[str] | None = None) -> int:
    return run_node(ServoBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
