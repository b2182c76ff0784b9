"""Test environment: an isolated, loopback-only ROS 2 domain and headless rendering."""

from __future__ import annotations

import os
import sys
from pathlib import Path

_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", ... in a pytest-xdist worker
# discovery stays on this machine
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


import time  # noqa: E402  (after the environment set-up above)

from ros_helpers import restore_ctrl_c, session_domain  # noqa: E402

# a domain of its own per test session and per pytest-xdist worker
os.environ["ROS_DOMAIN_ID"] = session_domain(os.environ, os.getpid())

# Launched in the background by a shell (`cmd &`), this process ignores SIGINT and so would
# every child a test interrupts: restore Ctrl-C first (see restore_ctrl_c).
restore_ctrl_c()

import pytest  # noqa: E402

_LOAD_ENV = "HAND_SUITE_TEST_LOAD"


def pytest_configure(config: pytest.Config) -> None:
    """``HAND_SUITE_TEST_LOAD=N``: run the session beside N CPU-burning processes
    (test/load.py), to check that the tests hold on a loaded machine."""
    raw = os.environ.get(_LOAD_ENV, "").strip()
    if not raw or config.option.collectonly or _WORKER:
        return  # under pytest-xdist the controller alone starts the burners
    try:
        n = int(raw)
    except ValueError as e:
        raise pytest.UsageError(f"{_LOAD_ENV} must be a whole number of burners, "
                                f"got {raw!r}") from e
    from load import CpuLoad

    load = CpuLoad(n, seconds=float(os.environ.get(_LOAD_ENV + "_SECONDS", "3600"))).start()
    config.add_cleanup(load.stop)
    config._hand_suite_load = load  # type: ignore[attr-defined]


def pytest_report_header(config: pytest.Config) -> str | None:
    load = getattr(config, "_hand_suite_load", None)
    return None if load is None else f"{_LOAD_ENV}: {load.n} CPU burner(s) running"


def _dds_participants() -> int:
    """Fast DDS participants alive in this process (one ``dds.ev.N`` event thread each;
    0 where /proc is not available)."""
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return 0
    n = 0
    for t in tasks:
        try:
            with open(f"/proc/self/task/{t}/comm") as fh:
                n += fh.read().startswith("dds.ev")
        except OSError:
            pass
    return n


@pytest.fixture(autouse=True)
def _finalise_ros_handles():
    """After a test that left a DDS participant alive, collect the garbage now: a destroyed
    node's or shut-down context's handles held in reference cycles are otherwise finalised by
    a garbage collection in the middle of a later test. Once, such a finalisation hung for
    good in Fast DDS (``destroy_participant`` -> ``set_listener`` waiting on a discovery
    callback stuck on a mutex), inside a test with no ROS in it."""
    yield
    if _dds_participants():
        import gc

        gc.collect()


@pytest.fixture
def rclpy_up():
    """rclpy initialised for the test, shut down after it (nodes are the test's own)."""
    import rclpy

    rclpy.init()
    yield
    rclpy.shutdown()


@pytest.fixture
def ros():
    """An in-process ROS graph: yields ``(peer, add, spin_until)``.

    ``peer`` is a node for test publishers/subscribers; ``add(node)`` spins a node under test
    (its ``on_shutdown()`` hook, if any, and ``destroy_node()`` run at teardown, as in
    run_node); ``spin_until(cond, timeout, tick=None)`` spins until ``cond()`` holds or
    ``timeout`` [s] passes, calling ``tick()`` before every spin.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    peer = rclpy.create_node("test_peer")
    ex = SingleThreadedExecutor()
    ex.add_node(peer)
    nodes = []

    def spin_until(cond, timeout: float, tick=None) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if tick is not None:
                tick()
            ex.spin_once(timeout_sec=0.005)
            if cond():
                return True
        return cond()

    def add(node):
        nodes.append(node)
        ex.add_node(node)
        return node

    yield peer, add, spin_until
    for n in nodes:
        hook = getattr(n, "on_shutdown", None)
        if callable(hook):
            hook()
        ex.remove_node(n)
        n.destroy_node()
    peer.destroy_node()
    rclpy.shutdown()
