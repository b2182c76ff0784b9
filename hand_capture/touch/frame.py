"""TouchFrame: the set of touches on a multi-touch surface at one instant (pure core).

The same content as ``hand_msgs/TouchFrame``: session ids that stay the same while a finger
stays down, positions in metres in the surface frame (x along the width from the left edge,
y along the height from the top edge), contact flags (false only in the frame a finger lifts)
and the surface size. Sources (TUIO, evdev) produce it; the encoder consumes it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError


@dataclass(frozen=True)
class TouchFrame:
    """Touches at one instant.

    Attributes:
        session_ids: (n,) int64, one per touch, stable while the finger stays down.
        positions: (n, 2) float64, [m] in the surface frame (x right, y down from the top).
        in_contact: (n,) bool; False marks a touch in the frame it lifts.
        width, height: surface size [m].
        stamp: time the frame was received [s] (source clock).
        frame_id: the surface's name.
    """

    session_ids: np.ndarray
    positions: np.ndarray
    in_contact: np.ndarray
    width: float
    height: float
    stamp: float = 0.0
    frame_id: str = "touch_surface"

    def __post_init__(self) -> None:
        ids = np.asarray(self.session_ids, dtype=np.int64).reshape(-1)
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.size == 0:
            pos = pos.reshape(0, 2)
        flags = np.asarray(self.in_contact, dtype=bool).reshape(-1)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise InputError(f"positions must have shape (n, 2), got {pos.shape}")
        if not (len(ids) == len(pos) == len(flags)):
            raise InputError(
                f"session_ids ({len(ids)}), positions ({len(pos)}) and in_contact "
                f"({len(flags)}) must have the same length")
        if len(np.unique(ids)) != len(ids):
            raise InputError(f"duplicate session ids in {ids.tolist()}")
        if not (np.isfinite(self.width) and np.isfinite(self.height)
                and self.width > 0 and self.height > 0):
            raise InputError(f"surface size must be finite and > 0, got "
                             f"{self.width} x {self.height} m")
        object.__setattr__(self, "session_ids", ids)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "in_contact", flags)
        object.__setattr__(self, "width", float(self.width))
        object.__setattr__(self, "height", float(self.height))

    def __len__(self) -> int:
        return len(self.session_ids)

    def contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """Session ids and positions of the touches that are in contact."""
        m = self.in_contact
        return self.session_ids[m], self.positions[m]

    def off_surface(self, margin: float = 0.0) -> np.ndarray:
        """(n,) bool: touches more than ``margin`` [m] outside the surface rectangle."""
        x, y = self.positions[:, 0], self.positions[:, 1]
        return (x < -margin) | (x > self.width + margin) | (y < -margin) | \
            (y > self.height + margin)

    @staticmethod
    def empty(width: float, height: float, stamp: float = 0.0,
              frame_id: str = "touch_surface") -> TouchFrame:
        return TouchFrame(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, bool),
                          width, height, stamp, frame_id)

