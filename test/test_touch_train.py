"""The touch trainer's sets (issue #13: the encodings on wider subjects) and the generator's
posture ranges."""

from __future__ import annotations

import hashlib
import importlib.util
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.model.joints import JOINT_INDEX
from hand_capture.touch.datagen import (
    GenConfig,
    build_model,
    generate,
    load_or_generate,
    model_fingerprint,
    sample_natural,
)
from hand_capture.touch.encoding import ContactFrame, PolynomialEncoder
from hand_capture.touch.labelling import LayoutPrior
from hand_capture.touch.train import (
    ENCODER_PARTS,
    TRAIN_PARTS,
    WIDER_PARTS,
    fit_model,
)

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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


def test_wider_parts_are_new_subjects_seeds_and_wider_postures():
    from hand_capture.bench.touch import TEST_SEEDS, TEST_SHAPE_SEED
    from hand_capture.touch.heldout import SEED_BASE

    assert ENCODER_PARTS[:len(TRAIN_PARTS)] == TRAIN_PARTS
    assert ENCODER_PARTS[len(TRAIN_PARTS):] == WIDER_PARTS
    validation = _script("touch_label_ceiling").VALIDATION
    wider_val = _script("touch_encoding_validation").WIDER_VALIDATION
    seen_seeds = {c.seed for c in TRAIN_PARTS + validation + wider_val} | set(TEST_SEEDS)
    seen_hands = {c.shape_seed for c in TRAIN_PARTS + validation + wider_val} | {
        TEST_SHAPE_SEED}
    seeds = [c.seed for c in WIDER_PARTS]
    hands = [c.shape_seed for c in WIDER_PARTS]
    assert len(set(seeds)) == len(set(hands)) == len(WIDER_PARTS) == 16
    assert not (set(seeds) & seen_seeds) and not (set(hands) & seen_hands)
    assert max(seeds) < SEED_BASE
    # the validation subjects are not the training's either
    val_hands = {c.shape_seed for c in validation + wider_val}
    assert not val_hands & {c.shape_seed for c in TRAIN_PARTS} and min(val_hands) >= 0
    for w in WIDER_PARTS:  # wider than every part of TRAIN_PARTS
        for t in TRAIN_PARTS:
            assert w.pitch_deg[1] > t.pitch_deg[1] and w.roll_sd_deg > t.roll_sd_deg
            assert w.curl[0] <= t.curl[0] and w.curl[1] >= t.curl[1]
            for name in ("spread", "thumb_abd_deg", "thumb_flex_deg"):
                lo, hi = getattr(w, name)
                assert lo < getattr(t, name)[0] and hi > getattr(t, name)[1]


def test_fit_model_takes_the_encodings_from_the_encoder_data_and_the_rest_from_its_own():
    hand = build_model(-1)
    ds = generate(hand, GenConfig(sequences=80, frames=4, seed=3))
    other = generate(build_model(23), GenConfig(sequences=80, frames=4, seed=4,
                                                spread=(-0.5, 1.2)))
    plain = fit_model(ds, ridge=1e-3, degrees=("quadratic",))
    both = fit_model(ds, ridge=1e-3, degrees=("quadratic",), encoder_data=other)
    frame = ContactFrame.fit(ds.pads, ds.contact)
    np.testing.assert_array_equal(both.frame.layouts, frame.layouts)
    np.testing.assert_array_equal(both.reference_poses, ds.inputs(frame)[1])
    np.testing.assert_array_equal(both.layout.to_arrays()["layout_mean"],
                                  LayoutPrior.fit(ds.pads, ds.contact).to_arrays()["layout_mean"])
    u, y = other.inputs(frame)
    expected = PolynomialEncoder.fit(u, y, 2, ridge=1e-3)
    np.testing.assert_allclose(both.encoder("quadratic").coef, expected.coef, atol=1e-10)
    assert both.meta["frames"] == str(len(ds)) and both.meta["encoder_frames"] == str(len(other))
    # without encoder data, the encodings come from the same frames as before
    u, y = ds.inputs(frame)
    np.testing.assert_allclose(plain.encoder("quadratic").coef,
                               PolynomialEncoder.fit(u, y, 2, ridge=1e-3).coef, atol=1e-10)
    assert not np.allclose(plain.encoder("quadratic").coef, both.encoder("quadratic").coef)
