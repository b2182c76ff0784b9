"""The touch generator's posture ranges and the validation study of the encodings' training
subjects (scripts/touch_encoding_validation.py, issue #13; not shipped)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict

import numpy as np
import pytest
from script_helpers import load_script as _script

from hand_capture.errors import InputError
from hand_capture.model.joints import JOINT_INDEX
from hand_capture.touch.datagen import (
    GenConfig,
    build_model,
    load_or_generate,
    model_fingerprint,
    sample_natural,
)
from hand_capture.touch.train import TRAIN_PARTS


def test_posture_ranges_are_the_given_ones_and_the_defaults_draw_as_before():
    thumb_abd, thumb_flex = JOINT_INDEX["thumb_tm_abd"], JOINT_INDEX["thumb_tm_flex"]
    q = sample_natural(np.random.default_rng(0), 400, thumb_abd_deg=(20.0, 20.0),
                       thumb_flex_deg=(5.0, 15.0), spread=(1.0, 1.0))
    np.testing.assert_allclose(np.degrees(q[:, thumb_abd]), 20.0)
    assert 5.0 <= np.degrees(q[:, thumb_flex]).min() < np.degrees(q[:, thumb_flex]).max() <= 15
    # a spread level of 1 turns the index out (+12 deg) and the little finger in (-14.4)
    assert np.degrees(q[:, JOINT_INDEX["index_mcp_abd"]]).mean() == pytest.approx(12.0, abs=1)
    assert np.degrees(q[:, JOINT_INDEX["little_mcp_abd"]]).mean() == pytest.approx(-14.4, abs=1)
    # the defaults give the draws of the fixed ranges they replaced
    a = sample_natural(np.random.default_rng(3), 50)
    b = sample_natural(np.random.default_rng(3), 50, spread=(-0.3, 1.0),
                       thumb_abd_deg=(0.0, 40.0), thumb_flex_deg=(-10.0, 35.0))
    np.testing.assert_array_equal(a, b)
    wide = sample_natural(np.random.default_rng(3), 2000, spread=(-0.5, 1.2))
    narrow = sample_natural(np.random.default_rng(3), 2000)
    idx = JOINT_INDEX["index_mcp_abd"]
    assert np.ptp(wide[:, idx]) > np.ptp(narrow[:, idx])


def test_gen_config_rejects_inverted_ranges():
    for field in ("curl", "spread", "thumb_abd_deg", "thumb_flex_deg"):
        with pytest.raises(InputError, match=field):
            GenConfig(**{field: (1.0, 0.0)})


def test_cache_key_of_a_config_with_default_ranges_is_the_key_before_them(tmp_path):
    # the cached training sets keep their files: the fields added later stay out of the key
    hand = build_model(-1)
    cfg = GenConfig(sequences=2, frames=2, seed=8)
    load_or_generate(cfg, model=hand, cache=tmp_path)
    old = {k: v for k, v in asdict(cfg).items()
           if k not in ("spread", "thumb_abd_deg", "thumb_flex_deg")}
    key = hashlib.sha1(json.dumps({**old, "model": model_fingerprint(hand), "version": 2},
                                  sort_keys=True).encode()).hexdigest()[:16]
    assert [p.name for p in tmp_path.glob("*.npz")] == [f"touch_8_-1_{key}.npz"]
    wider = GenConfig(sequences=2, frames=2, seed=8, spread=(-0.5, 1.2))
    load_or_generate(wider, model=hand, cache=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == 2  # another posture range: another file


def test_candidate_subjects_are_new_subjects_seeds_and_wider_postures():
    from hand_capture.bench.touch import TEST_SEEDS, TEST_SHAPE_SEED
    from hand_capture.touch.heldout import SEED_BASE

    study = _script("touch_encoding_validation")
    wider_parts = study.WIDER_PARTS
    assert study.CANDIDATES["wider16"] == TRAIN_PARTS + wider_parts
    assert study.CANDIDATES["shipped"] == TRAIN_PARTS
    validation = _script("touch_label_ceiling").VALIDATION
    wider_val = study.WIDER_VALIDATION
    seen_seeds = {c.seed for c in TRAIN_PARTS + validation + wider_val} | set(TEST_SEEDS)
    seen_hands = {c.shape_seed for c in TRAIN_PARTS + validation + wider_val} | {
        TEST_SHAPE_SEED}
    seeds = [c.seed for c in wider_parts]
    hands = [c.shape_seed for c in wider_parts]
    assert len(set(seeds)) == len(set(hands)) == len(wider_parts) == 16
    assert not (set(seeds) & seen_seeds) and not (set(hands) & seen_hands)
    assert max(seeds) < SEED_BASE
    # the validation subjects are not the training's either
    val_hands = {c.shape_seed for c in validation + wider_val}
    assert not val_hands & {c.shape_seed for c in TRAIN_PARTS} and min(val_hands) >= 0
    for w in wider_parts:  # wider than every part of TRAIN_PARTS
        for t in TRAIN_PARTS:
            assert w.pitch_deg[1] > t.pitch_deg[1] and w.roll_sd_deg > t.roll_sd_deg
            assert w.curl[0] <= t.curl[0] and w.curl[1] >= t.curl[1]
            for name in ("spread", "thumb_abd_deg", "thumb_flex_deg"):
                lo, hi = getattr(w, name)
                assert lo < getattr(t, name)[0] and hi > getattr(t, name)[1]
