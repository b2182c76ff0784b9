"""InputGate: the node side of the input-validation layer (:mod:`hand_capture.validate`).

Every subscription callback passes what it extracted from a message through
:meth:`InputGate.check` (or reports its own rejection with :meth:`InputGate.reject`): a
:class:`~hand_capture.errors.InputError` is caught, counted per topic and logged at most once a
second per topic (with the count so far), and the callback gets ``None`` back and drops the
message. The physical ranges are the node's ``input.*`` ROS parameters
(:class:`~hand_capture.validate.InputLimits`, e.g. ``input.future_stamp_tolerance``).
:meth:`InputGate.values` gives the counts for the node's ``diagnostics``
(``rejected/<topic>`` and ``rejected_total``), so the rule "bad input gets a counted, logged
rejection" holds in one place.
"""

from __future__ import annotations

import inspect
import math
import time
from collections import Counter
from collections.abc import Callable
from typing import TypeVar

from hand_capture.errors import InputError
from hand_capture.nodes.params import declare_config
from hand_capture.validate import InputLimits, check_stamp

T = TypeVar("T")
_TAKES_LIMITS: dict[Callable, bool] = {}  # whether a check function has a limits parameter


class InputGate:
    """Counts and logs (throttled, per topic) the inputs a node rejects.

    Args:
        node: the rclpy node (its logger and clock are used).
        limits: the physical ranges of the node's inputs; default: declared as the node's
            ``input.*`` parameters (YAML-settable, validated).
        throttle_s: at most one log line per topic this often [s].
        on_reject: called with the topic of every rejection (e.g. a core's own counter).
    """

    def __init__(self, node: object, limits: InputLimits | None = None,
                 throttle_s: float = 1.0,
                 on_reject: Callable[[str], None] | None = None) -> None:
        self.node = node
        self.on_reject = on_reject
        self.limits = limits if limits is not None else declare_config(
            node, InputLimits, prefix="input.")
        self.throttle_s = float(throttle_s)
        self.rejected: Counter[str] = Counter()
        self.last_reason: dict[str, str] = {}
        self._logged: dict[str, float] = {}

    @property
    def total(self) -> int:
        return sum(self.rejected.values())

    def reject(self, topic: str, reason: object) -> None:
        """Count one rejected message on ``topic`` and log it (throttled per topic)."""
        self.rejected[topic] += 1
        if self.on_reject is not None:
            self.on_reject(topic)
        text = str(reason)
        self.last_reason[topic] = text
        now = time.monotonic()
        if now - self._logged.get(topic, -math.inf) >= self.throttle_s:
            self._logged[topic] = now
            self.node.get_logger().warning(
                f"{topic} rejected ({self.rejected[topic]} so far): {text}")

    def check(self, topic: str, fn: Callable[..., T], *args: object,
              **kwargs: object) -> T | None:
        """``fn(*args, **kwargs)``, or None (counted, logged) when it raises InputError
        (``fn`` must return a value other than None when it accepts). A ``fn`` with a
        ``limits`` parameter (the :mod:`hand_capture.validate` functions) gets the node's."""
        takes = _TAKES_LIMITS.get(fn)
        if takes is None:
            takes = _TAKES_LIMITS[fn] = "limits" in inspect.signature(fn).parameters
        if takes and "limits" not in kwargs:
            kwargs["limits"] = self.limits
        try:
            return fn(*args, **kwargs)
        except InputError as e:
            self.reject(topic, e)
            return None

    def stamp_ok(self, topic: str, stamp: object) -> bool:
        """False (counted, logged) for a header stamp beyond the future-stamp tolerance of
        the node clock (skipped while a simulated clock reads 0)."""
        now = self.node.get_clock().now().nanoseconds * 1e-9
        t = stamp.sec + 1e-9 * stamp.nanosec
        try:
            check_stamp(t, now, self.limits, f"{topic} header.stamp")
        except InputError as e:
            self.reject(topic, e)
            return False
        return True

    def values(self) -> dict[str, str]:
        """Diagnostics key/values: ``rejected_total`` and ``rejected/<topic>``."""
        out = {"rejected_total": str(self.total)}
        out.update({f"rejected/{k}": str(v) for k, v in sorted(self.rejected.items())})
        for k, v in sorted(self.last_reason.items()):
            out[f"last_rejection/{k}"] = v[:200]
        return out
