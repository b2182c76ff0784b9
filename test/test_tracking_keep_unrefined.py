"""Step 4 keeps a screened candidate as it was when its refinement raised its cost of eq.
II.20 (``keep_unrefined``): the refinement's smoothness term holds every candidate near the
previous pose, so a regressed candidate that rightly leaves a wrong previous pose can come
out of it worse than it went in."""

from __future__ import annotations

import numpy as np
import pytest
from tracking_helpers import shipped_or_tiny_regressor, translation_camera

from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker

limit_blas_threads(1)

#: how far the spoiled refinement moves every candidate [m]
_SHIFT_M = 0.03


@pytest.fixture(scope="module")
def regressor():
    return shipped_or_tiny_regressor()


@pytest.fixture(scope="module")
def cam():
    return translation_camera()


@pytest.fixture(scope="module")
def frames(cam):
    return [cam.render(i / 30) for i in range(3)]


def _spoil_refinement(tr: HybridTracker) -> None:
    """Every full refinement (step 4, the finger-wise and abduction trials) ends 30 mm off
    along x, as a refinement pulled by a wrong smoothness reference would; the palm-only
    iterations of steps 1 and 3 are left alone."""
    refine_batch = tr.icp.refine_batch

    def spoiled(Q, obs, iterations, q_refs=None, palm_only=False, points=None):
        out = refine_batch(Q, obs, iterations, q_refs=q_refs, palm_only=palm_only,
                           points=points)
        if not palm_only:
            out = np.array(out, copy=True)
            out[:, 0] += _SHIFT_M
        return out

    tr.icp.refine_batch = spoiled


def _track_spoiled(regressor, cam, frames, cfg: TrackerConfig) -> tuple[float, float, bool]:
    """Frames 0-1 tracked normally, frame 2 with the spoiled refinement: its E_d [mm], mean
    keypoint error [mm] and success."""
    tr = HybridTracker(cam.model, cfg, regressor)
    for f in frames[:2]:
        assert tr.process(f.depth, f.depth_intrinsics).success
    _spoil_refinement(tr)
    r = tr.process(frames[2].depth, frames[2].depth_intrinsics)
    truth = cam.model.joint_positions(frames[2].pose)
    err = float(np.linalg.norm(tr.model.joint_positions(r.pose) - truth, axis=1).mean())
    return r.cost, err * 1e3, r.success


def test_a_refinement_that_raises_the_cost_is_not_taken(regressor, cam, frames):
    # the product keeps a candidate as screened: one of the right pose, tracked
    cost_on, err_on, ok_on = _track_spoiled(regressor, cam, frames, TrackerConfig())
    # without it, every candidate comes out of the refinement 30 mm off
    cost_off, err_off, _ = _track_spoiled(regressor, cam, frames,
                                          TrackerConfig(keep_unrefined=False))
    assert ok_on and err_on < 15.0
    assert err_off > 20.0 and cost_on < cost_off
