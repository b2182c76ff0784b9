"""The README's main job: teleoperation end to end, recorded, with a report.

Runs the ``teleop`` graph (config/graphs/teleop.yaml): on a machine without hardware, the
synthetic camera performs the operator's reach-grasp-lift of the scenario's box
(``data/teleop/lift_box.npz``), the tracker follows the hand in the depth images, grasp_phase
turns it into grasp phases and hand/object targets, the contact-force controller and the MuJoCo
simulation grasp, lift and carry the box, and the servo bridge drives the emulated LEAP Hand
bus. Every topic is recorded; the graph ends one second after the performance, and the report
(:func:`hand_control.report.build_report`, with rendered frames of the simulation) is written
from the bag.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from hand_capture.bench import print_table
from hand_capture.config import load_yaml
from hand_capture.paths import config_dir
from hand_control.graph import load_graph
from hand_control.report import build_report
from hand_control.report.frames import sim_frame_renderer
from hand_control.runner import run_graph

#: Numbers of the report printed at the end, with their labels.
SUMMARY = (
    ("tracking_mean_err_mm", "tracking error, mean keypoint [mm]"),
    ("tracking_success_20mm", "tracked frames with every keypoint within 20 mm"),
    ("latency_pose_p50_ms", "camera -> hand pose, p50 [ms]"),
    ("latency_command_p50_ms", "camera -> joint command, p50 [ms]"),
    ("latency_servo_write_p50_ms", "camera -> servo write, p50 [ms]"),
    ("latency_servo_write_p99_ms", "camera -> servo write, p99 [ms]"),
    ("object_max_lift_mm", "highest lift of the simulated box [mm]"),
    ("object_err_mean_mm", "object error against its target in manipulation [mm]"),
)


def teleop_scenario() -> str:
    """The scenario the teleop graph runs (``/**: scenario`` of config/teleop.yaml)."""
    data = load_yaml(config_dir() / "teleop.yaml") or {}
    return str(data["/**"]["ros__parameters"]["scenario"])


def teleop_demo(out: Path, timeout_s: float = 300.0) -> int:
    """Run the teleop graph into ``out``/teleop_bag and write ``out``/report; exit code."""
    out = out.resolve()
    bag, report_dir = out / "teleop_bag", out / "report"
    for p in (bag, report_dir):
        if p.exists():
            shutil.rmtree(p)
    out.mkdir(parents=True, exist_ok=True)
    print(f"[demo] teleop graph: synthetic camera -> tracker -> grasp_phase -> controller + sim "
          f"-> servo bridge (emulated bus); recording every topic to {bag}")
    t0 = time.monotonic()
    last = [t0]

    def progress() -> bool:
        now = time.monotonic()
        if now - last[0] >= 5.0:
            last[0] = now
            print(f"[demo] running for {now - t0:.0f} s ...", flush=True)
        return now - t0 > timeout_s

    run = run_graph(load_graph("teleop"), overrides={"bag_recorder": {"output": str(bag)}},
                    should_stop=progress)
    if run.code != 0:
        print(f"[demo] the teleop graph failed (nodes: {run.failed})")
        return run.code
    if time.monotonic() - t0 > timeout_s:
        print(f"[demo] stopped after {timeout_s:.0f} s: the performance did not end")
        return 1
    print(f"[demo] graph finished after {time.monotonic() - t0:.1f} s; writing the report")
    res = build_report(bag, report_dir, frames_fn=sim_frame_renderer(teleop_scenario()),
                       title="hand_suite teleoperation run")
    rows = [(label, f"{res.numbers[k]:.3g}") for k, label in SUMMARY if k in res.numbers]
    print_table("teleoperation run (from the recorded bag)", ["figure", "value"], rows)
    for m in res.missing:
        print(f"  not in the bag: {m}")
    print(f"\n[demo] bag:    {bag}")
    print(f"[demo] report: {res.html} ({len(res.figures)} figures; open it in a browser)")
    return 0
