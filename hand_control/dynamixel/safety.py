"""Safety logic of the servo bridge, free of I/O: limits, rate limits, timeouts, fault latches.

* :class:`GoalLimiter` clamps goals to each servo's position limits and limits how far a goal
  may move from the last commanded goal per second (per-servo rate limit).
* :class:`InputWatchdog` says when the command input is older than the command timeout.
* :class:`FailureCounter` counts consecutive failed bus cycles against a threshold.
* :class:`FaultLatch` remembers servos that reported a hardware error until they are rebooted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_control.dynamixel.control_table import TICKS_PER_RAD, describe_hardware_error
from hand_control.dynamixel.servo_map import ServoMap


class GoalLimiter:
    """Clamp goals to position limits and to a maximum speed away from the last command.

    ``last`` holds the last commanded goal per servo in ticks, NaN until a good read of the
    servo's present position has set it (a servo without one is never commanded).
    """

    def __init__(self, servo_map: ServoMap) -> None:
        self.lo = np.array([s.min_position for s in servo_map.servos], dtype=float)
        self.hi = np.array([s.max_position for s in servo_map.servos], dtype=float)
        self.vmax = np.array([s.max_velocity_rad_s * TICKS_PER_RAD for s in servo_map.servos])
        self.last = np.full(len(servo_map.servos), np.nan)

    def reset(self, present_ticks: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Start from the present positions (all servos, or those in ``mask``)."""
        p = np.asarray(present_ticks, dtype=float)
        if mask is None:
            self.last = p.copy()
        else:
            self.last[mask] = p[mask]

    def clamp(self, ticks: np.ndarray) -> np.ndarray:
        return np.clip(ticks, self.lo, self.hi)

    def __call__(self, target_ticks: np.ndarray, dt: float,
                 mask: np.ndarray | None = None) -> np.ndarray:
        """The next goals (float ticks): within limits, at most vmax * dt from the last goals.

        Only servos in ``mask`` (default all) take the new goal as their last goal: a servo
        that is not written this cycle keeps its last written goal as the reference. Servos
        with no last goal (NaN) come out NaN. A non-finite target holds that servo's last goal:
        it never enters ``last`` (one NaN would otherwise stop the servo for good).
        """
        lo, hi = self.lo, self.hi
        target = np.asarray(target_ticks, dtype=float)
        if not np.isfinite(target).all():
            target = np.where(np.isfinite(target), target, self.last)
        target = np.minimum(np.maximum(target, lo), hi)
        vdt = self.vmax * dt
        step = np.minimum(np.maximum(target - self.last, -vdt), vdt)
        goal = np.minimum(np.maximum(self.last + step, lo), hi)
        if mask is None:
            self.last = goal.copy()
        else:
            self.last[mask] = goal[mask]
        return goal


class InputWatchdog:
    """True from ``expired(now)`` once no input arrived for ``timeout_s``."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = float(timeout_s)
        self.t_last: float | None = None

    def feed(self, now: float) -> None:
        self.t_last = now

    def arm(self, now: float) -> None:
        """Start counting from ``now`` (activation): no input yet counts as stale after it."""
        self.t_last = now

    def age(self, now: float) -> float:
        return float("inf") if self.t_last is None else now - self.t_last

    def expired(self, now: float) -> bool:
        return self.age(now) > self.timeout_s


class FailureCounter:
    """Consecutive failures against a threshold (reset by a success)."""

    def __init__(self, threshold: int) -> None:
        self.threshold = int(threshold)
        self.consecutive = 0
        self.total = 0

    def record(self, ok: bool) -> bool:
        """Record one cycle; True when the threshold has been reached."""
        if ok:
            self.consecutive = 0
        else:
            self.consecutive += 1
            self.total += 1
        return self.consecutive >= self.threshold

    def reset(self) -> None:
        self.consecutive = 0


@dataclass
class Fault:
    bits: int
    since: float

    @property
    def description(self) -> str:
        return describe_hardware_error(self.bits)


class FaultLatch:
    """Servos with a hardware error: not commanded until an explicit reboot clears them."""

    def __init__(self) -> None:
        self.faults: dict[int, Fault] = {}

    def set(self, dxl_id: int, bits: int, now: float) -> bool:
        """Latch a fault; True when it is new (or has new bits)."""
        old = self.faults.get(dxl_id)
        if old is not None and old.bits | bits == old.bits:
            return False
        self.faults[dxl_id] = Fault((old.bits if old else 0) | bits, old.since if old else now)
        return True

    def clear(self, dxl_id: int) -> None:
        self.faults.pop(dxl_id, None)

    def __contains__(self, dxl_id: int) -> bool:
        return dxl_id in self.faults

    def __bool__(self) -> bool:
        return bool(self.faults)
