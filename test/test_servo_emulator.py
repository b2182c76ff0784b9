"""The Protocol 2.0 emulator: control table rules, motor, timing and fault injection, used
through the real dynamixel-sdk on a pty, and the standalone command."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from ros_helpers import ROOT, wait_for

from hand_control.dynamixel import control_table as ct
from hand_control.dynamixel import protocol as p2
from hand_control.dynamixel.bus import DynamixelBus
from hand_control.dynamixel.emulator import BusEmulator
from hand_control.errors import ServoError


@pytest.fixture
def bus_emu():
    emu = BusEmulator({1: "XC330-M288", 2: "XC330-M288", 3: "XM430-W350"}, tau=0.01)
    emu.start()
    # healthy emulated servos answer when the host schedules their thread: late under load
    bus = DynamixelBus(emu.port_name, 4_000_000, packet_timeout_ms=500.0)
    bus.open()
    yield bus, emu
    bus.close()
    emu.stop()


def test_ping_reports_each_model(bus_emu) -> None:
    bus, _ = bus_emu
    assert bus.ping(1) == (1240, "ok")
    assert bus.ping(3) == (1020, "ok")
    assert bus.ping(9) == (None, "timeout")


def test_eeprom_is_locked_while_torque_is_on(bus_emu) -> None:
    bus, emu = bus_emu
    bus.write(1, ct.ADDR_OPERATING_MODE, 1, 5)
    bus.write(1, ct.ADDR_TORQUE_ENABLE, 1, 1)
    with pytest.raises(ServoError, match="Access Error"):
        bus.write(1, ct.ADDR_OPERATING_MODE, 1, 3)
    assert emu.value(1, "operating_mode") == 5


def test_read_only_items_range_and_limits_are_refused(bus_emu) -> None:
    bus, _ = bus_emu
    with pytest.raises(ServoError, match="Access Error"):
        bus.write(1, ct.ADDR_PRESENT_POSITION, 4, 100)
    with pytest.raises(ServoError, match="Data Range Error"):
        bus.write(1, ct.ADDR_CURRENT_LIMIT, 2, 5000)  # XC330-M288 allows 0..2352
    bus.write(1, ct.ADDR_MAX_POSITION_LIMIT, 4, 3000)
    with pytest.raises(ServoError, match="Data Limit Error"):
        bus.write(1, ct.ADDR_GOAL_POSITION, 4, 3500)
    with pytest.raises(ServoError, match="Data Length Error"):
        bus.write(1, ct.ADDR_GOAL_POSITION, 2, 100)  # half of a 4-byte item


def test_motor_moves_toward_the_goal_only_with_torque(bus_emu) -> None:
    bus, emu = bus_emu
    bus.write(2, ct.ADDR_GOAL_POSITION, 4, 2600)
    time.sleep(0.05)
    assert emu.value(2, "present_position") == 2048  # torque off: no motion
    bus.write(2, ct.ADDR_TORQUE_ENABLE, 1, 1)
    assert wait_for(lambda: abs(bus.read(2, ct.ADDR_PRESENT_POSITION, 4)[0] - 2600) <= 2, 2.0)


def test_status_return_level_and_return_delay(bus_emu) -> None:
    bus, emu = bus_emu
    bus.write(1, ct.item("status_return_level")[0], 1, 1)  # 1: no answer to Write
    with pytest.raises(ServoError, match="timeout"):
        bus.write(1, ct.item("led")[0], 1, 1)
    assert emu.value(1, "led") == 1  # executed all the same
    bus.write(2, ct.ADDR_RETURN_DELAY, 1, 254)  # 508 us
    t0 = time.perf_counter()
    for _ in range(10):
        bus.ping(2)
    assert (time.perf_counter() - t0) / 10 >= 0.0005


def test_hardware_error_sets_alert_bit_and_switches_torque_off(bus_emu) -> None:
    bus, emu = bus_emu
    bus.write(1, ct.ADDR_TORQUE_ENABLE, 1, 1)
    emu.inject_hardware_error(1, 1 << 5)  # Overload
    value, error = bus.read(1, ct.ADDR_HARDWARE_ERROR, 1)
    assert value == 0x20 and error & ct.ERROR_ALERT
    assert ct.describe_hardware_error(value) == "Overload Error"
    assert emu.value(1, "torque_enable") == 0
    bus.write(1, ct.ADDR_TORQUE_ENABLE, 1, 1)  # accepted, but no torque until a reboot
    assert emu.value(1, "torque_enable") == 0
    bus.reboot(1)
    assert bus.read(1, ct.ADDR_HARDWARE_ERROR, 1) == (0, 0)


def test_faults_no_reply_bad_crc_missing_id(bus_emu) -> None:
    bus, emu = bus_emu
    ids = (1, 2, 3)
    emu.set_no_reply(2)
    res = bus.sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, ids)
    assert [res[i].ok for i in ids] == [True, False, True]  # the others still answered
    assert res[2].comm == "timeout"
    emu.set_no_reply(2, False)
    emu.set_bad_crc(3, 1)
    res = bus.sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, ids)
    assert [res[i].comm for i in ids] == ["ok", "ok", "corrupt"]
    res = bus.sync_read(ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN, ids)
    assert all(res[i].ok for i in ids)  # only the next packet was corrupted
    emu.remove_servo(1)
    assert bus.ping(1) == (None, "timeout")


def test_fast_sync_read_through_the_sdk(bus_emu) -> None:
    bus, emu = bus_emu
    emu.push(3, 1000)
    res = bus.fast_sync_read(ct.ADDR_PRESENT_POSITION, 4, (1, 2, 3))
    assert [p2.from_le(res[i].data) for i in (1, 2, 3)] == [2048, 2048, 1000]
    emu.set_no_reply(2)  # one silent servo breaks the single status packet
    res = bus.fast_sync_read(ct.ADDR_PRESENT_POSITION, 4, (1, 2, 3))
    assert not any(r.ok for r in res.values())


def test_bus_watchdog_stops_the_servo_and_refuses_goals(bus_emu) -> None:
    bus, emu = bus_emu
    bus.write(1, ct.ADDR_TORQUE_ENABLE, 1, 1)
    bus.write(1, ct.ADDR_BUS_WATCHDOG, 1, 2)  # 40 ms
    time.sleep(0.1)  # the bridge went silent
    assert emu.value(1, "bus_watchdog") == -1
    with pytest.raises(ServoError, match="Data Range Error"):
        bus.write(1, ct.ADDR_GOAL_POSITION, 4, 2500)
    bus.write(1, ct.ADDR_BUS_WATCHDOG, 1, 0)  # clearing it accepts goals again
    bus.write(1, ct.ADDR_GOAL_POSITION, 4, 2500)


def test_standalone_emulator_prints_its_pty_and_serves_it() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "hand_control.dynamixel.emulator", "--map",
                             "generic_3dof"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/pts/"), path
        bus = DynamixelBus(path, 4_000_000, packet_timeout_ms=200.0)
        bus.open()
        try:
            assert bus.ping(3) == (1020, "ok")  # XM430-W350 in generic_3dof
        finally:
            bus.close()
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0


def test_out_of_range_values_get_a_data_range_error(bus_emu) -> None:
    """Issue #20 item 11: LED = 2 was accepted; the status packet must carry Data Range
    Error (0x04) and the value must not change."""
    import dynamixel_sdk as sdk

    bus, emu = bus_emu
    result, error = bus.ph.write1ByteTxRx(bus.port, 1, ct.item("led")[0], 2)
    assert result == sdk.COMM_SUCCESS and error & 0x7F == p2.ERR_DATA_RANGE
    assert emu.value(1, "led") == 0
    bus.write(1, ct.item("led")[0], 1, 1)
    assert emu.value(1, "led") == 1
    for name, value in (("status_return_level", 3), ("profile_acceleration", 40_000),
                        ("position_p_gain", 20_000)):
        with pytest.raises(ServoError, match="Data Range Error"):
            bus.write(1, ct.item(name)[0], ct.item(name)[1], value)
    with pytest.raises(ServoError, match="Data Limit Error"):  # beyond PWM Limit(36)
        bus.write(1, ct.item("goal_pwm")[0], 2, 900)


def test_bulk_read_and_bulk_write_through_the_sdk(bus_emu) -> None:
    """Issue #20 item 11: Bulk Read / Bulk Write got no reply / were not applied."""
    import dynamixel_sdk as sdk

    bus, emu = bus_emu
    emu.push(3, 1500)
    w = sdk.GroupBulkWrite(bus.port, bus.ph)
    assert w.addParam(1, ct.item("led")[0], 1, [1])
    assert w.addParam(2, ct.item("profile_velocity")[0], 4, list(p2.u_le(77, 4)))
    assert w.txPacket() == sdk.COMM_SUCCESS
    assert emu.wait_idle()
    assert emu.value(1, "led") == 1 and emu.value(2, "profile_velocity") == 77
    for fast in (False, True):
        r = sdk.GroupBulkRead(bus.port, bus.ph)
        assert r.addParam(1, ct.item("led")[0], 1)
        assert r.addParam(2, ct.item("profile_velocity")[0], 4)
        assert r.addParam(3, ct.ADDR_PRESENT_POSITION, 4)
        result = r.fastBulkRead() if fast else r.txRxPacket()
        assert result == sdk.COMM_SUCCESS, (fast, bus.ph.getTxRxResult(result))
        assert r.getData(1, ct.item("led")[0], 1) == 1
        assert r.getData(2, ct.item("profile_velocity")[0], 4) == 77
        assert r.getData(3, ct.ADDR_PRESENT_POSITION, 4) == 1500
    kinds = {pkt.instruction for _, pkt in emu.log}
    assert {p2.INST_BULK_WRITE, p2.INST_BULK_READ, p2.INST_FAST_BULK_READ} <= kinds


def test_bulk_write_with_a_range_error_is_not_applied(bus_emu) -> None:
    import dynamixel_sdk as sdk

    bus, emu = bus_emu
    w = sdk.GroupBulkWrite(bus.port, bus.ph)
    assert w.addParam(1, ct.item("led")[0], 1, [2])  # out of range: refused
    assert w.addParam(2, ct.item("led")[0], 1, [1])
    assert w.txPacket() == sdk.COMM_SUCCESS
    assert emu.wait_idle()
    assert emu.value(1, "led") == 0 and emu.value(2, "led") == 1
