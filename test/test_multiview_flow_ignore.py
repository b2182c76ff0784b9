"""Seed 002 sec. 5.1's noise protocol: the structural-noise circles' pixel masks returned by the
sequence renderer, and optical flow features that touch them left out by the local optimiser
(only when a mask is passed: a real camera has none)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from hand_capture.multiview.correspondences import flow_correspondences, window_clear
from hand_capture.multiview.lo import LocalOptimizer, LOConfig
from hand_capture.multiview.rig import Rig, load_rig
from hand_capture.multiview.sequences import (
    _structural_noise,
    make_sequence,
    render_sequence,
)
from hand_capture.multiview.tracker import MultiviewTracker

#: main's ``_structural_noise`` (8757b78, before the masks) on the input of the test below:
#: the SHA-256 of its image and the generator's next ``integers(0, 2**30)`` after it
_OLD_DIGEST = "efddd611565554b09d83423fa0cc958f20ee76d5c7d0a8b2f94441a103fd166f"
_OLD_NEXT_DRAW = 295610589


def _centres(seed: int, n: int, w: int, h: int) -> np.ndarray:
    """(n, 2) circle centres (col, row) that ``_structural_noise`` draws from ``seed``."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        out.append((int(rng.integers(0, w)), int(rng.integers(0, h))))
        rng.integers(10, 31)
        if i % 2 == 0:
            rng.integers(0, 256, 3)
    return np.array(out)


def test_circle_masks_cover_the_circles_and_leave_the_image_and_draws_unchanged():
    h, w, n = 120, 160, 6
    img = np.random.default_rng(0).integers(0, 256, (h, w, 3)).astype(np.uint8)
    rng = np.random.default_rng(11)
    noisy, mask = _structural_noise(img, rng, n)
    assert hashlib.sha256(noisy.tobytes()).hexdigest() == _OLD_DIGEST
    # the same draws: what is drawn after the circles (detections, the next view) is too
    assert rng.integers(0, 1 << 30) == _OLD_NEXT_DRAW
    assert mask.shape == (h, w) and mask.dtype == bool
    assert not np.any(noisy[~mask] != img[~mask])       # every changed pixel is masked
    c = _centres(11, n, w, h)
    assert mask[c[:, 1], c[:, 0]].all()                   # each circle's centre
    rr, cc = np.mgrid[0:h, 0:w]
    far = np.min(np.hypot(rr[..., None] - c[:, 1], cc[..., None] - c[:, 0]), axis=2) > 32
    assert far.any() and not mask[far].any()              # beyond the largest radius


def test_scaled_circles_keep_the_draws_and_shrink_the_discs():
    """``radius_scale`` (seed 002's image share at another resolution) draws the same
    circles, smaller: same centres, same next draw, a third of the radius."""
    h, w, n = 120, 160, 6
    img = np.random.default_rng(0).integers(0, 256, (h, w, 3)).astype(np.uint8)
    r1, r3 = np.random.default_rng(11), np.random.default_rng(11)
    _, m1 = _structural_noise(img, r1, n)
    _, m3 = _structural_noise(img, r3, n, 1.0 / 3.0)
    assert r1.integers(0, 1 << 30) == r3.integers(0, 1 << 30) == _OLD_NEXT_DRAW
    c = _centres(11, n, w, h)
    assert m3[c[:, 1], c[:, 0]].all() and not (m3 & ~m1).any()
    rr, cc = np.mgrid[0:h, 0:w]
    far = np.min(np.hypot(rr[..., None] - c[:, 1], cc[..., None] - c[:, 0]), axis=2) > 12
    assert far.any() and not m3[far].any()               # beyond a third of 30 px (+ AA)
    assert m3.sum() < 0.25 * m1.sum()


def test_rendered_frames_carry_masks_of_exactly_what_the_circles_changed():
    """Held-out surface without colour noise: a view's pixels do not depend on the random
    draws, so with circles the image equals the circle-free one wherever the mask is off."""
    full = load_rig("studio6")
    rig = Rig(full.name, full.cameras[:2], full.world_frame)
    seq = make_sequence("box", 2)
    kw = {"surface": "heldout", "noise": False, "seed": 4}
    noisy = list(render_sequence(seq, rig, circles=20, **kw))
    clean = list(render_sequence(seq, rig, circles=0, **kw))
    for fn, fc in zip(noisy, clean, strict=True):
        assert fc.noise_masks == {}
        assert set(fn.noise_masks) == {c.name for c in rig.cameras}
        for cam in rig.cameras:
            m = fn.noise_masks[cam.name]
            a, b = fn.images[cam.name], fc.images[cam.name]
            assert m.shape == a.shape[:2] and 0.05 < m.mean() < 0.6
            assert np.array_equal(a[~m], b[~m])
            assert np.any(a[m] != b[m])
    assert not np.array_equal(noisy[0].noise_masks[rig.cameras[0].name],
                              noisy[1].noise_masks[rig.cameras[0].name])   # drawn anew


def _textured_pair(shift=(2.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random texture (120, 160) uint8 and the same texture moved by ``shift``
    (du, dv) [px]."""
    import cv2

    rng = np.random.default_rng(3)
    big = cv2.GaussianBlur(rng.uniform(0, 255, (160, 200)).astype(np.float32), (0, 0), 2.0)
    big = cv2.normalize(big, None, 0, 255, cv2.NORM_MINMAX)
    a = big[20:140, 20:180]
    M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    b = cv2.warpAffine(big, M, (200, 160), flags=cv2.INTER_LINEAR)[20:140, 20:180]
    return a.astype(np.uint8), b.astype(np.uint8)


def _disc(shape: tuple[int, int], centre: tuple[float, float], r: float) -> np.ndarray:
    rr, cc = np.mgrid[0:shape[0], 0:shape[1]]
    return np.hypot(cc - centre[0], rr - centre[1]) <= r


def test_flow_features_in_a_masked_window_are_dropped_the_others_kept():
    a, b = _textured_pair()
    uv = np.array([[45.0, 50.0], [115.0, 70.0]])
    sel, tgt = flow_correspondences(a, b, uv)
    assert list(sel) == [0, 1]                              # both tracked without a mask
    np.testing.assert_allclose(tgt, uv + (2.0, 1.0), atol=0.3)
    start = _disc(a.shape, (45.0, 50.0), 4.0)               # a circle at the first start
    sel, tgt = flow_correspondences(a, b, uv, ignore_prev=start)
    assert list(sel) == [1]
    np.testing.assert_allclose(tgt, uv[1:] + (2.0, 1.0), atol=0.3)
    end = _disc(a.shape, (117.0 + 9.0, 71.0), 4.0)          # 5 px from the second's end
    assert list(flow_correspondences(a, b, uv, ignore=end)[0]) == [0]
    assert list(flow_correspondences(a, b, uv, ignore=end, margin_px=3)[0]) == [0, 1]
    none = np.zeros(a.shape, bool)
    assert list(flow_correspondences(a, b, uv, ignore_prev=none, ignore=none)[0]) == [0, 1]


def test_window_clear_tests_the_square_window_and_ignores_pixels_off_the_image():
    m = np.zeros((20, 30), bool)
    m[10, 15] = True
    uv = np.array([[15.0, 10.0], [22.0, 3.0], [23.0, 10.0], [-5.0, -5.0]])
    np.testing.assert_array_equal(window_clear(m, uv, 7), [False, False, True, True])
    np.testing.assert_array_equal(window_clear(None, uv, 7), [True] * 4)


@pytest.fixture(scope="module")
def box_frames():
    full = load_rig("studio6")
    rig = Rig(full.name, full.cameras[:3], full.world_frame)
    seq = make_sequence("box", 2)
    frames = list(render_sequence(seq, rig, surface="own", noise=False, circles=0,
                                  salient_miss=0.0, salient_fp=0.0, seed=3))
    return rig, seq, frames


def test_the_optimiser_and_tracker_leave_out_flow_from_masked_pixels(box_frames):
    """A mask over every pixel (this frame's or the previous one's) leaves no flow; the
    tracker keeps the previous group's masks for the next group's flow; no mask: flow."""
    rig, seq, frames = box_frames
    model = seq.model()
    lo = LocalOptimizer(model, rig, LOConfig())
    prev = (frames[0].images, model.pose(seq.truth(model, 0)))
    full = {c.name: np.ones((c.intrinsics.height, c.intrinsics.width), bool)
            for c in rig.cameras}
    assert len(lo.prepare(frames[1].images, prev=prev).flow) > 50
    assert len(lo.prepare(frames[1].images, prev=prev, flow_ignore=full).flow) == 0
    assert len(lo.prepare(frames[1].images, prev=prev, prev_flow_ignore=full).flow) == 0
    counts = []
    for first in (full, None):
        tr = MultiviewTracker(model, rig, LOConfig(iterations=1, use_salient=False))
        tr.reset(seq.truth(model, 0))
        tr.step(frames[0].images, None, first)
        counts.append(tr.step(frames[1].images).lo.counts["flow"])
    assert counts[0] == 0 and counts[1] > 0
