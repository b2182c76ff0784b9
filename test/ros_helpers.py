"""Small helpers for tests that need ROS 2 processes (not collected as tests)."""

from __future__ import annotations

import fcntl
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent


def session_domain(environ: Mapping[str, str], pid: int) -> str:
    """The ROS_DOMAIN_ID a test process uses: the one set (else one drawn from ``pid`` in
    1..100), so parallel sessions on one machine never cross-talk; a pytest-xdist worker
    (``PYTEST_XDIST_WORKER=gwK``, which inherits its controller's domain) moves to domain
    ``1 + (D + K) % 100``, one of its own, or the graphs of two tests running at once on two
    workers would see each other's topics."""
    domain = int(environ.get("ROS_DOMAIN_ID") or random.Random(pid).randint(1, 100))
    worker = environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw") and worker[2:].isdigit():
        domain = 1 + (domain + int(worker[2:])) % 100
    return str(domain)


def restore_ctrl_c() -> bool:
    """Give SIGINT back its default (KeyboardInterrupt) handler if it is ignored; True if it was.

    A shell without job control starts a background command (``cmd &``, ``nohup cmd &``) with
    SIGINT and SIGQUIT ignored, every child inherits that, and Python then installs no
    KeyboardInterrupt handler: a child that should stop on Ctrl-C ignores the SIGINT a test
    sends it. Called once from conftest, so the suite behaves the same however it is launched.
    """
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        return False
    signal.signal(signal.SIGINT, signal.default_int_handler)
    return True


def hand_suite(*args: str, **kwargs: object) -> subprocess.Popen:
    """Start ``hand-suite ARGS`` as a child process with merged text output."""
    return subprocess.Popen([str(VENV_BIN / "hand-suite"), *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"}, **kwargs)


def wait_for(cond: Callable[[], bool], timeout: float, period: float = 0.05) -> bool:
    """Poll ``cond`` until it is true or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(period)
    return cond()


def spin_nodes(nodes: list, seconds: float, until: Callable[[], bool] | None = None) -> None:
    """Spin ``nodes`` on a fresh single-threaded executor for ``seconds`` [s] or until
    ``until()`` holds; the nodes are removed from it afterwards."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor()
    for n in nodes:
        ex.add_node(n)
    end = time.monotonic() + seconds
    while time.monotonic() < end and not (until is not None and until()):
        ex.spin_once(timeout_sec=0.01)
    for n in nodes:
        ex.remove_node(n)


@contextmanager
def machine_lock(name: str) -> Iterator[None]:
    """Hold the lock ``name``, shared by every process of this machine (pytest-xdist workers
    included): tests that must not run at the same time as each other wait here for the
    other's end, whichever worker runs them."""
    with open(Path(tempfile.gettempdir()) / f"hand_suite_test_{name}.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
