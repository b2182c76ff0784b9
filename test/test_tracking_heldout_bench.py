"""Pieces of the held-out sections of ``hand-suite bench tracking`` (issue 13). That the
sections run and report figures in their ranges is checked on the bench's own smoke run
(``test_bench_smoke.py``, ``_check_tracking``)."""

from __future__ import annotations

import math

import numpy as np

from hand_capture.bench._tracking_heldout import (
    segment_quality,
    suite_forearm_sequence,
)


def test_segment_quality_counts_arm_and_hand_pixels() -> None:
    label = np.zeros((4, 6), np.int16)
    label[:, :3] = 1          # 12 hand pixels
    label[:, 3:5] = 2         # 8 forearm pixels
    label[0, 5] = 3           # a sleeve pixel
    depth = np.full((4, 6), 500, np.uint16)
    depth[3, 0] = 0           # a hand pixel without depth: not counted as hand
    # the segment: 5 hand pixels, 3 forearm, 1 sleeve, 1 background
    px = np.array([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [3, 0], [4, 1], [3, 2], [5, 0],
                   [5, 3]])
    arm, kept = segment_quality(px, label, depth)
    assert arm == 40.0                       # 4 of 10
    assert math.isclose(kept, 100.0 * 5 / 11)
    assert segment_quality(np.zeros((0, 2)), label, depth) == (0.0, 0.0)
    assert segment_quality(px, np.full((4, 6), 2, np.int16), depth)[1] == 100.0


def test_suite_forearm_sequence_shows_the_arm_and_labels_it() -> None:
    model, intr, frames, kps, labels = suite_forearm_sequence(21, "pinch", 2, 4)
    assert len(frames) == len(kps) == len(labels) == 2
    for (depth, fi), kp, lab in zip(frames, kps, labels, strict=True):
        assert fi is intr and depth.shape == lab.shape == (intr.height, intr.width)
        assert kp.shape == (21, 3)
        arm, hand = lab == 2, lab == 1
        assert arm.sum() > 200 and hand.sum() > 200     # both in view
        assert np.mean(depth[arm] > 0) > 0.8            # and measured
    # reproducible: the validation set is the same in every run
    again = suite_forearm_sequence(21, "pinch", 2, 4)
    assert np.array_equal(again[2][1][0], frames[1][0])


def test_the_hard_validation_scene_has_clutter_touching_the_hand_and_a_sleeve() -> None:
    model, intr, frames, kps, labels = suite_forearm_sequence(21, "pinch", 3, 6)
    _, intr_c, frames_c, _, labels_c = suite_forearm_sequence(21, "pinch", 3, 6, close=True,
                                                              clutter=True, sleeve=True)
    assert intr_c.fx < intr.fx                           # wider field of view
    assert np.mean(frames_c[0][0][labels_c[0] == 1]) < 0.8 * np.mean(
        frames[0][0][labels[0] == 1])                    # and nearer the hand
    assert (labels_c[0] == 2).sum() > (labels[0] == 2).sum()   # sleeve over the arm
    box = [lab == 4 for lab in labels_c]
    assert all(b.sum() > 200 for b in box) and not (labels[0] == 4).any()
    # the box slides in: away from the hand first, touching it (8-connected) in the last frame
    import cv2

    def touches(lab: np.ndarray) -> bool:
        near = cv2.dilate((lab == 4).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        return bool((near & (lab == 1)).any())

    assert not touches(labels_c[0]) and touches(labels_c[-1])


def test_only_a_smoke_run_calibrates_with_fewer_rounds(monkeypatch) -> None:
    """The benchmark's figures come from the product's calibration; a smoke run (fewest
    rounds) changes that only while it runs."""
    import hand_capture.tracking.calibration as calibration
    from hand_capture.bench._tracking_heldout import (
        SMOKE_CAL_ROUNDS,
        bench_calibrate,
        smoke_calibration,
    )

    seen: list[dict] = []
    monkeypatch.setattr(calibration, "calibrate", lambda frames, **kw: seen.append(kw))
    bench_calibrate([], model=None)
    with smoke_calibration(False):
        bench_calibrate([])
    try:
        with smoke_calibration(True):
            bench_calibrate([])
            raise KeyError("a failing smoke section")
    except KeyError:
        pass
    bench_calibrate([])
    assert seen == [{"model": None}, {}, {"rounds": SMOKE_CAL_ROUNDS}, {}]


def test_the_stereo_validation_frames_carry_artifacts_drawn_from_their_seed() -> None:
    """``with_artifacts`` (the stereo artifacts validation): the frames change, the same seed
    gives the same frames, and the suite's frames it was given are left as they were."""
    from hand_capture.bench._tracking_heldout import (
        SurfaceVariant,
        suite_surface_sequence,
        with_artifacts,
    )

    _, _, frames, _, _, _ = suite_surface_sequence(21, "pinch", 4, 6, SurfaceVariant())
    before = [d.copy() for d, _ in frames]
    a, b = with_artifacts(frames, 3), with_artifacts(frames, 3)
    c = with_artifacts(frames, 4)
    assert all(np.array_equal(x[0], y[0]) for x, y in zip(a, b, strict=True))
    assert any(not np.array_equal(x[0], y[0]) for x, y in zip(a, c, strict=True))
    assert sum(int(np.count_nonzero(x[0] != d)) for x, d in zip(a, before, strict=True)) > 100
    assert all(np.array_equal(d, f[0]) for d, f in zip(before, frames, strict=True))
    assert all(x[1] is f[1] and x[0].dtype == np.uint16 for x, f in zip(a, frames, strict=True))
