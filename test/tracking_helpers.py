"""Shared set-up of the depth tracker's tests: the shipped regressor (a tiny one trained on
the spot when the file is missing), a regressor whose palm modes are moved off the hand, and
the synthetic camera on the ``translation`` clip."""

from __future__ import annotations

import numpy as np

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.tracking.hybrid import default_model_path
from hand_capture.tracking.regressor import HandRegressor
from hand_capture.tracking.train import train_tracker


def shipped_regressor() -> HandRegressor:
    """``data/tracker/regressor.npz`` (the test fails when it is missing)."""
    p = default_model_path()
    assert p.exists(), f"the shipped regressor {p} is missing (hand-suite train tracker)"
    return HandRegressor.load(p)


def shipped_or_tiny_regressor() -> HandRegressor:
    """``data/tracker/regressor.npz``, or a small regressor trained from seed 1."""
    p = default_model_path()
    if p.exists():
        return HandRegressor.load(p)
    return train_tracker(None, seed=1, n_samples=160, n_shapes=4, palm_stages=2,
                         finger_stages=1, n_trees=3, max_depth=8, n_features=120)


def translation_camera() -> SyntheticCamera:
    """The synthetic depth camera (no colour) playing the ``translation`` clip, opened."""
    c = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="translation"))
    c.open()
    return c


class OffPalms:
    """``reg`` with its palm modes moved ``off_m`` [m] along x (a surface it was not trained
    on), recording the palm modes and the palms the finger cascade runs on."""

    def __init__(self, reg: HandRegressor, off_m: float) -> None:
        self._reg = reg
        self.off_m = off_m
        self.roots: list[np.ndarray] = []
        self.modes: list[np.ndarray] = []

    def __getattr__(self, name: str):
        return getattr(self._reg, name)

    def palm_modes(self, *args, **kw) -> list[np.ndarray]:
        shift = np.zeros(27)
        shift[0] = self.off_m
        self.modes = [q + shift for q in self._reg.palm_modes(*args, **kw)]
        return self.modes

    def regress_fingers(self, frames, lookup, q, *args) -> np.ndarray:
        self.roots.append(np.array(q, copy=True))
        return self._reg.regress_fingers(frames, lookup, q, *args)
