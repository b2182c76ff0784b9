"""The fingers' penetration term of the depth tracker (hand_capture.tracking.overlap)."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.model import (
    BONE_NAMES,
    JOINT_INDEX,
    JOINT_LIMITS,
    N_DOF,
    HandModel,
    HandShape,
)
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.icp import Correspondences, ModelTracker
from hand_capture.tracking.overlap import FingerOverlap, finger_overlap_pairs
from hand_capture.tracking.preprocess import segment_hand


def _pressed() -> np.ndarray:
    """An open hand 0.4 m in front of the camera with the straight index swung into the
    middle finger (abducted towards it, within its limits): their capsules overlap."""
    q = np.zeros(N_DOF)
    q[2] = 0.4
    q[JOINT_INDEX["index_mcp_abd"]] = -0.3
    return q


def _random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo, hi = np.clip(JOINT_LIMITS[:, 0], -3, 3), np.clip(JOINT_LIMITS[:, 1], -3, 3)
    q = rng.uniform(lo, hi, (n, N_DOF))
    q[:, :3] = rng.uniform(-0.1, 0.1, (n, 3)) + [0, 0, 0.4]
    return q


def test_pairs_are_the_four_fingers_only():
    m = HandModel()
    caps = m.capsules
    fingers = {(BONE_NAMES[caps[i].bone].split("_")[0], BONE_NAMES[caps[j].bone].split("_")[0])
               for i, j in m.capsule_pairs[finger_overlap_pairs(m)]}
    names = {a for p in fingers for a in p}
    assert names == {"index", "middle", "ring", "little"}
    assert all(a != b for a, b in fingers)
    assert len(fingers) == 6   # every pair of the four


@pytest.mark.parametrize("shape,side", [(HandShape(global_scale=0.9), "right"),
                                        (HandShape(1.04, (0.3, 0, -0.2, 0, 0, 0.1)), "right"),
                                        (HandShape(global_scale=1.1), "left")])
def test_depth_is_the_models_capsule_penetration(shape, side):
    """The keypoint blend gives the same capsules as the model's own (any shape, side)."""
    m = HandModel(shape, side=side)
    o = FingerOverlap(m)
    Q = _random_poses(200, 1)
    ref = np.maximum(m.self_penetration(Q)[:, finger_overlap_pairs(m)], 0).sum(axis=1) * 1e3
    got = o.depth_mm(m.joint_positions(Q))
    assert np.allclose(got, ref, atol=1e-9)
    assert (got > 0).mean() > 0.05 and (got == 0).mean() > 0.05   # both kinds drawn


def test_zero_for_the_open_hand_positive_for_pressed_fingers():
    m = HandModel()
    o = FingerOverlap(m)
    assert o.depth_mm(m.joint_positions(np.zeros(N_DOF))[None])[0] == 0.0
    assert o.depth_mm(m.joint_positions(_pressed())[None])[0] > 3.0


def test_residual_jacobian_matches_finite_differences():
    m = HandModel()
    o = FingerOverlap(m)
    Q = _random_poses(60, 2)
    Q = Q[o.depth_mm(m.joint_positions(Q)) > 0][:8]
    assert len(Q) == 8
    eps = 1e-6
    for q in Q:
        kp, jac = m.keypoints_and_jacobian(q)
        r, J = o.residuals(kp[None], jac[None])[0]
        assert np.isclose(r.sum(), o.depth_mm(kp[None])[0])
        num = np.array([(o.depth_mm(m.joint_positions(q + eps * e)[None])[0]
                         - o.depth_mm(m.joint_positions(q - eps * e)[None])[0]) / (2 * eps)
                        for e in np.eye(N_DOF)])
        assert np.allclose(J.sum(axis=0), num, rtol=1e-5, atol=1e-4)


def test_gauss_newton_pushes_pressed_fingers_apart():
    """With no data, the term alone separates the fingers; off (weight 0) it does nothing;
    the batch step and normal_equations agree."""
    m = HandModel()
    q = _pressed()
    none = Correspondences(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 3)))
    dofs = np.arange(N_DOF)
    tr = ModelTracker(m, TrackerConfig(overlap_weight=30.0, smooth_weight=0.0))
    before = tr.overlap.depth_mm(m.joint_positions(q)[None])[0]
    x = q.copy()
    for _ in range(3):
        A, g, _ = tr.normal_equations(x, [(none, 1.0)], None, dofs)
        A[np.diag_indices(N_DOF)] += 1e-2 * (1 + A[np.diag_indices(N_DOF)])
        x = x - np.linalg.solve(A, g)
    assert before > 20.0
    assert tr.overlap.depth_mm(m.joint_positions(x)[None])[0] < 0.05 * before
    # the palm does not move for the fingers (the term's Jacobian has no root columns)
    assert np.allclose(x[:6], q[:6])
    off = ModelTracker(m, TrackerConfig(overlap_weight=0.0, smooth_weight=0.0))
    A0, g0, _ = off.normal_equations(q, [(none, 1.0)], None, dofs)
    assert not g0.any()


def test_tracker_step_adds_the_same_term_as_normal_equations():
    """The batched Gauss-Newton step of the tracker (ModelTracker.step) and the public
    normal equations carry the same penetration term."""
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="fist"))
    cam.open()
    f = cam.render(0.0)    # the open hand
    cfg = TrackerConfig(overlap_weight=30.0)
    obs = segment_hand(f.depth, f.depth_intrinsics, cfg)
    tr = ModelTracker(cam.model, cfg)
    pts = obs.subsample(cfg.max_points)
    q = f.pose.copy()
    q[JOINT_INDEX["index_mcp_abd"]] = -0.3
    assert tr.overlap.depth_mm(cam.model.joint_positions(q)[None])[0] > 10.0
    V, facing = tr.posed(q)
    corr = tr.correspond(*pts, V, facing, obs.intrinsics)
    rev = tr.reverse_correspond(pts[0], V, facing, obs)
    dofs = np.arange(N_DOF)
    A, g, _ = tr.normal_equations(q, [(corr, cfg.data_weight), (rev, cfg.reverse_weight)],
                                  f.pose, dofs)
    A[np.diag_indices(N_DOF)] += cfg.damping * (1.0 + A.diagonal())
    dq = -np.linalg.solve(A, g)
    big = np.max(np.abs(dq[3:]))
    if big > cfg.max_step_rad:
        dq *= cfg.max_step_rad / big
    q1, _ = tr.step(q, obs, *pts, f.pose, dofs)
    np.testing.assert_allclose(q1, q + dq, atol=1e-9)
    q0, _ = ModelTracker(cam.model, TrackerConfig()).step(q, obs, *pts, f.pose, dofs)
    assert not np.allclose(q0, q1)


def test_axes_that_cross_are_pushed_back_to_their_own_sides():
    """Two straight fingers in the palm's plane whose axes cross (distance 0, no gradient):
    the residual's row turns the index back towards its own side."""
    m = HandModel()
    o = FingerOverlap(m)
    q = np.zeros(N_DOF)
    q[2] = 0.4
    i_abd, m_abd = JOINT_INDEX["index_mcp_abd"], JOINT_INDEX["middle_mcp_abd"]
    q[i_abd], q[m_abd] = JOINT_LIMITS[i_abd, 0], JOINT_LIMITS[m_abd, 1]
    kp, jac = m.keypoints_and_jacobian(q)
    r, J = o.residuals(kp[None], jac[None])[0]
    k = int(np.argmax(r))
    assert r[k] > 10.0
    # the crossing pair's residual falls when the index swings back (+) and the middle
    # back (-), not further across
    assert J[k, i_abd] < 0.0 < J[k, m_abd]


def test_batch_rows_only_for_penetrating_poses_and_the_same_values():
    """The batched step forms the keypoint Jacobian only for the poses that penetrate: their
    rows equal those of the whole batch's, and the others get none."""
    m = HandModel()
    tr = ModelTracker(m, TrackerConfig())
    Q = _random_poses(40, 3)
    kp_all, jac_all = m.keypoints_and_jacobian(Q)
    hit = tr.overlap.penetrating(kp_all)
    assert np.array_equal(hit, tr.overlap.depth_mm(kp_all) > 0)
    assert 0 < hit.sum() < len(Q)
    full = tr.overlap.residuals(kp_all, jac_all)
    _, _, rot, pos = m.bone_basis(Q)
    rows = tr._overlap_rows(Q, np.arange(N_DOF), rot, pos)
    assert sorted(rows) == np.flatnonzero(hit).tolist()
    for b, (r, J) in rows.items():
        np.testing.assert_array_equal(r, full[b][0])
        np.testing.assert_array_equal(J, full[b][1])
