"""Grasp phases (III.6): reaching -> closing -> manipulation (object follows the wrist rigidly)
-> releasing -> reaching, driven by the hand model's keypoints."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.model import JOINT_INDEX, HandModel, rest_pose, root_rotation_matrix
from hand_control.teleop.phases import GraspPhaseDetector, Phase, grip_size

FLEX = [j for j in JOINT_INDEX if j.endswith(("_mcp_flex", "_pip_flex", "_dip_flex"))
        and not j.startswith("thumb")]


def _pose(x: float, close: float) -> np.ndarray:
    q = rest_pose().copy()
    q[JOINT_INDEX["root_tx"]] = x
    for j in FLEX:
        q[JOINT_INDEX[j]] = 1.0 * close
    return q


def _wrist(q: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = root_rotation_matrix(q[3:6])
    T[:3, 3] = q[:3]
    return T


def test_closing_the_hand_shrinks_the_grip() -> None:
    m = HandModel()
    open_kp = m.forward(_pose(0.0, 0.0)).joint_positions
    closed_kp = m.forward(_pose(0.0, 1.0)).joint_positions
    assert grip_size(closed_kp) < grip_size(open_kp) - 0.02


def test_full_cycle_and_rigid_following() -> None:
    m = HandModel()
    det = GraspPhaseDetector()
    kp0 = m.forward(_pose(0.0, 0.0)).joint_positions
    palm = kp0[[0, 5, 9, 13, 17]].mean(axis=0)
    obj = np.eye(4)
    obj[:3, 3] = palm + np.array([0.0, 0.0, 0.0])
    phases, t, dt = [], 0.0, 1 / 30
    # reaching: from 0.5 m away to the object
    for x in np.linspace(0.5, 0.0, 30):
        q = _pose(x, 0.0)
        phases.append(det.update(t, m.forward(q).joint_positions, _wrist(q), obj).phase)
        t += dt
    assert phases[0] == Phase.REACHING and phases[-1] == Phase.CLOSING
    # closing then holding the grip steady
    for c in list(np.linspace(0.0, 0.8, 10)) + [0.8] * 20:
        q = _pose(0.0, c)
        up = det.update(t, m.forward(q).joint_positions, _wrist(q), obj)
        t += dt
    assert up.phase == Phase.MANIPULATION
    # manipulation: the target follows the wrist rigidly
    q = _pose(0.07, 0.8)
    up = det.update(t, m.forward(q).joint_positions, _wrist(q), obj)
    t += dt
    assert up.phase == Phase.MANIPULATION
    np.testing.assert_allclose(up.object_target[:3, 3], obj[:3, 3] + [0.07, 0.0, 0.0],
                               atol=1e-9)
    # opening the grip (and keeping it open for release_time) releases, moving away returns
    # to reaching
    for c in list(np.linspace(0.8, 0.0, 8)) + [0.0] * 8:
        q = _pose(0.07, c)
        up = det.update(t, m.forward(q).joint_positions, _wrist(q), obj)
        t += dt
    assert up.phase == Phase.RELEASING and up.object_target is None
    for x in np.linspace(0.07, 0.5, 10):
        q = _pose(x, 0.0)
        up = det.update(t, m.forward(q).joint_positions, _wrist(q), obj)
        t += dt
    assert up.phase == Phase.REACHING


def test_a_hand_that_never_settles_stays_closing() -> None:
    m = HandModel()
    det = GraspPhaseDetector()
    obj = np.eye(4)
    obj[:3, 3] = m.forward(_pose(0.0, 0.0)).joint_positions[[0, 5, 9, 13, 17]].mean(axis=0)
    for k in range(60):
        q = _pose(0.0, 0.4 + 0.3 * np.sin(k / 3))
        up = det.update(k / 30, m.forward(q).joint_positions, _wrist(q), obj)
    assert up.phase == Phase.CLOSING


def test_bad_input_is_refused() -> None:
    det = GraspPhaseDetector()
    kp = np.full((21, 3), np.nan)
    with pytest.raises(InputError):
        det.update(0.0, kp, np.eye(4), np.eye(4))
    with pytest.raises(InputError):
        det.update(0.0, np.zeros((5, 3)), np.eye(4), np.eye(4))


def test_single_frames_of_an_open_grip_do_not_release() -> None:
    """Tracking jitter: two isolated frames of a fully open hand during manipulation are
    outvoted by the median of the last poses and do not drop the object."""
    m = HandModel()
    det = GraspPhaseDetector()
    obj = np.eye(4)
    obj[:3, 3] = m.forward(_pose(0.0, 0.0)).joint_positions[[0, 5, 9, 13, 17]].mean(axis=0)
    t, dt = 0.0, 1 / 30
    seq = [0.0] * 5 + list(np.linspace(0.0, 0.8, 10)) + [0.8] * 20
    seq += ([0.8] * 4 + [0.0]) * 6  # manipulation with a glitch every fifth frame
    for c in seq:
        q = _pose(0.0, c)
        up = det.update(t, m.forward(q).joint_positions, _wrist(q), obj)
        t += dt
    assert up.phase == Phase.MANIPULATION
