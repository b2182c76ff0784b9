"""``hand-suite bench executor``: CPU per wake-up of :class:`LeanExecutor` against rclpy's.

A node with one timer (2 ms period) and ``n`` idle subscriptions is spun by each executor for
a fixed number of ticks; the figure is the process's thread CPU time per tick [ms]
(``time.thread_time``), so other load on the machine does not count. Baseline in the same run:
rclpy's ``SingleThreadedExecutor`` on the same node. Every node of the suite spins on
:class:`~hand_capture.nodes.executor.LeanExecutor` (``run_node``'s default).
"""

from __future__ import annotations

import time
from typing import Any

from hand_capture.bench import print_table


def _cpu_per_tick_ms(executor_cls, n_subs: int, ticks: int) -> float:
    """Thread CPU [ms] per timer tick of a node with ``n_subs`` idle subscriptions."""
    import rclpy
    from std_msgs.msg import String

    rclpy.init()
    try:
        node = rclpy.create_node("bench_executor")
        for i in range(n_subs):
            node.create_subscription(String, f"bench_executor/idle_{i}", lambda _m: None, 10)
        ex = executor_cls()
        ex.add_node(node)
        n = [0]
        node.create_timer(0.002, lambda: n.__setitem__(0, n[0] + 1))
        for _ in range(20):  # warm-up
            ex.spin_once(timeout_sec=0.1)
        n[0], t0 = 0, time.thread_time()
        while n[0] < ticks:
            ex.spin_once(timeout_sec=0.1)
        dt = (time.thread_time() - t0) / n[0]
        ex.shutdown()
        node.destroy_node()
        return dt * 1e3
    finally:
        rclpy.try_shutdown()


def run(quick: bool = False) -> dict[str, Any]:
    from rclpy.executors import SingleThreadedExecutor

    from hand_capture.nodes.executor import LeanExecutor

    ticks = 200 if quick else 1000
    rows, out = [], {}
    for n_subs in (0, 25):
        base = min(_cpu_per_tick_ms(SingleThreadedExecutor, n_subs, ticks) for _ in range(2))
        lean = min(_cpu_per_tick_ms(LeanExecutor, n_subs, ticks) for _ in range(2))
        rows.append([n_subs, base, lean, lean / base])
        out[f"rclpy_ms_per_tick_{n_subs}_subs"] = base
        out[f"lean_ms_per_tick_{n_subs}_subs"] = lean
        out[f"lean_vs_rclpy_{n_subs}_subs"] = lean / base
    print_table("CPU per timer tick [ms] (thread time, best of 2)",
                ["idle subscriptions", "rclpy SingleThreadedExecutor", "LeanExecutor", "ratio"],
                rows)
    return out
