"""The regressor's training viewpoints (``random_pose`` / ``render_samples`` options, issue 13)
and the regressor validation harness (``scripts/regressor_validation.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from script_helpers import load_script

from hand_capture.errors import InputError
from hand_capture.model import JOINT_INDEX, JOINT_LIMITS, N_DOF, HandModel
from hand_capture.tracking.train import (
    default_intrinsics,
    finger_pitch_deg,
    random_pose,
    render_samples,
)

_MODEL = HandModel()


def _rest_pitch() -> float:
    """The fingers' pitch of the palm exactly towards the camera (tilt 0, no roll effect)."""
    q = random_pose(np.random.default_rng(0), _MODEL, max_tilt_deg=0.0)
    return finger_pitch_deg(_MODEL, q)


def test_towards_pitches_the_fingers_by_the_angle_asked_for() -> None:
    for seed in range(20):
        plain = random_pose(np.random.default_rng(seed), _MODEL)
        towards = random_pose(np.random.default_rng(seed), _MODEL, towards_prob=1.0,
                              towards_deg=(30.0, 30.0))
        p0, p1 = finger_pitch_deg(_MODEL, plain), finger_pitch_deg(_MODEL, towards)
        assert p0 + 30.0 < 90.0
        assert p1 - p0 == pytest.approx(30.0, abs=1e-6)


def test_towards_prob_zero_keeps_the_plain_generator() -> None:
    for seed in range(5):
        a = random_pose(np.random.default_rng(seed), _MODEL)
        b = random_pose(np.random.default_rng(seed), _MODEL, towards_prob=0.0)
        np.testing.assert_array_equal(a, b)
    with pytest.raises(InputError, match="towards_prob"):
        random_pose(np.random.default_rng(0), _MODEL, towards_prob=1.5)


def test_max_tilt_bounds_the_pitch_and_a_wider_tilt_reaches_further() -> None:
    rest = _rest_pitch()
    rng = np.random.default_rng(3)
    for tilt in (20.0, 60.0):
        p = np.array([finger_pitch_deg(_MODEL, random_pose(rng, _MODEL, max_tilt_deg=tilt))
                      for _ in range(300)])
        assert np.abs(p - rest).max() <= tilt + 1e-6
    wide = np.array([finger_pitch_deg(_MODEL, random_pose(rng, _MODEL, max_tilt_deg=80.0))
                     for _ in range(300)])
    assert np.abs(wide - rest).max() > 65.0


def test_render_samples_passes_the_viewpoint_options() -> None:
    rest = _rest_pitch()
    samples = render_samples(6, np.random.default_rng(5), [_MODEL], default_intrinsics(),
                             max_tilt_deg=0.0, towards_prob=1.0)
    pitch = np.array([finger_pitch_deg(_MODEL, s.pose) for s in samples]) - rest
    assert len(samples) == 6
    assert pitch.min() >= 20.0 - 1e-6 and pitch.max() <= 60.0 + 1e-6
    assert all(s.pose.shape == (N_DOF,) and math.isfinite(s.crop.max()) for s in samples)


def _harness():
    return load_script("regressor_validation")


def test_regressor_validation_scores_candidates_and_first_frames() -> None:
    from hand_capture.tracking import HandRegressor, TrackerConfig
    from hand_capture.tracking.hybrid import default_model_path

    h = _harness()
    models, samples = h.validation_renders(12, seed=7)
    assert len(samples) == 12 and len(models) == 4
    reg = HandRegressor.load(default_model_path())
    c = h.candidate_quality(reg, models, samples, 2)
    assert c["cand_frames"] == 12
    # the best candidate of a frame (21 keypoints) is no worse than its best-palm one
    # (6 palm + 15 finger keypoints)
    assert 0.0 < c["cand_best_mm"] <= (6 * c["cand_palm_mm"] + 15 * c["cand_finger_mm"]) / 21 \
        + 1e-9
    f = h.first_frames(reg, models, samples, TrackerConfig())
    assert 0.0 < f["ff_mean_mm"] < 200.0 and 0.0 <= f["ff_success_20mm"] <= 1.0
    with pytest.raises(InputError):
        h.validation_renders(0)


def test_regressor_validation_tracks_the_validation_families_with_the_product_alone(
        capsys) -> None:
    from hand_capture.tracking import HandRegressor
    from hand_capture.tracking.hybrid import default_model_path

    out = _harness().tracker_validation(HandRegressor.load(default_model_path()), True)
    # the product's figures only: no ablation, no cut-alone baseline, no hard set
    assert 0.0 < out["val_surface_mean_mm"] < 100.0 and out["val_surface_cpu_ms"] > 0.0
    assert 0.0 < out["val_forearm_first_mean_mm"] < 100.0
    assert 0.0 < out["val_capsule_reset_mean_mm"] < 100.0
    assert not [k for k in out if "_before" in k or "cut_only" in k or "val_hard" in k]
    assert "product" in capsys.readouterr().out


def test_uniform_poses_reach_the_joint_limits_and_a_floor_maps_the_same_draws() -> None:
    """With ``floor_rad`` None the uniformly drawn poses span the joint limits (MCP
    hyperextension to -30 deg, the little finger's spread to -25 deg); a floor maps the same
    draws into [max(lower limit, floor), upper limit], every other part of the pose unchanged;
    the default is the shipped regressors' floor."""
    lo, hi = JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1]
    lo_f = np.maximum(lo, -0.2)
    mcp = [JOINT_INDEX[f"{f}_mcp_flex"] - 6 for f in ("index", "middle", "ring", "little")]
    uniform = []
    for seed in range(120):
        full = random_pose(np.random.default_rng(seed), _MODEL, floor_rad=None)
        floored = random_pose(np.random.default_rng(seed), _MODEL, floor_rad=-0.2)
        np.testing.assert_array_equal(floored, random_pose(np.random.default_rng(seed), _MODEL))
        np.testing.assert_array_equal(full[:6], floored[:6])
        if np.array_equal(full, floored):
            continue                       # a library pose: no uniform draw
        r = (full[6:] - lo) / (hi - lo)    # the draw in [0, 1]
        np.testing.assert_allclose(floored[6:], lo_f + (hi - lo_f) * r, atol=1e-12)
        uniform.append(full[6:])
    u = np.array(uniform)
    assert len(u) > 15
    assert (u >= lo).all() and (u <= hi).all()
    assert u[:, mcp].min() < -0.35     # hyperextended beyond the earlier floor, -0.2


def test_articulation_family_centres_reach_the_hyperextension_only_when_asked() -> None:
    """``scripts/articulation_validation.py --mid 0 0.6`` (the validation family of the
    full-range training poses) hyperextends the MCPs; the default centres do so rarely."""
    art = load_script("articulation_validation")
    lo = JOINT_LIMITS[6:, 0]
    mcp = [JOINT_INDEX[f"{f}_mcp_flex"] - 6 for f in ("index", "middle", "ring", "little")]
    share = {}
    for mid in (art.MID_SHARE, (0.0, 0.6)):
        q = np.concatenate([art.finger_motion(np.random.default_rng(s), 40, mid_share=mid)
                            for s in range(30)])
        assert (q >= lo - 1e-12).all()
        share[mid] = float(np.mean(q[:, mcp] < -0.2))
    assert share[(0.0, 0.6)] > 2 * share[art.MID_SHARE] and share[(0.0, 0.6)] > 0.1
