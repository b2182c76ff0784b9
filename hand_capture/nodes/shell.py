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
"""

from __future__ import annotations

import os
import signal
import sys
import traceback
from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.task import Future

from hand_capture.dds import dds_environment
from hand_capture.errors import HandSuiteError
from hand_capture.network import apply_network_defaults
from hand_capture.nodes.executor import LeanExecutor
from hand_capture.nodes.realtime import apply_realtime_priority

_stop_signal: list[int] = []  # the SIGINT/SIGTERM that asked this process to stop


def _signal_to_keyboardinterrupt(signum: int, frame: object) -> None:
    """The first stop signal interrupts the spin; later ones (a runner escalating to SIGTERM)
    must not interrupt the shutdown hooks, e.g. the servos' torque-off."""
    _stop_signal.append(signum)
    if len(_stop_signal) == 1:
        raise KeyboardInterrupt


def run_node(
    factory: Callable[[], Node],
    args: Sequence[str] | None = None,
    executor_factory: Callable[[], object] = LeanExecutor,
) -> int:
    """Run one node until shutdown; returns the process exit code (0 on a clean stop).

    A node with a ``done`` attribute (an rclpy Future) is spun until it completes, and the
    Future's integer result becomes the exit code. The node may define ``on_shutdown()``:
    it is called on every exit path (normal, Ctrl-C, SIGTERM, exception) before the node is
    destroyed, e.g. to switch torque off.
    """
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _signal_to_keyboardinterrupt)
    argv = list(sys.argv if args is None else args)
    apply_network_defaults()  # loopback-only discovery unless the environment says otherwise
    os.environ.update(dds_environment(os.environ))  # Fast DDS profile for large images
    code = 0
    node: Node | None = None
    rclpy.init(args=argv, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = factory()
        apply_realtime_priority(node)  # the realtime_priority parameter
        executor = executor_factory()
        executor.add_node(node)
        done = getattr(node, "done", None)
        if isinstance(done, Future):
            # A node that finishes by itself (e.g. a bag player) sets done to its exit code.
            executor.spin_until_future_complete(done)
            result = done.result() if done.done() else 0
            code = result if isinstance(result, int) else 0
        else:
            executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except HandSuiteError as e:
        # the suite's own errors (a damaged bag, a bad parameter, a missing device) already
        # say what is wrong and where: one line, not a traceback
        name = node.get_name() if node is not None else getattr(factory, "__name__", "node")
        sys.stderr.write(f"[{name}] error: {e}\n")
        code = 1
    except Exception:
        # A signal that lands inside rclpy's C++ (e.g. while a message is taken) surfaces as a
        # RuntimeError from pybind11, not as KeyboardInterrupt: still a requested stop.
        # Any other failure: reported with the node name, exit 1.
        if not _stop_signal:
            name = node.get_name() if node is not None else getattr(factory, "__name__", "node")
            sys.stderr.write(f"[{name}] failed:\n{traceback.format_exc()}")
            code = 1
    finally:
        if node is not None:
            hook = getattr(node, "on_shutdown", None)
            if callable(hook):
                try:
                    hook()
                except Exception:  # shutdown must go on
                    sys.stderr.write(f"[{node.get_name()}] on_shutdown failed:\n"
                                     f"{traceback.format_exc()}")
                    code = 1
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code
