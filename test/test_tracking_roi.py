"""Something nearer the camera than a tracked hand (issue 13: clutter, another hand or an
object in view): ``segment_hand(roi=...)`` and the tracker's ``track_roi_m``.

The dissertation takes the nearest object in view for the hand (ch. II.2). While a hand is
tracked the segment is the component holding most pixels near the previous pose's bones,
and its depth band starts at the hand when something nearer elsewhere would leave the hand
behind the band; a forearm nearer than the hand, part of the hand's component, is kept as
before."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.cameras.base import Intrinsics
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker, default_model_path
from hand_capture.tracking.preprocess import near_segments_mask, segment_hand
from hand_capture.tracking.regressor import HandRegressor

INTR = Intrinsics(320, 240, 250.0, 250.0, 160.0, 120.0)


def _pixel(p: np.ndarray) -> tuple[int, int]:
    return (int(round(INTR.cx + INTR.fx * p[0] / p[2])),
            int(round(INTR.cy + INTR.fy * p[1] / p[2])))


def _bones(centre_uv: tuple[int, int], z: float) -> np.ndarray:
    """(2, 2, 3) [m]: two 60 mm bones at depth ``z`` through pixel ``centre_uv``, one
    along each image axis."""
    c = np.array([(centre_uv[0] - INTR.cx) * z / INTR.fx, (centre_uv[1] - INTR.cy) * z / INTR.fy,
                  z])
    dx, dy = np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.03, 0.0])
    return np.array([[c - dx, c + dx], [c - dy, c + dy]])


def _scene(box_z: float | None, arm: bool = False) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(240, 320) depth [m]: a palm-sized disc at 0.40 m round pixel (140, 120); a box face
    at ``box_z`` on the right (not touching the disc in the image); with ``arm`` a forearm
    strip from the disc to the image's bottom edge, nearing the camera to 0.30 m."""
    v, u = np.mgrid[0:240, 0:320]
    hand = (u - 140) ** 2 + (v - 120) ** 2 <= 40 ** 2
    box = (u >= 230) & (u < 300) & (v >= 60) & (v < 180)
    d = np.zeros((240, 320), np.float32)
    d[hand] = 0.40
    masks = {"hand": hand, "box": box}
    if arm:
        strip = (np.abs(u - 140) <= 18) & (v > 120) & ~hand
        d[strip] = 0.40 - 0.10 * (v[strip] - 120) / 119.0
        masks["arm"] = strip
    if box_z is not None:
        d[box] = box_z
    return d, masks


def _kept(obs) -> np.ndarray:
    m = np.zeros((240, 320), bool)
    m[obs.pixels[:, 1].astype(int), obs.pixels[:, 0].astype(int)] = True
    return m


def test_near_segments_mask_follows_the_bones_in_the_image_and_in_depth() -> None:
    d, masks = _scene(0.40)
    bones = _bones((140, 120), 0.40)
    near = near_segments_mask(d, INTR, bones, 0.02)
    assert near[120, 140] and near[120, 140 + 25]      # on a bone, within 20 mm of it
    assert not near[120, 140 + 39]                     # 37 mm off the bone's end
    assert not near[masks["box"]].any()                # the box: same depth, far off
    # the same pixels at another depth are not near: depth counts as much as the image
    assert not near_segments_mask(d + 0.05, INTR, bones, 0.02).any()
    assert not near_segments_mask(d, INTR, bones + np.nan, 0.02).any()   # no bones, nothing


@pytest.mark.parametrize("box_z", [0.35, 0.15])
def test_a_tracked_hand_is_segmented_with_something_nearer_in_view(box_z: float) -> None:
    # 0.35: the box in the hand's depth band; 0.15: the hand lies behind the box's band
    cfg = TrackerConfig()
    d, masks = _scene(box_z)
    assert _kept(segment_hand(d, INTR, cfg))[masks["box"]].all()   # the nearest in view
    kept = _kept(segment_hand(d, INTR, cfg, (_bones((140, 120), 0.40), 0.1)))
    assert kept[masks["hand"]].all() and not kept[masks["box"]].any()


def test_a_forearm_nearer_than_the_hand_stays_in_the_segment() -> None:
    cfg = TrackerConfig()
    d, masks = _scene(None, arm=True)
    alone = _kept(segment_hand(d, INTR, cfg))
    tracked = _kept(segment_hand(d, INTR, cfg, (_bones((140, 120), 0.40), 0.1)))
    assert alone[masks["arm"]].all() and alone[masks["hand"]].all()
    np.testing.assert_array_equal(tracked, alone)      # the same segment as without it


def test_nothing_near_the_tracked_hand_gives_no_segment_there() -> None:
    cfg = TrackerConfig()
    d, _ = _scene(0.35)
    obs = segment_hand(d, INTR, cfg, (_bones((60, 40), 0.40), 0.05))
    assert not obs.found


def test_the_tracker_keeps_the_hand_when_a_nearer_box_enters_the_view() -> None:
    # the suite's generator: a box 50-120 mm nearer than the hand slides in beside it a
    # third into the sequence (the distractor validation family of `bench tracking`)
    from hand_capture.bench._tracking_heldout import _suite_calibration, suite_forearm_sequence
    from hand_capture.model import HandModel

    reg = HandRegressor.load(default_model_path())
    true, intr, frames, kps, labels = suite_forearm_sequence(21, "finger_counting", 14, 3,
                                                             distractor=True)
    for (depth, _), lab in zip(frames[8:], labels[8:], strict=True):   # in view, nearer
        assert np.median(depth[(lab == 4) & (depth > 0)]) < depth[(lab == 1) & (depth > 0)].min()
    cal = _suite_calibration(true, intr, 21, HandModel())
    on_box, err = {}, {}
    for name, cfg in (("roi", TrackerConfig()), ("nearest", TrackerConfig(track_roi_m=0.0))):
        tr = HybridTracker(HandModel(), cfg, reg)
        tr.set_calibration(cal)
        box, e = [], []
        for (depth, it), kp, lab in zip(frames, kps, labels, strict=True):
            r = tr.process(depth, it)
            px = r.observation.pixels.astype(int)
            box.append(float(np.mean(lab[px[:, 1], px[:, 0]] == 4)))
            e.append(float(np.linalg.norm(tr.model.joint_positions(r.pose) - kp,
                                          axis=1).mean()) * 1e3)
        on_box[name], err[name] = np.array(box), np.array(e)
    assert (on_box["nearest"][10:] > 0.5).all()    # the nearest in view: the box
    assert (on_box["roi"] == 0.0).all()            # never a box pixel in the segment
    assert err["roi"].max() < 20.0                 # tracked through [mm]
