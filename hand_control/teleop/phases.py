"""Grasp phases of the performance interface (dissertation ch. III.6).

The performer starts in *reaching*. When the hand comes closer to the object than a threshold,
the object is highlighted and *closing* starts. Once the grip size stays unchanged for a short
time the object counts as grasped: *manipulation* starts and the object's target pose follows
the wrist rigidly (the object is assumed static relative to the hand in this phase). When the
grip size grows for a short time the object is *released*; once the hand has moved away the
cycle starts again with *reaching*.

The dissertation gives the logic but no numbers; the defaults below are ours and documented as
such (reach threshold, window lengths, tolerances).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model import FINGERTIP_KEYPOINTS, KEYPOINT_NAMES


class Phase(IntEnum):
    """Grasp phases; values match hand_msgs/GraspPhase."""

    REACHING = 0
    CLOSING = 1
    MANIPULATION = 2
    RELEASING = 3


@dataclass(frozen=True)
class PhaseConfig:
    """Thresholds of the phase detector (our defaults; III.6 names no values)."""

    reach_distance: float = param(0.10, "palm-object distance that starts closing [m]",
                                  lo=0.0, hi=1.0)
    leave_distance: float = param(0.18, "palm-object distance that ends releasing [m]",
                                  lo=0.0, hi=2.0)
    steady_time: float = param(0.3, "grip size must stay steady this long to grasp [s]",
                               lo=0.01, hi=5.0)
    steady_tolerance: float = param(0.004, "largest grip-size change counted as steady [m]",
                                    lo=0.0, hi=0.1)
    min_closing_time: float = param(0.2, "closing lasts at least this long [s]", lo=0.0, hi=5.0)
    grip_filter: int = param(
        5, "the grip size is the median of the last n hand poses (tracking jitter of single "
        "frames would otherwise end a grasp)", lo=1, hi=100)
    close_decrease: float = param(
        0.008, "the grip must have shrunk this much since closing began before it can settle "
        "into a grasp (an open hand held still near the object is not a grasp) [m]",
        lo=0.0, hi=0.2)
    release_time: float = param(0.2, "the grip must stay opened this long to release [s]",
                                lo=0.01, hi=5.0)
    release_increase: float = param(0.010, "grip-size increase over the grasped grip that "
                                    "releases [m]", lo=0.0, hi=0.2)

    def __post_init__(self) -> None:
        validate(self)


_TIPS = list(FINGERTIP_KEYPOINTS)
_MCPS = [KEYPOINT_NAMES.index(f"{f}_mcp") for f in ("index", "middle", "ring", "little")]
_WRIST = KEYPOINT_NAMES.index("wrist")


_PALM = [_WRIST, *_MCPS]


def palm_center(keypoints: np.ndarray) -> np.ndarray:
    """Palm centre [m]: mean of the wrist and the four finger MCP keypoints; (21,3) -> (3,)."""
    return keypoints[_PALM].sum(axis=0) / len(_PALM)  # = .mean(axis=0), without its overhead


def grip_size(keypoints: np.ndarray, palm: np.ndarray | None = None) -> np.ndarray:
    """Grip size [m]: mean distance of the five fingertips from the palm centre (``palm``
    when the caller has computed it)."""
    d = keypoints[_TIPS] - (palm_center(keypoints) if palm is None else palm)
    return np.sqrt(np.add.reduce(d * d, axis=1)).sum() / len(_TIPS)  # as norm(axis=1).mean()


def _median(values) -> float:
    """np.median of a few floats (the same value), without numpy's overhead."""
    v = sorted(values)
    n = len(v)
    return float(v[n // 2]) if n % 2 else float((v[n // 2 - 1] + v[n // 2]) / 2)


@dataclass(frozen=True)
class PhaseUpdate:
    """Output of one detector step."""

    phase: Phase
    changed: bool
    object_target: np.ndarray | None  # (4, 4) object pose to track in MANIPULATION, else None
    grip: float  # grip size (median of the last grip_filter poses) [m]
    distance: float  # palm-object distance [m]


class GraspPhaseDetector:
    """The phase state machine; call :meth:`update` with every tracked hand pose."""

    def __init__(self, config: PhaseConfig | None = None) -> None:
        self.cfg = config or PhaseConfig()
        self.phase = Phase.REACHING
        self._since = 0.0
        self._grips: deque[tuple[float, float]] = deque()
        self._offset: np.ndarray | None = None  # object pose in the wrist frame, (4, 4)
        self._open_grip = 0.0  # grip size when closing began [m]
        self._grasp_grip = 0.0  # grip size when manipulation began [m]
        self._raw: deque[float] = deque(maxlen=self.cfg.grip_filter)  # unfiltered grip sizes
        self._t_last: float | None = None  # time of the last update [s]
        self.time_jumps = 0  # updates whose time went back (counted; timers restarted)

    def reset(self) -> None:
        """Back to reaching, forgetting any grasp."""
        jumps = self.time_jumps
        self.__init__(self.cfg)
        self.time_jumps = jumps

    def _enter(self, phase: Phase, t: float) -> None:
        self.phase, self._since = phase, t
        self._grips.clear()

    def _window(self, t: float, length: float) -> np.ndarray:
        while self._grips and self._grips[0][0] < t - length:
            self._grips.popleft()
        return np.array([g for _, g in self._grips])

    def update(self, t: float, keypoints: np.ndarray, wrist: np.ndarray,
               object_pose: np.ndarray, raw_grip: float | None = None) -> PhaseUpdate:
        """Advance the detector.

        Args:
            t: time of the hand pose [s] (monotonic within an episode). When it goes back
                (a stamp from the future came before, a restarted source, a looped bag) the
                phase stays and its timers and grip windows start again at ``t``: a single
                bad stamp must not hold a phase for ever.
            keypoints: (21, 3) hand keypoints [m] in the object's frame of reference.
            wrist: (4, 4) wrist pose in the same frame.
            object_pose: (4, 4) current object pose in the same frame.
            raw_grip: ``grip_size(keypoints)`` when the caller has it (else computed).

        Raises:
            InputError: non-finite or wrongly shaped input.
        """
        kp = np.asarray(keypoints, dtype=float)
        if kp.shape != (len(KEYPOINT_NAMES), 3) or np.asarray(wrist).shape != (4, 4) \
                or np.asarray(object_pose).shape != (4, 4):
            raise InputError("expected keypoints (21,3), wrist (4,4), object_pose (4,4)")
        if not (np.isfinite(kp).all() and np.isfinite(wrist).all()
                and np.isfinite(object_pose).all() and np.isfinite(t)):
            raise InputError("non-finite hand or object pose")
        if self._t_last is not None and t < self._t_last:
            self.time_jumps += 1
            self._since = t
            self._grips.clear()
        self._t_last = t
        palm = palm_center(kp)
        self._raw.append(float(grip_size(kp, palm)) if raw_grip is None else raw_grip)
        grip = _median(self._raw)
        dist = float(np.linalg.norm(palm - object_pose[:3, 3]))
        self._grips.append((t, grip))
        before = self.phase
        c = self.cfg
        if self.phase == Phase.REACHING:
            if dist < c.reach_distance:
                self._enter(Phase.CLOSING, t)
                self._open_grip = grip
        elif self.phase == Phase.CLOSING:
            w = self._window(t, c.steady_time)
            if dist > c.leave_distance:
                self._enter(Phase.REACHING, t)
            elif (t - self._since >= max(c.min_closing_time, c.steady_time) and w.size >= 2
                  and np.ptp(w) <= c.steady_tolerance
                  and self._open_grip - grip >= c.close_decrease):
                self._offset = np.linalg.inv(wrist) @ object_pose
                self._grasp_grip = grip
                self._enter(Phase.MANIPULATION, t)
        elif self.phase == Phase.MANIPULATION:
            # released once the grip has stayed wider than the grasped grip by
            # release_increase for release_time (a single jittery frame does not drop it)
            w = self._window(t, c.release_time)
            if (w.size >= 2 and t - self._since >= c.release_time
                    and w.min() - self._grasp_grip > c.release_increase):
                self._offset = None
                self._enter(Phase.RELEASING, t)
        elif self.phase == Phase.RELEASING and dist > c.leave_distance:
            self._enter(Phase.REACHING, t)
        target = wrist @ self._offset if self.phase == Phase.MANIPULATION else None
        return PhaseUpdate(self.phase, self.phase != before, target, grip, dist)
