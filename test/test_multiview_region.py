"""Object region score (seed 000 eq. 4-5 per object): high at the object's true pose, low off
its image region; it flags an object LOST that left its last pose, and the colour hull
re-finds it in the same frame."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.multiview.hull import place_object
from hand_capture.multiview.lo import LOConfig
from hand_capture.multiview.region import ObjectRegions
from hand_capture.multiview.rig import load_rig
from hand_capture.multiview.sequences import Sequence, make_sequence, render_sequence
from hand_capture.multiview.tracker import (
    LOST,
    RECOVERED,
    MultiviewTracker,
    MultiviewTrackerConfig,
)

#: where the ball jumps on the second frame [m, world]: out of the right palm, up and across
JUMP = np.array([0.02, 0.07, 0.07])


@pytest.fixture(scope="module")
def jump():
    """Two clean frames of the tracker's own mesh: the ball in the right palm, then the same
    hands with the ball 10.2 cm away (beyond the +-8 cm search around its last pose)."""
    rig = load_rig("studio6")
    base = make_sequence("ball", 2)
    poses = base.object_poses.copy()
    poses[1] = poses[0]
    poses[1, 0, :3, 3] += JUMP
    hands = np.stack([base.hand_poses[0]] * 2)
    seq = Sequence("ball", base.sides, base.objects, hands, poses)
    frames = list(render_sequence(seq, rig, surface="own", noise=False, circles=0,
                                  salient_miss=0.0, salient_fp=0.0, seed=11))
    return rig, seq, frames


def test_region_score_is_high_at_the_true_pose_and_low_off_the_object(jump):
    rig, seq, frames = jump
    model = seq.model()
    ball = model.part_index("ball")
    reg = ObjectRegions(model, rig)
    truth = seq.truth(model, 0)
    s, n = reg.score(truth, reg.maps(frames[0].images), ball)
    assert np.isnan(s) and n == 0                                          # nothing learned
    assert reg.learn(frames[0].images, truth, [0, 1, ball]) == [ball]     # objects only
    maps = reg.maps(frames[0].images)
    at, n = reg.score(truth, maps, ball)
    assert at > 0.8 and n > 300, (at, n)
    # the 7 cm ball still overlaps its image region in views that look along a shift
    last = at
    for shift, most in (((0.02, 0.0, 0.0), 0.75), ((0.05, 0.0, 0.0), 0.4),
                        ((0.0, 0.05, 0.0), 0.4), ((0.0, 0.0, 0.06), 0.2), (tuple(JUMP), 0.1)):
        off = truth.copy()
        off[model.slices["ball"]][:3] += shift
        s, _ = reg.score(off, maps, ball)
        assert s < most, (shift, s)
        if shift[0]:
            assert s < last      # farther along x, less of it in the ball's colour
            last = s
    # the second frame: the ball's region moved with it
    maps1 = reg.maps(frames[1].images)
    assert reg.score(truth, maps1, ball)[0] < 0.2
    assert reg.score(seq.truth(model, 1), maps1, ball)[0] > 0.8
    # hidden / out of view: no score rather than a low one
    far = truth.copy()
    far[model.slices["ball"]][:3] = (0.0, 0.0, -5.0)
    assert np.isnan(reg.score(far, maps, ball)[0])


def test_colour_hull_places_the_object(jump):
    rig, seq, frames = jump
    model = seq.model()
    ball = model.part_index("ball")
    reg = ObjectRegions(model, rig)
    reg.learn(frames[0].images, seq.truth(model, 0), [ball])
    masks = reg.blob_masks(reg.maps(frames[1].images), ball)
    got, rms = place_object(masks, rig, model.objects[0].vertices, voxel_m=0.008)
    true = seq.truth(model, 1)[model.slices["ball"]]
    assert np.linalg.norm(got[:3] - true[:3]) < 0.01 and rms < 0.01
    with pytest.raises(InputError):
        place_object({k: np.zeros_like(v) for k, v in masks.items()}, rig,
                     model.objects[0].vertices)


@pytest.mark.parametrize("colours", [True, False])
def test_a_jumped_ball_is_flagged_and_re_found_by_its_colours(jump, colours):
    """With the edge-support threshold off, only the region score can flag the ball that
    left its pose; its colour hull then proposes where it went (10 cm away, beyond the
    +-8 cm candidates) and the ball is RECOVERED in that frame. Without colour models the
    ball stays 'tracked' at its old place."""
    rig, seq, frames = jump
    model = seq.model()
    ball = model.part_index("ball")
    cfg = MultiviewTrackerConfig(lost_support=0.0, object_colours=colours)
    tr = MultiviewTracker(model, rig, LOConfig(iterations=6), cfg)
    tr.reset(seq.truth(model, 0))
    r0 = tr.step(frames[0].images, frames[0].detections)
    assert r0.parts[ball].status == "tracking"
    assert (ball in tr.regions.colours) == colours
    r1 = tr.step(frames[1].images, frames[1].detections)
    err = np.linalg.norm(r1.params[model.slices["ball"]][:3] -
                         seq.truth(model, 1)[model.slices["ball"]][:3])
    if colours:
        assert r1.parts[ball].status == RECOVERED and err < 0.005, (r1.parts[ball], err)
        assert r1.parts[ball].region > 0.8
    else:
        assert r1.parts[ball].status != LOST and err > 0.08
        assert np.isnan(r1.parts[ball].region)


def test_a_colour_model_that_separates_nothing_is_not_kept(jump):
    """Black frames: the object's mixture cannot beat the rest's anywhere, so no model (and
    no region score) rather than one that flags every pose."""
    rig, seq, frames = jump
    model = seq.model()
    reg = ObjectRegions(model, rig)
    black = {c: np.zeros_like(v) for c, v in frames[0].images.items()}
    assert reg.learn(black, seq.truth(model, 0), [model.part_index("ball")]) == []
    assert not reg.colours


def test_the_lost_ball_script_reports_the_trackers_own_estimates(jump):
    """``scripts/multiview_lost_ball.py`` also scores the evidence at the true configuration
    each frame, which takes edge subsamples from the local optimiser's random draws; its rows
    must still be the estimates of the tracker run alone (the draws put back), or a script
    meant to show the tracker's behaviour shows another one."""
    from script_helpers import load_script

    rig, seq, frames = jump
    model = seq.model()
    lost_ball = load_script("multiview_lost_ball")

    def tracker() -> MultiviewTracker:
        tr = MultiviewTracker(model, rig, LOConfig(iterations=3))
        tr.reset(seq.truth(model, 0))
        return tr

    alone = tracker()
    plain = [alone.step(f.images, f.detections).params for f in frames]
    # the evidence at the truth does draw from the optimiser's generator
    probe = tracker()
    before = probe.lo._rng.bit_generator.state
    probe.lo.support(seq.truth(model, 0), probe.lo.prepare(frames[0].images),
                     list(range(len(model.part_names))))
    assert probe.lo._rng.bit_generator.state != before
    rows = lost_ball.track_rows(tracker(), seq, frames)
    assert [r["t"] for r in rows] == [0, 1]
    for r, p in zip(rows, plain, strict=True):
        np.testing.assert_array_equal(r["params"], p)
    assert rows[1]["moved_mm"] > 100.0 and rows[1]["truth_region"] > 0.8
