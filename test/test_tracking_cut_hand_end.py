"""While tracking, the forearm cut's wrist follows the segment's fingertip end
(``cut_hand_end_mm``, issue 13): at the previous wrist the cut lags a hand moving towards
its fingers and keeps that much more forearm, whose points hold the fit back."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.bench._tracking_heldout import SurfaceVariant
from hand_capture.cameras.render import make_renderer
from hand_capture.model import HandModel
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker
from hand_capture.tracking.train import default_intrinsics, forearm_mesh, random_pose

#: how far the hand moves towards its fingers between the two frames [m]
STEP_M = 0.008


@pytest.fixture(scope="module")
def moving_arm() -> tuple[HandModel, list[np.ndarray], list[np.ndarray]]:
    """The suite's hand with a forearm: two exact renders [mm], the second moved
    ``STEP_M`` along the hand's axis (wrist towards the fingers), and their poses."""
    m = HandModel()
    q0 = random_pose(np.random.default_rng(3), m)
    kp = m.joint_positions(q0)
    q1 = q0.copy()
    q1[0:3] += STEP_M * (kp[9] - kp[0]) / np.linalg.norm(kp[9] - kp[0])
    r, hand = make_renderer("zbuffer"), SurfaceVariant().mesh_fn(m)
    depths = [np.rint(r.render([hand(q), forearm_mesh(m, q, 0.03, 0.3)],
                               default_intrinsics()).depth * 1000).astype(np.uint16)
              for q in (q0, q1)]
    return m, [q0, q1], depths


def _arm_kept_mm(moving_arm, **cfg) -> float:
    """The moved frame tracked on from the first one's true pose with the cut alone (no arm
    classifier, no regressor): how far its segment reaches past the true wrist along the
    forearm (the 99.5th percentile) [mm]."""
    m, poses, depths = moving_arm
    tr = HybridTracker(m, TrackerConfig(arm_classifier=False, **cfg), None)
    tr.reset(poses[0])
    res = tr.process(depths[1], default_intrinsics())
    assert res.success
    kp = m.joint_positions(poses[1])
    d = (kp[0] - kp[9]) / np.linalg.norm(kp[0] - kp[9])         # middle MCP -> wrist
    return float(np.percentile((res.observation.points - kp[0]) @ d, 99.5)) * 1e3


def test_the_forearm_cut_follows_the_hand_end(moving_arm) -> None:
    margin_mm = TrackerConfig().forearm_margin_m * 1e3
    lagging = _arm_kept_mm(moving_arm, cut_hand_end_mm=0.0)
    following = _arm_kept_mm(moving_arm)
    # at the previous wrist the cut keeps about a frame's motion more forearm
    assert lagging > margin_mm + 0.6 * STEP_M * 1e3, lagging
    assert abs(following - margin_mm) < 0.3 * STEP_M * 1e3, following
    # a hand end farther than the limit (clutter at the fingertips, say) moves nothing
    assert _arm_kept_mm(moving_arm, cut_hand_end_mm=0.5 * STEP_M * 1e3) == lagging
