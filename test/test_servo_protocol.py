"""Protocol 2.0: the emulator answers the e-manual's published example packets byte for byte,
the real dynamixel-sdk writes the same instruction packets, and the bridge's faster SDK
packet routines give the SDK's results exactly."""

from __future__ import annotations

import random

import dynamixel_sdk as sdk
import pytest

from hand_control.dynamixel import protocol as p2
from hand_control.dynamixel.bus import _PacketHandler
from hand_control.dynamixel.emulator import BusEmulator


def h(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


def replies(emu: BusEmulator, packet: str) -> list[bytes]:
    return [r for _, r in emu.process(h(packet))]


@pytest.fixture
def xm430() -> BusEmulator:
    """The e-manual's example bus: ID1 and ID2 XM430-W210, firmware 38 (0x26)."""
    return BusEmulator({1: "XM430-W210", 2: "XM430-W210"}, firmware=38,
                       initial_positions={1: 166, 2: 2079})


# Examples of the ROBOTIS e-manual, Protocol 2.0 "Instruction Details".
def test_ping_example(xm430: BusEmulator) -> None:
    assert replies(xm430, "FF FF FD 00 01 03 00 01 19 4E") == [
        h("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")]


def test_broadcast_ping_example(xm430: BusEmulator) -> None:
    assert replies(xm430, "FF FF FD 00 FE 03 00 01 31 42") == [
        h("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
        h("FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D")]


def test_read_example(xm430: BusEmulator) -> None:
    # Present Position(132) of ID1 = 166
    assert replies(xm430, "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15") == [
        h("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")]


def test_write_example(xm430: BusEmulator) -> None:
    # 512 to Goal Position(116) of ID1
    assert replies(xm430, "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89") == [
        h("FF FF FD 00 01 04 00 55 00 A1 0C")]
    assert xm430.value(1, "goal_position") == 512


def test_sync_read_example(xm430: BusEmulator) -> None:
    assert replies(xm430, "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA") == [
        h("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"),
        h("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE")]


def test_sync_write_example(xm430: BusEmulator) -> None:
    # 150 to ID1 and 170 to ID2 Goal Position; no status packets
    assert replies(xm430, "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00"
                          " 82 87") == []
    assert xm430.value(1, "goal_position") == 150
    assert xm430.value(2, "goal_position") == 170


def test_fast_sync_read_example() -> None:
    emu = BusEmulator({3: "XC330-T288", 7: "XC330-T288", 4: "XC330-T288"},
                      initial_positions={3: 166, 7: 2079, 4: 1023})
    got = b"".join(replies(emu, "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"))
    assert got == h("FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08"  # ID 3
                    " 00 07 1F 08 00 00 16 CA"  # ID 7
                    " 00 04 FF 03 00 00 D1 9E")  # ID 4


def test_reboot_example(xm430: BusEmulator) -> None:
    assert replies(xm430, "FF FF FD 00 01 03 00 08 2F 4E") == [
        h("FF FF FD 00 01 04 00 55 00 A1 0C")]


def test_crc_of_the_examples() -> None:
    assert p2.crc16(h("FF FF FD 00 01 03 00 01")) == 0x4E19
    assert p2.instruction_packet(1, p2.INST_PING) == h("FF FF FD 00 01 03 00 01 19 4E")


def test_unknown_instruction_and_bad_crc_are_answered_with_errors(xm430: BusEmulator) -> None:
    (reply,) = replies(xm430, p2.instruction_packet(1, 0x40).hex())
    assert reply[8] == p2.ERR_INSTRUCTION
    bad = bytearray(h("FF FF FD 00 01 03 00 01 19 4E"))
    bad[-1] ^= 0xFF
    (reply,) = xm430.process(bytes(bad))
    assert reply[1][8] == p2.ERR_CRC


def test_byte_stuffing_round_trip_and_parser() -> None:
    params = bytes([0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x01, 0xFF, 0xFF, 0xFD, 0xFD])
    pkt = p2.instruction_packet(1, p2.INST_WRITE, params)
    assert pkt.count(b"\xff\xff\xfd\xfd") == 2  # both patterns stuffed
    parser = p2.PacketParser()
    got = parser.feed(b"\x00\x13" + pkt[:9]) + parser.feed(pkt[9:])  # garbage + split packet
    assert len(got) == 1 and got[0].crc_ok and got[0].params == params


def test_sdk_writes_the_published_ping_bytes_to_the_emulator() -> None:
    """Through a pty: the real SDK's ping packet is the e-manual's, and it reads the answer."""
    seen: list[p2.Packet] = []
    with BusEmulator({1: "XM430-W210"}, firmware=38) as emu:
        emu.add_listener(lambda t, pkt: seen.append(pkt))
        port = sdk.PortHandler(emu.port_name)
        assert port.openPort() and port.setBaudRate(4_000_000)
        try:
            model, result, error = sdk.PacketHandler(2.0).ping(port, 1)
        finally:
            port.closePort()
    assert (model, result, error) == (1030, sdk.COMM_SUCCESS, 0)
    assert p2.instruction_packet(seen[0].dxl_id, seen[0].instruction, seen[0].params) == h(
        "FF FF FD 00 01 03 00 01 19 4E")


def _random_packet(rng: random.Random) -> list[int]:
    n = rng.randint(0, 40)
    body = [rng.choice([0xFF, 0xFD, 0x00, rng.randint(0, 255)]) for _ in range(n)]
    pkt = [0xFF, 0xFF, 0xFD, 0x00, rng.randint(0, 253), 0, 0, 0x83, *body, 0, 0]
    length = n + 3
    pkt[5], pkt[6] = length & 0xFF, length >> 8
    return pkt + [0] * 64


def test_fast_packet_routines_equal_the_sdk() -> None:
    ref, fast = sdk.Protocol2PacketHandler(), _PacketHandler()
    rng = random.Random(7)
    for _ in range(500):
        pkt = _random_packet(rng)
        n = (pkt[5] | pkt[6] << 8) + 7
        assert fast.updateCRC(0, pkt, n - 2) == ref.updateCRC(0, pkt, n - 2)
        assert fast.addStuffing(list(pkt)) == ref.addStuffing(list(pkt))
        assert fast.removeStuffing(list(pkt)) == ref.removeStuffing(list(pkt))


def test_two_byte_crc_table_equals_the_bytewise_crc() -> None:
    def bytewise(data: bytes, crc: int) -> int:
        for b in data:
            crc = ((crc << 8) ^ p2._CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
        return crc

    rng = random.Random(3)
    for _ in range(300):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 500)))
        start = rng.randrange(65536)
        assert p2.crc16(data, start) == bytewise(data, start)
