"""The servo bridge core: hand poses in, safe goal positions out, servo state back.

:class:`ServoBridge` owns the bus (:mod:`.bus`, through ``dynamixel_sdk``), the retargeting
(:mod:`.retarget`) and the safety logic (:mod:`.safety`). It has the lifecycle of a managed node:

* ``configure()``: open the port (``port: emulator`` starts an in-process emulator on a pty),
  ping every ID and check its model, switch torque off, write Operating Mode, position limits,
  Current Limit (EEPROM, only when they differ), Profile Velocity and goal current.
* ``activate()``: a good read of every servo first, goal := present position, then torque on.
  Nothing is written as a goal before that read (never zeros, never stale values).
* ``step()``: one control cycle: Sync Read of the state block, fault checks, then Sync Write of
  the filtered, clamped and rate-limited goals of the servos that answered cleanly.
* ``deactivate()`` / ``close()``: torque off. ``close`` is also the context manager's exit and
  an ``atexit`` backstop; nothing relies on ``__del__``.

Safety behaviours (each covered by a test with an injected fault):

* goals clamped to each servo's position limits; per-servo rate limit (``max_velocity_rad_s``);
* command timeout: no fresh input for ``command_timeout_s`` -> hold the last goal, or torque
  off (``timeout_action``); torque comes back, from the present position, when input resumes;
* a status packet with the Alert bit, or a non-zero Hardware Error Status(70) in the periodic
  poll -> that servo is switched off and no longer commanded; diagnostics name the bits; only
  :meth:`reboot` (the node's ``~/reboot`` service) clears it, re-reading the position first;
* ``max_comm_failures`` consecutive cycles with a failed read -> ERROR state, a torque-off
  attempt, no more goals until re-activation or :meth:`reboot`, which both reopen the port
  first (a replugged USB adapter works again) and check every servo;
* Fast Sync Read spoils every servo's data when one servo fails; the same cycle then reads
  with Sync Read (one status packet per servo) to name the failing ID(s), and stays on Sync
  Read while they fail (until re-activation), so the ERROR names the dead servo;
* optional Bus Watchdog(98): the servos stop by themselves if the bridge stops talking.

No rclpy here; the node (``hand_control/nodes/servo_bridge.py``) is a thin wrapper.
"""

from __future__ import annotations

import atexit
import contextlib
import enum
import logging
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hand_capture.config import param, validate
from hand_control.dynamixel import control_table as ct
from hand_control.dynamixel.bus import BAUD_RATES, DynamixelBus, ReadResult, usb_latency_warning
from hand_control.dynamixel.retarget import (
    LowPassFilter,
    Retargeter,
    angles_to_ticks,
    ticks_to_angles,
)
from hand_control.dynamixel.safety import FailureCounter, FaultLatch, GoalLimiter, InputWatchdog
from hand_control.dynamixel.servo_map import ServoMap, load_servo_map
from hand_control.errors import ConfigError, InputError, ServoError

EMULATOR_PORT = "emulator"
_EMULATOR_SWITCH_INTERVAL_S = 2e-4  # GIL switch interval with the in-process emulator [s]
#: Least packet timeout on the emulated bus [ms]: its replies come when the host schedules the
#: emulator thread, not after a wire's transmission time; on a loaded 2-core machine that took
#: over 20 ms five cycles in a row and put the bridge in its ERROR state, and over 100 ms once
#: (load average 10, the test suite at nice 10).
_EMULATOR_MIN_PACKET_TIMEOUT_MS = 500.0
#: Pings a servo gets before configure calls it missing: one lost or corrupted status packet
#: (noise on the bus at power-up, or the emulator thread starved on a loaded host, seen once
#: with five processes on two cores) must not fail the whole configure.
_PING_TRIES = 3

#: Layout of the state block read every cycle, Present Current(126) .. Present Temperature(146).
_STATE_DTYPE = np.dtype({
    "names": ["current", "velocity", "position", "voltage", "temperature"],
    "formats": ["<i2", "<i4", "<i4", "<u2", "u1"],
    "offsets": [ct.ADDR_PRESENT_CURRENT - ct.STATE_BLOCK_ADDR,
                ct.ADDR_PRESENT_VELOCITY - ct.STATE_BLOCK_ADDR,
                ct.ADDR_PRESENT_POSITION - ct.STATE_BLOCK_ADDR,
                ct.ADDR_PRESENT_VOLTAGE - ct.STATE_BLOCK_ADDR,
                ct.ADDR_PRESENT_TEMPERATURE - ct.STATE_BLOCK_ADDR],
    "itemsize": ct.STATE_BLOCK_LEN,
})


@dataclass(frozen=True)
class BridgeConfig:
    """Parameters of the servo bridge (ROS parameters of ``servo_bridge``, same names)."""

    servo_map: str = param("leap_hand", "servo map YAML: a path, or a name under "
                           "config/servo_maps (leap_hand, generic_3dof)", read_only=True)
    port: str = param(EMULATOR_PORT, "serial port of the bus, e.g. /dev/ttyUSB0 or "
                      "/dev/serial/by-id/...; 'emulator' starts an emulated bus on a pty",
                      read_only=True)
    baud: int = param(4_000_000, "baud rate [bit/s]", choices=BAUD_RATES, read_only=True)
    source: str = param("tracked", "input: tracked (hand/pose, HandPose), simulated "
                        "(sim/joint_states, JointState), commanded (control/joint_command, "
                        "the controller's position targets) or robot (robot/joint_command, "
                        "the retargeting node's robot joints; needs a servo map with "
                        "joint_vocabulary: robot)",
                        choices=("tracked", "simulated", "commanded", "robot"), read_only=True)
    control_rate_hz: float = param(200.0, "control loop rate (sync read + sync write) [Hz]",
                                   lo=1.0, hi=2000.0, read_only=True)
    filter_cutoff_hz: float = param(10.0, "low-pass cutoff on servo targets [Hz]; 0 = off",
                                    lo=0.0, hi=500.0, read_only=True)
    command_timeout_s: float = param(0.5, "input older than this triggers timeout_action [s]",
                                     lo=0.01, hi=60.0, read_only=True)
    timeout_action: str = param("hold", "on command timeout: hold the last goal, or "
                                "torque_off", choices=("hold", "torque_off"), read_only=True)
    max_comm_failures: int = param(5, "consecutive failed cycles before the ERROR state, "
                                   "a torque-off attempt and the node going inactive (~/reboot "
                                   "or activate reopens the port)", lo=1, hi=1000,
                                   read_only=True)
    packet_timeout_ms: float = param(20.0, "extra wait for a status packet beyond its "
                                     "transmission time [ms] (at least 500 with port: "
                                     "emulator)", lo=0.2, hi=1000.0, read_only=True)
    read_mode: str = param("auto", "state read: sync (Sync Read, any firmware), fast_sync "
                           "(Fast Sync Read: X330 fw >= 46, X430 fw >= 45), or auto (fast_sync "
                           "when every servo's firmware has it and a trial read works); a "
                           "failed Fast Sync Read is followed by a Sync Read naming the "
                           "failing servo",
                           choices=("auto", "sync", "fast_sync"), read_only=True)
    hw_status_every: int = param(50, "cycles between polls of Hardware Error Status(70) "
                                 "(the Alert bit is checked every cycle)", lo=1, hi=100000,
                                 read_only=True)
    bus_watchdog_ms: float = param(0.0, "Bus Watchdog(98): servos stop when the bridge is "
                                   "silent this long [ms], 20 ms steps; 0 = off",
                                   lo=0.0, hi=2540.0, read_only=True)
    return_delay_us: int = param(-1, "Return Delay Time(9) to write [us] (0..508, 2 us "
                                 "steps); -1 leaves the servos' setting", lo=-1, hi=508,
                                 read_only=True)
    reboot_timeout_s: float = param(2.0, "how long to wait for a rebooted servo [s]",
                                    lo=0.05, hi=30.0, read_only=True)
    diagnostics_rate_hz: float = param(2.0, "diagnostics publication rate [Hz]", lo=0.1,
                                       hi=50.0, read_only=True)
    goal_current_scale: float = param(1.0, "current_based_position mode: fraction of each "
                                      "servo's goal_current_ma commanded (grip strength); "
                                      "may change while running", lo=0.0, hi=1.0)
    autostart: bool = param(True, "configure and activate on start (no lifecycle manager "
                            "needed)", read_only=True)
    autostart_retry_s: float = param(
        2.0, "with autostart: retry a failed configure (bus not plugged in yet, servos not "
        "powered) or activate (first reads timed out) this often [s]; 0 = give up after the "
        "first try", lo=0.0, hi=60.0,
        read_only=True)
    emulator_return_delay_us: float = param(0.0, "return delay of the emulated servos [us] "
                                            "(port: emulator)", lo=0.0, hi=508.0,
                                            read_only=True)

    def __post_init__(self) -> None:
        validate(self)


class BridgeState(enum.Enum):
    CLOSED = "closed"  # port closed
    INACTIVE = "inactive"  # configured, torque off
    ACTIVE = "active"  # torque on, commanding
    ERROR = "error"  # communication lost; torque-off attempted; not commanding


@dataclass
class CycleResult:
    """Outcome of one control cycle, arrays in servo-map order (NaN where not read)."""

    t: float
    fresh: np.ndarray  # bool: a clean read this cycle
    position: np.ndarray  # servo angle [rad]
    velocity: np.ndarray  # [rad/s]
    current: np.ndarray  # [A]
    written: int  # servos that got a goal this cycle
    duration_s: float  # software time of the cycle
    goal: np.ndarray  # last goal written to each servo [rad] (NaN: none yet)


@dataclass
class DiagnosticReport:
    """One diagnostic status (maps 1:1 onto diagnostic_msgs/DiagnosticStatus)."""

    name: str
    level: int  # 0 OK, 1 WARN, 2 ERROR, 3 STALE
    message: str
    hardware_id: str = ""
    values: dict[str, str] = field(default_factory=dict)


OK, WARN, ERROR, STALE = 0, 1, 2, 3


class ServoBridge:
    """Hand poses -> DYNAMIXEL goals with limits, rate limits, timeouts and fault handling.

    Args:
        config: validated parameters.
        servo_map: a loaded map; default: ``load_servo_map(config.servo_map)``.
        clock: monotonic time source [s] (tests pass a fake one).
        logger: anything with ``info/warning/error(str)``; default the ``logging`` module's.
    """

    def __init__(self, config: BridgeConfig, servo_map: ServoMap | None = None,
                 clock: Callable[[], float] = time.monotonic, logger=None) -> None:
        self.config = config
        self.map = servo_map if servo_map is not None else load_servo_map(config.servo_map)
        self.clock = clock
        self.log = logger if logger is not None else logging.getLogger("servo_bridge")
        self.ids: tuple[int, ...] = self.map.ids
        self.names: tuple[str, ...] = self.map.names
        self._index = {i: k for k, i in enumerate(self.ids)}
        self._ids_arr = np.array(self.ids, dtype=int)
        n = len(self.ids)
        robot_map = self.map.joint_vocabulary == "robot"
        if robot_map != (config.source == "robot"):
            raise ConfigError(
                f"servo map {self.map.name!r} has joint_vocabulary "
                f"{self.map.joint_vocabulary!r} but source is {config.source!r}: source "
                "'robot' (robot/joint_command) goes with a robot-joint map (e.g. "
                "leap_hand_joints), the other sources with a hand-model map (e.g. leap_hand)")
        self.retarget = Retargeter(self.map)
        self.filter = LowPassFilter(config.filter_cutoff_hz)
        self.limiter = GoalLimiter(self.map)
        self.watchdog = InputWatchdog(config.command_timeout_s)
        self.failures = FailureCounter(config.max_comm_failures)
        self.faults = FaultLatch()
        self.state = BridgeState.CLOSED
        self.emulator = None
        self.bus: DynamixelBus | None = None
        self.port_name = ""
        self.latency_warning: str | None = None
        self.error_reason = ""
        self.timed_out = False
        self.read_mode = config.read_mode if config.read_mode != "auto" else "sync"
        self._chosen_read_mode = self.read_mode  # read_mode after configure (before fallback)
        self._timeout_ms = config.packet_timeout_ms
        self._needs_reopen = False  # the ERROR state: reopen the port before using it again
        self._lock = threading.RLock()
        self._target: np.ndarray | None = None  # servo angles [rad]
        self._torque = np.zeros(n, dtype=bool)
        self._t_cmd: float | None = None
        self._cycle = 0
        self._current_mode = self.map.operating_mode == "current_based_position"
        self._goal_current_full = np.array([s.goal_current_raw for s in self.map.servos])
        self._goal_current_scale = config.goal_current_scale
        self._goal_current_sent = np.full(n, -1)  # raw value acknowledged or sync-written
        self._pending_enable = np.zeros(n, dtype=bool)  # torque back on after a timeout
        # latest readings (raw units), NaN/None until read
        self.present = np.full(n, np.nan)  # ticks
        self.velocity_raw = np.full(n, np.nan)
        self.current_raw = np.full(n, np.nan)
        self.voltage_raw = np.full(n, np.nan)
        self.temperature = np.full(n, np.nan)
        self.last_comm = ["never read"] * n
        self.read_failures = np.zeros(n, dtype=int)
        self._cycle_t: deque[float] = deque(maxlen=500)
        self._cycle_dur: deque[float] = deque(maxlen=500)
        self._rejects: dict[str, float] = {}
        self.rejected: dict[str, int] = {}  # rejected inputs per kind (diagnostics)
        self.skipped_writes = 0  # servos due a goal that had none finite (logged, counted)
        self._skipped_last = 0  # ... in the last cycle
        self._atexit_registered = False
        self._cur_unit = np.array([s.model.current_unit_ma for s in self.map.servos]) / 1000.0

    # ------------------------------------------------------------------------------ lifecycle
    def configure(self) -> None:
        """Open the port, check every servo and write modes and limits (torque stays off).

        Raises:
            ServoError: the port cannot be opened, a servo does not answer or is of the wrong
                model, or a setting is refused; the port is closed again.
        """
        with self._lock:
            if self.state is not BridgeState.CLOSED:
                return
            try:
                self._open()
                self._check_servos()
                self._write_settings()
                self._choose_read_mode()
            except Exception:
                self._close_port()
                self._unregister_atexit()
                raise
            self.state = BridgeState.INACTIVE
            self.error_reason = ""
            self.log.info(f"servo bridge configured: {len(self.ids)} servos of map "
                          f"{self.map.name!r} on {self.port_name} at {self.config.baud} baud")

    def _open(self) -> None:
        cfg = self.config
        port = cfg.port
        timeout_ms = cfg.packet_timeout_ms
        if port == EMULATOR_PORT:
            from hand_control.dynamixel.emulator import BusEmulator

            self.emulator = BusEmulator.from_map(
                self.map, return_delay_us=cfg.emulator_return_delay_us)
            port = self.emulator.start()
            # dynamixel-sdk polls the port while it waits for a status packet, holding the
            # GIL; the in-process emulator thread must get it within a fraction of a
            # millisecond, not CPython's default 5 ms switch interval
            sys.setswitchinterval(min(sys.getswitchinterval(), _EMULATOR_SWITCH_INTERVAL_S))
            timeout_ms = max(timeout_ms, _EMULATOR_MIN_PACKET_TIMEOUT_MS)
        else:
            self.latency_warning = usb_latency_warning(port)
            if self.latency_warning:
                self.log.warning(self.latency_warning)
        self.port_name = port
        self._timeout_ms = timeout_ms
        self.bus = DynamixelBus(port, cfg.baud, timeout_ms)
        self.bus.open()
        if not self._atexit_registered:
            atexit.register(self.close)
            self._atexit_registered = True

    def _check_servos(self) -> None:
        bus = self._bus()
        missing, wrong = [], []
        for s in self.map.servos:
            for _ in range(_PING_TRIES):
                model, why = bus.ping(s.id)
                if model is not None:
                    break
            if model is None:
                missing.append(f"{s.id} ({s.name}: {why})")
            elif model != s.model.model_number:
                found = ct.MODELS_BY_NUMBER.get(model)
                wrong.append(f"{s.id} ({s.name}) is model number {model}"
                             f"{' = ' + found.name if found else ''}, map says {s.model.name} "
                             f"({s.model.model_number})")
        if missing or wrong:
            parts = []
            if missing:
                parts.append(f"no answer to ping from ID(s) {', '.join(missing)}")
            if wrong:
                parts.append("wrong model: " + "; ".join(wrong))
            raise ServoError(f"servo check on {self.port_name} failed: " + "; ".join(parts))

    def _write_settings(self) -> None:
        bus = self._bus()
        cfg = self.config
        mode = self.map.operating_mode_value
        for s in self.map.servos:
            bus.write(s.id, ct.ADDR_TORQUE_ENABLE, 1, 0)
            self._torque[self._index[s.id]] = False
            eeprom = [(ct.ADDR_OPERATING_MODE, 1, mode),
                      (ct.ADDR_MAX_POSITION_LIMIT, 4, s.max_position),
                      (ct.ADDR_MIN_POSITION_LIMIT, 4, s.min_position),
                      (ct.ADDR_CURRENT_LIMIT, 2, s.current_limit_raw)]
            if cfg.return_delay_us >= 0:
                eeprom.append((ct.ADDR_RETURN_DELAY, 1, cfg.return_delay_us // 2))
            for addr, size, value in eeprom:  # EEPROM: write only what differs
                if bus.read(s.id, addr, size)[0] != value:
                    bus.write(s.id, addr, size, value)
            bus.write(s.id, ct.ADDR_BUS_WATCHDOG, 1, 0)
            bus.write(s.id, ct.ADDR_PROFILE_VELOCITY, 4, s.profile_velocity_raw)
            if bus.read(s.id, ct.ADDR_OPERATING_MODE, 1)[0] != mode:
                raise ServoError(f"servo {s.id} ({s.name}): operating mode {mode} not taken")

    def _choose_read_mode(self) -> None:
        """Resolve ``read_mode: auto``: Fast Sync Read when every servo's firmware supports
        it and one trial read answers cleanly, else Sync Read."""
        if self.config.read_mode != "auto":
            self.read_mode = self.config.read_mode
            return
        bus = self._bus()
        old = [f"{s.id} (fw {fw})" for s in self.map.servos
               if (fw := bus.read(s.id, ct.ADDR_FIRMWARE_VERSION, 1)[0])
               < s.model.fast_sync_min_firmware]
        self.read_mode = "sync"
        if old:
            self.log.info(f"read mode: Sync Read (no Fast Sync Read in firmware of {old})")
            return
        trial = bus.fast_sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, self.ids)
        if all(r.ok for r in trial.values()):
            self.read_mode = "fast_sync"
        else:
            self.log.warning("Fast Sync Read trial failed; using Sync Read")
        self._chosen_read_mode = self.read_mode
        self.log.info(f"read mode: {self.read_mode}")

    def _reopen(self) -> None:
        """Close the port and open it again by name (a replugged USB adapter gets a new file
        descriptor under the same device path), then ping and check every servo and write the
        settings again (torque stays off): servos that lost power forgot their RAM settings.

        Raises:
            ServoError: the port cannot be opened, or a servo is missing or wrong.
        """
        if self.bus is not None:
            self.bus.close()
        self.bus = DynamixelBus(self.port_name, self.config.baud, self._timeout_ms)
        self.bus.open()
        self._check_servos()
        self._write_settings()
        self._needs_reopen = False
        self.log.info(f"servo port {self.port_name} reopened; every servo answered")

    def activate(self) -> None:
        """Read every servo, set goal := present position, then switch torque on.

        Raises:
            ServoError: not configured, or a servo did not answer the read (torque stays off).
        """
        with self._lock:
            if self.state is BridgeState.ACTIVE:
                return
            if self.state is BridgeState.CLOSED:
                raise ServoError("activate: the bridge is not configured")
            if self._needs_reopen:  # after a bus ERROR: a fresh port, every servo checked
                self._reopen()
            self.read_mode = self._chosen_read_mode
            now = self.clock()
            res, _ = self._read_state()
            bad = [f"{i} ({res[i].comm})" for i in self.ids if res[i].data is None]
            if bad:
                raise ServoError(f"activate: no good read from servo(s) {', '.join(bad)}; "
                                 "torque stays off")
            self._check_alerts(res, now)
            try:
                self._enable(np.ones(len(self.ids), dtype=bool), now)
            except ServoError:
                self._torque_off_all()
                raise
            self._target = ticks_to_angles(self.limiter.last)
            self.filter.reset(self._target)
            self.watchdog.arm(now)
            self.failures.reset()
            self.timed_out = False
            self._pending_enable[:] = False
            self.error_reason = ""
            self._t_cmd = now
            self.state = BridgeState.ACTIVE
            self.log.info("servo bridge active: torque on")

    def _enable(self, mask: np.ndarray, now: float) -> None:
        """Goal := present (clamped), then torque on, for ``mask`` servos without a fault."""
        bus = self._bus()
        mask = mask & np.isfinite(self.present)
        mask &= np.array([i not in self.faults for i in self.ids])
        goal = self.limiter.clamp(self.present)
        self.limiter.reset(goal, mask)
        if self.filter.y is not None:
            self.filter.y[mask] = ticks_to_angles(goal[mask])
        ids = [self.ids[k] for k in np.flatnonzero(mask)]
        for k in np.flatnonzero(mask):
            if goal[k] != self.present[k]:
                self.log.warning(f"servo {self.ids[k]} ({self.names[k]}) is outside its "
                                 f"position limits at {self.present[k]:.0f}; goal clamped to "
                                 f"{goal[k]:.0f}")
        current = self._goal_current()
        for i in ids:  # acknowledged writes: torque must not come on without its goal
            k = self._index[i]
            bus.write(i, ct.ADDR_GOAL_POSITION, 4, int(round(goal[k])))
            if self._current_mode:
                bus.write(i, ct.ADDR_GOAL_CURRENT, 2, int(current[k]))
                self._goal_current_sent[k] = current[k]
        wd = int(math.ceil(self.config.bus_watchdog_ms / ct.WATCHDOG_UNIT_MS))
        for i in ids:
            bus.write(i, ct.ADDR_TORQUE_ENABLE, 1, 1)
            self._torque[self._index[i]] = True
            if wd:
                bus.write(i, ct.ADDR_BUS_WATCHDOG, 1, 0)
                bus.write(i, ct.ADDR_BUS_WATCHDOG, 1, wd)

    def deactivate(self) -> None:
        """Torque off; the port stays open (lifecycle: active/error -> inactive)."""
        with self._lock:
            if self.state is BridgeState.CLOSED:
                return
            self._torque_off_all()
            self.state = BridgeState.INACTIVE
            self.log.info("servo bridge inactive: torque off")

    def close(self) -> None:
        """Torque off (best effort) and close the port; safe to call more than once."""
        with self._lock:
            if self.bus is not None and self.bus.is_open:
                try:
                    self._torque_off_all()
                except Exception as e:  # an exit path must go on
                    self.log.error(f"torque off on close failed: {e}")
            self._close_port()
            self.state = BridgeState.CLOSED
            self._unregister_atexit()

    def _unregister_atexit(self) -> None:
        if self._atexit_registered:
            atexit.unregister(self.close)
            self._atexit_registered = False

    def _close_port(self) -> None:
        if self.bus is not None:
            self.bus.close()
        if self.emulator is not None:
            self.emulator.stop()

    def __enter__(self) -> ServoBridge:
        self.configure()
        self.activate()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def torque_off(self) -> bool:
        """Switch torque off on every servo; True when every servo acknowledged."""
        with self._lock:
            return self._torque_off_all()

    def _torque_off_all(self) -> bool:
        bus = self.bus
        if bus is None or not bus.is_open:
            return False
        bus.recover()  # an interrupted transfer must not block the torque-off packets
        with contextlib.suppress(Exception):  # one packet all servos obey, then confirmations
            bus.sync_write(ct.ADDR_TORQUE_ENABLE, 1, {i: 0 for i in self.ids})
        failed = []
        for k, i in enumerate(self.ids):
            # acknowledged, with one retry: this runs on exit paths and after bus trouble
            if bus.try_write(i, ct.ADDR_TORQUE_ENABLE, 1, 0) or bus.try_write(
                    i, ct.ADDR_TORQUE_ENABLE, 1, 0):
                self._torque[k] = False
            else:
                failed.append(i)
            if self.config.bus_watchdog_ms > 0:
                bus.try_write(i, ct.ADDR_BUS_WATCHDOG, 1, 0)
        if failed:
            self.log.error(f"torque off: no acknowledgement from servo(s) {failed}")
        return not failed

    def _bus(self) -> DynamixelBus:
        if self.bus is None or not self.bus.is_open:
            raise ServoError("the servo port is not open")
        return self.bus

    # ---------------------------------------------------------------------------------- input
    def handle_pose(self, names: Sequence[str], positions: Sequence[float], *,
                    handedness: str | None = None, valid: bool = True,
                    now: float | None = None) -> bool:
        """A tracked hand pose (HandPose): set the servo targets. False when rejected.

        Args:
            handedness: "right"/"left" of the message; refused if the map is for the other.
            valid: False for poses without a valid estimate (lost tracking): ignored, and they
                do not refresh the command timeout.
        """
        if not valid:
            self._reject("pose", "pose without a valid estimate ignored")
            return False
        if handedness and self.map.handedness not in ("any", handedness):
            self._reject("hand", f"{handedness} hand pose ignored: servo map "
                         f"{self.map.name!r} is for a {self.map.handedness} hand")
            return False
        return self._set_from(names, positions, True, now)

    def handle_joint_state(self, names: Sequence[str], positions: Sequence[float],
                           now: float | None = None) -> bool:
        """Joint angles by name (a simulated JointState or a controller's JointCommand
        positions): names outside the vocabulary are ignored."""
        return self._set_from(names, positions, False, now)

    def _set_from(self, names: Sequence[str], positions: Sequence[float], strict: bool,
                  now: float | None) -> bool:
        try:
            theta = self.retarget.from_named(names, positions, strict)
        except InputError as e:
            self._reject("input", f"input rejected: {e}")
            return False
        with self._lock:
            self._target = theta
            self.watchdog.feed(self.clock() if now is None else now)
        return True

    def _reject(self, key: str, msg: str) -> None:
        self.rejected[key] = self.rejected.get(key, 0) + 1
        now = time.monotonic()
        if now - self._rejects.get(key, -math.inf) > 1.0:  # at most once a second per kind
            self._rejects[key] = now
            self.log.warning(msg)

    # ---------------------------------------------------------------------------------- cycle
    def _read_state(self) -> tuple[dict[int, ReadResult], np.ndarray]:
        """Read the state block of every servo: (per-ID results, mask of clean reads)."""
        bus = self._bus()
        if self.read_mode == "fast_sync":
            res = bus.fast_sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, self.ids)
            if not all(r.ok for r in res.values()):
                res = self._fast_sync_fallback(res)
        else:
            res = bus.sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, self.ids)
        fresh = np.zeros(len(self.ids), dtype=bool)
        for k, i in enumerate(self.ids):
            r = res[i]
            if r.ok:
                fresh[k] = True
                self.last_comm[k] = "ok"
            else:
                self.read_failures[k] += 1
                self.last_comm[k] = (ct.describe_packet_error(r.error) if r.error & 0x7F
                                     else r.comm)
        if fresh.any():
            blob = b"".join(res[self.ids[k]].data for k in np.flatnonzero(fresh))
            st = np.frombuffer(blob, dtype=_STATE_DTYPE)
            self.current_raw[fresh] = st["current"]
            self.velocity_raw[fresh] = st["velocity"]
            self.present[fresh] = st["position"]
            self.voltage_raw[fresh] = st["voltage"]
            self.temperature[fresh] = st["temperature"]
        return res, fresh

    def _fast_sync_fallback(self, fast: dict[int, ReadResult]) -> dict[int, ReadResult]:
        """A failed Fast Sync Read (one packet for all: any servo's fault spoils every ID):
        read again with Sync Read, whose per-servo status packets show who failed. While
        servos fail, stay on Sync Read (a Fast Sync Read would time out every cycle first)."""
        why = next(r.comm for r in fast.values() if not r.ok)
        res = self._bus().sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, self.ids)
        bad = [f"{i} ({self.names[self._index[i]]}: {res[i].comm})" for i in self.ids
               if not res[i].ok]
        if bad:
            self.read_mode = "sync"
            self.log.warning(f"Fast Sync Read failed ({why}); Sync Read: no clean answer from "
                             f"servo(s) {', '.join(bad)}; reading with Sync Read until "
                             f"re-activation")
        else:
            self._reject("fast_sync", f"Fast Sync Read failed ({why}); every servo answered "
                                      f"the Sync Read that followed")
        return res

    def _check_alerts(self, res: dict[int, ReadResult], now: float) -> None:
        """Alert bit in a status packet -> read Hardware Error Status(70) of that servo."""
        for i in self.ids:
            r = res.get(i)
            if r is not None and r.data is not None and r.error & ct.ERROR_ALERT:
                if i in self.faults:
                    continue
                try:
                    bits = self._bus().read(i, ct.ADDR_HARDWARE_ERROR, 1)[0]
                except ServoError as e:  # the alert stays set: tried again next cycle
                    self.log.warning(f"servo {i}: alert bit set, status read failed: {e}")
                    continue
                if bits:
                    self._latch(i, bits, now)

    def _poll_hardware_status(self, now: float) -> None:
        res = self._bus().sync_read(ct.ADDR_HARDWARE_ERROR, 1, self.ids)
        for i, r in res.items():
            if r.data is not None and r.data[0] and i not in self.faults:
                self._latch(i, r.data[0], now)

    def _latch(self, dxl_id: int, bits: int, now: float) -> None:
        if self.faults.set(dxl_id, bits, now):
            k = self._index[dxl_id]
            self.log.error(f"servo {dxl_id} ({self.names[k]}): hardware error: "
                           f"{ct.describe_hardware_error(bits)}; "
                           "no longer commanded, torque off; call the reboot service to clear")
            if self._bus().try_write(dxl_id, ct.ADDR_TORQUE_ENABLE, 1, 0):
                self._torque[k] = False

    def step(self, now: float | None = None) -> CycleResult | None:
        """One control cycle; None unless active. Never raises for bus faults (they are
        counted and reported); raises only for programming errors."""
        with self._lock:
            if self.state is not BridgeState.ACTIVE:
                return None
            t0 = time.perf_counter()
            now = self.clock() if now is None else now
            res, fresh = self._read_state()
            if self.failures.record(bool(fresh.all())):
                self._enter_error(now, res)
                return self._result(now, fresh, 0, t0)
            self._check_alerts(res, now)
            self._cycle += 1
            if self._cycle % self.config.hw_status_every == 0:
                self._poll_hardware_status(now)
            written = self._command(now, fresh)
            return self._result(now, fresh, written, t0)

    def _goal_current(self) -> np.ndarray:
        return np.rint(self._goal_current_full * self._goal_current_scale).astype(int)

    def set_goal_current_scale(self, scale: float) -> None:
        """Change the commanded fraction of each servo's goal current (grip strength); sent
        with the next cycle's Sync Write of Goal Current (current_based_position mode)."""
        if not 0.0 <= scale <= 1.0:
            raise ValueError(f"goal_current_scale = {scale} is out of range [0, 1]")
        with self._lock:
            self._goal_current_scale = float(scale)

    def _rearm_bus_watchdog(self, now: float) -> None:
        """After a gap longer than Bus Watchdog(98) the servos have stopped and refuse goals
        until the watchdog is cleared: clear and set it again (their goal stays where they
        stopped, and the rate limit continues from the last goal)."""
        wd = int(math.ceil(self.config.bus_watchdog_ms / ct.WATCHDOG_UNIT_MS))
        if not wd or self._t_cmd is None:
            return
        gap = now - self._t_cmd
        if gap * 1000.0 < 0.8 * wd * ct.WATCHDOG_UNIT_MS:
            return
        self.log.warning(f"{gap * 1000:.0f} ms without a cycle (bus watchdog "
                         f"{wd * ct.WATCHDOG_UNIT_MS:.0f} ms): re-arming the watchdog")
        bus = self._bus()
        for k in np.flatnonzero(self._torque):
            bus.try_write(self.ids[k], ct.ADDR_BUS_WATCHDOG, 1, 0)
            bus.try_write(self.ids[k], ct.ADDR_BUS_WATCHDOG, 1, wd)

    def _command(self, now: float, fresh: np.ndarray) -> int:
        self._rearm_bus_watchdog(now)
        expired = self.watchdog.expired(now)
        if expired and not self.timed_out:
            self.timed_out = True
            age = self.watchdog.age(now)
            self.log.warning(f"no input for {age:.2f} s (command_timeout_s = "
                             f"{self.config.command_timeout_s}): {self.config.timeout_action}")
            if self.config.timeout_action == "torque_off":
                self._torque_off_all()
            else:  # hold: freeze the target at the last goals
                self._target = ticks_to_angles(self.limiter.last)
                self.filter.reset(self._target)
        elif not expired and self.timed_out:
            self.timed_out = False
            self.log.info("input resumed")
            if self.config.timeout_action == "torque_off":
                self._pending_enable[:] = True
        if self._pending_enable.any():
            self._resume(fresh, now)
        if self.timed_out:
            self._t_cmd = now
            return 0
        dt = min(max(now - (self._t_cmd if self._t_cmd is not None else now), 0.0), 0.1)
        self._t_cmd = now
        theta = self.filter(self._target, dt)
        writable = fresh & self._torque
        goal = self.limiter(angles_to_ticks(theta), dt, writable)
        idx = np.flatnonzero(writable & np.isfinite(goal))
        self._skipped_last = int(np.count_nonzero(writable)) - idx.size
        if self._skipped_last:  # never silent: a servo due a goal got none
            self.skipped_writes += self._skipped_last
            self._reject("skip", f"{self._skipped_last} servo(s) not written: no finite goal "
                         f"({self.skipped_writes} skipped writes so far)")
        values = dict(zip(self._ids_arr[idx].tolist(), np.rint(goal[idx]).astype(int).tolist(),
                          strict=True))
        if self._current_mode:  # Goal Current, only when it changed
            current = self._goal_current()
            todo = np.flatnonzero(writable & (current != self._goal_current_sent))
            if todo.size and self._bus().sync_write(
                    ct.ADDR_GOAL_CURRENT, 2,
                    dict(zip(self._ids_arr[todo].tolist(), current[todo].tolist(), strict=True))):
                self._goal_current_sent[todo] = current[todo]
        if values:
            self._bus().sync_write(ct.ADDR_GOAL_POSITION, 4, values)
        return len(values)

    def _resume(self, fresh: np.ndarray, now: float) -> None:
        """Torque back on after a torque-off timeout, from the present position, for the
        servos read cleanly this cycle; the others follow in later cycles."""
        self._pending_enable &= np.array([i not in self.faults for i in self.ids])
        todo = self._pending_enable & fresh
        if not todo.any():
            return
        try:
            self._enable(todo, now)
            self._pending_enable &= ~todo
        except ServoError as e:  # retried next cycle; never raised out of the loop
            self.log.warning(f"torque on after the timeout failed, retrying: {e}")
            self._pending_enable &= ~self._torque

    def _enter_error(self, now: float, res: dict[int, ReadResult]) -> None:
        silent = [f"{i} ({res[i].comm})" for i in self.ids if res[i].data is None]
        self.error_reason = (f"{self.failures.consecutive} consecutive failed cycles "
                             f"(max_comm_failures = {self.config.max_comm_failures}); last "
                             f"failures: {', '.join(silent)}")
        self.log.error(f"servo bus ERROR: {self.error_reason}; torque-off attempt")
        self._torque_off_all()
        self.state = BridgeState.ERROR
        self._needs_reopen = True

    def _result(self, now: float, fresh: np.ndarray, written: int, t0: float) -> CycleResult:
        pos = ticks_to_angles(self.present)
        vel = self.velocity_raw * ct.VELOCITY_UNIT_RAD_S
        cur = self.current_raw * self._cur_unit
        if not fresh.all():  # not read this cycle: NaN, never the previous value
            for a in (pos, vel, cur):
                a[~fresh] = np.nan
        dur = time.perf_counter() - t0
        self._cycle_t.append(now)
        self._cycle_dur.append(dur)
        goal = ticks_to_angles(np.asarray(self.limiter.last, dtype=float))
        return CycleResult(now, fresh, pos, vel, cur, written, dur, goal)

    # --------------------------------------------------------------------------------- reboot
    def reboot(self, ids: Sequence[int] | None = None) -> tuple[bool, str]:
        """Reboot servos with a latched hardware error (or ``ids``) and bring them back.

        Each rebooted servo is pinged until it answers, gets its RAM settings again, has its
        present position read, goal := that position, and only then torque on (when active).
        From the ERROR state, a reboot (even of no servo) reopens the port (a replugged adapter
        works again), checks every servo, re-reads them and resumes; inactive after an ERROR
        (the node's lifecycle went to inactive), it reopens and checks, and activation
        resumes. Returns (success, message) for the caller (the node's std_srvs/Trigger
        service).
        """
        with self._lock:
            if self.state is BridgeState.CLOSED:
                return False, "not configured"
            if self._needs_reopen:
                try:
                    self._reopen()
                except ServoError as e:
                    return False, f"bus still failing: {e}"
                if self.state is BridgeState.INACTIVE:
                    return True, "port reopened, every servo answered; activate to resume"
            targets = list(ids) if ids is not None else sorted(self.faults.faults)
            unknown = [i for i in targets if i not in self._index]
            if unknown:
                return False, f"unknown servo ID(s) {unknown}; map IDs: {list(self.ids)}"
            msgs = []
            ok = True
            for i in targets:
                try:
                    self._reboot_one(i)
                    msgs.append(f"servo {i} rebooted")
                except ServoError as e:
                    ok = False
                    msgs.append(str(e))
            if self.state is BridgeState.ERROR:
                now = self.clock()
                res, _ = self._read_state()
                bad = [i for i in self.ids if res[i].data is None]
                if bad:
                    return False, "; ".join(msgs + [f"still no answer from {bad}"])
                self._check_alerts(res, now)
                self.state = BridgeState.INACTIVE
                try:
                    self.activate()
                except ServoError as e:
                    return False, "; ".join(msgs + [str(e)])
                msgs.append("bus recovered, active again")
            if not msgs:
                msgs.append("no servo with a hardware error; nothing to reboot")
            return ok, "; ".join(msgs)

    def _reboot_one(self, dxl_id: int) -> None:
        bus = self._bus()
        k = self._index[dxl_id]
        s = self.map.servos[k]
        self._torque[k] = False
        bus.reboot(dxl_id)
        deadline = time.monotonic() + self.config.reboot_timeout_s
        while bus.ping(dxl_id)[0] is None:
            if time.monotonic() > deadline:
                raise ServoError(f"servo {dxl_id} did not answer within "
                                 f"{self.config.reboot_timeout_s} s of its reboot")
        bits = bus.read(dxl_id, ct.ADDR_HARDWARE_ERROR, 1)[0]
        if bits:
            raise ServoError(f"servo {dxl_id} still reports {ct.describe_hardware_error(bits)}"
                             " after its reboot")
        bus.write(dxl_id, ct.ADDR_PROFILE_VELOCITY, 4, s.profile_velocity_raw)
        self.present[k] = bus.read(dxl_id, ct.ADDR_PRESENT_POSITION, 4, signed=True)[0]
        self.faults.clear(dxl_id)
        if self.state is BridgeState.ACTIVE:
            mask = np.zeros(len(self.ids), dtype=bool)
            mask[k] = True
            self._enable(mask, self.clock())

    # ---------------------------------------------------------------------------- diagnostics
    def loop_stats(self) -> tuple[float, float, float]:
        """(loop rate [Hz], cycle time p50 [ms], p99 [ms]) over the recent cycles."""
        ts, ds = list(self._cycle_t), list(self._cycle_dur)
        rate = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else 0.0
        if not ds:
            return rate, float("nan"), float("nan")
        p50, p99 = np.percentile(ds, [50, 99]) * 1e3
        return rate, float(p50), float(p99)

    def diagnostics(self) -> list[DiagnosticReport]:
        """Bus-level and per-servo status: temperature, voltage, current, error bits, rate."""
        with self._lock:
            now = self.clock()
            rate, p50, p99 = self.loop_stats()
            level = {BridgeState.ACTIVE: OK, BridgeState.INACTIVE: OK,
                     BridgeState.CLOSED: WARN, BridgeState.ERROR: ERROR}[self.state]
            msg = self.state.value
            if self.state is BridgeState.ERROR:
                msg = f"error: {self.error_reason}"
            elif self.state is BridgeState.INACTIVE and self._needs_reopen:
                level = ERROR  # deactivated because of the bus ERROR: still not recovered
                msg = (f"inactive after a bus error: {self.error_reason}; reboot or activate "
                       f"reopens the port")
            elif self.timed_out:
                level = max(level, WARN)
                msg += f", command timeout ({self.config.timeout_action})"
            if self.faults:
                level = max(level, WARN)
                msg += f", {len(self.faults.faults)} servo(s) with hardware errors"
            if self.state is BridgeState.ACTIVE and self._skipped_last:
                level = max(level, ERROR)  # torque on, yet not commanding: never "active"
                msg = msg.replace("active", f"torque on, {self._skipped_last} servo(s) not "
                                  "written (no finite goal)", 1)
            if self.latency_warning:
                level = max(level, WARN)
            age = self.watchdog.age(now)
            reports = [DiagnosticReport(
                name=f"servo_bridge: bus {self.map.name}", level=level, message=msg,
                hardware_id=self.port_name or self.config.port,
                values={
                    "state": self.state.value,
                    "port": self.port_name or self.config.port,
                    "baud": str(self.config.baud),
                    "source": self.config.source,
                    "read_mode": self.read_mode,
                    "loop_rate_hz": f"{rate:.1f}",
                    "cycle_p50_ms": f"{p50:.3f}",
                    "cycle_p99_ms": f"{p99:.3f}",
                    "consecutive_comm_failures": str(self.failures.consecutive),
                    "total_comm_failures": str(self.failures.total),
                    "input_age_s": "never" if math.isinf(age) else f"{age:.3f}",
                    "latency_timer": self.latency_warning or "ok",
                    "skipped_writes": str(self.skipped_writes),
                    "rejected_inputs": str(sum(v for k, v in self.rejected.items()
                                               if k != "skip")),
                })]
            for k, s in enumerate(self.map.servos):
                fault = self.faults.faults.get(s.id)
                lvl, text = OK, "ok"
                if fault is not None:
                    lvl = ERROR
                    text = f"hardware error: {fault.description}; reboot to clear"
                elif self.last_comm[k] not in ("ok", "never read"):
                    lvl, text = WARN, f"last read: {self.last_comm[k]}"
                elif self.temperature[k] >= s.model.temperature_limit - 10:
                    lvl, text = WARN, f"hot: {self.temperature[k]:.0f} C"
                reports.append(DiagnosticReport(
                    name=f"servo_bridge: {s.name}", level=lvl, message=text,
                    hardware_id=f"{s.model.name} id {s.id}",
                    values={
                        "id": str(s.id),
                        "model": s.model.name,
                        "torque": "on" if self._torque[k] else "off",
                        "position_rad": f"{ct.ticks_to_rad(self.present[k]):.4f}",
                        "temperature_c": f"{self.temperature[k]:.0f}",
                        "voltage_v": f"{self.voltage_raw[k] * ct.VOLTAGE_UNIT_V:.1f}",
                        "current_a": f"{self.current_raw[k] * self._cur_unit[k]:.3f}",
                        "hardware_error": fault.description if fault else "none",
                        "read_failures": str(self.read_failures[k]),
                        "last_comm": self.last_comm[k],
                    }))
            return reports
