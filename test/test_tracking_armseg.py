"""The per-pixel hand/forearm classifier of the depth tracker (hand_capture.tracking.armseg,
issue 13): it separates hand from arm on the suite's renders, the tracker uses it, a hand
alone is left whole, and its model file is checked when loaded."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hand_capture.errors import ConfigError, InputError
from hand_capture.model import HandModel, sample_shape
from hand_capture.tracking import HandRegressor, HybridTracker, TrackerConfig
from hand_capture.tracking.armseg import (
    ArmClassifier,
    default_arm_path,
    load_arm_classifier,
    pixel_features,
    remove_arm,
)
from hand_capture.tracking.hybrid import default_model_path
from hand_capture.tracking.preprocess import HandObservation, touches_border
from hand_capture.tracking.regressor import BACKGROUND_REL_M
from hand_capture.tracking.train import ARM_LABEL, HAND_LABEL, default_intrinsics, render_samples


@pytest.fixture(scope="module")
def clf() -> ArmClassifier:
    return ArmClassifier.load(default_arm_path())


def _frames(forearm: float, n: int, seed: int):
    """Frames of the suite's generator (a shape not among the training ones): (depth [m],
    labels, intrinsics) of uncut segments."""
    intr = default_intrinsics()
    models = [HandModel().with_shape(sample_shape(np.random.default_rng(seed)))]
    out = []
    for s in render_samples(n, np.random.default_rng(seed), models, intr, forearm_prob=forearm,
                            cut_arm=False):
        h, w = s.crop.shape
        depth = np.zeros((intr.height, intr.width), np.float32)
        depth[s.v0:s.v0 + h, s.u0:s.u0 + w] = s.crop
        lab = np.zeros(depth.shape, np.uint8)
        lab[s.v0:s.v0 + h, s.u0:s.u0 + w] = s.label
        out.append((depth, lab, intr))
    return out


def _obs(depth: np.ndarray, intr) -> HandObservation:
    v, u = np.nonzero(depth > 0)
    box = (int(v.min()), int(v.max()) + 1, int(u.min()), int(u.max()) + 1)
    return HandObservation.from_pixels(depth, depth > 0, v, u, depth[v, u].astype(float),
                                       intr, box)


def _shares(obs: HandObservation, lab: np.ndarray, ref: HandObservation) -> tuple[float, float]:
    """(share of the segment on the arm, share of ref's hand pixels kept)."""
    v, u, _ = obs.vuz
    lv = lab[v, u]
    rv, ru, _ = ref.vuz
    n_hand = np.count_nonzero(lab[rv, ru] == HAND_LABEL)
    return (float(np.mean(lv == ARM_LABEL)),
            float(np.count_nonzero(lv == HAND_LABEL) / n_hand))


def test_classifier_separates_hand_from_arm_on_a_rendered_frame(clf) -> None:
    arm_before, arm_after, kept, acc = [], [], [], []
    for depth, lab, intr in _frames(1.0, 6, 2024):
        obs = _obs(depth, intr)
        out, prob, cut = remove_arm(obs, clf, margin_m=0.0)
        assert prob is not None and cut
        v, u, _ = obs.vuz
        lv = lab[v, u]
        ok = lv > 0
        acc.append(np.mean((prob[ok] > 0.5) == (lv[ok] == ARM_LABEL)))
        arm_before.append(_shares(obs, lab, obs)[0])
        a, k = _shares(out, lab, obs)
        arm_after.append(a)
        kept.append(k)
    assert np.mean(arm_before) > 0.3          # the uncut segments are a third arm or more
    assert np.mean(acc) > 0.85
    assert np.mean(arm_after) < 0.12          # most of the arm is gone ...
    assert np.mean(kept) > 0.9                # ... and the hand is still there


def test_the_tracker_drops_the_arm_pixels_before_fitting(clf) -> None:
    reg = HandRegressor.load(default_model_path())
    shares: dict[str, list] = {"classifier": [], "bypassed": []}
    for depth, lab, intr in _frames(1.0, 4, 78):
        mm = (depth * 1000).astype(np.uint16)
        # no arm margin: the segment's arm is what the classifier let through (no fallback:
        # an uncalibrated first frame often fails eq. II.19, and the retry on the cut alone
        # would then fit the cut's segment; test below)
        for name, cfg in (("classifier", TrackerConfig(arm_margin_m=0.0, arm_fallback=False)),
                          ("bypassed", TrackerConfig(arm_classifier=False))):
            tracker = HybridTracker(HandModel(), cfg, reg)
            assert (tracker.arm is not None) == (name == "classifier")
            r = tracker.process(mm, intr)   # a first frame: no previous wrist to cut at
            shares[name].append(_shares(r.observation, lab, _obs(depth, intr)))
    cls, byp = np.mean(shares["classifier"], axis=0), np.mean(shares["bypassed"], axis=0)
    # the segment the tracker fitted holds much less arm with the classifier, and the hand
    assert cls[0] < 0.6 * byp[0]
    assert cls[1] > 0.9


def test_a_probe_off_the_segment_reads_relative_to_the_pixel() -> None:
    # a flat patch at 0.4 m and at 0.7 m: the probe against the pixel itself that lands
    # off the segment reads the same at both distances (no absolute depth in a feature)
    intr = default_intrinsics()
    # (feature, probe, (du, dv)) [m]: probe 1 off the patch against the pixel itself, the
    # other way round, and a probe on the patch
    offsets = np.array([[[0.2, 0.0], [0.0, 0.0]],
                        [[0.0, 0.0], [0.2, 0.0]],
                        [[0.005, 0.0], [0.0, 0.0]]], np.float32)
    feats = []
    for z in (0.4, 0.7):
        img = np.full((intr.height, intr.width), -1.0, np.float32)
        img[110:130, 150:170] = z
        v, u = np.array([120]), np.array([160])
        feats.append(pixel_features(img, v, u, np.array([z]), offsets, intr.fx, intr.fy)[0])
    np.testing.assert_allclose(feats[0], feats[1], atol=1e-6)
    np.testing.assert_allclose(feats[0], [BACKGROUND_REL_M, -BACKGROUND_REL_M, 0.0], atol=1e-6)


def test_a_hand_farther_than_the_training_renders_is_not_called_arm(clf) -> None:
    # the suite's generator with a D435-like camera 0.2 m farther back (hand at 0.55-0.65 m,
    # the training renders' palms at 0.30-0.55 m): the hand's pixels stay hand (format 1 of
    # the classifier, with a constant background, called 85 % of them arm)
    from hand_capture.bench._tracking_heldout import FAR_CAMERA, suite_forearm_sequence

    _, intr, frames, _, labels = suite_forearm_sequence(21, "finger_counting", 3, 10,
                                                        camera=FAR_CAMERA)
    hand_called_arm, arm_called_arm = [], []
    for (mm, _), lab in zip(frames, labels, strict=True):
        depth = np.where(lab > 0, mm.astype(np.float32) * 1e-3, 0.0).astype(np.float32)
        obs = _obs(depth, intr)
        _, prob, _ = remove_arm(obs, clf, margin_m=0.0)
        v, u, _ = obs.vuz
        lv = lab[v, u]
        hand_called_arm.append(np.mean(prob[lv == 1] > 0.5))
        arm_called_arm.append(np.mean(prob[lv == 2] > 0.5))
    assert np.mean(hand_called_arm) < 0.1
    assert np.mean(arm_called_arm) > 0.8


def test_a_hand_alone_is_left_whole(clf) -> None:
    cfg = TrackerConfig()
    asked = []
    for depth, _, intr in _frames(0.0, 6, 5):
        obs = _obs(depth, intr)
        out, prob, cut = remove_arm(obs, clf, margin_m=cfg.arm_margin_m,
                                    reach_m=cfg.forearm_reach_m)
        asked.append(prob is not None)
        if not touches_border(obs):
            # inside the image and shorter than forearm_reach_m: not even classified
            assert prob is None and not cut and out is obs
        assert out.n_points >= 0.9 * obs.n_points
    assert not all(asked)


def test_model_file_round_trips_and_bad_files_are_refused(clf, tmp_path) -> None:
    p = tmp_path / "arm.npz"
    clf.save(p)
    back = ArmClassifier.load(p)
    depth, _, intr = _frames(1.0, 1, 9)[0]
    obs = _obs(depth, intr)
    v, u, _ = obs.vuz
    args = (obs.depth_m, obs.mask, obs.box, v, u, intr, 4.0)
    np.testing.assert_array_equal(back.segment_probability(*args),
                                  clf.segment_probability(*args))
    assert back.info["train_acc"] == clf.info["train_acc"]

    arrays = dict(np.load(p))
    bad = tmp_path / "bad.npz"

    def refused(match: str, **change) -> None:
        a = {k: v for k, v in arrays.items() if change.get(k, 0) is not None}
        a.update({k: v for k, v in change.items() if v is not None})
        np.savez(bad, **a)
        with pytest.raises(InputError, match=match):
            ArmClassifier.load(bad)

    refused("lacks", offsets=None)
    refused("format", format=np.array(99))
    refused("offsets must be", offsets=arrays["offsets"][:, :1])
    refused("reads feature", offsets=arrays["offsets"][:1])
    refused("1 output", f_value=np.zeros((len(arrays["f_value"]), 3), np.float32))
    split = arrays["f_feature"] >= 0
    refused("left children", f_left=np.where(split, len(split), arrays["f_left"]))
    refused("leaves outside", f_leaf=np.where(split, -1, len(arrays["f_value"])))
    refused("nodes, feature has", f_threshold=arrays["f_threshold"][:-1])
    refused("no trees", f_roots=np.zeros(0, np.int32))
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(InputError, match="cannot read"):
        ArmClassifier.load(tmp_path / "junk.npz")
    with pytest.raises(InputError, match="does not exist"):
        load_arm_classifier(tmp_path / "missing.npz")
    # a tracker told to use a missing file says so instead of tracking without it
    with pytest.raises(InputError, match="does not exist"):
        HybridTracker(HandModel(), TrackerConfig(arm_model_file=str(tmp_path / "none.npz")))


def test_arm_settings_are_validated() -> None:
    with pytest.raises(ConfigError, match="arm_threshold"):
        TrackerConfig(arm_threshold=1.5)
    with pytest.raises(ConfigError, match="arm_margin_m"):
        TrackerConfig(arm_margin_m=-0.01)
    cfg = dataclasses.replace(TrackerConfig(), arm_grid_mm=2.0)
    assert cfg.arm_grid_mm == 2.0


class _WrongClassifier:
    """Calls the hand arm and the arm hand (what the trained classifier does to a surface
    unlike its training renders, e.g. clutter touching the hand: the kept part is not the
    hand)."""

    def __init__(self, label: np.ndarray) -> None:
        self.label = label

    def segment_probability(self, depth, mask, box, v, u, intr, grid_mm) -> np.ndarray:
        return (self.label[v, u] == HAND_LABEL).astype(np.float64)


def test_a_classifier_that_keeps_the_wrong_part_is_no_worse_than_the_cut() -> None:
    # issue 13: the classifier's segment lost the hand on a held-out sequence (clutter next
    # to the hand) and the tracker never recovered; a failed frame the classifier cut is
    # now retried on the forearm cut alone and the lower E_d (eq. II.19) is kept
    reg = HandRegressor.load(default_model_path())
    model = HandModel()
    cost: dict[str, list] = {"fallback": [], "no fallback": [], "cut only": []}
    for depth, lab, intr in _frames(1.0, 3, 32):
        mm = (depth * 1000).astype(np.uint16)
        wrong = _WrongClassifier(lab)
        # a fit to the wrong part alone scores near tau = 25 mm (18-26 mm, by the CPU's
        # floating point): a strict tau makes every frame fail II.19, so the retry always runs
        # and the outcome is decided by E_d alone
        for name, cfg in (("fallback", TrackerConfig(success_tau_mm=5.0)),
                          ("no fallback", TrackerConfig(success_tau_mm=5.0,
                                                        arm_fallback=False)),
                          ("cut only", TrackerConfig(success_tau_mm=5.0,
                                                     arm_classifier=False))):
            tracker = HybridTracker(model, cfg, reg, arm=wrong)
            r = tracker.process(mm, intr)
            assert tracker.frame_count == 1           # one frame, whatever was retried
            assert r.status == "lost"
            _, kept = _shares(r.observation, lab, _obs(depth, intr))
            cost[name].append((r.cost, kept))
    fb, nofb, cut = (np.array(cost[k]) for k in ("fallback", "no fallback", "cut only"))
    assert np.all(nofb[:, 1] < 0.5)                   # the wrong part: most of the hand gone
    # the retry on the cut alone is kept where its E_d is the lower, and then the hand is
    # back; the wrong part's fit is kept otherwise
    np.testing.assert_allclose(fb[:, 0], np.minimum(nofb[:, 0], cut[:, 0]))
    won = cut[:, 0] < nofb[:, 0]
    assert won.any()
    assert np.all(fb[won, 1] > 0.9)


def test_a_lost_frame_with_clutter_touching_the_hand_is_retried_at_the_other_end() -> None:
    # issue 13, the suite's generator: a box slid against the hand, a sleeve, a close-range
    # camera; from a reset tracker the cloud cut takes the box for the palm and keeps the
    # wrong end; a failed frame is retried with the cloud's other end (flip_retry)
    from hand_capture.bench._tracking_heldout import suite_forearm_sequence

    reg = HandRegressor.load(default_model_path())
    true, intr, frames, kps, _ = suite_forearm_sequence(21, "fist", 12, 3, close=True,
                                                        clutter=True, sleeve=True)
    err, cost = {}, {}
    # measured under the whole-hand selection of eq. II.20 (finger_swap off): with the
    # finger-wise selection the wrong end's fit scores lower on one of these frames (mean
    # 27 mm with the retry); flip_retry stays off either way
    # (docs/experiments/depth_tracking.md)
    # split_retry (test_tracking_split.py) off: it finds the hand on these frames by
    # itself; the wider search of a reset tracker (acquire_modes) changes which of these
    # frames keep the wrong end (with it: 99 / 72 / 57 / 33 mm without the retry, 99 / 56 /
    # 57 / 33 with it), so the retry is measured under the narrower search
    narrow = {"finger_swap": False, "split_retry": False, "acquire_modes": 0,
              "acquire_refine_top": 0, "acquire_icp_iterations": 0}
    for name, cfg in (("retry", TrackerConfig(flip_retry=True, **narrow)),
                      ("no retry", TrackerConfig(**narrow))):
        tracker = HybridTracker(true, cfg, reg)
        e, c = [], []
        for (depth, _), kp in list(zip(frames, kps, strict=True))[-4:]:
            tracker.reset()
            r = tracker.process(depth, intr)
            e.append(np.linalg.norm(true.joint_positions(r.pose) - kp, axis=1).mean() * 1e3)
            c.append(r.cost)
        err[name], cost[name] = np.array(e), np.array(c)
    assert np.all(cost["retry"] <= cost["no retry"] + 1e-9)   # the lower E_d is kept
    # a frame that kept the wrong end (hand 40+ mm off) is brought back to the hand (per
    # frame: which of these frames fail differs in the last digits of the CPU's floating
    # point and with the regressor; shape 22's fist showed it until the regressor trained
    # with stereo artifacts, which keeps the wrong end there with and without the retry;
    # shape 21's fist, that regressor, this machine: 82 / 61 / 88 / 96 -> 30 / 21 / 88 / 67
    # mm)
    assert np.any((err["no retry"] > 40.0) & (err["retry"] < 30.0))
