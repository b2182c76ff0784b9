"""The held-out evaluation family, its split from training, bad-contact rejection, joint limits
and the labelling's layout prior (issue #13)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hand_capture.errors import InputError
from hand_capture.model.hand import HandModel
from hand_capture.model.joints import root_rotation_matrix, within_limits
from hand_capture.touch.datagen import GenConfig, build_model, generate
from hand_capture.touch.encoder import TouchEncoder, TouchEncoderConfig
from hand_capture.touch.encoding import surface_to_table_xy
from hand_capture.touch.frame import TouchFrame
from hand_capture.touch.heldout import (
    IPAD_SIZE,
    SEED_BASE,
    HeldoutConfig,
    generate_heldout,
    subject_shapes,
)
from hand_capture.touch.labelling import FingerLabeller, LayoutPrior
from hand_capture.touch.train import TRAIN_PARTS, fit_model

TOUCH = Path(__file__).resolve().parents[1] / "hand_capture" / "touch"
SMALL = HeldoutConfig(frames=80, subjects=2)


@pytest.fixture(scope="module")
def heldout():
    return generate_heldout(SMALL)


@pytest.fixture(scope="module")
def train_data():
    return generate(build_model(-1), GenConfig(sequences=150, frames=6, seed=21))


@pytest.fixture(scope="module")
def model(train_data):
    return fit_model(train_data, degrees=("linear", "quadratic"))


# --- the split ---------------------------------------------------------------------------

def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def test_training_code_never_imports_the_heldout_family():
    for path in TOUCH.glob("*.py"):
        if path.name != "heldout.py":
            assert not any("heldout" in m for m in _imports(path)), path.name
    code = ("import sys, hand_capture.touch.train, hand_capture.touch.encoder, "
            "hand_capture.touch.pcaik; print(any('heldout' in m for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_heldout_seeds_and_frames_are_not_the_trainings(heldout, train_data):
    assert all(c.seed < SEED_BASE for c in TRAIN_PARTS)
    with pytest.raises(InputError, match="held-out seeds"):
        HeldoutConfig(seed=TRAIN_PARTS[0].seed)
    ds, _ = heldout
    # no held-out pose is (near) a training-generator pose
    d = np.abs(ds.poses[:, None, 6:] - train_data.poses[None, :, 6:]).max(axis=-1)
    assert d.min() > 1e-3


# --- the family ----------------------------------------------------------------------------

def test_heldout_frames_touch_where_they_say_and_cover_the_wider_ranges(heldout):
    ds, reported = heldout
    assert len(ds) == SMALL.frames
    assert set(np.unique(ds.n_contacts)) == {2, 3, 4, 5}
    shapes = subject_shapes(SMALL)
    assert {round(s.global_scale, 2) for s in shapes} == {0.92, 1.08}
    for k, shape in enumerate(shapes):
        rows = ds.motion == k
        pads = HandModel(shape, side="right").fingertips(ds.poses[rows], where="pad")
        c = ds.contact[rows]
        np.testing.assert_allclose(pads[c][:, 2], 0.0, atol=5e-4)
        np.testing.assert_allclose(surface_to_table_xy(ds.pads[rows][c]), pads[c][:, :2],
                                   atol=1e-9)
        assert pads[~c][:, 2].min() >= SMALL.clearance - 1e-4
    assert within_limits(ds.poses).all()
    on = ds.pads[ds.contact]
    assert (on >= 0).all() and (on[:, 0] <= IPAD_SIZE[0]).all() and \
        (on[:, 1] <= IPAD_SIZE[1]).all()
    # the panel's report differs from the pads by its offset and jitter (a few mm at most)
    err = np.linalg.norm(reported - ds.pads, axis=-1)[ds.contact]
    assert 1e-4 < np.median(err) < 0.003 and err.max() < 0.01
    # wrist yaw beyond the training generator's +-35 deg occurs
    fwd = root_rotation_matrix(ds.poses[:, 3:6])[:, :, 0]
    yaw = np.degrees(np.arctan2(fwd[:, 1], fwd[:, 0])) - 90.0
    assert np.abs(yaw).max() > 36.0 and np.abs(yaw).max() < 50.0


def test_heldout_generation_is_reproducible():
    cfg = HeldoutConfig(frames=12, subjects=1, seed=SEED_BASE + 5)
    (a, ra), (b, rb) = generate_heldout(cfg), generate_heldout(cfg)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(ra, rb)


# --- bad contacts and joint limits ----------------------------------------------------------

def _frame(ids, pos, width=0.2, height=0.15):
    pos = np.asarray(pos, float)
    return TouchFrame(ids, pos, np.ones(len(pos), bool), width, height)


def test_contacts_off_the_surface_or_too_far_apart_are_rejected(train_data, model):
    enc = TouchEncoder(TouchEncoderConfig(), model=model)
    i = int(np.nonzero(train_data.n_contacts == 3)[0][0])
    pads = train_data.pads[i, train_data.contact[i]]
    pads = pads - pads.mean(axis=0) + (0.1, 0.075)
    good = enc.process(_frame([1, 2, 3], pads))
    assert good.status == "tracking"
    far = pads.copy()
    far[1] = (1e7, 0.05)
    with pytest.raises(InputError, match="outside"):
        enc.process(_frame([1, 2, 3], far))
    with pytest.raises(InputError, match="outside"):
        enc.process(_frame([1, 2, 3], pads - (0.3, 0.0)))
    # on a (wall-sized) surface but farther apart than one hand
    with pytest.raises(InputError, match="apart"):
        enc.process(_frame([1, 2, 3], pads * (1.0, 1.0) + [[0, 0], [2.0, 0], [0, 1.0]],
                           width=5.0, height=5.0))
    assert enc.labeller.labels == good.labels  # state unchanged
    again = enc.process(_frame([1, 2, 3], pads))
    assert not again.relabelled


def test_encoded_joints_stay_inside_their_limits(model):
    enc = TouchEncoder(TouchEncoderConfig(), model=model)
    rng = np.random.default_rng(3)
    for k in range(30):  # odd but valid layouts: anywhere inside one hand's span
        n = int(rng.integers(2, 6))
        pos = (0.1, 0.075) + rng.uniform(-0.09, 0.09, (n, 2)) * (1.0, 0.8)
        enc.reset()
        res = enc.process(_frame(list(range(k * 10, k * 10 + n)), pos))
        assert res.status == "tracking" and within_limits(res.pose).all()
        assert np.isfinite(res.pose).all()


# --- layout prior --------------------------------------------------------------------------

def test_layout_prior_prefers_the_finger_set_the_layout_fits():
    rng = np.random.default_rng(0)
    n = 400
    contact = np.zeros((2 * n, 5), bool)
    contact[:n, [0, 1]] = True   # thumb + index: 4 cm apart along x
    contact[n:, [1, 2]] = True   # index + middle: 2 cm apart along y
    pads = np.zeros((2 * n, 5, 2))
    pads[:n, 1] = (0.04, 0.0)
    pads[n:, 1] = (0.0, 0.0)
    pads[n:, 2] = (0.0, 0.02)
    pads += rng.normal(0.0, 0.002, pads.shape)
    prior = LayoutPrior.fit(pads, contact)
    perms = np.array([[0, 1], [1, 0], [1, 2], [2, 1], [3, 4]])
    ll = prior.log_likelihood(np.array([[0.0, 0.0], [0.04, 0.0]]), perms)
    assert np.argmax(ll) == 0 and ll[4] == -np.inf
    ll = prior.log_likelihood(np.array([[0.0, 0.02], [0.0, 0.0]]), perms)
    assert np.argmax(ll) == 3  # contact 0 is the middle finger, contact 1 the index
    back = LayoutPrior.from_arrays(prior.to_arrays())
    np.testing.assert_array_equal(back.log_likelihood(np.zeros((2, 2)) + [[0, 0], [0.04, 0]],
                                                      perms[:4]),
                                  prior.log_likelihood(np.zeros((2, 2)) + [[0, 0], [0.04, 0]],
                                                       perms[:4]))


def test_layout_labelling_is_stored_and_beats_nearest_alone_on_two_and_three(
        train_data, model, tmp_path):
    assert model.layout is not None
    path = model.save(tmp_path / "m.npz")
    from hand_capture.touch.touch_model import TouchModel

    back = TouchModel.load(path)
    assert back.layout is not None
    enc = back.encoder("quadratic")
    from hand_capture.touch.labelling import LabellerConfig

    near = FingerLabeller(enc, back.reference_poses, LabellerConfig(criterion="nearest"),
                          layout=back.layout)
    lay = FingerLabeller(enc, back.reference_poses, layout=back.layout)
    assert near.layout is None and lay.layout is not None
    test = generate(build_model(-1), GenConfig(sequences=60, frames=4, seed=22))
    rows = np.nonzero(np.isin(test.n_contacts, (2, 3)))[0]
    hits = {"near": 0, "lay": 0}
    rng = np.random.default_rng(1)
    for i in rows:
        f = np.nonzero(test.contact[i])[0]
        perm = rng.permutation(len(f))
        for name, lab in (("near", near), ("lay", lay)):
            hits[name] += np.array_equal(lab.search(test.pads[i, f[perm]]).labels, f[perm])
    assert hits["lay"] > hits["near"]


# --- the benchmark's held-out section (smoke) -----------------------------------------------

def test_bench_sections_compare_the_four_methods_on_heldout_frames(heldout, train_data, model,
                                                                  capsys):
    from hand_capture.bench.touch import _labelling_table, _methods_table
    from hand_capture.touch.datagen import TouchDataset
    from hand_capture.touch.labelling import LabellerConfig
    from hand_capture.touch.pcaik import PcaIk, PcaIkConfig

    ds, reported = heldout
    test = TouchDataset(ds.poses, reported, ds.contact, ds.sequence, ds.frame, ds.motion)
    _, rel = train_data.inputs()
    pk = PcaIk(build_model(-1), rel, PcaIkConfig(iterations=5))
    results, ms = _methods_table("H1", model.encoders, pk, test, 6, 0)
    assert set(results) == {"linear", "quadratic", "pcaik"} and ms > 0
    assert all(np.isfinite(w).all() and np.isfinite(a).all() for w, a in results.values())
    labellers = {"quadratic": FingerLabeller(model.encoder("quadratic"), model.reference_poses,
                                             LabellerConfig(criterion="nearest")),
                 "layout": FingerLabeller(model.encoder("quadratic"), model.reference_poses,
                                          layout=model.layout)}
    accs, counts, rows, poses = _labelling_table("H2", labellers, test, 30, 0)
    assert sum(counts.values()) == 30 and len(rows) == 30 and np.isfinite(poses).all()
    assert all(0.0 <= accs["layout"][n] <= 1.0 for n in counts if counts[n])
    out = capsys.readouterr().out
    assert "H1" in out and "PCA IK" in out and "Quadratic + layout" in out and "paper" in out
