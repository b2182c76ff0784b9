"""A DYNAMIXEL Protocol 2.0 multi-servo emulator on a pseudo-terminal.

The emulator plays the device side of a servo bus: it opens a pty (``pty.openpty``), answers on
the master end, and the bridge (or any program using the real ``dynamixel_sdk``) opens the slave
end as its serial port. It implements:

* the packet layer: header search, CRC-16, byte stuffing, status packets with an error byte
  whose bit 7 (Alert) is set while Hardware Error Status(70) is non-zero;
* instructions Ping (also broadcast), Read, Write, Reboot, Sync Read, Sync Write, Fast Sync
  Read, Bulk Read, Bulk Write and Fast Bulk Read (e-manual, Protocol 2.0: Bulk parameters are
  ``ID ADDR_L ADDR_H LEN_L LEN_H`` per device, Bulk Write followed by the data; Bulk Read is
  answered by one status packet per device, Fast Bulk Read by one packet with
  ``ERR ID DATA CRC`` per device, as Fast Sync Read); anything else is answered with
  Instruction Error;
* a control table per model (addresses of the X-series e-manual tables, EEPROM locked while
  torque is on, read-only items, range checks (Data Range Error, e.g. LED = 2) and limit
  checks (Data Limit Error), Status Return Level, Return Delay Time,
  Bus Watchdog);
* a motor: first-order motion of Present Position toward Goal Position (time constant ``tau``),
  limited by Profile Velocity or Velocity Limit; Present Current follows the position error,
  clipped to Goal Current / Current Limit;
* fault injection: hardware error bits (which switch torque off as the Shutdown setting does),
  no reply, a corrupted CRC, a missing ID, an external push of the position.

Run standalone to get a bus for any program::

    python -m hand_control.dynamixel.emulator --map leap_hand
    # prints the pty path, e.g. /dev/pts/5; Ctrl-C stops it

No rclpy here: tests and the bridge's ``port: emulator`` mode start it as a thread.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import pty
import select
import signal
import struct
import sys
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from hand_control.dynamixel import protocol as p2
from hand_control.dynamixel.control_table import (
    ITEMS,
    MODELS,
    OPERATING_MODES,
    POSITION_CENTER,
    WATCHDOG_UNIT_MS,
    ModelSpec,
)

_TABLE_SIZE = 700  # XM430 indirect data reaches address 661
_TICKS_PER_S_PER_VEL_UNIT = 0.229 / 60.0 * 4096.0  # 0.229 rev/min in ticks/s
_ADDR = {name: v[0] for name, v in ITEMS.items()}
_SIZE = {name: v[1] for name, v in ITEMS.items()}
_SIGNED = {name: v[2] for name, v in ITEMS.items()}
_FORMATS = {(1, False): "<B", (1, True): "<b", (2, False): "<H", (2, True): "<h",
            (4, False): "<I", (4, True): "<i"}
# item -> (unpack_from, address) and (pack_into, address, mask): the little-endian items of the
# table read and written in place (set() stores the two's complement, as protocol.u_le does)
_GET = {n: (struct.Struct(_FORMATS[(s, sg)]).unpack_from, a)
        for n, (a, s, sg, *_r) in ITEMS.items()}
_SET = {n: (struct.Struct(_FORMATS[(s, False)]).pack_into, a, (1 << (8 * s)) - 1)
        for n, (a, s, *_r) in ITEMS.items()}
# address -> item name, for every byte of every item (write checks)
_BYTE_OWNER: dict[int, str] = {}
for _n, (_a, _s, *_r) in ITEMS.items():
    for _k in range(_a, _a + _s):
        _BYTE_OWNER[_k] = _n
_I8 = struct.Struct("<b").unpack_from
_U16 = struct.Struct("<H").unpack_from
_I16 = struct.Struct("<h").unpack_from
_U32 = struct.Struct("<I").unpack_from
_I32 = struct.Struct("<i").unpack_from
_LIMITS = struct.Struct("<II").unpack_from  # Max Position Limit(48), Min Position Limit(52)
_TICK_MOVING = struct.Struct("<HB").pack_into  # Realtime Tick(120), Moving(122)
_PRESENT = struct.Struct("<HII").pack_into  # Present Current(126), Velocity(128), Position(132)
_OWNERS: dict[tuple[int, int], tuple[str, ...]] = {}  # (address, end) -> items touched


def _owners(addr: int, end: int) -> tuple[str, ...]:
    """The items a write of bytes [addr, end) touches, in address order (cached)."""
    names = _OWNERS.get((addr, end))
    if names is None:
        found: list[str] = []
        for k in range(addr, end):
            n = _BYTE_OWNER.get(k)
            if n is not None and (not found or found[-1] != n):
                found.append(n)
        names = _OWNERS[(addr, end)] = tuple(found)
    return names


_GOALS = ("goal_pwm", "goal_current", "goal_velocity", "goal_position")
#: Fixed value ranges of the X-series e-manual control tables; a write outside is answered with
#: Data Range Error (model-dependent ranges and limits are checked in ``_check_value``).
_RANGES = {
    "id": (0, 252), "baud_rate": (0, 7), "return_delay_time": (0, 254),
    "drive_mode": (0, 13), "secondary_id": (0, 255), "protocol_type": (1, 2),
    "homing_offset": (-1_044_479, 1_044_479), "moving_threshold": (0, 1023),
    "velocity_limit": (0, 2047),
    "temperature_limit": (0, 100), "max_voltage_limit": (31, 160),
    "min_voltage_limit": (31, 160), "pwm_limit": (0, 885), "startup_configuration": (0, 3),
    "torque_enable": (0, 1), "led": (0, 1), "status_return_level": (0, 2),
    "velocity_i_gain": (0, 16383), "velocity_p_gain": (0, 16383),
    "position_d_gain": (0, 16383), "position_i_gain": (0, 16383),
    "position_p_gain": (0, 16383), "bus_watchdog": (0, 127),
    "profile_acceleration": (0, 32767), "profile_velocity": (0, 32767),
}


@dataclass
class EmulatedServo:
    """One servo: its control table, its motor state and its injected faults."""

    dxl_id: int
    model: ModelSpec
    firmware: int = 52
    tau: float = 0.03  # motor time constant [s]
    position: float = float(POSITION_CENTER)  # [tick]
    table: bytearray = field(default_factory=lambda: bytearray(_TABLE_SIZE))
    # faults
    no_reply: bool = False
    bad_crc: int = 0  # replies left to corrupt (-1: all)
    present: bool = True
    # motor / timing state
    velocity: float = 0.0  # [tick/s]
    t_last: float = field(default_factory=time.perf_counter)
    t_comm: float = field(default_factory=time.perf_counter)
    reboot_until: float = 0.0

    def __post_init__(self) -> None:
        self.factory_reset()

    # -- control table ------------------------------------------------------------------------
    def get(self, name: str) -> int:
        unpack, a = _GET[name]
        return unpack(self.table, a)[0]

    def set(self, name: str, value: int) -> None:
        pack, a, mask = _SET[name]
        pack(self.table, a, int(value) & mask)

    def factory_reset(self) -> None:
        """Initial values of the e-manual tables (EEPROM and RAM)."""
        m = self.model
        self.table[:] = bytes(_TABLE_SIZE)
        self.set("model_number", m.model_number)
        self.set("firmware_version", self.firmware)
        self.set("id", self.dxl_id)
        self.set("baud_rate", 1)
        self.set("return_delay_time", 250)
        self.set("operating_mode", OPERATING_MODES["position"])
        self.set("protocol_type", 2)
        self.set("moving_threshold", 10)
        self.set("temperature_limit", m.temperature_limit)
        self.set("max_voltage_limit", 140)
        self.set("min_voltage_limit", 35)
        self.set("pwm_limit", 885)
        self.set("current_limit", m.max_current_limit)
        self.set("velocity_limit", m.velocity_limit)
        self.set("max_position_limit", m.max_position)
        self.set("min_position_limit", m.min_position)
        self.set("shutdown", 52)  # overload | electrical shock | overheating
        self._reset_ram()

    def _reset_ram(self) -> None:
        self.table[64:_TABLE_SIZE] = bytes(_TABLE_SIZE - 64)
        self.set("status_return_level", 2)
        self.set("position_p_gain", 800)
        self.set("velocity_p_gain", 100)
        self.set("velocity_i_gain", 1920)
        self.set("goal_current", self.get("current_limit"))
        self.set("goal_position", int(round(self.position)))
        self.set("present_input_voltage", self.model.nominal_voltage)
        self.set("present_temperature", 30)
        self.velocity = 0.0
        self._publish_state(0.0)

    # -- motor ----------------------------------------------------------------------------------
    def update(self, now: float) -> None:
        """Advance the motor to ``now``: watchdog, first-order motion, present values."""
        dt = now - self.t_last
        self.t_last = now
        t = self.table
        wd = _I8(t, 98)[0]  # Bus Watchdog(98)
        if wd > 0 and (now - self.t_comm) * 1000.0 > wd * WATCHDOG_UNIT_MS:
            self.set("bus_watchdog", -1)  # fired: stop and refuse goals until cleared
            self.set("goal_position", int(round(self.position)))
        torque = t[64] == 1
        err = 0.0
        if torque and dt > 0:
            hi, lo = _LIMITS(t, 48)  # Max / Min Position Limit(48, 52)
            goal = float(min(max(_I32(t, 116)[0], lo), hi))  # Goal Position(116)
            err = goal - self.position
            new = goal - err * math.exp(-dt / self.tau)
            prof = _U32(t, 112)[0]  # Profile Velocity(112), else Velocity Limit(44)
            vmax = (prof or _U32(t, 44)[0] or 1023) * _TICKS_PER_S_PER_VEL_UNIT
            step = max(-vmax * dt, min(vmax * dt, new - self.position))
            self.position += step
            self.velocity = step / dt
            err = goal - self.position
        elif not torque:
            self.velocity = 0.0
        self._publish_state(err)

    def _publish_state(self, pos_err: float) -> None:
        t = self.table
        limit = _U16(t, 38)[0]  # Current Limit(38)
        if t[11] in (0, 5):  # current-based modes: Goal Current(102) limits too
            limit = min(limit, abs(_I16(t, 102)[0]))
        current = 0 if t[64] != 1 else max(-limit, min(limit, int(2.0 * pos_err)))
        # Realtime Tick(120), Moving(122); Present Current(126), Velocity(128), Position(132)
        _TICK_MOVING(t, 120, int(self.t_last * 1000.0) % 32768, int(abs(self.velocity) > 1.0))
        _PRESENT(t, 126, current & 0xFFFF,
                 int(round(self.velocity / _TICKS_PER_S_PER_VEL_UNIT)) & 0xFFFFFFFF,
                 int(round(self.position)) & 0xFFFFFFFF)

    # -- access with protocol checks ---------------------------------------------------------
    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        if addr < 0 or length < 0 or addr + length > _TABLE_SIZE:
            return p2.ERR_DATA_RANGE, bytes(length)
        return 0, bytes(self.table[addr:addr + length])

    def write(self, addr: int, data: bytes) -> int:
        """Write bytes as the firmware would; returns the status error number (0 = done)."""
        end = addr + len(data)
        if addr < 0 or end > _TABLE_SIZE or not data:
            return p2.ERR_DATA_RANGE
        names = _owners(addr, end)
        staged = bytearray(self.table)
        staged[addr:end] = data
        torque_on = self.table[64] == 1
        for n in names:
            a, s, signed, writable, eeprom = ITEMS[n]
            if a < addr or a + s > end:
                return p2.ERR_DATA_LENGTH
            if not writable or (eeprom and torque_on):
                return p2.ERR_ACCESS
            v = int.from_bytes(staged[a:a + s], "little", signed=signed)
            err = self._check_value(n, v, staged)
            if err:
                return err
        self.table[:] = staged
        if "torque_enable" in names and self.table[64] == 1:
            if self.get("hardware_error_status"):
                self.table[64] = 0  # no torque until a reboot clears the error
        return 0

    def _check_value(self, name: str, v: int, staged: bytearray) -> int:
        def st(n: str) -> int:
            a, s = _ADDR[n], _SIZE[n]
            return int.from_bytes(staged[a:a + s], "little", signed=_SIGNED[n])

        m = self.model
        if name in _GOALS and self.get("bus_watchdog") == -1:
            return p2.ERR_DATA_RANGE
        lo_hi = _RANGES.get(name)
        if lo_hi is not None and not lo_hi[0] <= v <= lo_hi[1]:
            return p2.ERR_DATA_RANGE
        if name == "operating_mode" and v not in OPERATING_MODES.values():
            return p2.ERR_DATA_RANGE
        if name == "current_limit" and not 0 <= v <= m.max_current_limit:
            return p2.ERR_DATA_RANGE
        if name in ("max_position_limit", "min_position_limit") and not (
                m.min_position <= v <= m.max_position):
            return p2.ERR_DATA_RANGE
        if name == "goal_position" and st("operating_mode") in (3, 5) and not (
                st("min_position_limit") <= v <= st("max_position_limit")):
            return p2.ERR_DATA_LIMIT
        if name == "goal_current" and abs(v) > st("current_limit"):
            return p2.ERR_DATA_LIMIT
        if name == "goal_pwm" and abs(v) > st("pwm_limit"):
            return p2.ERR_DATA_LIMIT
        if name == "goal_velocity" and abs(v) > st("velocity_limit"):
            return p2.ERR_DATA_LIMIT
        return 0

    @property
    def replying(self) -> bool:
        return self.present and not self.no_reply


class BusEmulator:
    """Several emulated servos on one bus, served on a pty by a background thread.

    Args:
        servos: ``{id: model name}`` (or ``EmulatedServo`` objects).
        return_delay_us: initial Return Delay Time of every servo [us] (the servo's register
            9 is honoured, so a bridge that writes it changes the delay).
        reboot_time_s: how long a rebooting servo stays silent.
        tau: motor time constant [s].
        initial_positions: ``{id: tick}``; default the centre tick 2048.
        firmware: Firmware Version(6) reported by every servo.
    """

    def __init__(
        self,
        servos: dict[int, str] | Iterable[EmulatedServo],
        *,
        return_delay_us: float = 0.0,
        reboot_time_s: float = 0.0,
        tau: float = 0.03,
        initial_positions: dict[int, int] | None = None,
        firmware: int = 52,
    ) -> None:
        self.servos: dict[int, EmulatedServo] = {}
        items = servos.items() if isinstance(servos, dict) else ((s.dxl_id, s) for s in servos)
        for dxl_id, s in items:
            if not isinstance(s, EmulatedServo):
                if s not in MODELS:
                    raise ValueError(f"unknown model {s!r}; known: {sorted(MODELS)}")
                pos = (initial_positions or {}).get(dxl_id, POSITION_CENTER)
                s = EmulatedServo(dxl_id, MODELS[s], firmware=firmware, tau=tau,
                                  position=float(pos))
            s.set("return_delay_time", int(round(return_delay_us / 2.0)))
            self.servos[dxl_id] = s
        self.reboot_time_s = reboot_time_s
        self.lock = threading.RLock()
        self.log: deque[tuple[float, p2.Packet]] = deque(maxlen=4096)
        self._listeners: list[Callable[[float, p2.Packet], None]] = []
        self._parser = p2.PacketParser()
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._thread: threading.Thread | None = None
        self.port_name: str | None = None
        self._busy = False
        self.sleep = time.sleep  # replaced in tests that must not wait

    @classmethod
    def from_map(cls, servo_map, **kwargs) -> BusEmulator:
        """An emulator with one servo per entry of a :class:`ServoMap`."""
        return cls({s.id: s.model.name for s in servo_map.servos}, **kwargs)

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> str:
        """Open the pty and serve it from a daemon thread; returns the slave path."""
        if self._thread is not None:
            return self.port_name or ""
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        self.port_name = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._serve, name="dxl-emulator", daemon=True)
        self._thread.start()
        return self.port_name

    def stop(self) -> None:
        """Stop the thread and close the pty."""
        t, self._thread = self._thread, None
        if t is not None and self._wake_w is not None:
            os.write(self._wake_w, b"x")
            t.join(timeout=2.0)
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = None

    def __enter__(self) -> BusEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- observation ---------------------------------------------------------------------------
    def add_listener(self, fn: Callable[[float, p2.Packet], None]) -> None:
        """``fn(t_received, packet)`` for every valid instruction packet (perf_counter time)."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[float, p2.Packet], None]) -> None:
        with contextlib.suppress(ValueError):
            self._listeners.remove(fn)

    def servo(self, dxl_id: int) -> EmulatedServo:
        return self.servos[dxl_id]

    def wait_idle(self, timeout: float = 1.0) -> bool:
        """Wait until every byte sent to the bus so far has been processed (True) or timeout."""
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            master = self._master
            if master is None or self._thread is None:
                return True
            try:
                pending = select.select([master], [], [], 0)[0]
            except (OSError, ValueError):
                return True
            if not pending and not self._busy:
                return True
            time.sleep(0.0002)
        return False

    def value(self, dxl_id: int, name: str) -> int:
        """A control-table item of one servo (after advancing its motor to now), once the
        emulator has processed everything sent so far."""
        self.wait_idle()
        with self.lock:
            s = self.servos[dxl_id]
            s.update(time.perf_counter())
            return s.get(name)

    def writes(self, address: int, dxl_id: int | None = None) -> list[tuple[float, int, bytes]]:
        """Logged writes (Write and Sync Write) starting at ``address``: (t, id, data)."""
        out = []
        self.wait_idle()
        with self.lock:
            log = list(self.log)
        for t, pkt in log:
            if pkt.instruction == p2.INST_WRITE and p2.from_le(pkt.params[:2]) == address:
                if dxl_id is None or pkt.dxl_id == dxl_id:
                    out.append((t, pkt.dxl_id, pkt.params[2:]))
            elif pkt.instruction == p2.INST_SYNC_WRITE and p2.from_le(pkt.params[:2]) == address:
                n = p2.from_le(pkt.params[2:4])
                body = pkt.params[4:]
                for k in range(0, len(body) - n, n + 1):
                    if dxl_id is None or body[k] == dxl_id:
                        out.append((t, body[k], body[k + 1:k + 1 + n]))
        return out

    # -- fault injection -------------------------------------------------------------------------
    def inject_hardware_error(self, dxl_id: int, bits: int) -> None:
        """Set Hardware Error Status bits; a bit in Shutdown(63) switches torque off."""
        with self.lock:
            s = self.servos[dxl_id]
            s.update(time.perf_counter())
            s.set("hardware_error_status", s.get("hardware_error_status") | bits)
            if bits & s.get("shutdown"):
                s.table[64] = 0

    def set_no_reply(self, dxl_id: int, on: bool = True) -> None:
        """The servo goes silent (neither answers nor executes), as if unplugged."""
        with self.lock:
            self.servos[dxl_id].no_reply = on

    def set_bad_crc(self, dxl_id: int, count: int = -1) -> None:
        """Corrupt the CRC of the servo's next ``count`` status packets (-1: all, 0: none)."""
        with self.lock:
            self.servos[dxl_id].bad_crc = count

    def remove_servo(self, dxl_id: int) -> None:
        """Take the ID off the bus (a missing servo)."""
        with self.lock:
            self.servos[dxl_id].present = False

    def push(self, dxl_id: int, position: int) -> None:
        """Move the output shaft by an external force (the motor then servoes back)."""
        with self.lock:
            s = self.servos[dxl_id]
            s.update(time.perf_counter())
            s.position = float(position)
            s._publish_state(0.0)

    def set_temperature(self, dxl_id: int, celsius: int) -> None:
        with self.lock:
            self.servos[dxl_id].set("present_temperature", celsius)

    # -- the device side of the protocol -------------------------------------------------------
    def process(self, data: bytes, now: float | None = None) -> list[tuple[float, bytes]]:
        """Feed bus bytes; returns the replies as ``(delay_s_before, packet_bytes)`` in order.

        The pty thread calls this; tests can call it directly for byte-exact checks.
        """
        out: list[tuple[float, bytes]] = []
        for pkt in self._parser.feed(data):
            t = time.perf_counter() if now is None else now
            with self.lock:
                out.extend(self._dispatch(pkt, t))
        return out

    def _status(self, s: EmulatedServo, error: int, params: bytes = b"") -> tuple[float, bytes]:
        if s.get("hardware_error_status"):
            error |= 0x80
        pkt = p2.status_packet(s.dxl_id, error, params)
        if s.bad_crc:
            pkt = pkt[:-1] + bytes(((pkt[-1] + 1) & 0xFF,))
            if s.bad_crc > 0:
                s.bad_crc -= 1
        return s.table[9] * 2e-6, pkt

    def _alive(self, dxl_id: int, now: float) -> EmulatedServo | None:
        s = self.servos.get(dxl_id)
        if s is None or not s.replying or now < s.reboot_until:
            return None
        if s.reboot_until:
            s.reboot_until = 0.0
            s._reset_ram()
        s.t_comm = now
        s.update(now)
        return s

    def _dispatch(self, pkt: p2.Packet, now: float) -> list[tuple[float, bytes]]:
        bcast = pkt.dxl_id == p2.BROADCAST_ID
        if not pkt.crc_ok:
            s = None if bcast else self._alive(pkt.dxl_id, now)
            return [self._status(s, p2.ERR_CRC)] if s else []
        self.log.append((now, pkt))
        for fn in self._listeners:
            fn(now, pkt)
        inst, prm = pkt.instruction, pkt.params
        out: list[tuple[float, bytes]] = []
        if inst == p2.INST_PING:
            ids = sorted(self.servos) if bcast else [pkt.dxl_id]
            for i in ids:
                s = self._alive(i, now)
                if s:
                    body = p2.u_le(s.model.model_number, 2) + bytes((s.table[6],))
                    out.append(self._status(s, 0, body))
            return out
        if inst in (p2.INST_SYNC_WRITE, p2.INST_SYNC_READ, p2.INST_FAST_SYNC_READ):
            if not bcast or len(prm) < 4:
                return out
            addr, n = p2.from_le(prm[0:2]), p2.from_le(prm[2:4])
            if inst == p2.INST_SYNC_WRITE:
                body = prm[4:]
                for k in range(0, len(body) - n, n + 1):
                    s = self._alive(body[k], now)
                    if s:
                        s.write(addr, body[k + 1:k + 1 + n])
                return out
            return self._group_read([(i, addr, n) for i in prm[4:]],
                                    inst == p2.INST_FAST_SYNC_READ, now)
        if inst in (p2.INST_BULK_READ, p2.INST_FAST_BULK_READ, p2.INST_BULK_WRITE):
            if not bcast:
                return out
            if inst == p2.INST_BULK_WRITE:  # per device: ID ADDR(2) LEN(2) DATA(LEN)
                k = 0
                while k + 5 <= len(prm):
                    i, addr, n = prm[k], p2.from_le(prm[k + 1:k + 3]), p2.from_le(prm[k + 3:k + 5])
                    data = prm[k + 5:k + 5 + n]
                    if len(data) != n or n == 0:
                        break  # a malformed tail: the rest of the packet is ignored
                    s = self._alive(i, now)
                    if s:
                        s.write(addr, data)
                    k += 5 + n
                return out
            if len(prm) % 5:  # per device: ID ADDR(2) LEN(2)
                return out
            reads = [(prm[k], p2.from_le(prm[k + 1:k + 3]), p2.from_le(prm[k + 3:k + 5]))
                     for k in range(0, len(prm), 5)]
            return self._group_read(reads, inst == p2.INST_FAST_BULK_READ, now)
        if bcast:
            ids = [i for i in sorted(self.servos) if self._alive(i, now)]
            if inst == p2.INST_WRITE and len(prm) >= 3:
                for i in ids:
                    self.servos[i].write(p2.from_le(prm[0:2]), prm[2:])
            return out
        s = self._alive(pkt.dxl_id, now)
        if s is None:
            return out
        level = s.table[68]
        if inst == p2.INST_READ:
            if len(prm) != 4:
                return [self._status(s, p2.ERR_DATA_LENGTH)] if level >= 1 else []
            err, data = s.read(p2.from_le(prm[0:2]), p2.from_le(prm[2:4]))
            return [self._status(s, err, data if not err else b"")] if level >= 1 else []
        if inst == p2.INST_WRITE:
            err = s.write(p2.from_le(prm[0:2]), prm[2:]) if len(prm) >= 3 \
                else p2.ERR_DATA_LENGTH
            return [self._status(s, err)] if level >= 2 else []
        if inst == p2.INST_REBOOT:
            reply = [self._status(s, 0)] if level >= 2 else []
            s.set("hardware_error_status", 0)
            s.table[64] = 0
            s.reboot_until = now + self.reboot_time_s
            if not self.reboot_time_s:
                s.reboot_until = 0.0
                s._reset_ram()
            return reply
        return [self._status(s, p2.ERR_INSTRUCTION)]

    def _group_read(self, reads: list[tuple[int, int, int]], fast: bool,
                    now: float) -> list[tuple[float, bytes]]:
        """Answer a Sync/Bulk Read (one status packet per device, in parameter order) or a
        Fast Sync/Bulk Read (one packet with every device's part) for ``(id, addr, len)``."""
        out: list[tuple[float, bytes]] = []
        entries = []
        for i, addr, n in reads:
            s = self._alive(i, now)
            if s:
                err, data = s.read(addr, n)
                if not fast:
                    out.append(self._status(s, err, data))
                else:
                    hw = 0x80 if s.get("hardware_error_status") else 0
                    entries.append((i, err | hw, data))
        if entries:
            first = self.servos[entries[0][0]]
            pkt = p2.fast_status_packet(entries)
            corrupt = [self.servos[i] for i, _, _ in entries if self.servos[i].bad_crc]
            for s in corrupt:  # a damaged part of the one packet spoils its CRC
                if s.bad_crc > 0:
                    s.bad_crc -= 1
            if corrupt:
                pkt = pkt[:-1] + bytes(((pkt[-1] + 1) & 0xFF,))
            out.append((first.table[9] * 2e-6, pkt))
        return out

    # -- pty thread ------------------------------------------------------------------------
    def _serve(self) -> None:
        master, wake = self._master, self._wake_r
        assert master is not None and wake is not None
        while True:
            try:
                ready, _, _ = select.select([master, wake], [], [], 0.5)
            except (OSError, ValueError):
                return
            if wake in ready:
                return
            if master not in ready:
                continue
            self._busy = True  # before the read: wait_idle sees data pending or busy
            try:
                data = os.read(master, 65536)
            except OSError:
                return
            out = bytearray()  # replies without a delay between them go out in one write
            for delay, reply in self.process(data):
                if delay > 0:
                    if out:
                        self._write_all(master, bytes(out))
                        out.clear()
                    self.sleep(delay)
                out += reply
            if out:
                self._write_all(master, bytes(out))
            self._busy = False

    @staticmethod
    def _write_all(fd: int, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                select.select([], [fd], [], 0.1)
                continue
            except OSError:
                return
            view = view[n:]


def main(argv: list[str] | None = None) -> int:
    """``python -m hand_control.dynamixel.emulator --map NAME``: serve a bus until Ctrl-C."""
    from hand_control.dynamixel.servo_map import load_servo_map

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--map", default="leap_hand", help="servo map: path or name")
    ap.add_argument("--return-delay-us", type=float, default=0.0)
    ap.add_argument("--tau", type=float, default=0.03, help="motor time constant [s]")
    ap.add_argument("--link", default="", help="also create this symlink to the pty")
    args = ap.parse_args(argv)
    smap = load_servo_map(args.map)
    emu = BusEmulator.from_map(smap, return_delay_us=args.return_delay_us, tau=args.tau)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:  # Ctrl-C may come as soon as the path is printed
        path = emu.start()
        if args.link:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(args.link)
            os.symlink(path, args.link)
        print(path, flush=True)
        print(f"emulating {len(smap.servos)} servos of {smap.name!r} (IDs {list(smap.ids)}); "
              "Ctrl-C stops", file=sys.stderr, flush=True)
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        if args.link:
            with contextlib.suppress(OSError):
                os.unlink(args.link)
    return 0


if __name__ == "__main__":
    sys.exit(main())
