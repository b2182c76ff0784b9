"""Hand-model joint angles -> servo angles through a servo map, and a low-pass filter.

The map is linear: for servo ``i``, ``theta_i = offset_i + direction_i * scale_i *
sum_j w_ij q_j`` [rad], so the whole map is one matrix ``A`` (servos x articulated joints) and a
vector ``b``: ``theta = A q + b``. Joint angles arrive by name (HandPose.joint_names,
JointState.name); the name -> column lookup is cached per distinct name list. ``q`` is over the
hand model's articulated joints, or, for a map with ``joint_vocabulary: robot``, over the
robot joints the map names (in the map's order).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hand_capture.model.joints import ARTICULATED_JOINTS
from hand_capture.validate import DEFAULT_LIMITS, InputLimits, joint_bounds
from hand_control.dynamixel.control_table import POSITION_CENTER, TICKS_PER_RAD
from hand_control.dynamixel.servo_map import ServoMap
from hand_control.errors import InputError


class Retargeter:
    """Linear retargeting of named hand-model joint angles to servo angles and ticks."""

    def __init__(self, servo_map: ServoMap, limits: InputLimits = DEFAULT_LIMITS) -> None:
        self.servo_map = servo_map
        self.vocabulary: tuple[str, ...] = (
            ARTICULATED_JOINTS if servo_map.joint_vocabulary == "hand_model"
            else servo_map.joints_used())
        self._index = {name: i for i, name in enumerate(self.vocabulary)}
        n, m = len(servo_map.servos), len(self.vocabulary)
        self.A = np.zeros((n, m))
        self.b = np.zeros(n)
        for i, s in enumerate(servo_map.servos):
            for j, w in s.joints:
                self.A[i, self._index[j]] += s.direction * s.scale * w
            self.b[i] = s.offset
        self.required = tuple(servo_map.joints_used())
        self._required_idx = np.array([self._index[j] for j in self.required], dtype=int)
        # only the joints the map uses enter A q: a NaN in any other joint of a message can
        # never reach a servo (0 * NaN = NaN in a full product)
        self._A_used = np.ascontiguousarray(self.A[:, self._required_idx])
        # valid angle of each used joint: the hand model's limits widened by the validation
        # layer's margin [rad]; anything outside is refused, never clamped at the servo limits
        self._lo, self._hi = joint_bounds(self.required, limits)
        self._cache: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}

    def _lookup(self, names: tuple[str, ...], strict: bool) -> tuple[np.ndarray, np.ndarray]:
        hit = self._cache.get(names)
        if hit is not None:
            return hit
        index = self._index
        if strict:
            unknown = [n for n in names if n not in index]
            if unknown:
                raise InputError(f"unknown joint name(s) {unknown[:5]}; valid joints: "
                                 f"{list(self.vocabulary)}")
        if len(set(names)) != len(names):
            raise InputError("duplicate joint names in the message")
        src = [k for k, n in enumerate(names) if n in index]
        dst = [index[names[k]] for k in src]
        missing = [j for j in self.required if j not in names]
        if missing:
            raise InputError(f"joint(s) {missing} needed by servo map "
                             f"{self.servo_map.name!r} are missing from the message")
        out = (np.array(src, dtype=int), np.array(dst, dtype=int))
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[names] = out
        return out

    def joint_vector(self, names: Sequence[str], positions: Sequence[float],
                     strict: bool = True) -> np.ndarray:
        """The joint vector q (21 articulated joints, or the map's robot joints) from named
        angles [rad].

        Args:
            strict: refuse names outside the joint vocabulary (HandPose); when False they are
                ignored (JointState from a simulation that also carries other joints).

        Raises:
            InputError: length mismatch, unknown/duplicate/missing names, NaN or Inf, or an
                angle of a used joint outside its valid range (refused, not clamped).
        """
        names = tuple(names)
        if len(names) != len(positions):
            raise InputError(f"{len(names)} joint names but {len(positions)} positions")
        src, dst = self._lookup(names, strict)
        vals = np.asarray(positions, dtype=float)[src]
        q = np.zeros(len(self.vocabulary))
        q[dst] = vals
        if not np.all(np.isfinite(q[self._required_idx])):
            bad = [self.required[k] for k in np.flatnonzero(
                ~np.isfinite(q[self._required_idx]))]
            raise InputError(f"non-finite angle for joint(s) {bad}")
        used = q[self._required_idx]
        out = (used < self._lo) | (used > self._hi)
        if out.any():
            k = int(np.flatnonzero(out)[0])
            raise InputError(f"angle of {self.required[k]!r} = {used[k]:.6g} rad is outside "
                             f"its valid range [{self._lo[k]:.3f}, {self._hi[k]:.3f}] rad")
        return q

    def servo_angles(self, q: np.ndarray) -> np.ndarray:
        """Servo angles theta = A q + b [rad], one per servo in map order (only the joints
        the map uses are read from ``q``)."""
        return self._A_used @ q[self._required_idx] + self.b

    def from_named(self, names: Sequence[str], positions: Sequence[float],
                   strict: bool = True) -> np.ndarray:
        return self.servo_angles(self.joint_vector(names, positions, strict))


def angles_to_ticks(theta: np.ndarray) -> np.ndarray:
    """Servo angles [rad] -> position ticks (float), 0 rad = tick 2048."""
    return theta * TICKS_PER_RAD + POSITION_CENTER


def ticks_to_angles(ticks: np.ndarray) -> np.ndarray:
    return (np.asarray(ticks, dtype=float) - POSITION_CENTER) / TICKS_PER_RAD


class LowPassFilter:
    """First-order low-pass filter, y += alpha (x - y), alpha = 1 - exp(-2 pi f_c dt).

    ``cutoff_hz <= 0`` passes the input through. The state is reset explicitly (e.g. to the
    present servo angles) so the filter never starts from zeros.
    """

    def __init__(self, cutoff_hz: float) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self.y: np.ndarray | None = None

    def reset(self, y0: np.ndarray) -> None:
        self.y = np.array(y0, dtype=float)

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        if self.y is None or self.cutoff_hz <= 0:
            self.y = np.array(x, dtype=float)
            return self.y
        alpha = 1.0 - math.exp(-2.0 * math.pi * self.cutoff_hz * max(dt, 0.0))
        # a NaN in y (a servo not yet read) takes the input as it is
        y = self.y
        y += alpha * (x - y)
        if not np.isfinite(y).all():
            nan = ~np.isfinite(y)
            y[nan] = x[nan]
        return y
