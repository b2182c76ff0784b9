"""``hand-suite bench sim``: speed of the simulation + composite controller loop.

* ``baseline_rtf``: bare ``mj_step`` on the lift-box world while the box is held (1 ms steps,
  no Python around it): the ceiling every figure below is compared with.
* ``lockstep_rtf``: the lift-box scenario in one process (:class:`LockstepRunner`: servos,
  contact extraction, contact QP, Jacobian transpose and composite controller) with the
  controller at every 1 ms step (1 kHz); ``lockstep_rtf_250hz`` with the controller every 4th
  step.
  Real-time factor = simulated seconds / wall seconds, on one core (one Python thread).
* ``topics_control_hz``: the sim and controller as two ROS 2 nodes in one process (one
  executor, Fast DDS in-process), the sim paced to real time and publishing every 2 steps:
  the rate at which joint commands computed from fresh states arrive at the sim, and the
  real-time factor the sim keeps (``topics_rtf``); ``topics2_*`` the same with the two
  nodes in two processes (read from the sim's diagnostics).
"""

from __future__ import annotations

import time
from typing import Any

import mujoco

from hand_capture.bench import print_table
from hand_control.control import CompositeControlConfig
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import load_scenario


def _bare_rtf(runner: LockstepRunner, seconds: float) -> float:
    """RTF of mj_step alone from a held-box state (after lifting)."""
    w = runner.world
    w.reset()
    for _ in range(int(runner.reference.t_carry0 / w.model.opt.timestep)):
        runner.control_step(w.time)
        w.step()
    m, d = w.model, w.data
    n = int(seconds / m.opt.timestep)
    t0 = time.perf_counter()
    for _ in range(n):
        mujoco.mj_step(m, d)
    return n * m.opt.timestep / (time.perf_counter() - t0)


def _topics(seconds: float) -> dict[str, float]:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from hand_control.nodes.controller import ControllerNode
    from hand_control.nodes.sim import SimNode

    rclpy.init()
    try:
        sim = SimNode(parameter_overrides=[Parameter("scenario", value="lift_box"),
                                           Parameter("real_time", value=True),
                                           Parameter("steps_per_tick", value=2)])
        ctrl = ControllerNode(parameter_overrides=[Parameter("scenario", value="lift_box")])
        ex = SingleThreadedExecutor()
        ex.add_node(sim)
        ex.add_node(ctrl)
        t_end = time.perf_counter() + 1.0  # discovery and warm-up
        while time.perf_counter() < t_end:
            ex.spin_once(timeout_sec=0.001)
        acc0, sim0, t0 = sim.accepted, sim.world.time, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            ex.spin_once(timeout_sec=0.001)
        wall = time.perf_counter() - t0
        out = {"topics_control_hz": (sim.accepted - acc0) / wall,
               "topics_rtf": (sim.world.time - sim0) / wall,
               "topics_rejected": sim.rejected,
               "topics_qp_fallbacks": ctrl.core.counters["qp_fallbacks"]}
        ex.remove_node(sim)
        ex.remove_node(ctrl)
        ex.shutdown()  # before rclpy's: an executor collected after it logs an error
        sim.destroy_node()
        ctrl.destroy_node()
        return out
    finally:
        rclpy.shutdown()


def _topics_two_processes(seconds: float) -> dict[str, float]:
    """Sim and controller as two processes; rates read from the sim's diagnostics."""
    import os
    import subprocess
    import sys

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs = [subprocess.Popen([sys.executable, "-m", f"hand_control.nodes.{mod}", "--ros-args",
                               "-p", "scenario:=lift_box", *extra],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for mod, extra in (("sim", ["-p", "real_time:=true"]), ("controller", []))]
    rclpy.init()
    samples: list[tuple[float, float, float]] = []  # (wall, sim time, commands accepted)

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name == "sim":
                v = {kv.key: kv.value for kv in st.values}
                samples.append((time.perf_counter(), float(v["sim_time"]),
                                float(v["commands_accepted"])))

    node = rclpy.create_node("bench_sim_probe")
    node.create_subscription(DiagnosticArray, "diagnostics", on_diag, 10)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        deadline = time.perf_counter() + seconds + 15.0
        while time.perf_counter() < deadline:
            ex.spin_once(timeout_sec=0.1)
            # skip the first samples (start-up, discovery), then measure over `seconds`
            live = [s for s in samples if s[2] > 0]
            if len(live) >= 2 and live[-1][0] - live[0][0] >= seconds:
                break
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown()
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
    live = [s for s in samples if s[2] > 0]
    if len(live) < 2:
        return {"topics2_control_hz": float("nan"), "topics2_rtf": float("nan")}
    (w0, t0, c0), (w1, t1, c1) = live[0], live[-1]
    return {"topics2_control_hz": (c1 - c0) / (w1 - w0), "topics2_rtf": (t1 - t0) / (w1 - w0)}


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """The figures; ``smoke``: short episodes and topic runs through the same code."""
    from hand_capture.cameras.threads import limit_blas_threads

    limit_blas_threads(1)  # one core: no BLAS worker threads beside the loop
    spec = load_scenario("lift_box")
    if smoke:
        spec = spec.with_(t_reach=0.2, t_close=0.2, t_settle=0.1, t_lift=0.2, t_carry=0.2,
                          t_hold=0.1)
    elif quick:
        spec = spec.with_(t_lift=0.6, t_carry=0.6, t_hold=0.3)
    runner = LockstepRunner(spec)
    baseline = _bare_rtf(runner, 0.3 if smoke else 1.0 if quick else 3.0)
    r1 = runner.run()
    r4 = LockstepRunner(spec, control_every=4, plan=runner.plan).run()
    pd = LockstepRunner(spec, gains=CompositeControlConfig(mode="pd_only"),
                        plan=runner.plan).run()
    seconds = 1.0 if smoke else 3.0 if quick else 10.0
    topics = _topics(seconds)
    topics.update(_topics_two_processes(seconds))
    rows = [
        ["bare mj_step (baseline)", baseline, 1.0, "-"],
        ["lockstep, composite @ 1 kHz", r1.rtf, r1.rtf / baseline, 1000.0],
        ["lockstep, composite @ 250 Hz", r4.rtf, r4.rtf / baseline, 250.0],
        ["lockstep, PD only @ 1 kHz", pd.rtf, pd.rtf / baseline, 1000.0],
        ["two nodes, one process, over topics", topics["topics_rtf"],
         topics["topics_rtf"] / baseline, topics["topics_control_hz"]],
        ["two nodes, two processes, over topics", topics["topics2_rtf"],
         topics["topics2_rtf"] / baseline, topics["topics2_control_hz"]],
    ]
    print_table("sim + controller (lift_box, 1 ms physics step, one core)",
                ["loop", "real-time factor", "vs bare mj_step", "control rate Hz"], rows)
    return {
        "baseline_rtf": baseline,
        "lockstep_rtf": r1.rtf,
        "lockstep_rtf_250hz": r4.rtf,
        "lockstep_pd_only_rtf": pd.rtf,
        "lockstep_vs_baseline": r1.rtf / baseline,
        "lockstep_success": r1.success,
        "control_ms_per_step": 1e3 * r1.control_s / max(r1.control_steps, 1),
        **topics,
    }
