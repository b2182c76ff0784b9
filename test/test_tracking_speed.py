"""The tracker's fast paths give the results of the plain formulations they replace:
subset skinning and FK sharing (model), batched Gauss-Newton steps and costs (ICP), the
grouped finger forests and batched feature evaluation (regression), vectorised k-means, the
depth lookup cropped to the hand."""

from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np
import pytest

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.model import JOINT_LIMITS, N_DOF, HandModel, HandShape
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.forest import ForestGroup, RegressionForest, weighted_kmeans
from hand_capture.tracking.icp import ModelTracker, depth_error, render_depth
from hand_capture.tracking.preprocess import fill_gaps, segment_hand
from hand_capture.tracking.regressor import (
    BACKGROUND_REL_M,
    FINGER_KP,
    DepthLookup,
    HandRegressor,
    ModelFrames,
    palm_init_pca,
)
from hand_capture.tracking.train import train_tracker

limit_blas_threads(1)


@pytest.fixture(scope="module")
def scene():
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="fist"))
    cam.open()
    f = cam.render(0.7)
    cfg = TrackerConfig()
    obs = segment_hand(f.depth, f.depth_intrinsics, cfg)
    return cam.model, f, cfg, obs


def _poses(n, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(JOINT_LIMITS[:, 0], -3.0), np.minimum(JOINT_LIMITS[:, 1], 3.0)
    q = rng.uniform(lo, hi, (n, N_DOF))
    q[:, 0:3] = rng.normal(0, 0.05, (n, 3)) + [0, 0, 0.4]
    q[:, 3:6] = rng.normal(0, 0.6, (n, 3))
    return q


def test_bone_basis_matches_vertices_jacobian_and_keypoints():
    m = HandModel().with_shape(HandShape(1.04, (0.3, 0, -0.2, 0, 0, 0.1)))
    Q = _poses(3)
    idx = np.arange(5, m.n_vertices, 37)
    T, H, rot, pos = m.bone_basis(Q, jacobian=True)
    rows = m.skinning_rows(idx)
    for b in range(3):
        np.testing.assert_allclose(rows @ T[b], m.vertices(Q[b], idx), atol=1e-12)
        jac = (rows @ H[b]).reshape(len(idx), 3, N_DOF)
        np.testing.assert_allclose(jac, m.jacobian(Q[b], idx), atol=1e-12)
        np.testing.assert_allclose(m.keypoint_rows() @ T[b], m.joint_positions(Q[b]),
                                   atol=1e-12)
        fk = m.forward(Q[b])
        np.testing.assert_allclose(rot[b], fk.joint_frames[:, :3, :3], atol=0)
        np.testing.assert_allclose(pos[b], fk.joint_frames[:, :3, 3], atol=0)
    kp, kj = m.keypoints_and_jacobian(Q)
    np.testing.assert_array_equal(kp, m.joint_positions(Q))
    kp1, kj1 = m.keypoints_and_jacobian(Q, fk=(rot, pos))   # bone_basis' FK pass reused
    np.testing.assert_array_equal(kp1, kp)
    np.testing.assert_array_equal(kj1, kj)
    kp1, kj1 = m.keypoints_and_jacobian(Q[1], fk=(rot[1], pos[1]))
    np.testing.assert_array_equal(kj1, kj[1])
    np.testing.assert_allclose(kj, m.keypoint_jacobian(Q), atol=1e-12)
    rows, dofs = np.array([3, 8, 20]), np.array([1, 4, 9, 26])
    kp2, kj2 = m.keypoints_and_jacobian(Q, rows, dofs)
    np.testing.assert_array_equal(kp2, kp[:, rows])
    np.testing.assert_allclose(kj2, kj[:, rows][..., dofs], atol=1e-15)


def _kmeans_reference(x, w, k, iters=8):
    """The loop formulation of weighted k-means the vectorised one replaces."""
    k = min(k, len(x))
    centres = [x[int(np.argmax(w))]]
    for _ in range(1, k):
        d = np.min(np.stack([np.sum((x - c) ** 2, axis=1) for c in centres]), axis=0)
        if d.max() <= 1e-18:
            break
        centres.append(x[int(np.argmax(d * w))])
    c = np.array(centres)
    for _ in range(iters):
        a = np.argmin(np.sum((x[:, None, :] - c[None]) ** 2, axis=2), axis=1)
        for j in range(len(c)):
            m = a == j
            if m.any():
                c[j] = np.average(x[m], axis=0, weights=w[m] + 1e-12)
    a = np.argmin(np.sum((x[:, None, :] - c[None]) ** 2, axis=2), axis=1)
    weights = np.bincount(a, weights=w, minlength=len(c))
    keep = weights > 0
    return c[keep], weights[keep]


def test_weighted_kmeans_matches_the_loop_formulation():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = int(rng.integers(1, 30))
        x = np.r_[rng.normal(0, 1, (n, 4)), rng.normal(3, 1, (n, 4))]
        w = rng.random(len(x))
        for k in (1, 2, 3):
            c, cw = weighted_kmeans(x, w, k)
            c0, cw0 = _kmeans_reference(x, w, k)
            np.testing.assert_allclose(c, c0, atol=1e-12)
            np.testing.assert_allclose(cw, cw0, atol=1e-12)


def test_forest_group_predicts_like_its_forests():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(300, 5, 12)).astype(np.float32)
    forests = [RegressionForest.fit(X[:, g], np.c_[X[:, g, :3] * (g + 1), X[:, g, 4] > 0],
                                    n_trees=3, max_depth=4 + g, min_leaf=4, rng=g)
               for g in range(5)]
    group = ForestGroup(forests)
    got = group.predict(X[:7])
    for g, f in enumerate(forests):
        np.testing.assert_array_equal(got[:, g], f.predict(X[:7, g]))


def test_batched_steps_and_costs_match_single_ones(scene):
    model, f, cfg, obs = scene
    tr = ModelTracker(model, cfg)
    pts = obs.subsample(cfg.max_points)
    rng = np.random.default_rng(2)
    Q = np.array([f.pose + rng.normal(0, 0.02, N_DOF) for _ in range(3)])
    refs = [f.pose, None, Q[2]]
    for palm in (True, False):
        batch = tr.refine_batch(Q, obs, 2, q_refs=refs, palm_only=palm, points=pts)
        for b in range(3):
            one = tr.refine(Q[b], obs, 2, q_ref=refs[b], palm_only=palm, points=pts)
            np.testing.assert_allclose(batch[b], one, atol=1e-9)
    # the fast step equals the public building blocks on the whole mesh
    q = Q[0]
    V, facing = tr.posed(q)
    corr = tr.correspond(*pts, V, facing, obs.intrinsics)
    rev = tr.reverse_correspond(pts[0], V, facing, obs)
    A, g, _ = tr.normal_equations(q, [(corr, cfg.data_weight), (rev, cfg.reverse_weight)],
                                  f.pose, np.arange(N_DOF))
    A[np.diag_indices(N_DOF)] += cfg.damping * (1.0 + A.diagonal())
    dq = -np.linalg.solve(A, g)
    big = np.max(np.abs(dq[3:]))
    if big > cfg.max_step_rad:
        dq *= cfg.max_step_rad / big
    q1, c1 = tr.step(q, obs, *pts, f.pose, np.arange(N_DOF))
    np.testing.assert_array_equal(np.sort(c1.vertex), np.sort(corr.vertex))
    np.testing.assert_allclose(q1, q + dq, atol=1e-9)
    # windowed rendering: the same E_d as the whole image
    ds = cfg.cost_downsample
    o = obs.depth_m[::ds, ::ds]
    costs = tr.depth_costs(Q, obs, o)
    for b in range(3):
        r = render_depth(model.vertices(Q[b]), obs.intrinsics, ds)
        assert costs[b] == depth_error(r[:o.shape[0], :o.shape[1]], o, cfg.depth_cap_mm)
        assert tr.depth_cost(Q[b], obs) == costs[b]
    far = f.pose.copy()
    far[2] = -1.0  # behind the camera: nothing rendered
    assert tr.depth_cost(far, obs) == cfg.depth_cap_mm


def _plain_render(V, intr, ds):
    """Reference for render_depth: every vertex in front of the camera splatted into its
    nearest pixel of the whole 1/ds image, nearest depth kept, one-pixel holes closed."""
    H, W = (intr.height + ds - 1) // ds, (intr.width + ds - 1) // ds
    img = np.full((H, W), np.inf, np.float32)
    for x, y, z in V:
        if not z > 1e-3:
            continue
        u = np.rint((intr.fx * x / z + intr.cx) / ds)
        w = np.rint((intr.fy * y / z + intr.cy) / ds)
        if 0 <= u < W and 0 <= w < H:
            img[int(w), int(u)] = min(img[int(w), int(u)], np.float32(z))
    occ = np.isfinite(img).astype(np.uint8)
    k = np.ones((3, 3), np.uint8)
    holes = (cv2.morphologyEx(occ, cv2.MORPH_CLOSE, k) > 0) & (occ == 0)
    img[~np.isfinite(img)] = 1e3
    img[holes] = cv2.erode(img, k)[holes]
    img[img >= 1e3] = 0.0
    return img


def test_batched_rendering_matches_a_plain_z_buffer(scene):
    """depth_costs renders all poses' vertices together: poses leaving the image, straddling
    the camera plane and with vertices that are not finite give what a plain per-vertex
    z-buffer gives, one pose at a time, without warnings."""
    model, f, cfg, obs = scene
    tr = ModelTracker(model, cfg)
    ds = cfg.cost_downsample
    o = obs.depth_m[::ds, ::ds]
    Q = np.repeat(f.pose[None], 6, axis=0)
    Q[1, 0] += 0.12                      # half out of the image
    Q[2, 2] = 0.01                       # the hand straddles the camera plane
    Q[3, 0:3] += (0.01, -0.005, 0.02)
    Q[4, 1] += 0.09                      # out at the bottom: the poses' images are stacked
    Q[5, 1] -= 0.12                      # (row-wise) for the closing, and out at the top
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        costs = tr.depth_costs(Q, obs, o)
        for b in range(len(Q)):
            ref = _plain_render(model.vertices(Q[b]), obs.intrinsics, ds)
            assert costs[b] == depth_error(ref, o, cfg.depth_cap_mm)
            assert tr.depth_cost(Q[b], obs) == costs[b]
        # points no model pose gives: on the camera plane, behind it, closer than 1 mm,
        # not finite; dropped, not drawn (a point 2 mm away in the middle is drawn)
        odd = [[0, 0, 0], [0.01, 0, 0], [0, 0, -0.1], [1e-5, 0, 5e-4], [np.nan, 0, 0.4],
               [0, 0, np.nan], [np.inf, 0, 0.4], [0, 0, 2e-3]]
        V = np.r_[model.vertices(Q[0]), odd]
        got = render_depth(V, obs.intrinsics, ds)
        np.testing.assert_array_equal(got, _plain_render(V, obs.intrinsics, ds))
        assert np.count_nonzero(got == np.float32(2e-3)) == 1
    assert 0 < costs[0] < costs[1] < cfg.depth_cap_mm
    for b, row in ((4, -1), (5, 0)):   # drawn up to the image's last / first row
        assert render_depth(model.vertices(Q[b]), obs.intrinsics, ds)[row].any()


def test_stacked_splat_closes_each_image_alone():
    """E_d's renders of a batch are stacked into one image for the closing (icp._splat):
    each comes out as OpenCV's closing and hole fill of that image alone gives it, pixels
    on every edge included (small random silhouettes, so most touch an edge)."""
    from hand_capture.tracking.icp import _splat

    rng = np.random.default_rng(3)
    k = np.ones((3, 3), np.uint8)
    for density in (0.2, 0.4, 0.6):
        B, h, w = 5, 7, 9
        n = int(density * h * w)
        b = np.repeat(np.arange(B), n)
        pix = np.concatenate([rng.choice(h * w, n, replace=False) for _ in range(B)])
        z = rng.uniform(0.2, 0.6, B * n).astype(np.float32)
        got = _splat(b * (h + 1) * w + pix, z, (B, h + 1, w))
        for i in range(B):
            ref = np.full(h * w, 1e3, np.float32)
            np.minimum.at(ref, pix[b == i], z[b == i])
            ref = ref.reshape(h, w)
            occ = (ref < 1e3).astype(np.uint8)
            holes = (cv2.morphologyEx(occ, cv2.MORPH_CLOSE, k) > 0) & (occ == 0)
            ref[holes] = cv2.erode(ref, k)[holes]
            ref[ref >= 1e3] = 0.0
            np.testing.assert_array_equal(got[i, :h], ref)
            assert not got[i, h].any()


@pytest.fixture(scope="module")
def tiny_regressor():
    return train_tracker(None, seed=5, n_samples=40, n_shapes=2, palm_stages=2,
                         finger_stages=2, n_trees=2, max_depth=5, n_features=40)


def test_regression_fast_path_matches_the_plain_one(scene, tiny_regressor):
    model, f, cfg, obs = scene
    reg = tiny_regressor
    frames = ModelFrames(model)
    lookup = DepthLookup(obs.depth_m, 0, 0, obs.intrinsics)
    q0 = palm_init_pca(obs.points, frames)
    # palm cascade, plain: all vertices skinned, features evaluated on them
    q = q0.copy()
    for s in range(reg.palm_stages - 1):
        x = HandRegressor.palm_features_at(reg.palm_features[s], frames, q, lookup)
        q = HandRegressor.palm_update(frames, q, reg.palm_forests[s].predict(x[None])[0])
    x = HandRegressor.palm_features_at(reg.palm_features[-1], frames, q, lookup)
    centres, _ = reg.palm_forests[-1].predict_modes(x, 2)
    plain = [HandRegressor.palm_update(frames, q, c) for c in centres]
    fast = reg.palm_modes(frames, lookup, q0, 2)
    np.testing.assert_allclose(np.array(fast), np.array(plain), atol=1e-9)
    # finger cascade, plain: forest by forest, FK per call
    Q = np.array(plain)
    Q[:, 6:] = 0.0
    for feats, forests in zip(reg.finger_features, reg.finger_forests, strict=True):
        fk = model.forward(Q)
        Rf = np.stack([HandRegressor.finger_frames(frames, qq) for qq in Q])
        targets = np.empty((len(Q), 5, 3, 3))
        for fi in range(5):
            xf = feats[fi].evaluate_batch(fk.vertices, Rf[:, fi], lookup)
            d = forests[fi].predict(xf).reshape(len(Q), 3, 3)
            targets[:, fi] = fk.joint_positions[:, FINGER_KP[fi]] + np.einsum(
                "bkj,bij->bki", d, Rf[:, fi])
        for _ in range(reg.ik_iterations):
            rows = FINGER_KP.reshape(-1)
            kp = model.joint_positions(Q)[:, rows]
            J = model.keypoint_jacobian(Q)[:, rows][..., 6:].reshape(len(Q), 45, 21)
            r = (kp - targets.reshape(len(Q), 15, 3)).reshape(len(Q), 45)
            A = np.einsum("bki,bkj->bij", J, J) + 1e-4 * np.eye(21)[None]
            dq = -np.linalg.solve(A, np.einsum("bki,bk->bi", J, r)[..., None])[..., 0]
            Q[:, 6:] = np.clip(Q[:, 6:] + dq, JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1])
    got = reg.regress_fingers(frames, lookup, np.array(plain))
    np.testing.assert_allclose(got, Q, atol=1e-9)


def test_segmentation_window_and_off_hand_test(scene):
    model, f, cfg, obs = scene
    # the hand is one 8-connected component of the band, back-projected pixel by pixel
    assert obs.mask.sum() == len(obs.points)
    np.testing.assert_array_equal(obs.mask[obs.pixels[:, 1].astype(int),
                                           obs.pixels[:, 0].astype(int)], True)
    rng = np.random.default_rng(4)
    v = rng.integers(0, obs.mask.shape[0], 4000)
    u = rng.integers(0, obs.mask.shape[1], 4000)
    for margin in (0.0, 2.0, 5.5):
        np.testing.assert_array_equal(obs.off_hand(v, u, margin),
                                      obs.outside_distance[v, u] > margin)


@pytest.mark.parametrize("weights, which", [((1.0, 0.0), "all"), ((0.7, 0.7), "all"),
                                            ((1.0, 0.5), "fingers")])
def test_fast_step_matches_the_normal_equations_for_other_weights_and_dofs(scene, weights,
                                                                           which):
    model, f, cfg0, obs = scene
    cfg = dataclasses.replace(cfg0, data_weight=weights[0], reverse_weight=weights[1])
    tr = ModelTracker(model, cfg)
    pts = obs.subsample(cfg.max_points)
    rng = np.random.default_rng(5)
    q = f.pose + rng.normal(0, 0.03, N_DOF) * np.r_[0.2, 0.2, 0.2, np.ones(N_DOF - 3)]
    dofs = np.arange(N_DOF) if which == "all" else np.arange(6, N_DOF)
    V, facing = tr.posed(q)
    sets = [(tr.correspond(*pts, V, facing, obs.intrinsics), cfg.data_weight)]
    if cfg.reverse_weight > 0:
        sets.append((tr.reverse_correspond(pts[0], V, facing, obs), cfg.reverse_weight))
    A, g, _ = tr.normal_equations(q, sets, f.pose, dofs)
    A[np.diag_indices(len(dofs))] += cfg.damping * (1.0 + A.diagonal())
    dq = -np.linalg.solve(A, g)
    big = np.max(np.abs(dq[dofs >= 3]))
    if big > cfg.max_step_rad:
        dq *= cfg.max_step_rad / big
    want = q.copy()
    want[dofs] += dq
    q1, _ = tr.step(q, obs, *pts, f.pose, dofs)
    np.testing.assert_allclose(q1, want, atol=1e-9)


def test_hand_box_and_the_cropped_depth_lookup(scene):
    model, f, cfg, obs = scene
    # the segment's depth is the image's after the stereo gaps are filled (fill_gaps)
    d = fill_gaps(f.depth.astype(np.float32) * np.float32(0.001), cfg)
    np.testing.assert_array_equal(obs.depth_m, np.where(obs.mask, d, 0.0))
    r0, r1, c0, c1 = obs.box
    rows, cols = np.flatnonzero(obs.mask.any(axis=1)), np.flatnonzero(obs.mask.any(axis=0))
    assert (r0, r1, c0, c1) == (rows[0], rows[-1] + 1, cols[0], cols[-1] + 1)
    # the regressor's lookup in the box reads what it reads in the whole image, on and off
    # the hand and off the image
    full = DepthLookup(obs.depth_m, 0, 0, obs.intrinsics)
    crop = DepthLookup(obs.depth_m[r0:r1, c0:c1], c0, r0, obs.intrinsics)
    rng = np.random.default_rng(6)
    P = obs.points[rng.integers(0, len(obs.points), 3000)] + rng.normal(0, 0.04, (3000, 3))
    P[:50, 0] += 1.0
    P[50:100, 1] -= 1.0
    np.testing.assert_array_equal(crop(P.reshape(30, 100, 3)), full(P.reshape(30, 100, 3)))
    assert (full(P) < 1.0).any() and (full(P) == 2.0).any()
    # relative background (the shipped model's): a point off the hand reads its own depth
    # + BACKGROUND_REL_M, on the hand the same depth as before; so a hand and its points
    # moved 0.3 m farther give every feature (a difference of two reads) the same value
    rel = DepthLookup(obs.depth_m, 0, 0, obs.intrinsics, relative=True)
    rcrop = DepthLookup(obs.depth_m[r0:r1, c0:c1], c0, r0, obs.intrinsics, relative=True)
    got = rel(P)
    np.testing.assert_array_equal(rcrop(P), got)
    off = full(P) == 2.0
    np.testing.assert_allclose(got[off], P[off, 2] + BACKGROUND_REL_M, rtol=1e-6)
    np.testing.assert_array_equal(got[~off], full(P)[~off])
    scale = (P[:, 2] + 0.3) / P[:, 2]               # the same pixels, 0.3 m farther
    far_pts = P * scale[:, None]
    far = DepthLookup(np.where(obs.depth_m > 0, obs.depth_m + np.float32(0.3), 0.0)
                      .astype(np.float32), 0, 0, obs.intrinsics, relative=True)
    pairs = rng.integers(0, len(P), (500, 2))
    np.testing.assert_allclose(far(far_pts)[pairs[:, 0]] - far(far_pts)[pairs[:, 1]],
                               got[pairs[:, 0]] - got[pairs[:, 1]], atol=1e-5)


def test_lazy_back_projection_gives_the_same_points(scene):
    model, f, cfg, obs = scene
    a = segment_hand(f.depth, f.depth_intrinsics, cfg)
    sub_a = a.subsample(100)                  # the subsample only is back-projected
    b = segment_hand(f.depth, f.depth_intrinsics, cfg)
    pts, pix = b.points, b.pixels             # the whole cloud first
    sub_b = b.subsample(100)
    for x, y in zip(sub_a, sub_b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.n_points == len(pts) == len(pix) and a.found
    np.testing.assert_array_equal(a.points, pts)
    # the wrist cut keeps the points near the centroid, mask and box follow
    cut = segment_hand(f.depth, f.depth_intrinsics, dataclasses.replace(cfg, wrist_cut_m=0.06))
    assert 0 < cut.n_points < len(pts)
    assert np.linalg.norm(cut.points - pts.mean(axis=0), axis=1).max() <= 0.06 + 1e-9
    assert cut.mask.sum() == cut.n_points
    np.testing.assert_array_equal(cut.mask[cut.pixels[:, 1].astype(int),
                                           cut.pixels[:, 0].astype(int)], True)
    r0, r1, c0, c1 = cut.box
    assert cut.mask[r0:r1, c0:c1].sum() == cut.n_points
