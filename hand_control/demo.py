"""The README's main job, for now: the replay graph on a bag the project generates itself.

Writes a 3 s sample bag (a hand opening and closing, with contacts), plays it through the
``replay`` graph (bag_player -> bag_recorder) over ROS 2, and checks that the re-recorded bag
holds the same messages with the same relative timing.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from hand_capture.bag.compare import compare_bags
from hand_capture.bag.sample import write_sample_bag
from hand_capture.bench import print_table
from hand_control.graph import load_graph
from hand_control.runner import run_graph


def replay_demo(out: Path) -> int:
    """Run the replay demo into ``out``; returns the exit code (0 = round trip exact)."""
    out = out.resolve()
    sample, replayed = out / "sample_bag", out / "replayed_bag"
    for p in (sample, replayed):
        if p.exists():
            shutil.rmtree(p)
    out.mkdir(parents=True, exist_ok=True)
    n = write_sample_bag(sample)
    print(f"[demo] wrote the sample bag {sample} ({n} messages, 3 s)")
    graph = load_graph("replay")
    run = run_graph(graph, overrides={"bag_player": {"bag": str(sample)},
                                      "bag_recorder": {"output": str(replayed)}})
    if run.code != 0:
        print(f"[demo] the replay graph failed (nodes: {run.failed})")
        return run.code
    cmp = compare_bags(sample, replayed)
    rows = [(t, cmp.counts_a.get(t, 0), cmp.counts_b.get(t, 0))
            for t in sorted(set(cmp.counts_a) | set(cmp.counts_b))]
    print_table("replay round trip", ["topic", "played", "re-recorded"], rows)
    print(f"\npayloads identical: {cmp.payloads_equal}; relative timing error: "
          f"max {cmp.max_timing_err_ms:.2f} ms")
    for m in cmp.mismatches:
        print(f"  mismatch: {m}")
    print(f"\n[demo] bags: {sample} (played), {replayed} (re-recorded)")
    return 0 if cmp.same_messages else 1
