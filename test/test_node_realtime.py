"""The realtime_priority parameter every node gets from run_node: SCHED_FIFO for all of the
process's threads when permitted, otherwise a warning and normal scheduling; 0 changes
nothing; values outside 0..98 are refused."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
import rclpy
from rclpy.exceptions import InvalidParameterValueException
from rclpy.parameter import Parameter
from ros_helpers import ROOT

from hand_capture.nodes import realtime

NODE = """
import os, sys, threading
from rclpy.node import Node
from hand_capture.nodes.shell import run_node

class Probe(Node):
    def __init__(self):
        super().__init__("rt_probe")
        self.create_timer(0.05, self._tick)

    def _tick(self):
        later = []
        t = threading.Thread(target=lambda: later.append(os.sched_getscheduler(0)))
        t.start(); t.join()
        tasks = os.listdir("/proc/self/task")
        policies = {os.sched_getscheduler(int(x)) for x in tasks}
        print("policies", sorted(policies), "thread", later[0], "fifo", os.SCHED_FIFO,
              "threads", len(tasks), flush=True)
        raise KeyboardInterrupt

sys.exit(run_node(Probe, sys.argv))
"""


def test_a_node_runs_all_its_threads_under_sched_fifo_or_says_why_not() -> None:
    out = subprocess.run([sys.executable, "-c", NODE, "--ros-args", "-p",
                          "realtime_priority:=7"], cwd=ROOT, text=True, capture_output=True,
                         timeout=60, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    text = out.stdout + out.stderr
    assert out.returncode == 0, text
    line = next(x for x in out.stdout.splitlines() if x.startswith("policies"))
    m = re.match(r"policies \[([0-9, ]+)\] thread (\d+) fifo (\d+) threads (\d+)", line)
    assert m, line
    policies = {int(v) for v in m.group(1).split(", ")}
    later, fifo, n_threads = int(m.group(2)), int(m.group(3)), int(m.group(4))
    if "SCHED_FIFO priority 7" in text:  # permitted here (CAP_SYS_NICE or an rtprio limit)
        # every thread (rclpy's, the middleware's) and one started later
        assert policies == {fifo} and later == fifo and n_threads > 1, line
    else:  # not permitted: said, and the node ran normally
        assert "realtime_priority 7 not applied" in text, text
        assert fifo not in policies and later != fifo, line


@pytest.fixture()
def node():
    rclpy.init()
    made = []

    def make(**params):
        n = rclpy.create_node("rt_test", parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        made.append(n)
        return n

    yield make
    for n in made:
        n.destroy_node()
    rclpy.shutdown()


def test_without_permission_the_node_warns_and_keeps_normal_scheduling(node, monkeypatch):
    calls = []

    def refuse(tid, policy, param):
        calls.append((tid, policy, param.sched_priority))
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    n = node(realtime_priority=12)
    assert realtime.apply_realtime_priority(n) == 0
    assert calls and calls[0][1:] == (os.SCHED_FIFO, 12)


def test_zero_changes_nothing_and_out_of_range_is_refused(node, monkeypatch):
    monkeypatch.setattr(os, "sched_setscheduler",
                        lambda *a: pytest.fail("scheduling changed for priority 0"))
    assert realtime.apply_realtime_priority(node()) == 0  # the default
    with pytest.raises(InvalidParameterValueException):
        realtime.apply_realtime_priority(node(realtime_priority=99))
