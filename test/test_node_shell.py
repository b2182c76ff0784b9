"""The node shell's stop path: a stop signal ends the node with exit code 0 and its shutdown
hook runs to the end, whatever the signal interrupted and however many signals follow."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from ros_helpers import ROOT, wait_for

#: A node whose timer callback turns an interrupt into another exception (as pybind11 does
#: when a signal lands while rclpy converts a message), and whose shutdown hook takes 1 s;
#: with --stuck-teardown its destroy_node never returns (--stuck-teardown-gil: holding the GIL).
NODE = """
import atexit, sys, time
from rclpy.node import Node
from hand_capture.nodes.shell import run_node

class Slow(Node):
    def __init__(self):
        super().__init__("slow_stop")
        self.ticked = False
        self.create_timer(0.01, self._tick)
        if "--slow-build" in sys.argv:  # e.g. a recorder that has opened its bag, still busy
            print("building", flush=True)
            time.sleep(1.0)
        print("up", flush=True)

    def _tick(self):
        if not self.ticked:  # the executor spins: a stack dump now shows it
            self.ticked = True
            print("ticking", flush=True)
        try:
            time.sleep(0.05)
        except KeyboardInterrupt:
            raise RuntimeError("Unable to convert call argument") from None
        if "--fail" in sys.argv:
            raise RuntimeError("a real failure")

    def on_shutdown(self):
        print("stopping", flush=True)
        time.sleep(1.0)
        print("stopped", flush=True)

    def destroy_node(self):
        if "--stuck-teardown" in sys.argv:  # as Fast DDS's participant deletion once hung
            atexit.register(print, "backstop", flush=True)  # e.g. the servo bridge's close
            print("tearing down", flush=True)
            time.sleep(3600)
        if "--stuck-teardown-gil" in sys.argv:  # hung inside C code that holds the GIL,
            print("tearing down", flush=True)   # as rclpy's destroy calls in Fast DDS
            sum(range(10**14))
        super().destroy_node()

sys.exit(run_node(Slow, sys.argv))
"""


@contextmanager
def _node(*args: str) -> Iterator[tuple[subprocess.Popen, list[str]]]:
    """The NODE process and its output lines so far; killed on the way out if still up."""
    p = subprocess.Popen([sys.executable, "-c", NODE, *args], cwd=ROOT, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(p.stdout), daemon=True).start()
    try:
        yield p, lines
    finally:
        if p.poll() is None:
            p.kill()


def test_signal_inside_a_callback_is_a_clean_stop_and_a_second_signal_spares_the_hook() -> None:
    with _node() as (p, lines):
        assert wait_for(lambda: "up\n" in lines, 30.0), lines
        p.send_signal(signal.SIGINT)
        assert wait_for(lambda: "stopping\n" in lines, 10.0), lines
        p.send_signal(signal.SIGTERM)  # a runner escalating while torque goes off
        assert p.wait(timeout=10) == 0, "".join(lines)
    assert wait_for(lambda: "stopped\n" in lines, 2.0), lines
    assert not any("failed" in ln for ln in lines), lines


def test_signal_while_the_node_is_built_still_runs_its_shutdown_hook() -> None:
    # Under load a graph can be stopped while a node's constructor runs (a recorder that has
    # already opened its bag): the node must still be finished, or the bag is lost.
    with _node("--slow-build") as (p, lines):
        assert wait_for(lambda: "building\n" in lines, 30.0), lines
        p.send_signal(signal.SIGINT)
        assert p.wait(timeout=10) == 0, "".join(lines)
    assert wait_for(lambda: "stopped\n" in lines, 2.0), lines
    assert "up\n" in lines  # the constructor finished, then the hook ran


def test_a_failure_without_a_signal_is_reported_and_exits_one() -> None:
    with _node("--fail") as (p, lines):
        assert p.wait(timeout=30) == 1
    assert wait_for(lambda: "stopped\n" in lines, 2.0), lines
    out = "".join(lines)
    assert "[slow_stop] failed:" in out and "a real failure" in out


def test_sigusr1_prints_the_stacks_and_the_node_goes_on() -> None:
    """Where a stuck node is: SIGUSR1 prints every thread's stack (the graph runner sends it
    before SIGKILL); the node keeps running and still stops cleanly."""
    with _node() as (p, lines):
        # "up" comes from the constructor, before the executor exists: wait for the first
        # timer callback, so that the stack shows the spinning loop
        assert wait_for(lambda: "ticking\n" in lines, 30.0), lines
        p.send_signal(signal.SIGUSR1)
        assert wait_for(lambda: any("in _spin" in ln for ln in lines), 10.0), lines
        n_up = len(lines)
        p.send_signal(signal.SIGUSR1)  # again: still running, and says so again
        assert wait_for(lambda: sum("in _spin" in ln for ln in lines[n_up:]) >= 1, 10.0), lines
        assert p.poll() is None
        p.send_signal(signal.SIGINT)
        assert p.wait(timeout=10) == 0, "".join(lines)
    assert wait_for(lambda: "stopped\n" in lines, 2.0), lines
    assert not any("failed" in ln for ln in lines), lines


def _stop_through_a_hung_teardown(flag: str) -> tuple[list[str], str]:
    """Start NODE with ``flag``, stop it with SIGINT, expect exit 0 after its hook ran; the
    output lines and their text."""
    with _node(flag) as (p, lines):
        assert wait_for(lambda: "up\n" in lines, 30.0), lines
        p.send_signal(signal.SIGINT)
        assert wait_for(lambda: "tearing down\n" in lines, 10.0), lines
        assert p.wait(timeout=30) == 0, "".join(lines)
    out = "".join(lines)
    assert "stopped\n" in lines, out  # the hook ran to its end before the teardown
    return lines, out


def test_a_teardown_that_hangs_after_the_hook_still_ends_the_process_with_its_code() -> None:
    """Fast DDS's participant deletion once hung a camera node until the graph runner killed
    it (a graph that had stopped cleanly then exited 1): after the hook has finished, the
    shell gives the teardown TEARDOWN_TIMEOUT seconds, says so, runs the atexit backstops
    and exits with 0."""
    lines, out = _stop_through_a_hung_teardown("--stuck-teardown")
    assert "[slow_stop] the DDS teardown did not finish" in out, out
    assert "backstop\n" in lines, out  # the atexit backstops ran before the hard exit


def test_a_teardown_hung_with_the_gil_held_still_ends_the_process_with_its_code() -> None:
    """rclpy's destroy calls hold the GIL while Fast DDS hangs (a CI run's sim node: its
    Python watchdog never ran): the stacks are printed and a C-library timer exits with 0."""
    _, out = _stop_through_a_hung_teardown("--stuck-teardown-gil")
    assert "Timeout" in out and "in _teardown" in out, out  # where it hung
