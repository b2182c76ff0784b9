"""``hand-suite bench pipeline``: end-to-end latency, throughput and CPU of the teleop graph.

The ``teleop`` graph runs live over DDS as the README's main job does (synthetic camera at
30 fps performing the reach-grasp-lift, tracker, grasp_phase, controller + sim, servo bridge on
the emulated bus, recorder of every topic). From the recorded bag, for each source image stamp,
the first message of each stage carrying it gives that stage's latency (receive time minus the
image stamp): image -> hand/pose -> control/hand_target -> control/joint_command -> servo/goal
(the goals written to the bus). Throughput: hand poses per second while the performance runs;
CPU: each node's share of one core over the performance (``psutil``, sampled every 0.5 s).

Baselines in the same run: the same graph with the tracker replaced by the camera's ground
truth (grasp_phase follows ``hand/pose_truth``), i.e. the latency of everything but tracking;
and the same graph with normal scheduling (``realtime_priority`` 0 for every node; the teleop
parameters put the chain camera -> servo bridge under ``SCHED_FIFO`` where the machine permits
it, and the table says on how many nodes it took effect). ``--quick`` plays the performance at
double speed.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from io import StringIO
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.bench import print_table

STAGES = (("image", "camera/depth/image_raw"), ("pose", "hand/pose"),
          ("hand target", "control/hand_target"), ("command", "control/joint_command"),
          ("servo write", "servo/goal"))


def _motion_window(data) -> tuple[int, int]:
    """Receive times [ns] of the performance: first change of the true pose to the last one."""
    from hand_capture.posemsg import pose_from_msg

    td = data.topics["hand/pose_truth"]
    q = np.array([pose_from_msg(m) for m in td.msgs])
    moving = np.nonzero(np.abs(np.diff(q, axis=0)).max(axis=1) > 1e-9)[0]
    if moving.size == 0:
        return td.t_ns[0], td.t_ns[-1]
    return td.t_ns[int(moving[0])], td.t_ns[int(moving[-1]) + 1]


def _rate(t_ns: list[int], w0: int, w1: int) -> float:
    """Messages per second received between w0 and w1 [ns]."""
    t = np.asarray(t_ns)
    return np.count_nonzero((t >= w0) & (t <= w1)) / max((w1 - w0) * 1e-9, 1e-9)


def _cpu_share(samples: list[tuple[float, dict[str, float]]], t0: float, t1: float
               ) -> dict[str, float]:
    """Each node's CPU [% of one core] between wall times t0 and t1 [s] from the samples."""
    if len(samples) < 2:
        return {}
    ts = np.array([s[0] for s in samples])
    i0 = int(np.clip(np.searchsorted(ts, t0), 0, len(ts) - 1))
    i1 = int(np.clip(np.searchsorted(ts, t1), 0, len(ts) - 1))
    if i1 <= i0:
        i0, i1 = 0, len(ts) - 1
    a, b = samples[i0][1], samples[i1][1]
    dt = ts[i1] - ts[i0]
    return {k: 100.0 * (b[k] - a.get(k, 0.0)) / dt for k in b if dt > 0}


def _run_graph(graph, out: Path, quick: bool, log: StringIO,
               normal_scheduling: bool = False, speed: float | None = None) -> dict[str, Any]:
    from hand_control.report.series import (
        SAME_CLOCK_MS,
        latency_ms,
        load_bag,
        max_lift_mm,
        positions,
    )
    from hand_control.runner import run_graph

    cpu: dict[str, float] = {}
    samples: list[tuple[float, dict[str, float]]] = []
    last = [0.0]

    def poll() -> bool:
        now = time.time()
        if now - last[0] >= 0.5:
            last[0] = now
            samples.append((now, dict(cpu)))
        return False

    over: dict[str, dict[str, Any]] = {n.name: {} for n in graph.nodes}
    over["bag_recorder"]["output"] = str(out)
    if speed is not None:
        over["synthetic_camera"]["speed"] = speed
    elif quick:
        over["synthetic_camera"]["speed"] = 2.0
    if normal_scheduling:
        for n in graph.nodes:
            over[n.name]["realtime_priority"] = 0
    run = run_graph(graph, overrides=over, out=log, install_signal_handlers=False,
                    should_stop=poll, cpu=cpu)
    if run.code != 0:
        raise RuntimeError(f"graph {graph.name} failed ({run.failed}):\n{log.getvalue()[-4000:]}")
    data = load_bag(out, skip=("camera/color/image_raw", "hand/debug_image", "hand/markers",
                               "control/contact_markers"))
    w0, w1 = _motion_window(data)
    res: dict[str, Any] = {"stages": {},
                           "realtime_nodes": log.getvalue().count("real-time scheduling: ")}
    for label, topic in STAGES:
        td = data.topics.get(topic)
        if td is None or not td.msgs:
            continue
        st, lat = latency_ms(td)
        keep = (st >= w0) & (np.abs(lat) <= SAME_CLOCK_MS)
        if keep.any():
            res["stages"][label] = lat[keep]
    poses = data.topics.get("hand/pose") or data.topics.get("control/hand_target")
    res["fps"] = _rate(poses.t_ns, w0, w1)
    res["camera_fps"] = _rate(data.topics["camera/depth/image_raw"].t_ns, w0, w1)
    res["cpu"] = _cpu_share(samples, w0 * 1e-9, w1 * 1e-9)
    obj = data.topics.get("sim/object_pose")
    if obj is not None and obj.msgs:
        res["lift_mm"] = max_lift_mm(positions(obj.msgs))
    return res


def _truth_graph(graph):
    """The teleop graph with the camera's ground truth in place of the tracker."""
    from hand_capture.config import load_yaml
    from hand_capture.paths import config_dir

    cam = load_yaml(config_dir() / "teleop.yaml")["synthetic_camera"]["ros__parameters"]
    wait = [t for t in cam.get("wait_for_topics", []) if t != "hand/pose"]  # no tracker
    nodes = []
    for n in graph.nodes:
        if n.executable == "tracker":
            continue
        if n.name == "grasp_phase":
            n = replace(n, remappings={**n.remappings, "hand/pose": "hand/pose_truth"})
        if n.name == "synthetic_camera" and wait:
            n = replace(n, parameters={**n.parameters, "wait_for_topics": wait})
        nodes.append(n)
    return replace(graph, name=f"{graph.name}_truth", nodes=tuple(nodes))


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """The figures; ``smoke``: the performance played 5x faster through the same graphs."""
    from hand_control.graph import load_graph

    graph = load_graph("teleop")
    results = {}
    with tempfile.TemporaryDirectory(prefix="hand_suite_pipeline_") as tmp:
        for key, g, normal in (("tracked", graph, False), ("truth", _truth_graph(graph), False),
                               ("normal", graph, True)):
            t0 = time.monotonic()
            results[key] = _run_graph(g, Path(tmp) / key, quick, StringIO(), normal,
                                      speed=5.0 if smoke else None)
            print(f"[bench pipeline] {key}: {time.monotonic() - t0:.1f} s, real-time "
                  f"scheduling on {results[key]['realtime_nodes']} nodes", flush=True)
    rows = []
    for key in ("tracked", "truth", "normal"):
        for label, v in results[key]["stages"].items():
            rows.append([key, label, len(v), float(np.percentile(v, 50)),
                         float(np.percentile(v, 99)), float(v.max())])
    print_table("latency since the source image stamp [ms] (first message per stamp; normal = "
                "tracked with normal scheduling)",
                ["graph", "stage", "n", "p50", "p99", "max"], rows)
    tr, base = results["tracked"], results["truth"]
    print_table("throughput while the performance runs",
                ["graph", "real-time nodes", "camera fps", "hand poses / s", "box lift mm"],
                [[k, results[k]["realtime_nodes"], results[k]["camera_fps"], results[k]["fps"],
                  results[k].get("lift_mm", float("nan"))]
                 for k in ("tracked", "truth", "normal")])
    nodes = sorted(set(tr["cpu"]) | set(base["cpu"]))
    print_table("CPU per node [% of one core] while the performance runs",
                ["node", "tracked", "truth (no tracker)"],
                [[n, tr["cpu"].get(n, float("nan")), base["cpu"].get(n, float("nan"))]
                 for n in nodes])
    end = tr["stages"].get("servo write", np.array([np.nan]))
    end_b = base["stages"].get("servo write", np.array([np.nan]))
    end_n = results["normal"]["stages"].get("servo write", np.array([np.nan]))
    p50, p99 = float(np.percentile(end, 50)), float(np.percentile(end, 99))
    b50 = float(np.percentile(end_b, 50))
    return {
        "latency_p50_ms": p50, "latency_p99_ms": p99, "fps": float(tr["fps"]),
        "camera_fps": float(tr["camera_fps"]),
        "pose_latency_p50_ms": float(np.percentile(tr["stages"].get("pose", [np.nan]), 50)),
        "command_latency_p50_ms": float(np.percentile(tr["stages"].get("command", [np.nan]),
                                                      50)),
        "truth_latency_p50_ms": b50, "latency_vs_truth": p50 / b50 if b50 > 0 else None,
        "realtime_nodes": tr["realtime_nodes"],
        "normal_latency_p50_ms": float(np.percentile(end_n, 50)),
        "normal_latency_p99_ms": float(np.percentile(end_n, 99)),
        "cpu_percent": {k: round(v, 1) for k, v in tr["cpu"].items()},
        "lift_mm": tr.get("lift_mm"), "truth_lift_mm": base.get("lift_mm"),
    }
