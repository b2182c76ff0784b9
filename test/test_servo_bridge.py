"""The servo bridge core against the emulator, through the real dynamixel-sdk: poses become
the mapped goals, and every safety behaviour holds under an injected fault."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from ros_helpers import wait_for

from hand_capture.model.joints import ARTICULATED_JOINTS, joint_limits_dict
from hand_control.dynamixel import control_table as ct
from hand_control.dynamixel import protocol as p2
from hand_control.dynamixel.bridge import BridgeConfig, BridgeState, ServoBridge
from hand_control.dynamixel.bus import usb_latency_warning
from hand_control.dynamixel.emulator import BusEmulator
from hand_control.dynamixel.servo_map import load_servo_map
from hand_control.errors import ServoError

NAMES = list(ARTICULATED_JOINTS)
GOAL = ct.ADDR_GOAL_POSITION


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def make(servo_map: str = "generic_3dof", clock=None, **cfg) -> ServoBridge:
    # the emulator answers from a thread of this process: on a loaded machine an answer can
    # wait for a CPU well past 100 ms (tests of timeouts set their own, shorter, value)
    cfg.setdefault("packet_timeout_ms", 500.0)
    return ServoBridge(BridgeConfig(servo_map=servo_map, **cfg),
                       clock=clock if clock is not None else time.monotonic)


def pose(**angles: float) -> list[float]:
    q = dict.fromkeys(NAMES, 0.0)
    q.update(angles)
    return [q[n] for n in NAMES]


def run(b: ServoBridge, clock: FakeClock, q: list[float] | None, cycles: int,
        dt: float = 0.005) -> None:
    """Advance the fake clock and step; feed the pose every cycle when given."""
    for _ in range(cycles):
        clock.t += dt
        if q is not None:
            assert b.handle_pose(NAMES, q, now=clock.t)
        b.step()


def goals(b: ServoBridge) -> list[int]:
    return [b.emulator.value(i, "goal_position") for i in b.ids]


def expected_ticks(b: ServoBridge, q: list[float]) -> list[int]:
    theta = b.retarget.from_named(NAMES, q)
    lo = [s.min_position for s in b.map.servos]
    hi = [s.max_position for s in b.map.servos]
    return np.rint(np.clip(theta * ct.TICKS_PER_RAD + 2048, lo, hi)).astype(int).tolist()


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def leap(clock):
    b = make("leap_hand", clock)
    b.configure()
    b.activate()
    yield b
    b.close()


@pytest.fixture
def gen(clock):
    b = make("generic_3dof", clock, max_comm_failures=3)
    b.configure()
    b.activate()
    yield b
    b.close()


def test_configure_writes_modes_limits_current_and_torque_stays_off(clock) -> None:
    b = make("leap_hand", clock)
    b.configure()
    try:
        emu, s = b.emulator, b.map.servos[5]
        assert emu.value(s.id, "operating_mode") == 5  # current-based position
        assert emu.value(s.id, "min_position_limit") == s.min_position
        assert emu.value(s.id, "max_position_limit") == s.max_position
        assert emu.value(s.id, "current_limit") == 550
        assert all(emu.value(i, "torque_enable") == 0 for i in b.ids)
        assert emu.writes(GOAL) == []  # no goal before activation
        b.activate()
        assert emu.value(s.id, "goal_current") == 550
    finally:
        b.close()


def test_goal_current_goes_out_by_sync_write_when_it_changes(leap, clock) -> None:
    emu = leap.emulator
    run(leap, clock, pose(), 3)
    t0 = time.perf_counter()
    leap.set_goal_current_scale(0.5)
    run(leap, clock, pose(), 3)
    assert [emu.value(i, "goal_current") for i in leap.ids] == [275] * 16
    sent = [(t, pkt) for t, pkt in emu.log if t > t0 and pkt.instruction == p2.INST_SYNC_WRITE
            and pkt.params[:2] == p2.u_le(ct.ADDR_GOAL_CURRENT, 2)]
    assert len(sent) == 1  # once, not every cycle
    with pytest.raises(ValueError):
        leap.set_goal_current_scale(1.5)


def test_hand_pose_becomes_the_mapped_goals_of_16_servos(leap, clock) -> None:
    rng = np.random.default_rng(0)
    lim = joint_limits_dict()  # angles within the hand model's joint limits
    q = pose(**{n: float(rng.uniform(*lim[n])) for n in NAMES})
    run(leap, clock, q, 300)  # 1.5 s of control time: filter and rate limit settle
    assert goals(leap) == expected_ticks(leap, q)
    assert all(leap.emulator.value(i, "torque_enable") == 1 for i in leap.ids)


def test_activation_holds_the_present_position(clock) -> None:
    b = make("generic_3dof", clock)
    b.configure()
    try:
        b.emulator.push(3, 3000)  # wherever the servo happens to be
        b.activate()
        run(b, clock, None, 5)
        assert goals(b)[2] == 3000
        assert [g for _, i, g in b.emulator.writes(GOAL) if i == 3][0] == p2.u_le(3000, 4)
    finally:
        b.close()


def test_no_goal_before_the_first_good_read(clock) -> None:
    b = make("generic_3dof", clock, read_mode="sync")  # per-servo answers
    b.configure()
    try:
        emu = b.emulator
        emu.push(3, 3000)
        emu.set_no_reply(2)
        with pytest.raises(ServoError, match=r"no good read from servo\(s\) 2"):
            b.activate()
        assert emu.writes(GOAL) == []  # nothing, in particular no zeros
        assert all(emu.value(i, "torque_enable") == 0 for i in (1, 3))
        emu.set_no_reply(2, False)
        b.activate()
        first = {}
        for _, i, data in emu.writes(GOAL):
            first.setdefault(i, p2.from_le(data, signed=True))
        assert first == {1: 2048, 2: 2048, 3: 3000}
    finally:
        b.close()


@pytest.mark.parametrize("mode", ["sync", "fast_sync"])
def test_a_failed_read_means_no_goal_for_that_servo_that_cycle(mode, clock) -> None:
    gen = make("generic_3dof", clock, read_mode=mode)
    gen.configure()
    gen.activate()
    try:
        _failed_read_cycle(gen, clock, mode)
    finally:
        gen.close()


def _failed_read_cycle(gen: ServoBridge, clock: FakeClock, mode: str) -> None:
    run(gen, clock, pose(), 3)
    emu = gen.emulator
    emu.set_bad_crc(2, 1)
    n_before = len(emu.writes(GOAL, 2))
    gen.handle_pose(NAMES, pose(index_mcp_flex=1.0), now=clock.t)
    r = gen.step()
    if mode == "fast_sync":
        # one status packet for all: the bad CRC spoils every servo's data; the Sync Read
        # that follows in the same cycle reads each servo (the CRC fault was transient)
        assert r.fresh.all() and r.written == 3 and gen.read_mode == "fast_sync"
        return
    assert list(r.fresh) == [True, False, True] and r.written == 2  # the others commanded
    assert len(emu.writes(GOAL, 2)) == n_before
    assert np.isnan(r.position[1])  # not published as a stale value
    run(gen, clock, pose(index_mcp_flex=1.0), 1)
    assert len(emu.writes(GOAL, 2)) == n_before + 1
    assert 0 not in [p2.from_le(d) for _, _, d in emu.writes(GOAL)]


def test_goals_are_clamped_to_the_position_limits(gen, clock) -> None:
    # valid angles (within the model's limits + the validation margin) past the servo's limit
    q = pose(index_mcp_flex=1.85, index_pip_flex=2.2, index_dip_flex=1.85)
    run(gen, clock, q, 300)
    assert goals(gen)[1] == gen.map.by_id(2).min_position  # direction -1: closes downwards
    assert all(gen.map.by_id(2).min_position <= p2.from_le(d) for _, _, d in
               gen.emulator.writes(GOAL, 2))


def test_rate_limit_per_servo(clock) -> None:
    b = make("generic_3dof", clock, filter_cutoff_hz=0.0)
    b.configure()
    b.activate()
    try:
        q = pose(middle_pip_flex=1.0, ring_pip_flex=1.0, little_pip_flex=1.0)
        run(b, clock, q, 40, dt=0.005)
        vals = [p2.from_le(d) for _, _, d in b.emulator.writes(GOAL, 3)]
        steps = np.abs(np.diff(vals))
        vmax = b.map.by_id(3).max_velocity_rad_s * ct.TICKS_PER_RAD * 0.005
        assert steps.max() <= vmax + 1
        assert steps.max() >= vmax - 1  # it was limiting, not idling
    finally:
        b.close()


def test_command_timeout_holds_the_last_goal(gen, clock) -> None:
    q = pose(index_mcp_flex=0.8, index_pip_flex=0.8, index_dip_flex=0.8)
    run(gen, clock, q, 20)
    held = goals(gen)
    n = len(gen.emulator.writes(GOAL))
    clock.t += 0.6  # > command_timeout_s = 0.5
    run(gen, clock, None, 20)
    assert gen.timed_out
    assert goals(gen) == held and len(gen.emulator.writes(GOAL)) == n
    assert all(gen.emulator.value(i, "torque_enable") == 1 for i in gen.ids)
    assert "command timeout" in gen.diagnostics()[0].message
    run(gen, clock, pose(), 5)  # input resumes
    assert not gen.timed_out and len(gen.emulator.writes(GOAL)) > n


def test_command_timeout_torque_off_then_resume_from_the_present_position(clock) -> None:
    b = make("generic_3dof", clock, timeout_action="torque_off")
    b.configure()
    b.activate()
    try:
        emu = b.emulator
        run(b, clock, pose(), 10)
        clock.t += 0.6
        run(b, clock, None, 3)
        assert all(emu.value(i, "torque_enable") == 0 for i in b.ids)
        emu.push(1, 2500)  # the limp thumb servo was moved by hand
        t_resume = time.perf_counter()
        run(b, clock, pose(), 1)
        assert all(emu.value(i, "torque_enable") == 1 for i in b.ids)
        first = [p2.from_le(d) for t, _, d in emu.writes(GOAL, 1) if t >= t_resume][0]
        assert first == 2500  # goal := present before torque on, never a jump
    finally:
        b.close()


def test_resume_after_torque_off_waits_for_a_good_read_of_each_servo(clock) -> None:
    b = make("generic_3dof", clock, timeout_action="torque_off", read_mode="sync")
    with b:
        emu = b.emulator
        run(b, clock, pose(), 5)
        clock.t += 0.6
        run(b, clock, None, 2)
        emu.set_bad_crc(2, 1)  # servo 2's answer is damaged in the cycle input resumes
        run(b, clock, pose(), 1)
        assert [emu.value(i, "torque_enable") for i in b.ids] == [1, 0, 1]
        run(b, clock, pose(), 1)
        assert [emu.value(i, "torque_enable") for i in b.ids] == [1, 1, 1]


def test_unplugged_port_is_a_communication_failure_not_a_crash(clock) -> None:
    b = make("generic_3dof", clock, max_comm_failures=3, packet_timeout_ms=20.0)
    b.configure()
    b.activate()
    try:
        run(b, clock, pose(), 3)
        b.emulator.stop()  # the pty goes away under the bridge, like a USB adapter pulled
        run(b, clock, pose(), 4)  # must not raise
        assert b.state is BridgeState.ERROR
        assert "port error" in b.diagnostics()[0].message or "timeout" in b.error_reason
    finally:
        b.close()  # must not raise either


def test_emulated_bus_tolerates_a_slow_host(clock) -> None:
    """The emulator answers when the host schedules its thread: a 50 ms stall (a loaded
    machine) is not a communication failure, even with a 20 ms hardware packet timeout."""
    b = make("generic_3dof", clock, max_comm_failures=1, packet_timeout_ms=20.0)
    b.configure()
    b.activate()
    try:
        run(b, clock, pose(), 2)
        stall = threading.Timer(0.0, lambda: (b.emulator.lock.acquire(), time.sleep(0.05),
                                              b.emulator.lock.release()))
        stall.start()
        time.sleep(0.005)
        run(b, clock, pose(), 1)
        stall.join()
        assert b.state is BridgeState.ACTIVE and b.failures.consecutive == 0
    finally:
        b.close()


def test_hardware_error_stops_commanding_and_reboot_rereads_first(gen, clock) -> None:
    emu = gen.emulator
    run(gen, clock, pose(), 5)
    emu.inject_hardware_error(2, 1 << 5)  # overload
    run(gen, clock, pose(index_mcp_flex=0.5), 2)
    assert 2 in gen.faults
    t_fault = time.perf_counter()
    run(gen, clock, pose(index_mcp_flex=1.0), 20)
    assert [g for t, _, g in emu.writes(GOAL, 2) if t > t_fault] == []
    assert emu.value(2, "torque_enable") == 0
    diag = {d.name: d for d in gen.diagnostics()}
    d2 = diag["servo_bridge: index_curl"]
    assert d2.level == 2 and "Overload Error" in d2.message
    assert d2.values["hardware_error"] == "Overload Error"
    assert [g for t, i, g in emu.writes(GOAL) if t > t_fault and i != 2]  # others go on

    emu.push(2, 1500)  # the servo was forced away while off
    t_reboot = time.perf_counter()
    ok, msg = gen.reboot()
    assert ok and "servo 2 rebooted" in msg and 2 not in gen.faults
    after = [(pkt.instruction, pkt.dxl_id, pkt.params) for t, pkt in emu.log if t >= t_reboot]
    goal_at = after.index((p2.INST_WRITE, 2, p2.u_le(GOAL, 2) + p2.u_le(1500, 4)))
    torque_at = after.index((p2.INST_WRITE, 2, p2.u_le(ct.ADDR_TORQUE_ENABLE, 2) + b"\x01"))
    read_at = [k for k, (inst, i, prm) in enumerate(after)
               if inst == p2.INST_READ and i == 2 and prm[:2] == p2.u_le(132, 2)][0]
    assert read_at < goal_at < torque_at  # re-read position, goal := it, then torque
    assert emu.value(2, "torque_enable") == 1
    run(gen, clock, pose(index_mcp_flex=1.0), 5)
    assert emu.writes(GOAL, 2)[-1][0] > t_reboot  # commanded again


def test_hardware_status_poll_latches_faults(clock) -> None:
    b = make("generic_3dof", clock, hw_status_every=1)
    b.configure()
    b.activate()
    try:
        b.emulator.inject_hardware_error(3, 1 << 2)  # overheating
        b._poll_hardware_status(clock.t)  # the periodic Sync Read of address 70
        assert b.faults.faults[3].description == "Overheating Error"
    finally:
        b.close()


def test_consecutive_comm_failures_enter_error_and_switch_torque_off(gen, clock) -> None:
    emu = gen.emulator
    run(gen, clock, pose(), 3)
    emu.set_no_reply(3)
    run(gen, clock, pose(), 2)
    assert gen.state is BridgeState.ACTIVE  # 2 < max_comm_failures = 3
    emu.set_no_reply(3, False)
    run(gen, clock, pose(), 1)  # a good cycle resets the count
    assert gen.failures.consecutive == 0
    emu.set_no_reply(3)
    run(gen, clock, pose(), 3)
    assert gen.state is BridgeState.ERROR
    assert "3 consecutive failed cycles" in gen.diagnostics()[0].message
    assert emu.value(1, "torque_enable") == 0 and emu.value(2, "torque_enable") == 0
    n = len(emu.writes(GOAL))
    run(gen, clock, pose(index_mcp_flex=1.0), 5)
    assert len(emu.writes(GOAL)) == n  # no goals in the ERROR state
    emu.set_no_reply(3, False)
    ok, msg = gen.reboot()  # recovery: re-read every servo, torque back on
    assert ok and "recovered" in msg and gen.state is BridgeState.ACTIVE
    assert all(emu.value(i, "torque_enable") == 1 for i in gen.ids)


def test_missing_or_wrong_servo_fails_configure_with_names() -> None:
    smap = load_servo_map("generic_3dof")
    with BusEmulator({1: "XL330-M288", 3: "XM430-W350"}) as emu:  # ID 2 missing
        b = ServoBridge(BridgeConfig(servo_map="generic_3dof", port=emu.port_name,
                                     packet_timeout_ms=20.0), smap)
        with pytest.raises(ServoError, match=r"no answer to ping from ID\(s\) 2 \(index_curl"):
            b.configure()
        assert b.state is BridgeState.CLOSED and not b.bus.is_open
    with BusEmulator({1: "XL330-M288", 2: "XL330-M288", 3: "XM430-W350"}) as emu:
        emu.set_bad_crc(2, -1)  # every answer corrupted: missing, named with the reason
        b = ServoBridge(BridgeConfig(servo_map="generic_3dof", port=emu.port_name,
                                     packet_timeout_ms=20.0), smap)
        with pytest.raises(ServoError, match=r"no answer to ping from ID\(s\) 2 \(index_curl"):
            b.configure()
    with BusEmulator({1: "XL330-M288", 2: "XC330-M288", 3: "XM430-W350"}) as emu:
        b = ServoBridge(BridgeConfig(servo_map="generic_3dof", port=emu.port_name), smap)
        with pytest.raises(ServoError, match="wrong model: 2 .* XC330-M288, map says "
                                             "XL330-M288"):
            b.configure()


def test_one_lost_ping_answer_does_not_fail_configure() -> None:
    """A corrupted status packet at start-up is retried, not reported as a missing servo."""
    smap = load_servo_map("generic_3dof")
    with BusEmulator({1: "XL330-M288", 2: "XL330-M288", 3: "XM430-W350"}) as emu:
        emu.set_bad_crc(2, 2)  # the first two answers of servo 2 are corrupted
        b = ServoBridge(BridgeConfig(servo_map="generic_3dof", port=emu.port_name,
                                     packet_timeout_ms=20.0), smap)
        try:
            b.configure()
            assert b.state is BridgeState.INACTIVE
        finally:
            b.close()


def test_torque_off_when_an_exception_leaves_the_context(clock) -> None:
    b = make("generic_3dof", clock)
    with pytest.raises(RuntimeError), b:
        run(b, clock, pose(), 3)
        assert all(b.emulator.value(i, "torque_enable") == 1 for i in b.ids)
        raise RuntimeError("crash in user code")
    assert all(b.emulator.servo(i).get("torque_enable") == 0 for i in b.ids)
    assert b.state is BridgeState.CLOSED


def test_torque_off_after_a_transfer_interrupted_by_a_signal(clock) -> None:
    # A signal raised while a packet is in flight leaves the SDK's port flagged busy and a
    # half-read reply behind; every later packet would be refused. Closing must recover.
    b = make("generic_3dof", clock)
    b.configure()
    b.activate()
    b.bus.port.is_using = True  # what an interrupted txRxPacket leaves behind
    b.bus.port.ser.write(b"\xff\xff\xfd")  # and stray bytes on the line
    b.close()
    assert all(b.emulator.servo(i).get("torque_enable") == 0 for i in b.ids)


def test_deactivate_switches_torque_off_and_stops_commanding(gen, clock) -> None:
    run(gen, clock, pose(), 3)
    gen.deactivate()
    assert all(gen.emulator.value(i, "torque_enable") == 0 for i in gen.ids)
    assert gen.step() is None


def test_bus_watchdog_is_armed_and_rearmed_after_a_stall() -> None:
    b = make("generic_3dof", bus_watchdog_ms=40.0)
    with b:
        emu = b.emulator
        assert emu.value(1, "bus_watchdog") == 2
        b.handle_pose(NAMES, pose())
        b.step()
        time.sleep(0.1)  # the bridge stalls: the servos stop by themselves
        assert emu.value(1, "bus_watchdog") == -1
        b.handle_pose(NAMES, pose(thumb_tm_flex=0.5))
        for _ in range(50):
            b.step()
            time.sleep(0.002)
        assert emu.value(1, "bus_watchdog") == 2  # re-armed
        assert emu.value(1, "goal_position") > 2048 - 196 + 50  # goals accepted again
    assert emu.servo(1).get("bus_watchdog") == 0


def test_usb_latency_timer_warning(tmp_path) -> None:
    (tmp_path / "ttyUSB7").mkdir()
    (tmp_path / "ttyUSB7" / "latency_timer").write_text("16\n")
    msg = usb_latency_warning("/dev/ttyUSB7", sysfs_root=str(tmp_path))
    assert msg is not None and "16 ms" in msg and "1 ms" in msg
    (tmp_path / "ttyUSB7" / "latency_timer").write_text("1\n")
    assert usb_latency_warning("/dev/ttyUSB7", sysfs_root=str(tmp_path)) is None
    with BusEmulator({1: "XL330-M288"}) as emu:  # a pty is skipped
        assert usb_latency_warning(emu.port_name, sysfs_root=str(tmp_path)) is None


def test_bad_input_is_refused_and_does_not_refresh_the_timeout(gen, clock) -> None:
    run(gen, clock, pose(), 3)
    t_fed = gen.watchdog.t_last
    clock.t += 0.1
    assert not gen.handle_pose(NAMES, pose(index_mcp_flex=float("nan")), now=clock.t)
    assert not gen.handle_pose(NAMES[:-1], pose(), now=clock.t)
    assert not gen.handle_pose(NAMES, pose(), valid=False, now=clock.t)  # lost tracking
    assert gen.watchdog.t_last == t_fed
    leap_like = make("leap_hand")  # a right hand
    assert not leap_like.handle_pose(NAMES, pose(), handedness="left")
    assert leap_like.handle_pose(NAMES, pose(), handedness="right")


def test_simulated_joint_states_drive_the_servos(gen, clock) -> None:
    names = ["sim_object_z", *NAMES]
    q = pose(thumb_tm_flex=0.5, thumb_mcp_flex=0.5)
    for _ in range(200):
        clock.t += 0.005
        assert gen.handle_joint_state(names, [0.3, *q], now=clock.t)
        gen.step()
    assert goals(gen)[0] == expected_ticks(gen, q)[0]


def test_fast_sync_read_mode(clock) -> None:
    b = make("leap_hand", clock, read_mode="fast_sync")
    with b:
        q = pose(index_pip_flex=0.7, thumb_ip_flex=0.4)
        run(b, clock, q, 300)
        assert goals(b) == expected_ticks(b, q)

        def arrived() -> bool:  # the emulated motors move in real time, not the fake clock's
            run(b, clock, q, 1)
            r = b.step()
            return bool(r.fresh.all()) and abs(r.position[2] - 0.7) <= 0.01

        assert wait_for(arrived, 10.0)


def test_read_mode_auto_uses_fast_sync_read_only_where_the_firmware_has_it() -> None:
    smap = load_servo_map("generic_3dof")
    models = {1: "XL330-M288", 2: "XL330-M288", 3: "XM430-W350"}
    with BusEmulator(models, firmware=52) as emu:
        with ServoBridge(BridgeConfig(servo_map="generic_3dof", port=emu.port_name), smap) as b:
            assert b.read_mode == "fast_sync"
            assert b.step().fresh.all()
    with BusEmulator(models, firmware=52) as emu:
        emu.servo(2).set("firmware_version", 45)  # X330 needs 46
        with ServoBridge(BridgeConfig(servo_map="generic_3dof", port=emu.port_name), smap) as b:
            assert b.read_mode == "sync"
            assert b.step().fresh.all()
            assert b.diagnostics()[0].values["read_mode"] == "sync"


def test_diagnostics_report_servo_state(gen, clock) -> None:
    gen.emulator.set_temperature(1, 65)
    run(gen, clock, pose(), 5)
    d = {r.name: r for r in gen.diagnostics()}
    bus = d["servo_bridge: bus generic_3dof"]
    assert bus.level == 0 and bus.values["state"] == "active"
    assert float(bus.values["loop_rate_hz"]) > 0
    thumb = d["servo_bridge: thumb"]
    assert thumb.values["temperature_c"] == "65" and thumb.level == 1  # near its 70 C limit
    assert thumb.values["voltage_v"] == "5.0" and thumb.values["torque"] == "on"


def test_fast_sync_read_names_the_dead_servo_and_keeps_the_others(clock) -> None:
    """Issue #20 item 8: with Fast Sync Read one dead servo failed every ID, so the ERROR
    named all of them and the whole hand stopped."""
    b = make("generic_3dof", clock, read_mode="fast_sync", max_comm_failures=3,
             packet_timeout_ms=500.0)  # healthy servos answer late under load
    b.configure()
    b.activate()
    try:
        run(b, clock, pose(), 2)
        b.emulator.set_no_reply(2)
        clock.t += 0.005
        b.handle_pose(NAMES, pose(), now=clock.t)
        r = b.step()
        assert list(r.fresh) == [True, False, True] and r.written == 2
        assert b.read_mode == "sync"  # while servo 2 is dead
        run(b, clock, pose(), 2)
        assert b.state is BridgeState.ERROR
        assert "2 (" in b.error_reason and "1 (" not in b.error_reason \
            and "3 (" not in b.error_reason, b.error_reason
        b.emulator.set_no_reply(2, False)
        ok, msg = b.reboot()
        assert ok and b.state is BridgeState.ACTIVE and b.read_mode == "fast_sync", msg
    finally:
        b.close()


def test_reboot_and_activate_reopen_a_replugged_port(clock, tmp_path) -> None:
    """Issue #20 item 8: after the adapter is pulled and plugged back (same device path, new
    device), ~/reboot (or activate) reopens the port instead of reusing the dead one."""
    smap = load_servo_map("generic_3dof")
    emu = BusEmulator.from_map(smap)
    link = tmp_path / "ttyUSB_hand"
    link.symlink_to(emu.start())
    b = ServoBridge(BridgeConfig(servo_map="generic_3dof", port=str(link),
                                 packet_timeout_ms=500.0, max_comm_failures=3), clock=clock)
    try:
        b.configure()
        b.activate()
        run(b, clock, pose(), 2)
        emu.stop()  # pulled
        run(b, clock, pose(), 3)
        assert b.state is BridgeState.ERROR
        ok, msg = b.reboot()  # still unplugged: refused, named
        assert not ok and "still failing" in msg and b.state is BridgeState.ERROR
        b.deactivate()  # what the node's lifecycle does on the ERROR
        with pytest.raises(ServoError):
            b.activate()
        link.unlink()
        link.symlink_to(emu.start())  # plugged back: a new device under the same path
        b.activate()  # re-activation reopens the port and checks every servo
        assert b.state is BridgeState.ACTIVE
        assert all(emu.value(i, "torque_enable") == 1 for i in b.ids)
        q = pose(index_mcp_flex=0.3)
        run(b, clock, q, 300)
        assert goals_of(emu, b) == expected_ticks(b, q)
        emu.stop()
        run(b, clock, pose(), 3)
        link.unlink()
        link.symlink_to(emu.start())
        ok, msg = b.reboot()  # the reboot service's path: reopen, re-read, active again
        assert ok and b.state is BridgeState.ACTIVE, msg
    finally:
        b.close()
        emu.stop()


def goals_of(emu: BusEmulator, b: ServoBridge) -> list[int]:
    return [emu.value(i, "goal_position") for i in b.ids]
