"""A single-threaded rclpy executor without the per-wake-up cost of rclpy's own.

rclpy's ``SingleThreadedExecutor`` rebuilds its wait set in Python on every wake-up (an
``ExitStack`` entry and a callback-group check per entity, a ``Task`` and a coroutine per
callback, ``inspect.signature`` of every timer callback) and wakes a second time after each
callback, because the callback's handler triggers the executor's guard condition. Measured on the
2-core teleop machine: 0.7 ms of CPU per timer tick of a bare node, 2 ms with 25 subscriptions
(this executor: 0.3 and 0.5 ms); at the teleop graph's rates (30-300 callbacks per second and
node) that was a large share of each node's CPU.

:class:`LeanExecutor` keeps the entity tables and the wait set between wake-ups (rebuilt when
an entity or node is added or removed: rclpy calls :meth:`wake` then), and runs timer and
subscription callbacks directly, as the base executor would. Everything else -- services,
clients, guard conditions, waitables (QoS events), tasks and ``async`` callbacks -- goes
through the base class's own handlers, so its behaviour is rclpy's. Single-threaded only, and a
callback must not spin the executor that runs it (as with rclpy's own).

Batched wake-ups (``min_wake_interval``, e.g. the bag recorder's ``batch_period``): the executor
waits at least that long between two wake-ups and then takes every queued message of a ready
subscription, not one, for nodes that need throughput, not latency.
"""

from __future__ import annotations

import inspect
import time
from functools import partial
from typing import Any

from rclpy.exceptions import InvalidHandle, TimerCancelledError
from rclpy.executors import (
    ExternalShutdownException,
    SingleThreadedExecutor,
    TimeoutObject,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription
from rclpy.timer import TimerInfo
from rclpy.utilities import timeout_sec_to_nsec
from rclpy.waitable import NumberOfEntities

__all__ = ["LeanExecutor"]

_BATCH_TAKES = 1000  # most messages taken from one subscription per batched wake-up


class _Tables:
    """Entities of the executor's nodes, their handles and the wait set that holds them."""

    def __init__(self, executor: LeanExecutor) -> None:
        self.nodes = executor.get_nodes()
        self.subs: list[tuple[Any, Any]] = []  # (subscription, node)
        self.timers: list[tuple[Any, Any]] = []
        self.services: list[tuple[Any, Any]] = []
        self.clients: list[tuple[Any, Any]] = []
        self.guards: list[tuple[Any, Any]] = []
        self.waitables: list[tuple[Any, Any]] = []
        count = NumberOfEntities()
        for node in self.nodes:
            self.subs += [(s, node) for s in node.subscriptions]
            self.timers += [(t, node) for t in node.timers]
            self.guards += [(g, node) for g in node.guards]
            self.clients += [(c, node) for c in node.clients]
            self.services += [(s, node) for s in node.services]
            for w in node.waitables:
                self.waitables.append((w, node))
                count += w.get_num_entities()
        self.own_guards = [g for g in (executor._guard, executor._sigint_gc) if g]
        count += NumberOfEntities(len(self.subs), len(self.guards) + len(self.own_guards),
                                  len(self.timers), len(self.clients), len(self.services))
        self.wait_set = _rclpy.WaitSet(
            count.num_subscriptions, count.num_guard_conditions, count.num_timers,
            count.num_clients, count.num_services, count.num_events,
            executor.context.handle)
        self.sub_by_ptr = {s.handle.pointer: (s, n) for s, n in self.subs}
        self.timer_by_ptr = {t.handle.pointer: (t, n) for t, n in self.timers}
        self.guard_by_ptr = {g.handle.pointer: (g, n) for g, n in self.guards}
        self.client_by_ptr = {c.handle.pointer: (c, n) for c, n in self.clients}
        self.service_by_ptr = {s.handle.pointer: (s, n) for s, n in self.services}
        self.timer_order = {t.handle.pointer: k for k, (t, _) in enumerate(self.timers)}
        self.sub_order = {s.handle.pointer: k for k, (s, _) in enumerate(self.subs)}
        # the handles waited on every time (an entity's handle object never changes)
        self.always = ([s.handle for s, _ in self.subs], [t.handle for t, _ in self.timers],
                       [g.handle for g in self.own_guards])

    def fill(self) -> None:
        """(Re-)add every waiting entity: rcl_wait clears the ones that were not ready."""
        ws = self.wait_set
        ws.clear_entities()
        subs, timers, own_guards = self.always
        add = ws.add_subscription
        for h in subs:
            add(h)
        add = ws.add_timer
        for h in timers:
            add(h)
        for c, _ in self.clients:
            if not c._executor_event:
                ws.add_client(c.handle)
        for s, _ in self.services:
            if not s._executor_event:
                ws.add_service(s.handle)
        for g, _ in self.guards:
            if g._executor_triggered:  # triggered but not handled yet: keep it ready
                g.trigger()
            ws.add_guard_condition(g.handle)
        add = ws.add_guard_condition
        for h in own_guards:
            add(h)
        for w, _ in self.waitables:
            if not w._executor_event:
                w.add_to_wait_set(ws)


class LeanExecutor(SingleThreadedExecutor):
    """Drop-in replacement of ``SingleThreadedExecutor`` (module docstring)."""

    def __init__(self, *, context=None, min_wake_interval: float = 0.0) -> None:
        """``min_wake_interval``: least time between two wake-ups [s] (0 = none); what
        arrives meanwhile is taken in one batch. A node can also ask for it with a
        ``min_wake_interval`` attribute (the largest one of the executor's nodes holds)."""
        super().__init__(context=context)
        self._tables: _Tables | None = None
        self._timer_arg: dict[Any, str | None] = {}
        self.min_wake_interval = min_wake_interval
        self._last_wake = 0.0  # time.monotonic() of the last wake-up [s]

    # -- entity changes ---------------------------------------------------------------------
    def wake(self) -> None:
        self._tables = None  # a node created or destroyed an entity (or a future completed)
        super().wake()

    def add_node(self, node) -> bool:
        self._tables = None
        self.min_wake_interval = max(self.min_wake_interval,
                                     float(getattr(node, "min_wake_interval", 0.0)))
        return super().add_node(node)

    def remove_node(self, node) -> None:
        self._tables = None
        super().remove_node(node)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        self._tables = None
        return super().shutdown(timeout_sec)

    # -- spinning ---------------------------------------------------------------------------
    def _spin_once_impl(self, timeout_sec=None, wait_condition=lambda: False) -> None:
        if self._tasks:
            self._run_tasks()
        if self._is_shutdown or wait_condition():
            return
        if not self._context.ok():
            raise ExternalShutdownException()
        tables = self._tables
        if tables is None:
            tables = self._tables = _Tables(self)
        try:
            tables.fill()
        except InvalidHandle:  # destroyed behind our back (another thread): rebuild
            self._tables = None
            return
        timeout = timeout_sec.timeout if isinstance(timeout_sec, TimeoutObject) \
            else timeout_sec
        if self.min_wake_interval > 0.0:
            rest = self._last_wake + self.min_wake_interval - time.monotonic()
            if rest > 0.0:  # batch: let more arrive before this wake-up
                if timeout is not None and 0 <= timeout < rest:
                    time.sleep(timeout)
                    return  # timed out before the next wake-up is due
                time.sleep(rest)
                if timeout is not None and timeout >= 0:
                    timeout -= rest
        ws = tables.wait_set
        ws.wait(timeout_sec_to_nsec(timeout))
        self._last_wake = time.monotonic()
        if self._is_shutdown:
            return
        if not self._context.ok():
            raise ExternalShutdownException()
        self._dispatch(tables, ws)

    def _dispatch(self, tables: _Tables, ws) -> None:
        timers = ws.get_ready_entities("timer")
        subs = ws.get_ready_entities("subscription")
        guards = ws.get_ready_entities("guard_condition") if tables.guards else ()
        clients = ws.get_ready_entities("client") if tables.clients else ()
        services = ws.get_ready_entities("service") if tables.services else ()
        for ptr in guards:
            hit = tables.guard_by_ptr.get(ptr)
            if hit is not None:
                hit[0]._executor_triggered = True
        # the order of rclpy's executor: waitables, then timers, subscriptions, guard
        # conditions, clients, services
        ready = [(w, n) for w, n in tables.waitables
                 if not w._executor_event and w.is_ready(ws)]
        for w, n in ready:
            self._run_handler(w, n, self._take_waitable)
        for tmr in _in_order(timers, tables.timer_by_ptr, tables.timer_order):
            self._run_timer(tmr)
        for sub in _in_order(subs, tables.sub_by_ptr, tables.sub_order):
            self._run_subscription(sub)
        for g, n in tables.guards:
            if g._executor_triggered:
                self._run_handler(g, n, self._take_guard_condition)
        for ptr in clients:
            hit = tables.client_by_ptr.get(ptr)
            if hit is not None:
                self._run_handler(hit[0], hit[1], self._take_client)
        for ptr in services:
            hit = tables.service_by_ptr.get(ptr)
            if hit is not None:
                self._run_handler(hit[0], hit[1], self._take_service)

    def _run_timer(self, tmr) -> None:
        try:
            with tmr.handle:
                if not tmr.handle.is_timer_ready():  # rcl reports cancelled timers ready
                    return
                cb = tmr.callback
                arg = self._timer_info_arg(cb)
                if arg is None:
                    tmr.handle.call_timer()
                else:
                    info = tmr.handle.call_timer_with_info()
                    cb = partial(cb, **{arg: TimerInfo(
                        expected_call_time=info["expected_call_time"],
                        actual_call_time=info["actual_call_time"],
                        clock_type=tmr.clock.clock_type)})
        except (InvalidHandle, TimerCancelledError):
            return
        if cb is not None:
            self._call(cb, ())

    def _timer_info_arg(self, cb) -> str | None:
        """Name of the callback's TimerInfo parameter (cached per callback), or None."""
        if cb is None:
            return None
        try:
            return self._timer_arg[cb]
        except KeyError:
            pass
        except TypeError:  # unhashable callable
            return _timer_info_param(cb)
        if len(self._timer_arg) > 256:
            self._timer_arg.clear()
        arg = self._timer_arg[cb] = _timer_info_param(cb)
        return arg

    def _run_subscription(self, sub) -> None:
        # one message per wake-up, as rclpy; with batched wake-ups every message queued
        # (at most _BATCH_TAKES, so that a flood cannot hold the other entities off)
        for _ in range(_BATCH_TAKES if self.min_wake_interval > 0.0 else 1):
            try:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:
                return
            if taken is None:
                return
            if sub._callback_type is Subscription.CallbackType.MessageOnly:
                self._call(sub.callback, (taken[0],))
            else:
                self._call(sub.callback, taken)

    def _call(self, cb, args: tuple) -> None:
        result = cb(*args)
        if inspect.iscoroutine(result):  # an async callback: a task, as rclpy runs it
            self.create_task(_await, result)
            self._run_tasks()

    def _run_handler(self, entity, node, take) -> None:
        """One entity through rclpy's own handler (services, clients, guards, waitables)."""
        handler = self._make_handler(entity, node, take)
        handler()
        self._drop_done_tasks()
        exc = handler.exception()
        if exc is not None:
            raise exc

    def _run_tasks(self) -> None:
        """Run the pending tasks once, as rclpy's executor does before it waits."""
        with self._tasks_lock:
            tasks = list(self._tasks)
        for task, _, node in tasks:
            if task.executing() or task.done():
                continue
            if node is not None and node not in self._nodes:
                continue
            task()
            exc = task.exception() if task.done() else None
            if exc is not None:
                self._drop_done_tasks()
                raise exc
        self._drop_done_tasks()

    def _drop_done_tasks(self) -> None:
        with self._tasks_lock:
            self._tasks = [t for t in self._tasks if not (t[0].done() or t[0].cancelled())]


def _in_order(ptrs, by_ptr: dict, order: dict) -> list:
    """The entities of the ready handle pointers ``ptrs`` that the tables know, in the order
    they were created (as rclpy's executor runs them)."""
    if len(ptrs) > 1:
        ptrs = sorted(ptrs, key=lambda p: order.get(p, 0))
    return [hit[0] for p in ptrs if (hit := by_ptr.get(p)) is not None]


async def _await(coroutine):
    return await coroutine


def _timer_info_param(cb) -> str | None:
    try:
        params = inspect.signature(cb).parameters.values()
    except (TypeError, ValueError):
        return None
    return next((p.name for p in params if p.annotation == TimerInfo), None)
