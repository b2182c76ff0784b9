"""Depth hand tracking core (ch. II.3.6-II.5): segmentation, Gauss-Newton ICP, Jacobian,
success flag, recovery with a small forest trained here, calibration, storage."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.synthetic import SyntheticCamera, SyntheticCameraConfig
from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.errors import ConfigError, InputError
from hand_capture.model import N_DOF, HandModel, HandShape
from hand_capture.tracking.calibration import (
    calibrate,
    load_shape,
    render_calibration_frames,
    save_shape,
)
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.forest import RegressionForest
from hand_capture.tracking.hybrid import HybridTracker
from hand_capture.tracking.icp import Correspondences, ModelTracker, cost_grid
from hand_capture.tracking.preprocess import segment_hand
from hand_capture.tracking.regressor import HandRegressor
from hand_capture.tracking.train import default_intrinsics, train_tracker

limit_blas_threads(1)


@pytest.fixture(scope="module")
def cam():
    c = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="finger_counting"))
    c.open()
    return c


def _kp_err(model, q, q_true):
    return float(np.linalg.norm(model.joint_positions(q) - model.joint_positions(q_true),
                                axis=1).mean() * 1e3)


def test_segmentation_keeps_the_hand_and_drops_a_far_wall(cam):
    f = cam.render(2.0)
    depth = f.depth.copy()
    wall = depth == 0
    depth[wall] = 900  # a wall 0.9 m away behind the hand
    depth[5:25, 5:25] = 650  # a small object between, not touching the hand
    obs = segment_hand(depth, f.depth_intrinsics, TrackerConfig())
    sil = f.silhouette
    inter = np.count_nonzero(obs.mask & sil)
    union = np.count_nonzero(obs.mask | sil)
    assert inter / union > 0.9
    assert not obs.mask[wall].any()
    assert not obs.mask[5:25, 5:25].any()
    # points are the back-projected hand pixels, in the optical frame near the true hand
    assert len(obs.points) == np.count_nonzero(obs.mask)
    assert abs(np.median(obs.points[:, 2]) - f.pose[2]) < 0.06


def test_segmentation_of_an_empty_or_malformed_image():
    intr = default_intrinsics()
    obs = segment_hand(np.zeros((240, 320), np.uint16), intr)
    assert not obs.found
    with pytest.raises(InputError):
        segment_hand(np.zeros((10, 10), np.uint16), intr)
    with pytest.raises(InputError):
        segment_hand(np.zeros((240, 320, 3), np.uint8), intr)


def test_gauss_newton_converges_from_a_perturbed_pose(cam):
    f = cam.render(1.2, noise=False)
    cfg = TrackerConfig()
    obs = segment_hand(f.depth, f.depth_intrinsics, cfg)
    tr = ModelTracker(cam.model, cfg)
    before, after = [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        q = f.pose.copy()
        q[0:3] += rng.normal(0, 0.008, 3)
        q[3:6] += rng.normal(0, 0.08, 3)
        q[6:] += rng.normal(0, 0.12, N_DOF - 6)
        q1 = tr.refine(q, obs, 8, q_ref=q)
        before.append(_kp_err(cam.model, q, f.pose))
        after.append(_kp_err(cam.model, q1, f.pose))
        assert after[-1] < 0.6 * before[-1]
        assert tr.depth_cost(q1, obs) < tr.depth_cost(q, obs)
    assert min(before) > 8.0
    assert np.median(after) < 8.0


def test_data_term_gradient_matches_finite_differences(cam):
    """g = J^T r of the normal equations is half the gradient of E (fixed pairs; the
    least-squares data term of eq. II.23, without the Huber reweighting)."""
    f = cam.render(1.0, noise=False)
    cfg = TrackerConfig(smooth_weight=0.2, limit_weight=1000.0, robust_mm=0.0)
    tr = ModelTracker(cam.model, cfg)
    rng = np.random.default_rng(0)
    q = f.pose + rng.normal(0, 0.05, N_DOF) * np.r_[0.1, 0.1, 0.1, np.ones(N_DOF - 3)]
    q[7] = 1.2  # beyond its limit: the joint-limit term is active
    vid = np.arange(0, cam.model.n_vertices, 40)
    P = cam.model.vertices(f.pose)[vid] + 0.002

    def energy(qq, dofs):
        c = Correspondences(P, vid, cam.model.vertices(qq)[vid])
        return tr.normal_equations(qq, c, f.pose, dofs)

    for dofs in (np.arange(N_DOF), np.arange(6)):
        A, g, E = energy(q, dofs)
        num = np.zeros(len(dofs))
        for k, d in enumerate(dofs):
            h = 1e-6
            qp, qm = q.copy(), q.copy()
            qp[d] += h
            qm[d] -= h
            num[k] = (energy(qp, dofs)[2] - energy(qm, dofs)[2]) / (2 * h)
        np.testing.assert_allclose(2 * g, num, rtol=2e-4, atol=1e-3 * np.abs(num).max())
        assert np.all(np.linalg.eigvalsh(A) > -1e-6)


def test_success_flag_fails_on_a_blank_frame(cam):
    f = cam.render(0.5)
    tr = HybridTracker(cam.model, TrackerConfig(mode="icp"))
    tr.reset(f.pose)
    r = tr.process(f.depth, f.depth_intrinsics)
    assert r.success and r.status == "tracking"
    assert r.cost < tr.cfg.success_tau_mm
    blank = tr.process(np.zeros_like(f.depth), f.depth_intrinsics)
    assert not blank.success and blank.status == "no_hand"
    assert blank.cost >= tr.cfg.success_tau_mm
    np.testing.assert_allclose(blank.last_good, r.pose)
    # a wrong pose (hand 8 cm off) fails the test of eq. II.19 too
    q = f.pose.copy()
    q[0] += 0.08
    assert tr.icp.depth_cost(q, r.observation) > tr.cfg.success_tau_mm


@pytest.fixture(scope="module")
def small_regressor():
    return train_tracker(None, seed=1, n_samples=160, n_shapes=4, palm_stages=2,
                         finger_stages=1, n_trees=3, max_depth=8, n_features=120)


def test_forest_fits_a_simple_function_and_keeps_two_modes():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(600, 6)).astype(np.float32)
    Y = np.c_[np.sign(X[:, 0]), X[:, 1] > 0.5]
    f = RegressionForest.fit(X, Y, n_trees=4, max_depth=6, min_leaf=4, leaf_modes=2, rng=0)
    pred = f.predict(X)
    assert np.mean(np.abs(pred - Y)) < 0.15
    # a feature the forest never sees separated: the two-valued target gives two modes
    g = RegressionForest.fit(X[:, 2:], Y[:, :1], n_trees=3, max_depth=1, min_leaf=200,
                             leaf_modes=2, rng=0)
    centres, w = g.predict_modes(X[0, 2:], 2)
    assert len(centres) == 2 and sorted(np.round(centres[:, 0]).tolist()) == [-1.0, 1.0]
    np.testing.assert_allclose(w.sum(), 1.0)


def test_regressor_round_trip(small_regressor, tmp_path):
    p = tmp_path / "reg.npz"
    small_regressor.save(p)
    r2 = HandRegressor.load(p)
    assert r2.palm_stages == 2 and r2.finger_stages == 1
    np.testing.assert_array_equal(r2.palm_forests[1].threshold,
                                  small_regressor.palm_forests[1].threshold)
    with pytest.raises(InputError):
        HandRegressor.load(tmp_path / "missing.npz")


def test_hybrid_recovers_after_a_blank_gap(small_regressor):
    cam = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="translation"))
    cam.open()
    tr = HybridTracker(cam.model, TrackerConfig(), small_regressor)
    flags = []
    for t in [0.0, 0.1, 0.2, 0.3]:  # tracking starts by itself (no initial pose)
        f = cam.render(t)
        flags.append(tr.process(f.depth, f.depth_intrinsics).success)
    assert any(flags)
    blank = np.zeros_like(f.depth)
    for _ in range(5):
        r = tr.process(blank, f.depth_intrinsics)
        assert not r.success
    ok_at = None
    for k, t in enumerate([1.3, 1.35, 1.4, 1.45, 1.5]):  # the hand moved 8 cm meanwhile
        f = cam.render(t)
        r = tr.process(f.depth, f.depth_intrinsics)
        err = np.linalg.norm(cam.model.joint_positions(r.pose)
                             - cam.model.joint_positions(f.pose), axis=1).max() * 1e3
        if r.success and err < 30.0:
            ok_at = k
            break
    assert ok_at is not None and ok_at < 5
    assert r.status in ("recovering", "tracking")


def _calibration_frames(model):
    return render_calibration_frames(model, default_intrinsics())


def test_calibration_recovers_the_scale_of_a_smaller_hand():
    base = HandModel()
    truth = base.with_shape(HandShape(0.92))
    res = calibrate(_calibration_frames(truth), model=base, subject_id="small")

    def length(m):
        kp = m.joint_positions(np.zeros(N_DOF))
        return np.linalg.norm(kp[12] - kp[0])

    fitted = base.with_shape(res.shape)
    assert abs(length(fitted) / length(base) - 0.92) < 0.03
    # s_g alone trades off against the bone scales alpha; the hand's size is what counts
    assert abs(res.shape.global_scale - 0.92) < 0.07
    assert res.residual_mm < 5.0
    assert res.shape.subject_id == "small"


def test_shape_save_load_round_trip(tmp_path):
    s = HandShape(1.05, (0.5, -0.2, 0.1, 0, 0, 0), (0.001, 0, 0, 0, -0.001), "ann")
    p = save_shape(s, tmp_path, "ann", residual_mm=2.5)
    assert p.name == "ann.yaml"
    s2 = load_shape(tmp_path, "ann")
    np.testing.assert_allclose(s2.params, s.params)
    with pytest.raises(ConfigError):
        load_shape(tmp_path, "nobody")
    with pytest.raises(ConfigError):
        save_shape(s, tmp_path, "../evil")


def test_config_rejects_bad_values():
    with pytest.raises(ConfigError):
        TrackerConfig(near_m=1.0, far_m=0.5)
    with pytest.raises(ConfigError):
        TrackerConfig(mode="pso")
    with pytest.raises(ConfigError):
        TrackerConfig(data_weight=-1.0)


def test_training_is_reproducible_from_its_seed(tmp_path):
    kw = dict(n_samples=40, n_shapes=2, palm_stages=1, finger_stages=1, n_trees=2,
              max_depth=5, n_features=40)
    train_tracker(tmp_path / "a.npz", seed=5, **kw)
    train_tracker(tmp_path / "b.npz", seed=5, **kw)
    a, b = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    assert set(a.files) == set(b.files)
    for k in a.files:
        if k != "info_values":  # holds the training time
            np.testing.assert_array_equal(a[k], b[k])


def test_e_d_of_a_near_hand_counts_no_holes_between_splatted_vertices():
    """E_d (eq. II.19) of a hand 0.23 m from a 640x480 70 deg camera, where a pixel covers
    0.5 mm of it, at its true pose: about what the usual camera gives, not the holes of the
    rendered silhouette at the fixed step 2 (``cost_footprint_mm`` 0); the usual camera's
    step is unchanged (icp.cost_grid)."""
    e_d, grid = {}, {}
    for name, kw in (("usual", {}), ("near", {"width": 640, "height": 480, "hfov_deg": 70.0,
                                             "camera_position": (0.0, 0.0, 0.15)})):
        c = SyntheticCamera(SyntheticCameraConfig(render_color=False, clip="fist", **kw))
        c.open()
        f = c.render(0.7)
        for fp in (TrackerConfig().cost_footprint_mm, 0.0):
            cfg = TrackerConfig(cost_footprint_mm=fp)
            obs = segment_hand(f.depth, f.depth_intrinsics, cfg)
            tr = ModelTracker(c.model, cfg)
            e_d[name, fp] = tr.depth_cost(f.pose, obs)
            grid[name, fp] = cost_grid(obs, cfg)
            if grid[name, fp] != cfg.cost_downsample:   # another grid's image: refused
                with pytest.raises(InputError, match="E_d grid"):
                    tr.depth_cost(f.pose, obs, obs.depth_m[::2, ::2])
    fp = TrackerConfig().cost_footprint_mm
    assert grid["usual", fp] == grid["usual", 0.0] == TrackerConfig().cost_downsample
    assert e_d["usual", fp] == e_d["usual", 0.0]
    assert grid["near", fp] > TrackerConfig().cost_downsample
    assert e_d["near", fp] < 1.2 * e_d["usual", fp]
    assert e_d["near", 0.0] > 1.5 * e_d["usual", fp]
