"""``hand-suite run``: start a node graph as one process per node, like ``ros2 launch``.

Every node runs as its console script with ``--ros-args`` (name, parameter files, overrides,
remappings). Output lines are prefixed with the node name. The runner stops the whole graph
and exits

* 0 after SIGINT/SIGTERM (forwarded to every node as SIGINT; SIGTERM after 6 s, SIGUSR1
  after 8 s for a stuck node's stacks, SIGKILL after 8.5 s, so the graph is down within
  9.5 s), or when a ``required`` node exits with 0;
* non-zero when any node exits with an error; its traceback (printed by the node's main)
  appears under its name, followed by a line naming the node and its exit code. A node that
  does not stop cleanly when the graph stops (killed, or a failing shutdown hook: e.g. a
  recorder whose bag was not finished) is named the same way and makes the exit code 1.

A node that gets the stop signal while its Python modules still load exits at once with 0
(nothing was built yet); from :func:`~hand_capture.nodes.shell.run_node` on, the node shell
handles the signals (build finishes, shutdown hook runs).

Children get SIGTERM if the runner itself dies (PR_SET_PDEATHSIG), so no node is orphaned.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, TextIO

from hand_capture.dds import dds_environment
from hand_capture.errors import GraphError
from hand_control.graph import GraphSpec, NodeSpec, ros_args

#: seconds after SIGINT before SIGTERM, then before SIGKILL: a node's shutdown (its hook,
#: destroying its DDS participant, a MuJoCo world) took over 4.5 s once on a 2-core CI-like
#: host running the test suite (the teleop graph's sim node was killed; 3 s + 1.5 s before)
_STOP_GRACE = (6.0, 2.0)
_PR_SET_PDEATHSIG = 1


def console_scripts() -> dict[str, str]:
    """Console scripts of the installed hand_suite distribution: name -> ``module:function``."""
    return {ep.name: ep.value for ep in entry_points(group="console_scripts")
            if ep.dist is not None and ep.dist.name.replace("-", "_") == "hand_suite"}


def node_command(node: NodeSpec, params_files: list[Path],
                 overrides: dict[str, Any] | None = None) -> list[str]:
    """The command line that runs ``node`` with this interpreter.

    Raises:
        GraphError: the node's executable is not a console script of hand_suite.
    """
    scripts = console_scripts()
    target = scripts.get(node.executable)
    if target is None:
        raise GraphError(f"node {node.name}: no console script {node.executable!r}; "
                         f"available: {sorted(scripts)}")
    module, func = target.split(":")
    # a stop while the modules load ends the process cleanly; run_node installs its own
    # handlers before it builds anything
    code = ("import signal, sys\n"
            "def _early_stop(*_): raise SystemExit(0)\n"
            "signal.signal(signal.SIGINT, _early_stop)\n"
            "signal.signal(signal.SIGTERM, _early_stop)\n"
            f"from {module} import {func} as m\n"
            "sys.exit(m())")
    return [sys.executable, "-c", code, *ros_args(node, params_files, overrides)]


def _die_with_parent() -> None:
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


@dataclass
class _Child:
    spec: NodeSpec
    proc: subprocess.Popen
    reader: threading.Thread
    code: int | None = None


@dataclass
class GraphRun:
    """Outcome of :func:`run_graph`: exit code and the nodes that failed."""

    code: int
    failed: list[str] = field(default_factory=list)
    stopped_by_signal: bool = False


def _pump(name: str, stream: TextIO, out: TextIO, lock: threading.Lock) -> None:
    for line in stream:
        with lock:
            out.write(f"[{name}] {line}")
            out.flush()


def node_environment() -> dict[str, str]:
    """The environment of every node process: this one's, unbuffered output, and the
    shipped Fast DDS profile for large images (:func:`hand_capture.dds.dds_environment`)."""
    return dds_environment({**os.environ, "PYTHONUNBUFFERED": "1"})


def run_graph(
    graph: GraphSpec,
    extra_params: list[Path] | None = None,
    overrides: dict[str, dict[str, Any]] | None = None,
    out: TextIO | None = None,
    install_signal_handlers: bool = True,
    should_stop: Callable[[], bool] | None = None,
    cpu: dict[str, float] | None = None,
) -> GraphRun:
    """Run ``graph`` until it ends, fails or is interrupted; see the module docstring.

    Args:
        graph: the graph description.
        extra_params: parameter files applied after the graph's own.
        overrides: node name -> {parameter: value} given on the command line.
        out: where node output goes (stdout by default).
        install_signal_handlers: handle SIGINT/SIGTERM (main thread only).
        should_stop: polled every 50 ms; True stops the graph like SIGINT.
        cpu: when given, kept up to date (every 0.5 s and at the end) with each node's CPU
            time [s], e.g. for ``should_stop`` to read.
    """
    out = out or sys.stdout
    overrides = overrides or {}
    unknown = set(overrides) - {n.name for n in graph.nodes}
    if unknown:
        raise GraphError(f"overrides for unknown node(s) {sorted(unknown)}; graph "
                         f"{graph.name} has {[n.name for n in graph.nodes]}")
    files = list(graph.params_files) + list(extra_params or [])
    for f in files:
        if not Path(f).is_file():
            raise GraphError(f"parameter file not found: {f}")
    commands = {n.name: node_command(n, files, overrides.get(n.name)) for n in graph.nodes}

    stop = threading.Event()
    previous: dict[int, Any] = {}
    if install_signal_handlers:
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    lock = threading.Lock()
    env = node_environment()
    children: list[_Child] = []
    result = GraphRun(code=0)
    try:
        for spec in graph.nodes:
            proc = subprocess.Popen(commands[spec.name], stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True, env=env,
                                    start_new_session=True, preexec_fn=_die_with_parent)
            reader = threading.Thread(target=_pump, args=(spec.name, proc.stdout, out, lock),
                                      daemon=True)
            reader.start()
            children.append(_Child(spec, proc, reader))
        with lock:
            out.write(f"[runner] graph {graph.name}: started "
                      f"{', '.join(c.spec.name for c in children)}\n")
        result = _supervise(children, stop, should_stop, out, lock, cpu)
    finally:
        running = [c for c in children if c.code is None]
        _stop_all(children)
        for c in children:
            c.reader.join(timeout=1.0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    for c in running:  # the nodes this stop ended: did each finish cleanly?
        code = c.proc.poll()
        if code is None or code == 0:
            continue
        how = "was killed" if code == -signal.SIGKILL else "did not stop cleanly"
        with lock:
            out.write(f"[runner] node {c.spec.name} {how} (exit code {code})\n")
        result.code = 1
        result.failed.append(c.spec.name)
    with lock:
        out.write(f"[runner] graph {graph.name} stopped, exit code {result.code}\n")
        out.flush()
    return result


def _sample_cpu(children: list[_Child], cpu: dict[str, float]) -> None:
    """Record each running node's CPU time (user + system) [s] into ``cpu``."""
    import psutil

    for c in children:
        if c.code is None:
            try:
                t = psutil.Process(c.proc.pid).cpu_times()
                cpu[c.spec.name] = t.user + t.system
            except psutil.Error:  # it just exited: keep its last sample
                pass


def _supervise(children: list[_Child], stop: threading.Event,
               should_stop: Callable[[], bool] | None, out: TextIO,
               lock: threading.Lock, cpu: dict[str, float] | None) -> GraphRun:
    polls = 0
    while True:
        polls += 1
        result = _supervise_once(children, stop, should_stop, out, lock)
        if cpu is not None and (result is not None or polls % 10 == 0):
            _sample_cpu(children, cpu)
        if result is not None:
            return result
        time.sleep(0.05)


def _supervise_once(children: list[_Child], stop: threading.Event,
                    should_stop: Callable[[], bool] | None, out: TextIO,
                    lock: threading.Lock) -> GraphRun | None:
    """One poll of the nodes: the graph's outcome once it ends, else None."""
    if stop.is_set() or (should_stop is not None and should_stop()):
        return GraphRun(code=0, stopped_by_signal=True)
    running = 0
    for c in children:
        if c.code is not None:
            continue
        code = c.proc.poll()
        if code is None:
            running += 1
            continue
        c.code = code
        if code != 0:
            with lock:
                out.write(f"[runner] node {c.spec.name} failed with exit code {code}\n")
            return GraphRun(code=1, failed=[c.spec.name])
        if c.spec.required:
            with lock:
                out.write(f"[runner] required node {c.spec.name} finished\n")
            return GraphRun(code=0)
    if running == 0:
        return GraphRun(code=0)
    return None


def _stop_all(children: list[_Child]) -> None:
    """SIGINT every running node, then SIGTERM, then SIGKILL (within 9.5 s in all).

    Before SIGKILL a node still running gets SIGUSR1, on which the suite's nodes print every
    thread's stack (:mod:`hand_capture.nodes.shell`): the log then says where it was stuck.
    """
    alive = [c for c in children if c.proc.poll() is None]
    for sig, grace in ((signal.SIGINT, _STOP_GRACE[0]), (signal.SIGTERM, _STOP_GRACE[1]),
                       (signal.SIGUSR1, 0.5), (signal.SIGKILL, 0.5)):
        for c in alive:
            try:
                c.proc.send_signal(sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace
        while alive and time.monotonic() < deadline:
            alive = [c for c in alive if c.proc.poll() is None]
            time.sleep(0.02)
        if not alive:
            return
