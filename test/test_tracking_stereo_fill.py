"""Short gaps of a stereo camera's depth filled before segmentation (issue 13: stereo noise).

``preprocess.fill_row_gaps`` (``fill_band_px``, ``fill_hole_px``, on by default): the
occlusion band beside a nearer surface takes the farther side's depth, a short hole between
similar depths is interpolated; longer gaps, gaps at the silhouette and gaps next to empty
background stay empty."""

from __future__ import annotations

import dataclasses

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.preprocess import fill_row_gaps, segment_hand

INTR = Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0)


def test_band_beside_a_step_takes_the_farther_depth() -> None:
    row = np.array([[0.0, 0.40, 0.40, 0, 0, 0, 0.45, 0.45, 0.0]], np.float32)
    out = fill_row_gaps(row.copy(), 4, 0.015)
    np.testing.assert_allclose(out[0, 3:6], 0.45)
    assert out[0, 0] == 0 and out[0, -1] == 0   # next to no measurement: left alone
    # wider than max_px: left alone
    assert np.all(fill_row_gaps(row.copy(), 2, 0.015)[0, 3:6] == 0)
    # without a step it is a hole, not a band: only the hole filler interpolates it
    flat = np.array([[0.40, 0, 0, 0.406]], np.float32)
    assert np.all(fill_row_gaps(flat.copy(), 4, 0.015)[0, 1:3] == 0)
    np.testing.assert_allclose(fill_row_gaps(flat.copy(), 0, 0.015, 2)[0, 1:3], [0.402, 0.404],
                               atol=1e-6)
    assert np.all(fill_row_gaps(flat.copy(), 0, 0.015, 1)[0, 1:3] == 0)


def test_columns_through_a_transposed_view() -> None:
    d = np.zeros((5, 3), np.float32)
    d[0], d[4] = 0.4, 0.4
    fill_row_gaps(d.T, 0, 0.015, 3)
    np.testing.assert_allclose(d, 0.4)


def _scene() -> tuple[np.ndarray, np.ndarray]:
    """(240, 320) depth [m]: a palm (disc, 0.45 m) with a finger bar 40 mm in front of it,
    a 3 px occlusion band on the bar's left over the palm and round holes in the palm; and
    the true hand mask."""
    v, u = np.mgrid[0:240, 0:320]
    palm = (u - 160) ** 2 + (v - 120) ** 2 <= 50 ** 2
    bar = (np.abs(u - 160) <= 5) & (v > 60) & (v < 200)
    d = np.where(palm, 0.45, 0.0)
    d[bar] = 0.41
    truth = d > 0
    band = (u >= 152) & (u < 155) & palm & ~bar
    holes = ((u - 130) ** 2 + (v - 110) ** 2 <= 2) | ((u - 190) ** 2 + (v - 140) ** 2 <= 1)
    d[band | holes] = 0.0
    return d.astype(np.float32), truth


def test_segment_fills_the_band_and_holes() -> None:
    d, truth = _scene()
    off = dataclasses.replace(TrackerConfig(), fill_band_px=0, fill_hole_px=0)
    on = TrackerConfig()   # the product settings: 4 and 3 px
    before = segment_hand(d, INTR, off)
    after = segment_hand(d, INTR, on)
    missing = truth & ~before.mask
    assert missing.sum() > 300
    assert np.all(after.mask[missing])            # band and holes back on the hand
    assert not np.any(after.mask & ~truth)        # nothing added off it
    z = after.depth_m[missing & (np.abs(np.mgrid[0:240, 0:320][1] - 153) <= 1)]
    np.testing.assert_allclose(z, 0.45, atol=1e-6)   # the band took the palm's depth
    # the input image is not modified
    assert np.count_nonzero(d) == np.count_nonzero(_scene()[0])
