"""DYNAMIXEL Protocol 2.0 packets: CRC-16, byte stuffing, building and parsing.

Used by the emulator (the device side of the bus); the bridge itself talks through the official
``dynamixel_sdk``. Packet layout (e-manual, Protocol 2.0):

    FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM... | CRC_L CRC_H

LEN counts INST, the (stuffed) parameters and the CRC. Byte stuffing: inside INST..PARAM every
``FF FF FD`` is followed by an extra ``FD``; LEN and the CRC cover the stuffed bytes. The CRC is
CRC-16 with polynomial 0x8005 (x^16 + x^15 + x^2 + 1), initial value 0, no reflection.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_FACTORY_RESET = 0x06
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_FAST_SYNC_READ = 0x8A
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93
INST_FAST_BULK_READ = 0x9A

ERR_RESULT_FAIL = 0x01
ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_RANGE = 0x04
ERR_DATA_LENGTH = 0x05
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07


def _crc_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()
_CRC_TABLE16: list[int] | None = None


def _crc_table16() -> list[int]:
    """Register after feeding two zero bytes, for every register value (65536 entries).

    Feeding byte b to register c equals feeding a zero byte to c ^ (b << 8), and the update
    is linear, so two bytes b0 b1 take one lookup: c' = T16[c ^ (b0 << 8 | b1)].
    """
    global _CRC_TABLE16
    if _CRC_TABLE16 is None:
        import numpy as np

        t8 = np.array(_CRC_TABLE, dtype=np.uint32)
        r = np.arange(65536, dtype=np.uint32)
        for _ in range(2):
            r = ((r << 8) ^ t8[r >> 8]) & 0xFFFF
        _CRC_TABLE16 = r.tolist()
    return _CRC_TABLE16


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 of the protocol (poly 0x8005, init 0); ``crc`` continues a running value."""
    n = len(data)
    if n < 16:
        table = _CRC_TABLE
        for b in data:
            crc = ((crc << 8) ^ table[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
        return crc
    t16 = _crc_table16()
    for w in struct.unpack_from(f">{n // 2}H", data):
        crc = t16[crc ^ w]
    if n & 1:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ data[-1]) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert a 0xFD after every ``FF FF FD`` inside the instruction+parameter field."""
    if b"\xff\xff\xfd" not in body:
        return bytes(body)
    out = bytearray()
    for i, b in enumerate(body):
        out.append(b)
        if b == 0xFD and i >= 2 and body[i - 1] == 0xFF and body[i - 2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the stuffing 0xFD of ``FF FF FD FD`` inside the instruction+parameter field."""
    if b"\xff\xff\xfd\xfd" not in body:
        return bytes(body)
    out = bytearray()
    i = 0
    n = len(body)
    while i < n:
        b = body[i]
        out.append(b)
        if (b == 0xFD and i + 1 < n and body[i + 1] == 0xFD and len(out) >= 3
                and out[-2] == 0xFF and out[-3] == 0xFF):
            i += 1  # skip the stuffing byte
        i += 1
    return bytes(out)


def _frame(dxl_id: int, body: bytes) -> bytes:
    body = stuff(body)
    length = len(body) + 2
    pkt = bytearray(HEADER)
    pkt += bytes((dxl_id & 0xFF, length & 0xFF, (length >> 8) & 0xFF))
    pkt += body
    crc = crc16(pkt)
    pkt += bytes((crc & 0xFF, crc >> 8))
    return bytes(pkt)


def instruction_packet(dxl_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete instruction packet with stuffing and CRC."""
    return _frame(dxl_id, bytes((instruction,)) + bytes(params))


def status_packet(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    """A complete status packet (instruction 0x55) with stuffing and CRC."""
    return _frame(dxl_id, bytes((INST_STATUS, error & 0xFF)) + bytes(params))


def fast_status_packet(entries: list[tuple[int, int, bytes]]) -> bytes:
    """The single status packet answering a Fast Sync Read, for ``(id, error, data)`` entries.

    Layout (e-manual, Fast Sync Read): header with ID 0xFE and INST 0x55, then per device
    ``ERR ID DATA CRC_L CRC_H``, where each device's CRC is the running CRC of the whole packet
    up to its data, so the last one is the packet's CRC. No byte stuffing is applied.
    """
    n_data = sum(len(d) + 4 for _, _, d in entries)
    length = 1 + n_data  # INST + per-device (ERR ID DATA CRC2)
    pkt = bytearray(HEADER)
    pkt += bytes((BROADCAST_ID, length & 0xFF, (length >> 8) & 0xFF, INST_STATUS))
    crc = crc16(pkt)
    for dxl_id, error, data in entries:
        chunk = bytes((error & 0xFF, dxl_id & 0xFF)) + bytes(data)
        crc = crc16(chunk, crc)
        pkt += chunk
        pkt += bytes((crc & 0xFF, crc >> 8))
        crc = crc16(pkt[-2:], crc)
    return bytes(pkt)


@dataclass(frozen=True)
class Packet:
    """A received packet. ``params`` are unstuffed; for a status packet ``error`` is set."""

    dxl_id: int
    instruction: int
    params: bytes
    crc_ok: bool = True

    @property
    def error(self) -> int:
        return self.params[0] if self.instruction == INST_STATUS and self.params else 0

    @property
    def data(self) -> bytes:
        """Status packet payload after the error byte."""
        return self.params[1:] if self.instruction == INST_STATUS else self.params


class PacketParser:
    """Incremental parser of a byte stream into packets (header search, length, CRC).

    ``feed`` returns complete packets; a packet with a wrong CRC is returned with
    ``crc_ok=False`` (its parameters are not unstuffed). Garbage before a header is dropped.
    """

    def __init__(self, max_length: int = 4096) -> None:
        self._buf = bytearray()
        self._max_length = max_length

    def feed(self, data: bytes) -> list[Packet]:
        self._buf += data
        out: list[Packet] = []
        buf = self._buf
        while True:
            start = buf.find(b"\xff\xff\xfd")
            if start < 0:
                # keep a possible partial header at the end
                keep = 2 if buf.endswith(b"\xff\xff") else 1 if buf.endswith(b"\xff") else 0
                del buf[: len(buf) - keep]
                break
            if start:
                del buf[:start]
            if len(buf) < 7:
                break
            if buf[3] != 0x00:  # reserved byte; FF FF FD FD is stuffing, not a header
                del buf[:3]
                continue
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > self._max_length:
                del buf[:3]
                continue
            total = 7 + length
            if len(buf) < total:
                break
            pkt = bytes(buf[:total])
            del buf[:total]
            crc_ok = crc16(pkt[:-2]) == (pkt[-2] | (pkt[-1] << 8))
            body = pkt[7:-2]
            if crc_ok:
                body = unstuff(body)
            out.append(Packet(pkt[4], body[0], bytes(body[1:]), crc_ok))
        return out

    def clear(self) -> None:
        self._buf.clear()


def u_le(value: int, size: int) -> bytes:
    """Little-endian bytes of an integer (two's complement for negative values)."""
    return (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")


def from_le(data: bytes, signed: bool = False) -> int:
    return int.from_bytes(data, "little", signed=signed)
