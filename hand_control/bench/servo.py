"""``hand-suite bench servo``: the servo bridge on 16 emulated servos (LEAP-Hand-style map).

Measured in one run, on in-process Protocol 2.0 emulators served on ptys and reached through
the real ``dynamixel_sdk``:

* **loop rate**: ``ServoBridge.step()`` free-running; each cycle reads the 21-byte state block
  of 16 servos (Fast Sync Read or Sync Read), checks faults, filters, clamps and rate-limits,
  and Sync-Writes 16 goal positions. The default configuration (``read_mode: auto``, which
  picks Fast Sync Read when the firmware has it) and ``read_mode: sync`` are both measured;
* **software time per cycle**: CPU time of the bridge's thread per cycle (``time.thread_time``):
  the bridge and the SDK's packet work, not the time spent waiting for the bus; the emulator
  runs in another thread and its work is not counted (real servos do it themselves). The wall
  time per cycle, which includes the emulated bus, is printed too;
* **pose -> bus latency**: the default bridge paced at 300 Hz in a thread while poses arrive
  from another thread: time from calling ``handle_pose`` to the emulator receiving the next
  Sync Write of Goal Position (includes waiting for the next cycle); and the same with the
  cycle run right after the handler (``pose_to_bus_direct_ms_p50``);
* **baseline**: the plain ``dynamixel_sdk`` loop most drivers use (``GroupSyncWrite.txPacket`` +
  ``GroupSyncRead.txRxPacket`` + ``getData`` per servo and item, stock ``PortHandler``), same
  emulator code, same run. Bridge and baseline run in alternating chunks so that load changes
  on a shared machine hit both; ``loop_ratio`` = bridge rate / baseline rate.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any

import dynamixel_sdk as sdk
import numpy as np

from hand_capture.bench import json_line, print_table
from hand_capture.model.joints import ARTICULATED_JOINTS, joint_limits_dict
from hand_control.dynamixel import control_table as ct
from hand_control.dynamixel import protocol as p2
from hand_control.dynamixel.bridge import BridgeConfig, ServoBridge
from hand_control.dynamixel.emulator import BusEmulator
from hand_control.dynamixel.servo_map import load_servo_map

MAP = "leap_hand"
CONTROL_RATE_HZ = 300.0


def _poses(n: int, seed: int = 0) -> np.ndarray:
    """Smooth random hand poses (n, 21) [rad] within the hand model's joint limits (the
    bridge refuses angles outside them)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None] * 0.05
    phase = rng.uniform(0, 2 * np.pi, len(ARTICULATED_JOINTS))
    lim = np.array([joint_limits_dict()[j] for j in ARTICULATED_JOINTS])
    mid, half = lim.mean(axis=1), 0.45 * (lim[:, 1] - lim[:, 0])
    return mid + half * np.sin(t + phase)


def _bridge_chunk(bridge: ServoBridge, seconds: float, out: dict[str, list]) -> None:
    """Free-running ``step()`` for ``seconds``; appends the rate and per-cycle times."""
    names = list(ARTICULATED_JOINTS)
    poses = _poses(64)
    n = 0
    t_end = time.perf_counter() + seconds
    t_start = time.perf_counter()
    while time.perf_counter() < t_end:
        bridge.handle_pose(names, poses[n % len(poses)])
        c0, w0 = time.thread_time(), time.perf_counter()
        r = bridge.step()
        out["cpu"].append(time.thread_time() - c0)
        out["wall"].append(time.perf_counter() - w0)
        if r is None or r.written != len(bridge.ids):
            out["faults"].append(n)
        n += 1
    out["hz"].append(n / (time.perf_counter() - t_start))


class _Baseline:
    """The plain SDK loop: stock PortHandler and groups, getData per servo and item."""

    def __init__(self, port: str, ids: tuple[int, ...]) -> None:
        self.ids = ids
        self.ph = sdk.PacketHandler(2.0)
        self.port = sdk.PortHandler(port)
        self.port.openPort()
        self.port.setBaudRate(4_000_000)
        self.sw = sdk.GroupSyncWrite(self.port, self.ph, ct.ADDR_GOAL_POSITION, 4)
        self.sr = sdk.GroupSyncRead(self.port, self.ph, ct.STATE_BLOCK_ADDR, ct.STATE_BLOCK_LEN)
        for i in ids:
            self.sr.addParam(i)

    def chunk(self, seconds: float, out: dict[str, list]) -> None:
        n = 0
        t_end = time.perf_counter() + seconds
        t_start = time.perf_counter()
        while time.perf_counter() < t_end:
            c0, w0 = time.thread_time(), time.perf_counter()
            goal = 2048 + (n % 200)
            self.sw.clearParam()
            for i in self.ids:
                self.sw.addParam(i, [sdk.DXL_LOBYTE(goal), sdk.DXL_HIBYTE(goal), 0, 0])
            self.sw.txPacket()
            if self.sr.txRxPacket() != sdk.COMM_SUCCESS:
                out["faults"].append(n)
            for i in self.ids:
                self.sr.getData(i, ct.ADDR_PRESENT_POSITION, 4)
                self.sr.getData(i, ct.ADDR_PRESENT_VELOCITY, 4)
                self.sr.getData(i, ct.ADDR_PRESENT_CURRENT, 2)
            out["cpu"].append(time.thread_time() - c0)
            out["wall"].append(time.perf_counter() - w0)
            n += 1
        out["hz"].append(n / (time.perf_counter() - t_start))

    def close(self) -> None:
        self.port.closePort()


class _GoalWriteClock:
    """Emulator listener: perf_counter times of Sync Writes to Goal Position."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.lock = threading.Lock()

    def __call__(self, t: float, pkt: p2.Packet) -> None:
        if pkt.instruction == p2.INST_SYNC_WRITE and pkt.params[:2] == b"\x74\x00":
            with self.lock:
                self.times.append(t)

    def first_after(self, t0: float, timeout: float = 0.5) -> float | None:
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            with self.lock:
                later = [t for t in self.times[-8:] if t >= t0]
            if later:
                return min(later)
            time.sleep(0.0002)
        return None


def _paced_latency(bridge: ServoBridge, clock: _GoalWriteClock, seconds: float,
                   rate_hz: float) -> dict[str, Any]:
    """Loop paced at rate_hz in a thread; poses from this thread; pose -> bus latency."""
    stop = threading.Event()
    period = 1.0 / rate_hz
    cycles = [0]
    overruns = [0]

    def loop() -> None:
        t_next = time.perf_counter()
        while not stop.is_set():
            bridge.step()
            cycles[0] += 1
            t_next += period
            delay = t_next - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                overruns[0] += 1
                t_next = time.perf_counter()

    names = list(ARTICULATED_JOINTS)
    poses = _poses(97, seed=1)
    th = threading.Thread(target=loop, daemon=True)
    lat = []
    t_start = time.perf_counter()
    th.start()
    rng = np.random.default_rng(2)
    try:
        k = 0
        while time.perf_counter() - t_start < seconds:
            time.sleep(rng.uniform(0.005, 0.015))  # poses at ~100 Hz, random phase
            t0 = time.perf_counter()
            bridge.handle_pose(names, poses[k % len(poses)])
            t1 = clock.first_after(t0)
            if t1 is not None:
                lat.append(t1 - t0)
            k += 1
    finally:
        stop.set()
        th.join(timeout=2.0)
    elapsed = time.perf_counter() - t_start
    return {"hz": cycles[0] / elapsed, "overruns": overruns[0], "cycles": cycles[0],
            "lat": np.array(lat) * 1e3}


def _direct_latency(bridge: ServoBridge, clock: _GoalWriteClock, n: int) -> np.ndarray:
    names = list(ARTICULATED_JOINTS)
    poses = _poses(n, seed=3)
    lat = []
    for k in range(n):
        t0 = time.perf_counter()
        bridge.handle_pose(names, poses[k])
        bridge.step()
        t1 = clock.first_after(t0)
        if t1 is not None:
            lat.append(t1 - t0)
    return np.array(lat) * 1e3


def _summary(label: str, m: dict[str, list]) -> list:
    cpu, wall = np.array(m["cpu"]) * 1e3, np.array(m["wall"]) * 1e3
    return [label, float(np.median(m["hz"])), *np.percentile(cpu, [50, 99]),
            *np.percentile(wall, [50, 99]), len(m["faults"])]


def run(quick: bool = False) -> dict[str, Any]:
    """Run the servo benchmark; prints tables, returns the figures (last line: JSON).

    The bridge (Sync Read and Fast Sync Read) and the baseline run in alternating chunks, so
    a load change on a shared machine hits all three alike; rates are the median over chunks.
    """
    rounds, chunk = (5, 0.4) if quick else (10, 0.8)
    seconds = 2.0 if quick else 8.0
    smap = load_servo_map(MAP)
    cfg = BridgeConfig(servo_map=MAP, command_timeout_s=60.0, packet_timeout_ms=50.0,
                       control_rate_hz=CONTROL_RATE_HZ)
    keys = ("hz", "cpu", "wall", "faults")
    m = {name: {k: [] for k in keys} for name in ("auto", "sync", "baseline")}
    bridges = {mode: ServoBridge(dataclasses.replace(cfg, read_mode=mode), smap)
               for mode in ("auto", "sync")}
    emu = BusEmulator.from_map(smap)
    baseline = None
    try:
        for b in bridges.values():
            b.configure()
            b.activate()
            _bridge_chunk(b, 0.2, {k: [] for k in keys})  # warm-up
        baseline = _Baseline(emu.start(), smap.ids)
        baseline.chunk(0.2, {k: [] for k in keys})
        for _ in range(rounds):
            for mode, b in bridges.items():
                _bridge_chunk(b, chunk, m[mode])
            baseline.chunk(chunk, m["baseline"])
    finally:
        for b in bridges.values():
            b.close()
        if baseline is not None:
            baseline.close()
        emu.stop()
    mode = bridges["auto"].read_mode
    rows = [_summary(f"bridge, default (read_mode auto -> {mode})", m["auto"]),
            _summary("bridge, read_mode sync", m["sync"]),
            _summary("baseline: plain dynamixel-sdk", m["baseline"])]
    print_table(f"servo loop, {len(smap.ids)} emulated servos (map {MAP}), {rounds} rounds of "
                f"{chunk} s each, interleaved",
                ["loop", "rate Hz", "cpu p50 ms", "cpu p99 ms", "wall p50 ms", "wall p99 ms",
                 "faults"], rows)

    bridge = ServoBridge(cfg, smap)
    clock = _GoalWriteClock()
    with bridge:
        bridge.emulator.add_listener(clock)
        paced = _paced_latency(bridge, clock, seconds, CONTROL_RATE_HZ)
        direct = _direct_latency(bridge, clock, 200 if quick else 1000)
    lat_rows = [
        [f"paced loop at {CONTROL_RATE_HZ:.0f} Hz", len(paced["lat"]),
         *np.percentile(paced["lat"], [50, 99])],
        ["handler + immediate cycle", len(direct), *np.percentile(direct, [50, 99])],
    ]
    print_table("pose -> goal bytes received by the emulator",
                ["case", "samples", "p50 ms", "p99 ms"], lat_rows)
    print(f"paced loop: {paced['hz']:.1f} Hz achieved of {CONTROL_RATE_HZ:.0f} Hz, "
          f"{paced['overruns']} overruns in {paced['cycles']} cycles")

    auto, sync, base = rows
    return {
        "servos": len(smap.ids),
        "read_mode": mode,
        "loop_hz": auto[1],
        "cycle_p50_ms": auto[2],
        "cycle_p99_ms": auto[3],
        "cycle_wall_p50_ms": auto[4],
        "cycle_wall_p99_ms": auto[5],
        "sync_loop_hz": sync[1],
        "sync_cycle_p50_ms": sync[2],
        "sync_cycle_p99_ms": sync[3],
        "paced_hz": paced["hz"],
        "paced_target_hz": CONTROL_RATE_HZ,
        "paced_overruns": paced["overruns"],
        "pose_to_bus_ms_p50": float(np.percentile(paced["lat"], 50)),
        "pose_to_bus_ms_p99": float(np.percentile(paced["lat"], 99)),
        "pose_to_bus_direct_ms_p50": float(np.percentile(direct, 50)),
        "baseline_loop_hz": base[1],
        "baseline_cycle_p50_ms": base[2],
        "baseline_cycle_p99_ms": base[3],
        "loop_ratio": auto[1] / base[1],
        "sync_loop_ratio": sync[1] / base[1],
        "bus_faults": auto[6] + sync[6],
    }


if __name__ == "__main__":
    import sys

    print(json_line(run(quick="--quick" in sys.argv)))
