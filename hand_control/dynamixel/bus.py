"""Bus I/O through the official ``dynamixel_sdk`` (Protocol 2.0).

A thin wrapper that makes every transfer's outcome explicit: reads return per-servo results
(value or failure, and the status error byte with its Alert bit) instead of the SDK groups'
silent zeros. Group transfers use the SDK's ``GroupSyncWrite`` / ``GroupSyncRead`` to send;
replies are collected packet by packet with the SDK's ``rxPacket`` and dispatched by ID, so one
silent servo costs only its own answer, not the answers of every servo after it.

The SDK's packet timeout assumes a 16 ms USB latency timer (34 ms per transfer); here it is
``packet_timeout_ms`` plus the bytes' transmission time, so a missing servo costs milliseconds.
"""

from __future__ import annotations

import contextlib
import os
import select
import termios
from dataclasses import dataclass
from pathlib import Path

import dynamixel_sdk as sdk
from serial import SerialException

from hand_control.dynamixel.control_table import (
    ADDR_MODEL_NUMBER,
    describe_packet_error,
)
from hand_control.dynamixel.protocol import crc16
from hand_control.errors import ServoError

BAUD_RATES = (9600, 57600, 115200, 1000000, 2000000, 3000000, 4000000)
#: What a vanished or broken serial port raises from inside the SDK.
_PORT_ERRORS = (OSError, SerialException, termios.error)


class _PortHandler(sdk.PortHandler):
    """The SDK's PortHandler with a configurable packet timeout."""

    def __init__(self, port_name: str, packet_timeout_ms: float) -> None:
        super().__init__(port_name)
        self.extra_timeout_ms = float(packet_timeout_ms)

    def setPacketTimeout(self, packet_length: int) -> None:
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + self.extra_timeout_ms

    def readPort(self, length: int) -> bytes:
        # The SDK polls a non-blocking port in a tight loop; when nothing has arrived, wait
        # for the port to become readable (at most 0.5 ms) instead, which wakes on the first
        # byte, frees the CPU and lets other threads (an in-process emulator) run.
        data = self.ser.read(length)
        if not data:
            with contextlib.suppress(OSError, ValueError):
                select.select([self.ser.fileno()], [], [], 0.0005)
        return data


class _PacketHandler(sdk.Protocol2PacketHandler):
    """The SDK's Protocol 2.0 packet handler with faster, equivalent CRC and byte stuffing.

    The SDK rebuilds its 256-entry CRC table on every call and walks every byte to (un)stuff
    packets that contain no ``FF FF FD`` at all; at 16 servos and hundreds of cycles per second
    that is most of the bridge's CPU time. Results are identical (checked by the tests).
    """

    def updateCRC(self, crc_accum: int, data_blk_ptr, data_blk_size: int) -> int:
        return crc16(bytes(data_blk_ptr[:data_blk_size]), crc_accum)

    def addStuffing(self, packet):
        n = (packet[5] | (packet[6] << 8)) + 5  # LEN_L .. last parameter
        if b"\xff\xff\xfd" not in bytes(packet[5:n]):
            return packet
        return super().addStuffing(packet)

    def removeStuffing(self, packet):
        n = (packet[5] | (packet[6] << 8)) + 6  # the SDK's scan reaches CRC_L
        if b"\xff\xff\xfd\xfd" not in bytes(packet[5:n]):
            return packet
        return super().removeStuffing(packet)


@dataclass(frozen=True)
class ReadResult:
    """One servo's answer in a group read: ``data`` is None when it did not answer cleanly."""

    data: bytes | None
    error: int = 0  # status packet error byte (bit 7: Alert)
    comm: str = "ok"  # "ok", "timeout", "corrupt", ...

    @property
    def ok(self) -> bool:
        return self.data is not None and (self.error & 0x7F) == 0


def _comm_name(ph: sdk.PacketHandler, result: int) -> str:
    return {
        sdk.COMM_SUCCESS: "ok",
        sdk.COMM_RX_TIMEOUT: "timeout",
        sdk.COMM_RX_CORRUPT: "corrupt",
        sdk.COMM_TX_FAIL: "tx failed",
        sdk.COMM_PORT_BUSY: "port busy",
    }.get(result, ph.getTxRxResult(result) or f"result {result}")


def usb_latency_warning(port: str, sysfs_root: str = "/sys/bus/usb-serial/devices") -> str | None:
    """A warning when the USB-serial latency timer of ``port`` is not 1 ms, else None.

    The FTDI default of 16 ms caps the loop far below the servos' capability. Pseudo-terminals
    and ports without the sysfs entry are skipped (None).
    """
    try:
        real = Path(os.path.realpath(port))
    except OSError:
        return None
    if real.parent == Path("/dev/pts") or "pts" in real.parts:
        return None
    f = Path(sysfs_root) / real.name / "latency_timer"
    try:
        value = int(f.read_text().strip())
    except (OSError, ValueError):
        return None
    if value != 1:
        return (f"USB latency timer of {port} is {value} ms (from {f}); set it to 1 ms for a "
                f"fast servo loop: echo 1 | sudo tee {f}")
    return None


class DynamixelBus:
    """One serial bus of DYNAMIXELs, Protocol 2.0, through ``dynamixel_sdk``."""

    def __init__(self, port: str, baud: int = 4_000_000, packet_timeout_ms: float = 10.0):
        if baud not in BAUD_RATES:
            raise ServoError(f"baud {baud} is not one of {list(BAUD_RATES)}")
        self.port_name = port
        self.baud = baud
        self.port = _PortHandler(port, packet_timeout_ms)
        self.ph = _PacketHandler()
        self._readers: dict[tuple[int, int, tuple[int, ...]], sdk.GroupSyncRead] = {}

    # -- port ------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return bool(self.port.is_open)

    def open(self) -> None:
        """Open the port at the configured baud rate.

        Raises:
            ServoError: the port does not exist or cannot be opened / set to the baud rate.
        """
        try:
            ok = self.port.openPort() and self.port.setBaudRate(self.baud)
        except Exception as e:  # serial.SerialException, OSError
            raise ServoError(f"cannot open servo port {self.port_name!r}: {e}") from e
        if not ok:
            raise ServoError(f"cannot open servo port {self.port_name!r} at {self.baud} baud")

    def recover(self) -> None:
        """Make the port usable after a transfer was interrupted (a signal raised while a
        packet was in flight): the SDK leaves its busy flag set, which refuses every later
        packet, and half a reply may wait in the input buffer. Exit paths call this before
        switching torque off."""
        self.port.is_using = False
        try:
            self.port.clearPort()
        except Exception:  # a vanished adapter: the writes that follow will report it
            pass

    def close(self) -> None:
        if self.port.is_open:
            try:
                self.port.closePort()
            except Exception:  # closing a vanished device must not raise on an exit path
                self.port.is_open = False

    # -- single-servo transfers ------------------------------------------------------------
    def _call(self, fn, *args):
        """An SDK single-servo transfer; a serial/OS error becomes a ServoError."""
        try:
            return fn(self.port, *args)
        except _PORT_ERRORS as e:
            raise ServoError(self._port_failed(e)) from e

    def ping(self, dxl_id: int) -> tuple[int | None, str]:
        """(model number, "ok") or (None, reason)."""
        try:
            model, result, error = self._call(self.ph.ping, dxl_id)
        except ServoError as e:
            return None, str(e)
        if result != sdk.COMM_SUCCESS:
            return None, _comm_name(self.ph, result)
        return model, "ok"

    def read(self, dxl_id: int, addr: int, size: int, signed: bool = False) -> tuple[int, int]:
        """(value, status error byte).

        Raises:
            ServoError: no clean answer, or an error number in the status packet.
        """
        data, result, error = self._call(self.ph.readTxRx, dxl_id, addr, size)
        if result != sdk.COMM_SUCCESS:
            raise ServoError(f"servo {dxl_id}: read of address {addr} failed: "
                             f"{_comm_name(self.ph, result)}")
        if error & 0x7F or len(data) != size:
            raise ServoError(f"servo {dxl_id}: read of address {addr} refused: "
                             f"{describe_packet_error(error)}")
        return int.from_bytes(bytes(data), "little", signed=signed), error

    def write(self, dxl_id: int, addr: int, size: int, value: int) -> int:
        """Write and wait for the status packet; returns its error byte.

        Raises:
            ServoError: no clean answer, or an error number in the status packet.
        """
        data = list((int(value) & ((1 << (8 * size)) - 1)).to_bytes(size, "little"))
        result, error = self._call(self.ph.writeTxRx, dxl_id, addr, size, data)
        if result != sdk.COMM_SUCCESS:
            raise ServoError(f"servo {dxl_id}: write of {value} to address {addr} failed: "
                             f"{_comm_name(self.ph, result)}")
        if error & 0x7F:
            raise ServoError(f"servo {dxl_id}: write of {value} to address {addr} refused: "
                             f"{describe_packet_error(error)}")
        return error

    def try_write(self, dxl_id: int, addr: int, size: int, value: int) -> bool:
        """Best-effort write for exit paths: True when acknowledged without error."""
        try:
            self.write(dxl_id, addr, size, value)
            return True
        except ServoError:
            return False

    def reboot(self, dxl_id: int) -> None:
        result, error = self._call(self.ph.reboot, dxl_id)
        if result != sdk.COMM_SUCCESS:
            raise ServoError(f"servo {dxl_id}: reboot failed: {_comm_name(self.ph, result)}")

    def model_number(self, dxl_id: int) -> int:
        return self.read(dxl_id, ADDR_MODEL_NUMBER, 2)[0]

    # -- group transfers -------------------------------------------------------------------
    def _port_failed(self, e: Exception) -> str:
        """A serial/OS error from inside the SDK (e.g. the adapter was unplugged): free the
        SDK's port flag, which it leaves set when it is interrupted, and name the failure."""
        self.port.is_using = False
        return f"port error: {e}"

    def sync_write(self, addr: int, size: int, values: dict[int, int]) -> bool:
        """One Sync Write packet (no status packets come back); False if it was not sent."""
        try:
            return self._sync_write(addr, size, values)
        except _PORT_ERRORS as e:
            self._port_failed(e)
            return False

    def _sync_write(self, addr: int, size: int, values: dict[int, int]) -> bool:
        if not values:
            return True
        # the parameters GroupSyncWrite would assemble (ID, then the value's bytes, per servo),
        # handed to the SDK's packet builder without its per-servo bookkeeping
        mask = (1 << (8 * size)) - 1
        param: list[int] = []
        for dxl_id, v in values.items():
            param.append(dxl_id)
            param += (int(v) & mask).to_bytes(size, "little")
        return self.ph.syncWriteTxOnly(self.port, addr, size, param, len(param)) == \
            sdk.COMM_SUCCESS

    def sync_read(self, addr: int, size: int, ids: tuple[int, ...]) -> dict[int, ReadResult]:
        """Sync Read ``size`` bytes at ``addr`` from ``ids``; one result per ID."""
        try:
            return self._sync_read(addr, size, ids)
        except _PORT_ERRORS as e:
            reason = self._port_failed(e)
            return {i: ReadResult(None, 0, reason) for i in ids}

    def _sync_read(self, addr: int, size: int, ids: tuple[int, ...]) -> dict[int, ReadResult]:
        if not ids:
            return {}
        key = (addr, size, ids)
        r = self._readers.get(key)
        if r is None:
            if len(self._readers) > 16:
                self._readers.clear()
            r = self._readers[key] = sdk.GroupSyncRead(self.port, self.ph, addr, size)
            for i in ids:
                r.addParam(i)
        result = r.txPacket()
        if result != sdk.COMM_SUCCESS:
            reason = _comm_name(self.ph, result)
            return {i: ReadResult(None, 0, reason) for i in ids}
        return self._collect(ids, size)

    def _collect(self, ids: tuple[int, ...], size: int) -> dict[int, ReadResult]:
        out: dict[int, ReadResult] = {}
        pending = set(ids)
        reason = "timeout"
        while pending:
            pkt, result = self.ph.rxPacket(self.port, False)
            if result == sdk.COMM_SUCCESS:
                dxl_id = pkt[4]
                if dxl_id in pending:
                    pending.discard(dxl_id)
                    data = bytes(pkt[9:9 + size])
                    ok = len(data) == size
                    out[dxl_id] = ReadResult(data if ok else None, pkt[8], "ok" if ok else "short")
                continue
            if result == sdk.COMM_RX_CORRUPT and self.port.packet_timeout != 0:
                # a complete packet with a bad CRC (the timer has not run out): keep listening
                if len(pkt) > 4 and pkt[4] in pending:
                    pending.discard(pkt[4])
                    out[pkt[4]] = ReadResult(None, 0, "corrupt")
                continue
            reason = _comm_name(self.ph, result)
            break
        self.port.is_using = False
        for i in pending:
            out[i] = ReadResult(None, 0, reason)
        return out

    def fast_sync_read(self, addr: int, size: int, ids: tuple[int, ...]) -> dict[int, ReadResult]:
        """Fast Sync Read (one status packet for all); any failure fails every ID."""
        try:
            return self._fast_sync_read(addr, size, ids)
        except _PORT_ERRORS as e:
            reason = self._port_failed(e)
            return {i: ReadResult(None, 0, reason) for i in ids}

    def _fast_sync_read(self, addr: int, size: int,
                        ids: tuple[int, ...]) -> dict[int, ReadResult]:
        if not ids:
            return {}
        result = self.ph.syncReadTx(self.port, addr, size, list(ids), len(ids), True)
        if result != sdk.COMM_SUCCESS:
            return {i: ReadResult(None, 0, _comm_name(self.ph, result)) for i in ids}
        n = (size + 4) * len(ids)
        raw, result, _ = self.ph.fastSyncReadRx(self.port, sdk.BROADCAST_ID, n)
        if result != sdk.COMM_SUCCESS or len(raw) != n:
            reason = _comm_name(self.ph, result) if result != sdk.COMM_SUCCESS else "short"
            return {i: ReadResult(None, 0, reason) for i in ids}
        raw = bytes(raw)
        out: dict[int, ReadResult] = {}
        for k in range(len(ids)):
            chunk = raw[k * (size + 4):(k + 1) * (size + 4)]
            err, dxl_id = chunk[0], chunk[1]
            if dxl_id in ids:
                out[dxl_id] = ReadResult(chunk[2:2 + size], err, "ok")
        if len(out) != len(ids):
            for i in ids:
                if i not in out:
                    out[i] = ReadResult(None, 0, "corrupt")
        return out
