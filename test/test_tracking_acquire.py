"""The wider search on frames without a tracked previous pose (``acquire_modes``,
``acquire_refine_top``, ``acquire_icp_iterations``): the first frame and every frame after a
loss ask the regressor for more palm modes and refine more candidates, each for more
Gauss-Newton iterations; tracked frames keep the product's ``n_modes`` / ``refine_top`` /
``icp_iterations``; the ablation modes are untouched."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tracking_helpers import shipped_or_tiny_regressor, translation_camera

from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.errors import ConfigError
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


@pytest.fixture(scope="module")
def frames(cam):
    return [cam.render(i / 30) for i in range(3)]


class _Modes:
    """A regressor that records how many palm modes each frame asked for (step 1)."""

    def __init__(self, reg: HandRegressor) -> None:
        self.reg = reg
        self.asked: list[int] = []

    def palm_modes(self, frames, lookup, q0, n_modes):
        self.asked.append(n_modes)
        return self.reg.palm_modes(frames, lookup, q0, n_modes)

    def regress_fingers(self, *a, **kw):
        return self.reg.regress_fingers(*a, **kw)

    def lookup(self, *a, **kw):
        return self.reg.lookup(*a, **kw)


def _run(tr: HybridTracker, frames: list) -> list:
    return [tr.process(f.depth, f.depth_intrinsics) for f in frames]


def test_the_first_frame_and_a_frame_after_a_loss_search_wider(regressor, cam, frames):
    cfg = TrackerConfig()
    assert cfg.acquire_modes > cfg.n_modes and cfg.acquire_refine_top > cfg.refine_top
    spy = _Modes(regressor)
    tr = HybridTracker(cam.model, cfg, spy)
    res = _run(tr, frames)
    assert all(r.success for r in res)
    # the first frame: acquire_modes palms and more than refine_top candidates refined;
    # then the previous pose is tracked: the product's numbers
    assert spy.asked == [cfg.acquire_modes, cfg.n_modes, cfg.n_modes]
    assert cfg.refine_top < res[0].n_candidates <= cfg.acquire_refine_top
    assert [r.n_candidates for r in res[1:]] == [cfg.refine_top] * 2
    # a blank frame loses the hand; the next frame searches wider again
    blank = tr.process(np.zeros_like(frames[0].depth), frames[0].depth_intrinsics)
    assert blank.status == "no_hand" and not blank.success
    r = tr.process(frames[2].depth, frames[2].depth_intrinsics)
    assert spy.asked[-1] == cfg.acquire_modes and r.status == "recovering"
    assert r.n_candidates > cfg.refine_top


def test_zero_keeps_the_tracking_numbers_and_the_ablations_are_untouched(regressor, cam,
                                                                         frames):
    spy = _Modes(regressor)
    cfg = TrackerConfig(acquire_modes=0, acquire_refine_top=0)
    res = _run(HybridTracker(cam.model, cfg, spy), frames[:2])
    assert spy.asked == [cfg.n_modes, cfg.n_modes]
    assert [r.n_candidates for r in res] == [cfg.refine_top] * 2
    # regressor-only (Fig. II.18's ablation) never tracks: still n_modes on every frame
    spy = _Modes(regressor)
    _run(HybridTracker(cam.model, dataclasses.replace(TrackerConfig(), mode="regressor"), spy),
         frames[:2])
    assert spy.asked == [TrackerConfig().n_modes] * 2


class _Iterations:
    """Records the Gauss-Newton iterations of every full (not palm-only) refinement."""

    def __init__(self, icp) -> None:
        self.calls: list[tuple[int, int]] = []
        self._refine = icp.refine_batch
        icp.refine_batch = self

    def __call__(self, Q, obs, iterations, *a, palm_only=False, **kw):
        if not palm_only:
            self.calls.append((len(Q), iterations))
        return self._refine(Q, obs, iterations, *a, palm_only=palm_only, **kw)


def test_candidates_of_a_frame_without_a_tracked_pose_get_more_iterations(regressor, cam,
                                                                          frames):
    cfg = TrackerConfig()
    assert cfg.acquire_icp_iterations > cfg.icp_iterations
    tr = HybridTracker(cam.model, cfg, regressor)
    spy = _Iterations(tr.icp)
    r0 = tr.process(frames[0].depth, frames[0].depth_intrinsics)
    # step 4 on the first frame: all its candidates in one batch, acquire_icp_iterations
    assert spy.calls[0] == (r0.n_candidates, cfg.acquire_icp_iterations)
    n = len(spy.calls)
    r1 = tr.process(frames[1].depth, frames[1].depth_intrinsics)
    assert r1.status == "tracking"
    assert spy.calls[n] == (cfg.refine_top, cfg.icp_iterations)
    # 0: the tracking number on every frame
    tr = HybridTracker(cam.model, dataclasses.replace(cfg, acquire_icp_iterations=0),
                       regressor)
    spy = _Iterations(tr.icp)
    tr.process(frames[0].depth, frames[0].depth_intrinsics)
    assert spy.calls[0][1] == cfg.icp_iterations


def test_the_settings_are_range_checked():
    for bad in ({"acquire_modes": 17}, {"acquire_modes": -1}, {"acquire_refine_top": 33},
                {"acquire_icp_iterations": -1}, {"acquire_icp_iterations": 51},
                {"acquire_above_tau": -0.1}, {"acquire_above_tau": 1.5}):
        with pytest.raises(ConfigError):
            TrackerConfig(**bad)


def test_a_doubtful_tracked_frame_searches_as_one_without_a_tracked_pose(regressor, cam,
                                                                         frames):
    """``acquire_above_tau``: while tracking, a frame whose previous E_d was above that
    share of tau asks for acquire_modes palms and refines acquire_refine_top candidates for
    acquire_icp_iterations, the previous pose among them; below it (or 0, off) the tracked
    frame keeps the product's numbers."""
    cfg = dataclasses.replace(TrackerConfig(), acquire_above_tau=0.01)   # every frame doubtful
    spy = _Modes(regressor)
    tr = HybridTracker(cam.model, cfg, spy)
    calls = _Iterations(tr.icp)
    res = []
    for f in frames:   # step 4 of each frame: its first full refinement
        n = len(calls.calls)
        res.append(tr.process(f.depth, f.depth_intrinsics))
        assert calls.calls[n] == (res[-1].n_candidates, cfg.acquire_icp_iterations)
    assert all(r.success for r in res) and res[1].status == "tracking"
    assert spy.asked == [cfg.acquire_modes] * 3
    assert [r.n_candidates for r in res[1:]] == [res[0].n_candidates] * 2
    # a share no fit reaches: the tracking numbers
    spy = _Modes(regressor)
    tr = HybridTracker(cam.model, dataclasses.replace(cfg, acquire_above_tau=1.0), spy)
    res = _run(tr, frames)
    assert res[0].cost < tr.tau_mm
    assert spy.asked == [cfg.acquire_modes, cfg.n_modes, cfg.n_modes]
    assert TrackerConfig().acquire_above_tau > 0.0   # the product's setting: on
