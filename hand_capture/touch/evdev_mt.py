"""Linux evdev multi-touch reader, multi-touch protocol type B -> :class:`TouchFrame`.

The kernel's MT protocol B (Documentation/input/multi-touch-protocol.rst) reports contacts in
slots: ``ABS_MT_SLOT n`` selects slot n, ``ABS_MT_TRACKING_ID id`` starts a contact in it
(``-1`` ends it), ``ABS_MT_POSITION_X/Y`` move it, and ``SYN_REPORT`` closes a frame.
``SYN_DROPPED`` means the kernel's buffer overflowed: events up to the next ``SYN_REPORT`` are
discarded and every contact is reported lifted, as the state can no longer be trusted.

:class:`MTParser` is the pure state machine (feed it ``(type, code, value)`` triples; testable
with synthetic sequences). :class:`EvdevTouchReader` opens ``/dev/input/event*`` with the
``evdev`` package and feeds the parser; a missing package, device or MT-B capability raises
:class:`~hand_capture.errors.DeviceError`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import DeviceError
from hand_capture.touch.frame import TouchFrame

# linux/input-event-codes.h
EV_SYN, EV_ABS = 0x00, 0x03
SYN_REPORT, SYN_DROPPED = 0, 3
ABS_MT_SLOT = 0x2F
ABS_MT_POSITION_X, ABS_MT_POSITION_Y = 0x35, 0x36
ABS_MT_TRACKING_ID = 0x39


@dataclass(frozen=True)
class EvdevConfig:
    """Which device to read and how to scale its coordinates."""

    device: str = param("", "evdev device path, e.g. /dev/input/event5 ('' = first "
                        "multi-touch device found)", read_only=True)
    width: float = param(0.0, "surface width [m]; 0 = from the device's resolution",
                         lo=0.0, hi=10.0)
    height: float = param(0.0, "surface height [m]; 0 = from the device's resolution",
                          lo=0.0, hi=10.0)
    frame_id: str = param("touch_surface", "frame name of the surface")

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class AxisRange:
    """Raw range of one axis (evdev ``absinfo``): min, max and resolution [units/mm]."""

    min: int
    max: int
    resolution: int = 0

    def span_m(self) -> float:
        """Physical length of the axis [m] from its resolution (0 when unknown)."""
        return (self.max - self.min) / self.resolution / 1000.0 if self.resolution > 0 else 0.0


@dataclass
class MTStats:
    frames: int = 0
    dropped_syncs: int = 0
    bad_slots: int = 0


class MTParser:
    """State machine of multi-touch protocol B.

    Args:
        x_range, y_range: the device's raw axis ranges (ABS_MT_POSITION_X/Y absinfo).
        width, height: surface size [m]; the raw range is mapped linearly onto [0, size].
        num_slots: slots the device has (ABS_MT_SLOT max + 1).
        clock: stamp of each frame [s] when the event carries none.
    """

    def __init__(self, x_range: AxisRange, y_range: AxisRange, width: float, height: float,
                 num_slots: int = 10, frame_id: str = "touch_surface",
                 clock: Callable[[], float] = time.time) -> None:
        if x_range.max <= x_range.min or y_range.max <= y_range.min:
            raise DeviceError(f"degenerate axis range x {x_range}, y {y_range}")
        if not (width > 0 and height > 0):
            raise DeviceError(f"surface size must be > 0, got {width} x {height} m; set "
                              "width/height when the device reports no resolution")
        self.x_range, self.y_range = x_range, y_range
        self.width, self.height = float(width), float(height)
        self.num_slots = int(num_slots)
        self.frame_id = frame_id
        self.clock = clock
        self.stats = MTStats()
        self._slot = 0
        self._ids = [-1] * self.num_slots
        self._xy = [[0, 0] for _ in range(self.num_slots)]
        self._ended: dict[int, tuple[int, int]] = {}  # tracking id -> last raw xy
        self._dropping = False

    def _scale(self, raw: tuple[int, int] | list[int]) -> tuple[float, float]:
        xr, yr = self.x_range, self.y_range
        return ((raw[0] - xr.min) / (xr.max - xr.min) * self.width,
                (raw[1] - yr.min) / (yr.max - yr.min) * self.height)

    def _end(self, slot: int) -> None:
        if self._ids[slot] >= 0:
            self._ended[self._ids[slot]] = tuple(self._xy[slot])
        self._ids[slot] = -1

    def feed(self, etype: int, code: int, value: int,
             stamp: float | None = None) -> TouchFrame | None:
        """Take one input event; returns a frame at each ``SYN_REPORT``."""
        if etype == EV_SYN:
            if code == SYN_DROPPED:
                self.stats.dropped_syncs += 1
                self._dropping = True
                return None
            if code != SYN_REPORT:
                return None
            if self._dropping:  # resynchronise: nothing in the slots can be trusted
                self._dropping = False
                for s in range(self.num_slots):
                    self._end(s)
            return self._report(stamp)
        if etype != EV_ABS or self._dropping:
            return None
        if code == ABS_MT_SLOT:
            if 0 <= value < self.num_slots:
                self._slot = value
            else:
                self.stats.bad_slots += 1
                self._slot = -1
            return None
        s = self._slot
        if s < 0:
            return None
        if code == ABS_MT_TRACKING_ID:
            if value != self._ids[s]:
                self._end(s)
                self._ids[s] = value if value >= 0 else -1
        elif code == ABS_MT_POSITION_X:
            self._xy[s][0] = value
        elif code == ABS_MT_POSITION_Y:
            self._xy[s][1] = value
        return None

    def feed_many(self, events: Iterable[tuple]) -> list[TouchFrame]:
        """Feed ``(type, code, value)`` or ``(type, code, value, stamp)`` tuples."""
        frames = []
        for ev in events:
            f = self.feed(*ev)
            if f is not None:
                frames.append(f)
        return frames

    def _report(self, stamp: float | None) -> TouchFrame:
        down = [(self._ids[s], self._scale(self._xy[s]))
                for s in range(self.num_slots) if self._ids[s] >= 0]
        lifted = [(i, self._scale(xy)) for i, xy in self._ended.items()
                  if i not in {d for d, _ in down}]
        self._ended.clear()
        ids = [i for i, _ in down] + [i for i, _ in lifted]
        pos = np.asarray([p for _, p in down] + [p for _, p in lifted], np.float64)
        flags = np.r_[np.ones(len(down), bool), np.zeros(len(lifted), bool)]
        self.stats.frames += 1
        return TouchFrame(np.asarray(ids, np.int64), pos.reshape(-1, 2), flags, self.width,
                          self.height, self.clock() if stamp is None else stamp, self.frame_id)


def _import_evdev():
    try:
        import evdev
    except ImportError as e:  # pragma: no cover - evdev is in requirements.txt
        raise DeviceError("the 'evdev' package is not installed: pip install evdev") from e
    return evdev


def find_multitouch_device() -> str:
    """Path of the first input device with multi-touch protocol B axes."""
    evdev = _import_evdev()
    for path in evdev.list_devices():
        try:
            dev = evdev.InputDevice(path)
        except OSError:
            continue
        try:
            abs_codes = {c for c, _ in dev.capabilities().get(EV_ABS, [])}
        finally:
            dev.close()
        if {ABS_MT_SLOT, ABS_MT_POSITION_X, ABS_MT_POSITION_Y} <= abs_codes:
            return path
    raise DeviceError("no multi-touch (protocol B) input device found under /dev/input; "
                      "is the user in the 'input' group?")


class EvdevTouchReader:
    """Reads a multi-touch protocol B device without blocking; call :meth:`poll` from a timer.

    Raises:
        DeviceError: evdev is missing, the device cannot be opened, it has no MT-B axes, or
            its size is unknown (no resolution and no width/height configured).
    """

    def __init__(self, config: EvdevConfig | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        evdev = _import_evdev()
        self.config = cfg = config or EvdevConfig()
        path = cfg.device or find_multitouch_device()
        try:
            self._dev = evdev.InputDevice(path)
        except OSError as e:
            raise DeviceError(f"cannot open touch device {path}: {e}") from e
        try:
            axes = {c: info for c, info in self._dev.capabilities(absinfo=True).get(EV_ABS, [])}
            missing = {ABS_MT_SLOT, ABS_MT_POSITION_X, ABS_MT_POSITION_Y} - set(axes)
            if missing:
                raise DeviceError(f"{path} ({self._dev.name}) is not a multi-touch protocol B "
                                  f"device (missing ABS codes {sorted(missing)})")
            xr = AxisRange(axes[ABS_MT_POSITION_X].min, axes[ABS_MT_POSITION_X].max,
                           axes[ABS_MT_POSITION_X].resolution)
            yr = AxisRange(axes[ABS_MT_POSITION_Y].min, axes[ABS_MT_POSITION_Y].max,
                           axes[ABS_MT_POSITION_Y].resolution)
            self.parser = MTParser(xr, yr, cfg.width or xr.span_m(), cfg.height or yr.span_m(),
                                   axes[ABS_MT_SLOT].max + 1, cfg.frame_id, clock)
        except DeviceError:
            self._dev.close()
            raise
        self.path = path

    def poll(self) -> list[TouchFrame]:
        """Every frame completed by the events waiting on the device."""
        try:
            events = [(ev.type, ev.code, ev.value, ev.timestamp()) for ev in self._dev.read()]
        except BlockingIOError:
            return []
        except OSError as e:
            raise DeviceError(f"touch device {self.path} failed: {e}") from e
        return self.parser.feed_many(events)

    def close(self) -> None:
        self._dev.close()
