"""Step 3 also starts from the previous pose moved by the shift of the hand segment's
centroid (``shift_previous``, issue 13): the validation families' clips hold the wrist
still, a real hand (and the held-out family) moves it several millimetres a frame, and the previous
pose then starts a frame behind."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.bench._tracking_heldout import SurfaceVariant
from hand_capture.cameras.render import make_renderer
from hand_capture.model import HandModel
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker
from hand_capture.tracking.train import default_intrinsics, random_pose

#: how far the hand moves between the two frames [m] (a fast hand at 30 fps)
JUMP_M = np.array([0.035, -0.02, 0.0])


@pytest.fixture(scope="module")
def frames() -> tuple[HandModel, np.ndarray, np.ndarray, list[np.ndarray]]:
    """The suite's hand, and two exact renders [mm]: at rest, then moved by ``JUMP_M``."""
    m = HandModel()
    q1 = random_pose(np.random.default_rng(3), m)
    q2 = q1.copy()
    q2[0:3] += JUMP_M
    r = make_renderer("zbuffer")
    depths = [np.rint(r.render([SurfaceVariant().mesh_fn(m)(q)], default_intrinsics()).depth * 1000
                      ).astype(np.uint16) for q in (q1, q2)]
    return m, q1, q2, depths


def _track(frames, cfg: TrackerConfig):
    """The first frame tracked on from its truth, then the moved one (no regressor: the
    pool is the previous pose and, with ``shift_previous``, its shifted copy)."""
    m, q1, q2, depths = frames
    tr = HybridTracker(m, cfg, None)
    tr.reset(q1)
    r1 = tr.process(depths[0], default_intrinsics())
    r2 = tr.process(depths[1], default_intrinsics())
    err = np.linalg.norm(m.joint_positions(r2.pose) - m.joint_positions(q2), axis=1).mean()
    return r1, r2, float(err) * 1e3


def test_a_hand_that_jumps_is_found_from_the_shifted_previous_pose(frames) -> None:
    r1_off, r2_off, err_off = _track(frames, TrackerConfig(shift_previous=False))
    r1_on, r2_on, err_on = _track(frames, TrackerConfig())
    assert r1_on.n_candidates == r1_off.n_candidates == 1   # no shift known on the first
    assert r2_on.n_candidates == r2_off.n_candidates + 1
    assert err_off > 10.0, err_off
    assert err_on < 4.0, err_on


def test_no_shifted_start_without_a_tracked_previous_frame(frames) -> None:
    """After a loss the tracker searches as on a first frame: nothing to shift."""
    m, q1, _, depths = frames
    tr = HybridTracker(m, TrackerConfig(), None)
    tr.reset(q1)
    tr.process(depths[0], default_intrinsics())
    tr.delta = False          # as after a frame that failed eq. II.19
    assert tr.process(depths[1], default_intrinsics()).n_candidates == 1


def test_no_shifted_start_for_a_hand_that_holds_still(frames) -> None:
    """A centroid that moved less than ``shift_min_mm`` (the same frame again) adds nothing:
    a finger closing moves it a few millimetres too."""
    m, q1, _, depths = frames
    tr = HybridTracker(m, TrackerConfig(), None)
    tr.reset(q1)
    tr.process(depths[0], default_intrinsics())
    assert tr.process(depths[0], default_intrinsics()).n_candidates == 1
    tr = HybridTracker(m, TrackerConfig(shift_min_mm=0.0), None)
    tr.reset(q1)
    tr.process(depths[0], default_intrinsics())
    assert tr.process(depths[0], default_intrinsics()).n_candidates == 2
