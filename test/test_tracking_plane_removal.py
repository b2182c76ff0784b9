"""A table or wall behind the hand, dropped from the segment (issue 13: clutter in view).

``preprocess.drop_background_plane`` (``plane_removal``): a plane less than the depth band
behind the hand joins its segment, and through a forearm running into it the whole plane
does; the plane and all behind it go, the hand, a finger in front and the forearm stay."""

from __future__ import annotations

import dataclasses

import numpy as np

from hand_capture.bench._tracking_heldout import suite_forearm_sequence
from hand_capture.cameras.base import Intrinsics
from hand_capture.model import HandModel
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker, default_model_path
from hand_capture.tracking.preprocess import (
    drop_background_plane,
    fit_plane_ransac,
    segment_hand,
)
from hand_capture.tracking.regressor import HandRegressor

INTR = Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0)
OFF = dataclasses.replace(TrackerConfig(), plane_removal=False)


def _scene(table: bool = True) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(240, 320) float depth [m]: a palm-sized disc at 0.40 m, a finger piece 30 mm in
    front of it, a forearm from the disc to the image's bottom edge whose depth runs from
    0.40 m into the table, and optionally the table: a tilted plane 100 mm behind the hand
    filling the image; and the masks of each."""
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    hand = (u - 150) ** 2 + (v - 100) ** 2 <= 45 ** 2
    finger = (u - 140) ** 2 + (v - 90) ** 2 <= 8 ** 2
    arm = (np.abs(u - 150) <= 14) & (v > 100) & ~hand
    plane = 0.50 + 0.0003 * (u - 160) + 0.0002 * (v - 120)
    d = np.zeros((240, 320))
    if table:
        d[:] = plane
    d[hand] = 0.40
    d[finger] = 0.37
    # the forearm reaches the table at the image's bottom edge
    d[arm] = 0.40 + (plane[arm] - 0.40) * (v[arm] - 100) / 139
    masks = {"hand": hand & ~finger, "finger": finger, "arm": arm,
             "table": ~(hand | arm) if table else np.zeros_like(hand)}
    return d.astype(np.float32), masks


def _pixels(mask: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows, columns and depths [m] of the pixels ``mask``."""
    v, u = np.nonzero(mask)
    return v, u, d[v, u].astype(np.float64)


def _kept(obs) -> np.ndarray:
    m = np.zeros(obs.mask.shape, bool)
    m[obs.pixels[:, 1].astype(int), obs.pixels[:, 0].astype(int)] = True
    return m


def test_a_table_the_forearm_runs_into_is_dropped_and_the_hand_kept() -> None:
    d, masks = _scene()
    before = _kept(segment_hand(d, INTR, OFF))
    assert before[masks["table"]].mean() > 0.9       # the band and the arm join the table
    obs = segment_hand(d, INTR, TrackerConfig())
    assert obs.background_plane                      # said on the observation
    kept = _kept(obs)
    assert kept[masks["table"]].mean() < 0.01        # the plane is gone
    assert kept[masks["hand"]].mean() > 0.97
    assert kept[masks["finger"]].mean() > 0.6        # a piece in front stays
    # the forearm stays but for its end within plane_tol_m of the table
    assert kept[masks["arm"]].mean() > 0.8


def test_a_hand_and_forearm_alone_are_left_alone() -> None:
    """No plane of a background's size: the segment is the band's, pixel for pixel (the
    segment is below plane_min_area_m2, the search does not even run)."""
    d, masks = _scene(table=False)
    cfg = TrackerConfig()
    on, off = segment_hand(d, INTR, cfg), segment_hand(d, INTR, OFF)
    assert np.array_equal(on.mask, off.mask)
    assert not on.background_plane
    assert drop_background_plane(d, *_pixels(on.mask, d), INTR, cfg) is None


def test_no_background_without_something_in_front_or_wide_enough() -> None:
    cfg = TrackerConfig()
    v, u = np.mgrid[0:240, 0:320]
    # a wall alone: nothing is in front of the plane
    wall = (0.5 + 0.0003 * (u - 160)).astype(np.float32)
    assert drop_background_plane(wall, *_pixels(np.ones(wall.shape, bool), wall), INTR,
                                 cfg) is None
    # a long planar strip (a forearm's side) larger than plane_min_area_m2 but narrow
    strip = (np.abs(u - 160) <= 15) & (v >= 0)
    d = np.where(strip, 0.6 + 0.0005 * (v - 120), 0.0).astype(np.float32)
    z = d[strip]
    assert float(np.sum(z * z)) / (INTR.fx * INTR.fy) > cfg.plane_min_area_m2
    assert drop_background_plane(d, *_pixels(strip, d), INTR, cfg) is None


def test_ransac_finds_the_plane_among_outliers() -> None:
    rng = np.random.default_rng(3)
    normal = np.array([0.2, -0.3, 1.0])
    normal /= np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    centre = np.array([0.05, -0.02, 0.5])
    st = rng.uniform(-0.2, 0.2, (400, 2))
    on = centre + st[:, :1] * e1 + st[:, 1:] * e2 + rng.normal(0, 0.002, (400, 1)) * normal
    out = rng.uniform([-0.2, -0.2, 0.3], [0.2, 0.2, 0.45], (250, 3))
    c, n = fit_plane_ransac(np.concatenate([on, out]), 0.01, rng)
    assert abs(float(n @ normal)) > np.cos(np.deg2rad(1.0))
    assert abs(float((c - centre) @ normal)) < 0.002


def test_the_benchs_table_scene_is_segmented_to_the_hand_and_arm() -> None:
    """The bench's table validation scene (the suite's generator: hand, forearm, a plane
    behind them): without the removal the segment is mostly table."""
    _, intr, frames, _, labels = suite_forearm_sequence(21, "pinch", 2, 6, table=True)
    for (depth, _), lab in zip(frames, labels, strict=True):
        measured_hand = (lab == 1) & (depth > 0)
        for cfg, table_share in ((OFF, (0.5, 1.0)), (TrackerConfig(), (0.0, 0.05))):
            seg = _kept(segment_hand(depth, intr, cfg))
            share = float(np.mean(lab[seg] == 4))
            assert table_share[0] <= share <= table_share[1]
        assert seg[measured_hand].mean() > 0.9


def test_the_tracker_says_when_it_dropped_a_background_plane() -> None:
    """``TrackResult.background_plane`` (the node's ``background_plane_share``)."""
    _, intr, frames, _, _ = suite_forearm_sequence(21, "pinch", 1, 6, table=True)
    _, _, alone, _, _ = suite_forearm_sequence(21, "pinch", 1, 6)
    tracker = HybridTracker(HandModel(), TrackerConfig(), HandRegressor.load(
        default_model_path()))
    assert tracker.process(*frames[0]).background_plane
    tracker.reset()
    assert not tracker.process(*alone[0]).background_plane
