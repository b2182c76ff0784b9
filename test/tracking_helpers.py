"""Shared set-up of the depth tracker's tests: the shipped regressor (a tiny one trained on
the spot when the file is missing) and the synthetic camera on the ``translation`` clip."""

from __future__ import annotations

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.tracking.hybrid import default_model_path
from hand_capture.tracking.regressor import HandRegressor
from hand_capture.tracking.train import train_tracker


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
