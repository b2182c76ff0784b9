"""Approximate-time grouping of frames from N cameras with independent clocks.

Seed 000 captures with six cameras recording at 20 fps (sec. 4.1) and seed 002 with eight
(sec. 3); both need, for every instant, one image per camera. Cameras without a hardware
trigger stamp their frames on their own clocks with jitter, drop frames, and may stop.
:class:`FrameSynchronizer` groups such streams: a group holds one frame per live camera whose
stamps lie within ``tolerance_s`` of each other, and is given one common stamp (the mean of its
members' stamps).

It is a pure core object driven by two clocks: frame stamps (the cameras' time) decide what
belongs together, and the receive time ``now`` (the host's time) decides when a camera is
declared missing. A missing camera is named; groups go on over the cameras that are alive
(``complete`` is False on those), and the camera rejoins when its frames come back.

Silence alone does not make a camera missing: the rest of the rig must have gone on without
it (another camera delivered ``missing_after_frames`` frames since its last one). A process
starved of CPU takes its backlog late, one message per subscription in turn, so on a loaded
host every camera looks silent at once after a stall; judged by time alone, the first camera
taken would be grouped without the others, whose frames were waiting in the middleware.

Counters (for ``diagnostics``):
    groups: groups emitted; incomplete: of those, groups missing a camera;
    dropped: frames discarded because no partner frame was within the tolerance;
    late: frames older than the last emitted group (they can never be grouped);
    overflow: frames dropped because a camera's queue was full.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, InputError

__all__ = ["FrameGroup", "FrameSynchronizer", "SyncConfig", "SyncStats"]


@dataclass(frozen=True)
class SyncConfig:
    """Parameters of :class:`FrameSynchronizer`."""

    tolerance_s: float = param(
        0.010, "largest stamp difference inside a group [s]; below half a frame period",
        lo=1e-6, hi=1.0)
    camera_timeout_s: float = param(
        0.5, "a camera without a frame for this long (receive time) is missing [s]",
        lo=1e-3, hi=60.0)
    max_queue: int = param(30, "frames kept per camera while waiting for partners", lo=2,
                           hi=10000)
    missing_after_frames: int = param(
        2, "a silent camera is missing only once another camera delivered this many frames "
        "since its last one (a starved host takes its backlog late)", lo=1, hi=1000)
    min_cameras: int = param(
        1, "fewest live cameras a group may hold (degraded rig) before nothing is emitted",
        lo=1, hi=64)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class SyncStats:
    """Counters of a :class:`FrameSynchronizer` (see the module docstring)."""

    groups: int = 0
    incomplete: int = 0
    dropped: int = 0
    late: int = 0
    overflow: int = 0
    max_skew_s: float = 0.0
    received: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class FrameGroup:
    """One synchronised instant.

    Attributes:
        stamp: the common stamp given to every member [s] (mean of the members' stamps).
        frames: camera name -> (its own stamp [s], payload), for the cameras in the group.
        missing: cameras of the rig that are not in the group (dead or timed out).
        skew_s: largest minus smallest member stamp [s].
    """

    stamp: float
    frames: dict[str, tuple[float, Any]]
    missing: tuple[str, ...]
    skew_s: float

    @property
    def complete(self) -> bool:
        """True when every camera of the rig is in the group."""
        return not self.missing


class FrameSynchronizer:
    """Group frames of named cameras by stamp (approximate time, see the module docstring).

    Args:
        cameras: the rig's camera names.
        config: tolerance, timeouts and queue bound.
    """

    def __init__(self, cameras: Sequence[str], config: SyncConfig | None = None) -> None:
        names = list(cameras)
        if not names or len(set(names)) != len(names):
            raise ConfigError(f"FrameSynchronizer: camera names must be unique and non-empty, "
                              f"got {names}")
        self.config = config or SyncConfig()
        if self.config.min_cameras > len(names):
            raise ConfigError(f"SyncConfig.min_cameras = {self.config.min_cameras} exceeds the "
                              f"{len(names)} cameras of the rig")
        self.cameras = tuple(names)
        self._queues: dict[str, deque[tuple[float, Any]]] = {n: deque() for n in names}
        self._last_rx: dict[str, float | None] = dict.fromkeys(names)
        # _seen_at[a]: every camera's ``stats.received`` when camera a's last frame came
        self._seen_at: dict[str, dict[str, int]] = {a: dict.fromkeys(names, 0) for a in names}
        self._last_group = -math.inf
        self._start: float | None = None  # receive time of the first frame
        self.stats = SyncStats(received=dict.fromkeys(names, 0))

    def missing(self, now: float) -> tuple[str, ...]:
        """Cameras with no frame for longer than ``camera_timeout_s`` before ``now`` [s] (a
        camera never heard from counts from the first frame of any camera) while another
        camera delivered at least ``missing_after_frames`` frames since their last one; every
        camera when all of them are that long silent (the whole rig stopped)."""
        t = self.config.camera_timeout_s
        if self._start is None:
            return ()
        silent = [n for n in self.cameras
                  if now - (self._start if self._last_rx[n] is None else self._last_rx[n]) > t]
        if len(silent) == len(self.cameras):
            return tuple(silent)
        k, rx = self.config.missing_after_frames, self.stats.received
        return tuple(n for n in silent
                     if max(rx[b] - seen for b, seen in self._seen_at[n].items()) >= k)

    def push(self, camera: str, stamp: float, payload: Any, now: float) -> list[FrameGroup]:
        """Add one frame and return the groups it completes (oldest first).

        Args:
            camera: the camera's name.
            stamp: the frame's stamp on the camera's clock [s].
            payload: anything (an image message, an array); handed back in the group.
            now: receive time on the host's clock [s].

        Raises:
            InputError: for an unknown camera (the message lists the rig's cameras) or a
                non-finite stamp.
        """
        if camera not in self._queues:
            raise InputError(f"unknown camera {camera!r}; cameras: {list(self.cameras)}")
        if not math.isfinite(stamp):
            raise InputError(f"camera {camera!r}: stamp must be finite, got {stamp}")
        self.stats.received[camera] += 1
        self._last_rx[camera] = now
        self._seen_at[camera] = dict(self.stats.received)
        if self._start is None:
            self._start = now
        if stamp <= self._last_group:
            self.stats.late += 1
            return []
        q = self._queues[camera]
        if q and stamp <= q[-1][0]:
            self.stats.late += 1  # out of order on its own stream
            return []
        q.append((stamp, payload))
        if len(q) > self.config.max_queue:
            q.popleft()
            self.stats.overflow += 1
        return self.poll(now)

    def poll(self, now: float) -> list[FrameGroup]:
        """Emit every group that can be formed at receive time ``now`` [s].

        Call it from a timer too, so a camera that stopped is noticed without new frames.
        """
        out: list[FrameGroup] = []
        missing = set(self.missing(now))
        live = [n for n in self.cameras if n not in missing]
        if len(live) < self.config.min_cameras:
            return out
        # A dead camera's stale frames can never be matched: discard them.
        for n in missing:
            self.stats.dropped += len(self._queues[n])
            self._queues[n].clear()
        tol = self.config.tolerance_s
        while all(self._queues[n] for n in live):
            heads = {n: self._queues[n][0][0] for n in live}
            hi = max(heads.values())
            stale = [n for n in live if heads[n] < hi - tol]
            if stale:
                for n in stale:  # no partner within tolerance of the newest head
                    self._queues[n].popleft()
                    self.stats.dropped += 1
                continue
            members = {n: self._queues[n].popleft() for n in live}
            stamps = [s for s, _ in members.values()]
            group = FrameGroup(stamp=sum(stamps) / len(stamps), frames=members,
                               missing=tuple(n for n in self.cameras if n in missing),
                               skew_s=max(stamps) - min(stamps))
            self._last_group = max(stamps)
            self.stats.groups += 1
            self.stats.incomplete += int(not group.complete)
            self.stats.max_skew_s = max(self.stats.max_skew_s, group.skew_s)
            out.append(group)
        return out
