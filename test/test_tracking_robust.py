"""Tracker robustness (issue 13): forearm cut, robust data term, tau following the
calibration, calibration that refuses untrusted frames and recovers bone lengths.

Data from the suite's own renderer and model only (a forearm cylinder added at the wrist,
as the training generator may widen it); the held-out evaluation family is elsewhere."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hand_capture.cameras.motion import R_PALM_TO_CAMERA
from hand_capture.cameras.primitives import cylinder
from hand_capture.cameras.render import Mesh, make_renderer
from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.model import N_DOF, HandModel, HandShape
from hand_capture.model.joints import root_angles_from_matrix
from hand_capture.model.skeleton import LEVELS
from hand_capture.tracking.calibration import (
    CALIBRATION_POSES,
    CalibrationResult,
    calibrate,
    render_calibration_frames,
    tangent_projector,
)
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker
from hand_capture.tracking.icp import huber_sqrt_weights
from hand_capture.tracking.preprocess import cut_forearm, segment_hand
from hand_capture.tracking.train import default_intrinsics

limit_blas_threads(1)


def _rot_z_to(d: np.ndarray) -> np.ndarray:
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, d)
    s, c = np.linalg.norm(v), float(z @ d)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K * ((1 - c) / s ** 2)


class _WithForearm:
    """A hand model with a forearm cylinder (radius 27 mm, 26 cm) from its wrist."""

    def __init__(self, model: HandModel) -> None:
        self.m = model
        self.cyl = cylinder(0.027, 0.26, 24)
        self.faces = np.vstack([model.faces, self.cyl[1] + model.rest_vertices.shape[0]])

    def arm(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        kp = self.m.joint_positions(q)
        d = kp[0] - kp[9]
        return kp[0], d / np.linalg.norm(d)

    def vertices(self, q: np.ndarray) -> np.ndarray:
        w, d = self.arm(q)
        C = self.cyl[0] @ _rot_z_to(d).T + w + d * (0.13 - 0.012)
        return np.vstack([self.m.vertices(q), C])


def _pose(fingers: str = "flat") -> np.ndarray:
    q = CALIBRATION_POSES[fingers].copy()
    q[3:6] = root_angles_from_matrix(R_PALM_TO_CAMERA)
    q[0:3] = (0.0, -0.02, 0.42)
    return q


def _render(model, q: np.ndarray) -> np.ndarray:
    res = make_renderer("zbuffer").render([Mesh(model.vertices(q), model.faces, 1,
                                                closed=True)], default_intrinsics())
    return np.rint(res.depth * 1000).astype(np.uint16)


def _beyond(points: np.ndarray, arm: tuple[np.ndarray, np.ndarray], dist: float) -> int:
    return int(np.count_nonzero((points - arm[0]) @ arm[1] > dist))


@pytest.mark.parametrize("fingers", ["flat", "bent"])
def test_forearm_cut_removes_the_forearm_and_keeps_the_hand(fingers):
    hand = HandModel()
    fa = _WithForearm(hand)
    q = _pose(fingers)
    intr = default_intrinsics()
    cfg = TrackerConfig()
    obs = segment_hand(_render(fa, q), intr, cfg)
    arm = fa.arm(q)
    assert _beyond(obs.points, arm, 0.06) > 500        # the forearm is in the segment
    n_hand = obs.n_points - _beyond(obs.points, arm, 0.0)   # the hand side of the wrist
    for prior in (None, arm):  # from the cloud alone, and from a tracked wrist
        cut, did = cut_forearm(obs, cfg, 1.0, prior)
        assert did
        assert _beyond(cut.points, arm, 0.06) < 0.05 * _beyond(obs.points, arm, 0.06)
        assert cut.n_points - _beyond(cut.points, arm, 0.0) > 0.97 * n_hand
        # the observation stays consistent: mask, depth and points agree
        assert cut.mask.sum() == cut.n_points == np.count_nonzero(cut.depth_m)


@pytest.mark.parametrize(("radius", "length"), [(0.027, 0.26), (0.036, 0.2)])
def test_the_cloud_cut_finds_the_palm_through_holes(radius, length):
    # a stereo camera leaves holes on the palm (4 px squares here, longer than the fill
    # closes): they must not shrink the palm's inscribed circle below the forearm's, or the
    # cut from the cloud's shape takes the palm for the arm and keeps the arm
    fa = _WithForearm(HandModel())
    fa.cyl = cylinder(radius, length, 24)
    fa.faces = np.vstack([fa.m.faces, fa.cyl[1] + fa.m.rest_vertices.shape[0]])
    q = _pose("flat")
    intr = default_intrinsics()
    depth = _render(fa, q)
    kp = fa.m.joint_positions(q)
    c = (kp[0] + kp[9]) / 2   # the palm's centre
    u0, v0 = int(intr.fx * c[0] / c[2] + intr.cx), int(intr.fy * c[1] / c[2] + intr.cy)
    for dv in range(-24, 25, 8):
        for du in range(-24, 25, 8):
            depth[v0 + dv: v0 + dv + 4, u0 + du: u0 + du + 4] = 0
    cfg = TrackerConfig()
    obs = segment_hand(depth, intr, cfg)
    arm = fa.arm(q)
    n_hand = obs.n_points - _beyond(obs.points, arm, 0.0)
    cut, did = cut_forearm(obs, cfg, 1.0)
    assert did
    assert _beyond(cut.points, arm, 0.06) < 0.05 * _beyond(obs.points, arm, 0.06)
    assert cut.n_points - _beyond(cut.points, arm, 0.0) > 0.95 * n_hand


def test_a_flipped_cloud_cut_keeps_the_other_end():
    # the second guess of the cloud cut (flip_retry): the arm's end kept, the hand cut off
    fa = _WithForearm(HandModel())
    q = _pose("flat")
    cfg = TrackerConfig()
    obs = segment_hand(_render(fa, q), default_intrinsics(), cfg)
    arm = fa.arm(q)
    n_arm = _beyond(obs.points, arm, 0.06)
    cut, did = cut_forearm(obs, cfg, 1.0, None, flip=True)
    assert did
    assert _beyond(cut.points, arm, 0.06) > 0.9 * n_arm
    assert cut.n_points - _beyond(cut.points, arm, 0.0) < 0.3 * (
        obs.n_points - _beyond(obs.points, arm, 0.0))


def test_forearm_cut_leaves_a_hand_alone_untouched():
    cfg = TrackerConfig()
    for fingers in ("flat", "bent"):
        obs = segment_hand(_render(HandModel(), _pose(fingers)), default_intrinsics(), cfg)
        out, did = cut_forearm(obs, cfg, 1.0)
        assert not did and out is obs


def test_tracking_with_a_forearm_in_view_stays_on_the_hand():
    hand = HandModel()
    fa = _WithForearm(hand)
    q = _pose("flat")
    depth = _render(fa, q)
    errs = {}
    for cut in (False, True):
        tr = HybridTracker(hand, TrackerConfig(mode="icp", forearm_cut=cut))
        tr.reset(q)
        for _ in range(3):
            r = tr.process(depth, default_intrinsics())
        errs[cut] = float(np.linalg.norm(hand.joint_positions(r.pose)
                                         - hand.joint_positions(q), axis=1).mean() * 1e3)
        assert r.forearm_cut == cut
    assert errs[True] < 5.0
    assert errs[True] < errs[False]


def test_huber_weights_bound_the_pull_of_far_pairs():
    r = np.array([[3.0, 0.0, 4.0], [0.0, 30.0, 40.0]]).reshape(-1)   # 5 mm and 50 mm
    w = huber_sqrt_weights(r, 8.0) ** 2
    assert np.allclose(w[:3], 1.0)
    assert np.allclose(w[3:], 8.0 / 50.0)
    # the weighted residual of a far pair grows no faster than k (a bounded force)
    assert np.linalg.norm(w[3:] * r[3:]) == pytest.approx(8.0)


def _result(ok: bool, e_d: float) -> CalibrationResult:
    return CalibrationResult(HandShape(1.05), [], 2.0, 1, ok, "ok" if ok else "refused: x",
                             e_d)


def test_success_threshold_follows_the_calibrated_fit():
    cfg = TrackerConfig(success_tau_mm=25.0, tau_fit_ratio=1.6, tau_max_mm=40.0)
    tr = HybridTracker(HandModel(), cfg)
    assert tr.tau_mm == 25.0                      # uncalibrated: eq. II.19's fixed tau
    tr.set_calibration(_result(True, 20.0))      # a surface the model fits less well
    assert tr.tau_mm == pytest.approx(32.0)
    assert tr.model.shape.global_scale == pytest.approx(1.05)
    tr.set_calibration(_result(True, 40.0))
    assert tr.tau_mm == 40.0                      # capped
    tr2 = HybridTracker(HandModel(), cfg)
    tr2.set_calibration(_result(False, 20.0))    # refused: nothing changes
    assert tr2.tau_mm == 25.0 and tr2.model.shape.global_scale == 1.0
    # the threshold is the one the frame's success flag used
    r = tr.process(np.zeros((240, 320), np.uint16), default_intrinsics())
    assert r.tau_mm == 40.0


def test_calibration_refuses_an_occluded_hand():
    base = HandModel()
    frames = render_calibration_frames(base.with_shape(HandShape(1.05)), default_intrinsics())
    ok = calibrate(frames, model=base)
    assert ok.ok and ok.status == "ok"
    # half of the hand hidden in one frame (an object in front of it, out of the band)
    bad = [(d.copy(), i) for d, i in frames]
    d = bad[1][0]
    rows = np.flatnonzero(d.any(axis=1))
    d[rows[0]:(rows[0] + rows[-1]) // 2] = 0
    res = calibrate(bad, model=base)
    assert not res.ok and res.status.startswith("refused")
    assert res.shape == base.shape                 # the starting shape, unchanged
    # too few points: refused with the reason named
    res = calibrate(frames, model=base, min_points=100000)
    assert not res.ok and "hand points" in res.status


@pytest.mark.parametrize("scale", [0.88, 1.12])
def test_calibration_recovers_bone_lengths_of_a_scaled_hand(scale):
    base = HandModel()
    truth = base.with_shape(HandShape(scale))

    def bones(m):
        kp = m.joint_positions(np.zeros(N_DOF))
        pairs = [(0, 9)] + [(a, a + 1) for f in range(5) for a in range(1 + 4 * f, 4 + 4 * f)]
        return np.array([np.linalg.norm(kp[a] - kp[b]) for a, b in pairs])

    res = calibrate(render_calibration_frames(truth, default_intrinsics()), model=base)
    assert res.ok
    err = np.abs(bones(base.with_shape(res.shape)) / bones(truth) - 1.0)
    assert err.mean() < 0.05


def test_calibration_recovers_long_and_short_fingers():
    """Hands whose fingers are 9 % longer / shorter than the template's at the template's
    palm (the first bone-scale component at +-2.2 population SDs), clean depth. Before the
    weaker alpha prior and the normal-weighted pairs the long fingers came out 6.3 % short
    and the short-fingered hand was fitted as a smaller hand (s_g 0.94); now 3.5 % and
    0.97."""
    base = HandModel()
    fingers = LEVELS[:, 1:].ravel()
    for alpha0 in (2.2, -2.2):
        truth = base.with_shape(HandShape(1.0, (alpha0, 0, 0, 0, 0, 0)))
        res = calibrate(render_calibration_frames(truth, default_intrinsics()), model=base)
        assert res.ok
        fit = base.with_shape(res.shape).bone_lengths[fingers]
        true = truth.bone_lengths[fingers]
        assert abs(fit.sum() / true.sum() - 1.0) < 0.045
        assert abs(res.shape.global_scale - 1.0) < 0.03


def test_tangent_projector_keeps_the_normal_and_scales_the_tangent():
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    P = tangent_projector(n, 0.2)
    np.testing.assert_allclose(P[0] @ n[0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(P[0] @ [2.0, -1.0, 0.5], [0.4, -0.2, 0.5], atol=1e-12)
    t = np.array([-0.8, 0.6, 0.0])                       # tangent of the second normal
    np.testing.assert_allclose(P[1] @ (n[1] + t), n[1] + 0.2 * t, atol=1e-12)
    np.testing.assert_allclose(tangent_projector(n, 1.0), np.broadcast_to(np.eye(3), P.shape))


def test_calibration_with_a_forearm_does_not_inflate_the_hand():
    base = HandModel()
    truth = _WithForearm(base)
    frames = render_calibration_frames(truth, default_intrinsics())
    res = calibrate(frames, model=base)
    assert res.ok
    # the old calibration inflated the hand by 40-60 % with a forearm in view
    assert abs(res.shape.global_scale - 1.0) < 0.06


@pytest.mark.parametrize("scale", [0.88, 1.12])
def test_calibration_does_not_slide_down_a_forearm(scale):
    """Cut at the fitted wrists with the tracker's 36 mm margin, the fit slid down the
    forearm and grew (clean depth: s_g 0.966 for 0.88, 1.194 for 1.12; bone error 5.3 /
    3.5 %); cut 25 mm before the wrist with the model beyond the cut optional it stays
    (0.881 / 1.095, 0.6 / 1.4 %)."""
    base = HandModel()
    truth = base.with_shape(HandShape(scale))
    res = calibrate(render_calibration_frames(_WithForearm(truth), default_intrinsics()),
                    model=base)
    assert res.ok
    assert abs(res.shape.global_scale / scale - 1.0) < 0.03
    fit, true = base.with_shape(res.shape).bone_lengths, truth.bone_lengths
    assert np.mean(np.abs(fit / true - 1.0)) < 0.025


def test_forearm_config_is_validated():
    with pytest.raises(Exception, match="forearm_margin_m"):
        dataclasses.replace(TrackerConfig(), forearm_margin_m=-1.0)


def test_training_samples_with_forearms_are_cut_like_live_frames():
    from hand_capture.tracking.train import render_samples

    rng = np.random.default_rng(3)
    m = HandModel()
    samples = render_samples(6, rng, [m], default_intrinsics(), forearm_prob=1.0,
                             surface_mm=(-1.0, 2.5))
    assert len(samples) == 6
    for s in samples:
        kp = m.joint_positions(s.pose)
        d = (kp[0] - kp[9]) / np.linalg.norm(kp[0] - kp[9])
        # the forearm (up to 0.5 m long) is cut near the wrist in every training crop
        assert np.percentile((s.points - kp[0]) @ d, 99) < 0.12


def test_an_arm_reaching_towards_the_camera_does_not_hide_the_hand():
    """The arm enters the image nearer than the hand (beyond the depth band behind its
    nearest pixel): the segment grows along the continuous surface to the hand, and the
    forearm cut then takes the arm off."""
    hand = HandModel()
    q = _pose("flat")
    q[0:3] = (0.0, -0.03, 0.55)
    kp = hand.joint_positions(q)
    tip = np.array([0.02, 0.45, 0.2])          # off the image, 0.2 m from the camera
    axis = tip - kp[0]
    length = float(np.linalg.norm(axis))
    d = axis / length
    V, F = cylinder(0.03, length, 20)
    arm = Mesh(V @ _rot_z_to(d).T + kp[0] + d * (0.5 * length - 0.015), F, 2, closed=True)
    res = make_renderer("zbuffer").render([Mesh(hand.vertices(q), hand.faces, 1, closed=True),
                                           arm], default_intrinsics())
    depth = np.rint(res.depth * 1000).astype(np.uint16)
    intr = default_intrinsics()
    visible = res.label == 1                   # hand pixels not hidden by the arm
    n_hand = int(np.count_nonzero(visible))
    assert np.percentile(res.depth[res.label == 2], 1) < np.median(res.depth[visible]) - 0.16
    for grow, expect in ((0.0, False), (0.4, True)):
        cfg = TrackerConfig(grow_m=grow)
        obs = segment_hand(depth, intr, cfg)
        assert (np.count_nonzero(obs.mask & visible) > 0.9 * n_hand) == expect
    cut, did = cut_forearm(obs, cfg, 1.0)
    assert did
    assert np.count_nonzero(cut.mask & visible) > 0.9 * n_hand
    assert np.count_nonzero(cut.mask & ~visible) < 0.2 * cut.n_points


def test_a_hand_farther_than_the_training_renders_is_regressed_as_well() -> None:
    # the shipped regressor's features read a point off the hand relative to the point's
    # own depth, so a hand 0.2 m farther than the training renders' (a D435-like camera,
    # 640x480, 87 deg; about the same pixels per millimetre) is regressed about as well;
    # with a constant background (format of earlier models) the first frames were ~1.7x
    # worse there
    from hand_capture.bench._tracking_heldout import FAR_CAMERA, suite_forearm_sequence
    from hand_capture.tracking.hybrid import default_model_path
    from hand_capture.tracking.regressor import HandRegressor

    limit_blas_threads(1)
    reg = HandRegressor.load(default_model_path())
    assert reg.info.get("background") == "relative"
    mean = {}
    for name, cam in (("near", None), ("far", FAR_CAMERA)):
        errs = []
        for seed, clip in ((21, "finger_counting"), (21, "pinch"), (22, "finger_counting"),
                           (22, "pinch")):
            true, _, frames, kps, _ = suite_forearm_sequence(seed, clip, 4, 12, camera=cam)
            tracker = HybridTracker(true, TrackerConfig(), reg)   # the true shape
            for (depth, intr), kp in zip(frames, kps, strict=True):
                tracker.reset()   # every frame a first frame: the regression finds the hand
                r = tracker.process(depth, intr)
                errs.append(np.linalg.norm(tracker.model.joint_positions(r.pose) - kp,
                                           axis=1).mean())
        mean[name] = float(np.mean(errs))
    assert mean["near"] < 0.012
    assert mean["far"] < 1.35 * mean["near"]
