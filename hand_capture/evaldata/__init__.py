"""Held-out evaluation data for the depth tracker (issue 13): built apart from training.

Nothing here is used to train or tune the tracker, and nothing here uses the training
generator's pieces (the template mesh and its rasteriser ``hand_capture.cameras.render``, the
sensor noise model ``hand_capture.cameras.noise``, the keyframe clips
``hand_capture.cameras.motion``, ``hand_capture.tracking.train``); ``test_evaldata.py``
checks the split both ways. Only the skeleton's forward kinematics (the keypoints the
tracker is scored on) is shared.

Modules: ``raycast`` (analytic ray casting of capsules / ellipsoids / planes), ``surface``
(the capsule-and-ellipsoid hand family, forearms, sleeves), ``stereo`` (stereo-like depth
noise), ``motion`` (sinusoid / random-walk joint trajectories, wrist paths), ``scene``
(cameras, clutter, sequences, calibration frames).
"""

from hand_capture.evaldata.scene import (
    CAMERAS,
    HeldoutSequence,
    calibration_frames,
    make_sequence,
    sample_subject,
)
from hand_capture.evaldata.surface import sample_surface

__all__ = ["CAMERAS", "HeldoutSequence", "calibration_frames", "make_sequence",
           "sample_subject", "sample_surface"]
