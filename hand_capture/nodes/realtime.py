"""Real-time scheduling of a node's process: the ``realtime_priority`` parameter.

Every node run by :func:`~hand_capture.nodes.shell.run_node` has it. With a priority p in
1..98 the process's threads (the executor's, the middleware's and those started later, which
inherit it) run under ``SCHED_FIFO`` at p: a woken node then preempts the normally scheduled
processes at once instead of waiting for a time slice, which is what keeps the latency of a
camera -> tracker -> controller -> servo chain low on a machine with few cores. Higher
priorities preempt lower ones. The kernel's real-time throttling (``sched_rt_runtime_us``,
95 % of each second by default) keeps a runaway node from locking the machine.

It needs ``CAP_SYS_NICE`` or an rtprio limit (e.g. ``@realtime - rtprio 98`` in
``/etc/security/limits.conf``, as ros2_control asks for); without them the node logs a
warning and runs with normal scheduling, as it would with 0 (the default).
"""

from __future__ import annotations

import os

from rcl_interfaces.msg import IntegerRange, ParameterDescriptor
from rclpy.node import Node

__all__ = ["PARAMETER", "apply_realtime_priority"]

PARAMETER = "realtime_priority"
MAX_PRIORITY = 98  # 99 is left to the kernel's own threads (watchdogs)


def apply_realtime_priority(node: Node) -> int:
    """Declare ``realtime_priority`` on ``node`` and apply it to the process.

    Returns:
        the priority in effect: the parameter's value, or 0 when it is 0 or could not be
        applied (then a warning says why).
    """
    prio = int(node.declare_parameter(PARAMETER, 0, ParameterDescriptor(
        description="SCHED_FIFO priority of this node's process (1-98; 0 = normal "
        "scheduling); needs CAP_SYS_NICE or an rtprio limit, else a warning and normal "
        "scheduling",
        read_only=True,
        integer_range=[IntegerRange(from_value=0, to_value=MAX_PRIORITY, step=1)],
    )).value)
    if prio <= 0:
        return 0
    try:
        param = os.sched_param(prio)
        for tid in sorted(int(t) for t in os.listdir("/proc/self/task")):
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, param)
            except ProcessLookupError:  # a thread that ended meanwhile
                continue
    except (AttributeError, OSError) as e:  # no permission, or not Linux
        node.get_logger().warning(
            f"realtime_priority {prio} not applied ({e}); running with normal scheduling. "
            "Real-time scheduling needs CAP_SYS_NICE or an rtprio limit "
            "(/etc/security/limits.conf).")
        return 0
    node.get_logger().info(f"real-time scheduling: SCHED_FIFO priority {prio}")
    return prio
