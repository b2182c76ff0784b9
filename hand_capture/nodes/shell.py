"""The standard ``main()`` of every node: init, spin, clean shutdown.

``run_node(MyNode)`` does what ros2/demos do by hand in each file: ``rclpy.init`` with the
process arguments, build the node, spin it, and shut down cleanly on Ctrl-C, SIGTERM or an
external shutdown. A node that raises while starting or spinning has its traceback printed with
its name and the process exits non-zero, which the graph runner reports; a
:class:`~hand_capture.errors.HandSuiteError` (e.g. a damaged bag) is printed as one line.
Nodes spin on :class:`~hand_capture.nodes.executor.LeanExecutor` (rclpy's single-threaded
executor without its per-wake-up Python cost) unless ``executor_factory`` names another.
Every node gets the ``realtime_priority`` parameter (:mod:`hand_capture.nodes.realtime`) and
loopback-only discovery unless the environment sets it (:mod:`hand_capture.network`).

Stopping, in this order (the graph runner escalates SIGINT -> SIGTERM -> SIGKILL):

1. The first SIGINT/SIGTERM only *asks* to stop. A node being built finishes its
   constructor (a recorder that has opened its bag must reach its shutdown hook, however late
   the signal comes), and a callback that runs finishes too (a message half-written into a bag
   would corrupt it); the spin loop wakes at least every :data:`STOP_POLL` seconds to look.
2. A second signal while the node is still being built or spun means it is stuck (a long
   constructor or callback): that is interrupted (KeyboardInterrupt).
3. Once the shutdown hook runs, no signal interrupts it (torque-off, closing a bag).
4. Then the node and rclpy are torn down. Fast DDS's participant deletion has been seen to
   hang there (a synthetic camera on a loaded 2-core CI host sat in ``destroy_node`` until the
   runner killed it; the cause is a deadlock between a receive thread removing a departed
   peer's endpoints under the discovery lock and the event thread waiting for that lock,
   upstream Fast-DDS issue 6502, README "Networking and safety"): everything the node owns
   is finished by then, so after :data:`TEARDOWN_TIMEOUT` seconds the process says so, runs
   its ``atexit`` backstops and exits with the code it had; where the hang holds the GIL,
   its stacks are printed and a C-library timer exits with that code half a second later
   (:func:`_teardown`).

``SIGUSR1`` makes a node print every thread's stack to stderr (``faulthandler``) without
stopping it: the graph runner sends it to a node that ignored SIGINT and SIGTERM, before
SIGKILL, so the log says where it was stuck.
"""

from __future__ import annotations

import atexit
import contextlib
import faulthandler
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future

from hand_capture.dds import dds_environment
from hand_capture.errors import HandSuiteError
from hand_capture.network import apply_network_defaults
from hand_capture.nodes.executor import LeanExecutor
from hand_capture.nodes.exit_timer import ExitTimer
from hand_capture.nodes.realtime import apply_realtime_priority

_stop_signal: list[int] = []  # the SIGINT/SIGTERM that asked this process to stop
_running: list[bool] = [False]  # building or spinning the node: a 2nd signal interrupts it
#: longest time [s] between two looks at a stop request while spinning
STOP_POLL = 0.1
#: longest time [s] the middleware teardown after the shutdown hook may take (module doc, 4),
#: short: the node's own work is done, and the hook (a MuJoCo world, a bag) must fit with it
#: in the graph runner's 6 s between SIGINT and SIGTERM
TEARDOWN_TIMEOUT = 2.0


def _on_stop_signal(signum: int, frame: object) -> None:
    """Record a stop request; interrupt only a spin that ignored a first one (module doc)."""
    _stop_signal.append(signum)
    if len(_stop_signal) >= 2 and _running[0]:
        _running[0] = False  # interrupt once; the shutdown hook that follows is spared
        raise KeyboardInterrupt


def _spin(executor: object, done: Future | None) -> int:
    """Spin until a stop is requested (or ``done`` completes); the exit code."""
    while not _stop_signal:
        if done is not None and done.done():
            result = done.result()
            return result if isinstance(result, int) else 0
        executor.spin_once(timeout_sec=STOP_POLL)
    return 0


def run_node(
    factory: Callable[[], Node],
    args: Sequence[str] | None = None,
    executor_factory: Callable[[], object] = LeanExecutor,
    own_process: bool = True,
) -> int:
    """Run one node until shutdown; returns the process exit code (0 on a clean stop).

    A node with a ``done`` attribute (an rclpy Future) is spun until it completes, and the
    Future's integer result becomes the exit code. A stop signal ends the spin (module doc).
    The node may define ``on_shutdown()``: it is called on every exit path (normal, Ctrl-C,
    SIGTERM, exception) before the node is destroyed, e.g. to switch torque off.
    ``own_process``: the node is the process (every console script), so a teardown hung in
    the middleware ends the process (module doc, 4); a caller that runs a node inside a
    process it goes on using (a test) passes False.
    """
    _stop_signal.clear()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_stop_signal)
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # where a stuck node is (doc)
    argv = list(sys.argv if args is None else args)
    apply_network_defaults()  # loopback-only discovery unless the environment says otherwise
    os.environ.update(dds_environment(os.environ))  # Fast DDS profile for large images
    code = 0
    node: Node | None = None
    rclpy.init(args=argv, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    _running[0] = True
    try:
        node = factory()
        apply_realtime_priority(node)  # the realtime_priority parameter
        executor = executor_factory()
        executor.add_node(node)
        # A node that finishes by itself (e.g. a bag player) sets ``done`` (a Future) to its
        # exit code.
        done = getattr(node, "done", None)
        code = _spin(executor, done if isinstance(done, Future) else None)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except HandSuiteError as e:
        # the suite's own errors (a damaged bag, a bad parameter, a missing device) already
        # say what is wrong and where: one line, not a traceback
        name = node.get_name() if node is not None else getattr(factory, "__name__", "node")
        sys.stderr.write(f"[{name}] error: {e}\n")
        code = 1
    except Exception:
        # A (second) signal that lands inside rclpy's C++ (e.g. while a message is taken)
        # surfaces as a RuntimeError from pybind11, not as KeyboardInterrupt: still a stop.
        # Any other failure: reported with the node name, exit 1.
        if not _stop_signal:
            name = node.get_name() if node is not None else getattr(factory, "__name__", "node")
            sys.stderr.write(f"[{name}] failed:\n{traceback.format_exc()}")
            code = 1
    finally:
        _running[0] = False  # from here on no signal interrupts: the hook must finish
        if node is not None:
            hook = getattr(node, "on_shutdown", None)
            if callable(hook):
                try:
                    hook()
                except Exception:  # shutdown must go on
                    sys.stderr.write(f"[{node.get_name()}] on_shutdown failed:\n"
                                     f"{traceback.format_exc()}")
                    code = 1
        _teardown(node, code, own_process)
    return code


def _teardown(node: Node | None, code: int, bounded: bool) -> None:
    """Destroy ``node`` and shut rclpy down; ``bounded``: within :data:`TEARDOWN_TIMEOUT`
    seconds, else the process leaves with ``code`` (module doc, 4; :func:`_exit_if_stuck`)."""
    name = node.get_name() if node is not None else "node"
    with _exit_if_stuck(name, code) if bounded else contextlib.nullcontext():
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


@contextlib.contextmanager
def _exit_if_stuck(name: str, code: int) -> Iterator[None]:
    """Leave the process with ``code`` if the block runs over :data:`TEARDOWN_TIMEOUT` s.

    Two watchdogs: a Python timer that says so, runs the ``atexit`` backstops (the servo
    bridge's torque-off, should its hook have failed) and exits; and, for a hang that holds
    the GIL (rclpy's destroy calls wait inside Fast DDS without releasing it, so no Python
    runs again), the stacks printed by ``faulthandler`` and ``_exit(code)`` from a C-library
    timer thread (:class:`~hand_capture.nodes.exit_timer.ExitTimer`) shortly after.
    """
    def give_up() -> None:
        sys.stderr.write(f"[{name}] the DDS teardown did not finish within {TEARDOWN_TIMEOUT} s"
                         f" (shutdown hook done): exiting with {code} without it\n")
        # os._exit skips the interpreter's exit: run the atexit backstops first
        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)

    watchdog = threading.Timer(TEARDOWN_TIMEOUT, give_up)
    watchdog.daemon = True
    watchdog.start()
    faulthandler.dump_traceback_later(TEARDOWN_TIMEOUT + 0.25)  # needs no GIL
    hard_exit = ExitTimer.start(TEARDOWN_TIMEOUT + 0.5, code)
    try:
        yield
    finally:
        watchdog.cancel()
        faulthandler.cancel_dump_traceback_later()
        if hard_exit is not None:
            hard_exit.cancel()
