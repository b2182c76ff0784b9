"""A stream of tracked hands -> robot joint commands, holding the last command on bad frames.

The pure core of the ``retarget`` node: each frame is a hand pose or 21 keypoints with the
tracker's status. A frame that cannot be retargeted -- NaN keypoints, no hand (status LOST or
UNKNOWN, no points), the other hand, a solver error -- does not produce a new command: the
last command is repeated (held) for at most ``hold_timeout_s`` after the last good frame, and
the frame is counted by reason. After the hold time nothing is sent, so a consumer's own
command timeout (the servo bridge's ``command_timeout_s``) takes over.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from hand_capture.errors import HandSuiteError
from hand_capture.model.keypoints21 import keypoints21
from hand_control.retarget.solver import HandRetargeter

#: HandPose / HandKeypoints status codes that carry a hand (tracking, recovering, truth).
USABLE_STATUS = frozenset({1, 2, 4})
#: Reasons a frame is held (the keys of :attr:`RetargetStream.held`).
HOLD_REASONS = ("invalid", "no_hand", "other_hand", "solver")


@dataclass(frozen=True)
class StreamOutput:
    """What to publish for one frame: ``q`` (n,) robot joints [rad or m], or None for
    nothing; ``held`` is True when ``q`` repeats the last command."""

    q: np.ndarray | None
    held: bool
    solve_ms: float = 0.0
    tip_error_mm: float = float("nan")


class RetargetStream:
    """Frames in, robot joint commands out (see the module docstring).

    Args:
        retargeter: the solver (its config names the robot and the human hand side).
        hold_timeout_s: how long after the last good frame the last command is repeated [s].
        model: the operator's :class:`~hand_capture.model.HandModel` for pose input (None:
            the template hand).
        mirror_other_hand: retarget the other hand than the config's mirror-imaged (a left
            hand drives a right robot hand as its mirror image would); False: such frames
            are held and counted (``other_hand``).
    """

    def __init__(self, retargeter: HandRetargeter, hold_timeout_s: float = 1.0,
                 model: object | None = None, mirror_other_hand: bool = False) -> None:
        self.rt = retargeter
        self.hold_timeout_s = float(hold_timeout_s)
        self.model = model
        self.mirror_other_hand = bool(mirror_other_hand)
        self.last: np.ndarray | None = None
        self.last_good_t: float | None = None
        self.solved = 0
        self.held: Counter[str] = Counter()
        self.last_reason = ""

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.rt.joint_names

    def hold(self, reason: str, t: float, detail: str = "") -> StreamOutput:
        """A frame that gives no new command: count it, repeat the last command if it is
        recent enough."""
        if reason not in HOLD_REASONS:
            raise ValueError(f"hold reason {reason!r} is not one of {HOLD_REASONS}")
        self.held[reason] += 1
        self.last_reason = f"{reason}: {detail}" if detail else reason
        if self.last is None or self.last_good_t is None or \
                t - self.last_good_t > self.hold_timeout_s:
            return StreamOutput(None, True)
        return StreamOutput(self.last.copy(), True)

    def keypoints(self, points: np.ndarray | None, t: float, status: int = 1,
                  side: str = "right") -> StreamOutput:
        """One frame of 21 keypoints [m] (None or any NaN: invalid) at time ``t`` [s]."""
        if status not in USABLE_STATUS or points is None:
            return self.hold("no_hand", t, f"status {status}")
        pts = np.asarray(points, dtype=np.float64)
        if pts.shape != (21, 3) or not np.isfinite(pts).all():
            return self.hold("invalid", t, "keypoints not 21 finite points")
        if side != self.rt.config.handedness:
            if not self.mirror_other_hand:
                return self.hold("other_hand", t, f"a {side} hand; the robot follows a "
                                 f"{self.rt.config.handedness} hand")
            # the mirror image (y -> -y) of a left hand is a right hand, and vice versa
            pts = pts * np.array([1.0, -1.0, 1.0])
            side = self.rt.config.handedness
        try:
            res = self.rt.solve(pts, stamp_s=t, side=side)
        except HandSuiteError as e:
            return self.hold("solver", t, str(e))
        self.last = res.q.copy()
        self.last_good_t = t
        self.solved += 1
        tips = self.rt.tip_rows
        err = float(np.mean(res.point_error_m[tips]) * 1e3) if tips else float("nan")
        return StreamOutput(res.q, False, res.time_s * 1e3, err)

    def pose(self, pose: np.ndarray | None, t: float, status: int = 1,
             side: str = "right") -> StreamOutput:
        """One frame of a suite hand pose (27,) [m, rad] (None or NaN: invalid)."""
        if status not in USABLE_STATUS:
            return self.hold("no_hand", t, f"status {status}")
        if pose is None or not np.isfinite(np.asarray(pose, dtype=np.float64)).all():
            return self.hold("invalid", t, "pose not finite")
        try:
            kp = keypoints21(self.model, pose, side)
        except HandSuiteError as e:
            return self.hold("invalid", t, str(e))
        return self.keypoints(kp, t, status, side)

    def counts(self) -> dict[str, int]:
        """Frames solved and held (by reason), for diagnostics."""
        out = {"solved": self.solved, "held_total": sum(self.held.values())}
        out.update({f"held/{r}": self.held[r] for r in HOLD_REASONS})
        return out
