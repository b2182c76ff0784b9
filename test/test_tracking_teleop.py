"""The tracker's cheaper settings (regression every n-th frame while tracking succeeds, one
refined candidate) used by the teleop graph: the schedule of the regression, recovery after a
loss, and the teleop parameter files."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tracking_helpers import shipped_or_tiny_regressor, translation_camera

from hand_capture.bench.tracking import teleop_config
from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.config import load_yaml
from hand_capture.errors import ConfigError
from hand_capture.paths import config_dir
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker
from hand_capture.tracking.regressor import HandRegressor

limit_blas_threads(1)


@pytest.fixture(scope="module")
def regressor():
    return shipped_or_tiny_regressor()


@pytest.fixture(scope="module")
def cam():
    return translation_camera()


class _Counting:
    """A regressor that counts its palm regressions (step 1)."""

    def __init__(self, reg: HandRegressor) -> None:
        self.reg = reg
        self.calls = 0

    def palm_modes(self, *a, **kw):
        self.calls += 1
        return self.reg.palm_modes(*a, **kw)

    def regress_fingers(self, *a, **kw):
        return self.reg.regress_fingers(*a, **kw)

    def lookup(self, *a, **kw):
        return self.reg.lookup(*a, **kw)


def _track(tr, cam, times):
    out = []
    for t in times:
        f = cam.render(t)
        out.append(tr.process(f.depth, f.depth_intrinsics))
    return out


def test_regression_every_nth_frame_while_tracking_and_after_a_loss(cam, regressor):
    spy = _Counting(regressor)
    tr = HybridTracker(cam.model, TrackerConfig(regress_every=3, refine_top=1), spy)
    res = _track(tr, cam, [i / 30 for i in range(7)])
    assert all(r.success for r in res)
    # the first frame has no previous pose; then every third frame
    assert [r.regressed for r in res] == [True, False, False, True, False, False, True]
    assert spy.calls == 3
    # frames without regression: the previous pose only, refined; the first frame, with no
    # previous pose, refines acquire_refine_top of its candidates (the wider search)
    assert all(r.n_candidates == 1 for r in res[1:])
    assert res[0].n_candidates > 1
    f = cam.render(0.3)
    blank = tr.process(np.zeros_like(f.depth), f.depth_intrinsics)
    assert blank.status == "no_hand" and not blank.regressed
    # after a loss the regression runs on every frame until tracking succeeds again: the
    # hand moved meanwhile and is found again at once
    res = _track(tr, cam, [1.3, 1.3 + 1 / 30, 1.3 + 2 / 30])
    assert res[0].regressed
    assert res[0].success and res[0].status == "recovering"
    err = np.linalg.norm(cam.model.joint_positions(res[0].pose)
                         - cam.model.joint_positions(cam.render(1.3).pose), axis=1).max()
    assert err < 0.03
    assert [r.regressed for r in res[1:]] == [False, False]
    assert spy.calls == 4


def test_doubtful_frames_trigger_the_regression(cam, regressor):
    # a threshold below any E_d: every frame counts as doubtful
    tr = HybridTracker(cam.model, TrackerConfig(regress_every=100, regress_above_mm=0.5),
                       regressor)
    assert all(r.regressed for r in _track(tr, cam, [0.0, 1 / 30, 2 / 30]))
    tr = HybridTracker(cam.model, TrackerConfig(regress_every=100), regressor)
    assert [r.regressed for r in _track(tr, cam, [0.0, 1 / 30, 2 / 30])] == \
        [True, False, False]


def test_a_deferred_regression_runs_after_the_frame_and_feeds_the_next_one(cam, regressor):
    """defer_regression: a regression due while tracking is not in process() (the pose is
    out first) but in run_deferred() on the same frame; a candidate better than the tracked
    pose joins the next frame's pool. After a loss it runs at once."""
    spy = _Counting(regressor)
    cfg = TrackerConfig(regress_every=3, refine_top=1, defer_regression=True,
                        finger_postures=False, abduction_min_deg=0.0)  # as in teleop.yaml
    tr = HybridTracker(cam.model, cfg, spy)
    flags, deferred = [], []
    for i in range(7):
        f = cam.render(i / 30)
        r = tr.process(f.depth, f.depth_intrinsics)
        flags.append(r.regressed)
        deferred.append(tr.run_deferred() is not None)
        assert r.success
    # the first frame has no previous pose: at once; then every third frame, deferred
    assert flags == [True, False, False, False, False, False, False]
    assert deferred == [False, False, False, True, False, False, True]
    assert spy.calls == 3
    assert tr.run_deferred() is None  # once only
    # a deferred candidate that fits its frame better than the tracked pose: next frame's
    # pool holds it and the previous pose (screened, the better one refined)
    f = cam.render(7 / 30)
    tr.process(f.depth, f.depth_intrinsics)
    tr.process(f.depth, f.depth_intrinsics)
    r = tr.process(f.depth, f.depth_intrinsics)  # a regression is due: deferred
    assert not r.regressed and tr._deferred is not None
    reg, obs, intr, pts, obs_ds, q, c = tr._deferred
    bad = q.copy()
    bad[6:] += 0.4  # as if the tracked fingers had drifted: the regression fits better
    tr._deferred = (reg, obs, intr, pts, obs_ds, bad, tr._costs([bad], obs, obs_ds)[0][0])
    tr.run_deferred()
    assert tr._carry is not None
    sizes = []
    costs = tr._costs
    tr._costs = lambda qs, *a: (sizes.append(len(qs)), costs(qs, *a))[1]
    r = tr.process(f.depth, f.depth_intrinsics)
    # screened 2, refined 1, then the abduction trial's one pose and the exchange trial's
    # six (and its refinement, when one of them is cheaper)
    assert sizes[:4] == [2, 1, 1, 6] and len(sizes) <= 5
    assert tr._carry is None and r.success
    sizes.clear()
    tr.process(f.depth, f.depth_intrinsics)
    # no candidate carried: the previous pose alone, not screened
    assert sizes[:3] == [1, 1, 6] and len(sizes) <= 4
    tr._costs = costs
    # after a loss: at once
    tr.process(np.zeros_like(f.depth), f.depth_intrinsics)
    f = cam.render(1.3)
    r = tr.process(f.depth, f.depth_intrinsics)
    assert r.regressed and tr.run_deferred() is None


def test_product_settings_regress_on_every_frame(cam, regressor):
    cfg = TrackerConfig()
    assert cfg.regress_every == 1 and cfg.regress_above_mm == 0.0
    tr = HybridTracker(cam.model, cfg, regressor)
    res = _track(tr, cam, [0.0, 1 / 30, 2 / 30])
    assert all(r.regressed for r in res)
    # the first frame has no tracked previous pose: the wider search (acquire_refine_top)
    assert res[0].n_candidates > cfg.refine_top
    assert all(r.n_candidates == cfg.refine_top for r in res[1:])


def test_teleop_parameters_are_the_cheaper_hybrid_settings():
    cfg = teleop_config()
    assert cfg.mode == "hybrid"
    assert cfg.regress_every > 1 and cfg.refine_top == 1
    # the teleop file sets only known tracker parameters, each as the graph applies it
    own = load_yaml(config_dir() / "teleop.yaml")["tracker"]["ros__parameters"]
    names = {f.name for f in dataclasses.fields(TrackerConfig)}
    node_only = {"debug_image_every", "markers_every", "subject_id", "shape_folder",
                 "calibrate_on_start", "calibration_frames", "poll_period_s", "blas_threads",
                 "realtime_priority"}
    assert set(own) <= names | node_only
    for k, v in own.items():
        if k in names:
            assert getattr(cfg, k) == v
    # the product's file keeps the dissertation's scheme
    prod = load_yaml(config_dir() / "tracker.yaml")["tracker"]["ros__parameters"]
    assert prod["regress_every"] == 1 and prod["refine_top"] == 2


def test_regression_schedule_parameters_are_validated():
    with pytest.raises(ConfigError):
        TrackerConfig(regress_every=0)
    with pytest.raises(ConfigError):
        TrackerConfig(regress_above_mm=-1.0)
