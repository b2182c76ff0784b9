"""Polynomial encodings (eq. 1-3), the input vector u, the model file and the PCA-IK basis."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from hand_capture.errors import ConfigError, InputError
from hand_capture.touch.encoding import (
    INCH,
    PREDICT_BLOCK,
    PolynomialEncoder,
    PolynomialFeatures,
    absolute_pose,
    encode_input,
    n_features,
    relative_pose,
)
from hand_capture.touch.pcaik import components_for
from hand_capture.touch.touch_model import TouchModel


def test_feature_counts_match_the_paper():
    # sec. 2: "120 + 15 + 1 = 136 coefficients per degree-of-freedom" for 15-dim u
    assert n_features(2) == 136 == PolynomialFeatures(2).size
    assert n_features(1) == 16 and n_features(3) == 816  # eq. (2), eq. (3)
    with pytest.raises(ConfigError):
        PolynomialFeatures(4)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_features_are_all_monomials_in_order(degree):
    u = np.random.default_rng(0).normal(size=(7, 15))
    ref = [np.ones(7)] + [u[:, i] for i in range(15)]
    for d in range(2, degree + 1):
        ref += [np.prod(u[:, list(c)], axis=1)
                for c in itertools.combinations_with_replacement(range(15), d)]
    np.testing.assert_allclose(PolynomialFeatures(degree)(u), np.stack(ref, 1), rtol=1e-12)


def test_fit_reproduces_a_known_quadratic_exactly():
    rng = np.random.default_rng(1)
    u = rng.normal(size=(600, 15))
    coef = rng.normal(size=(136, 27))
    y = PolynomialFeatures(2)(u) @ coef
    enc = PolynomialEncoder.fit(u, y, degree=2)
    np.testing.assert_allclose(enc.coef, coef, atol=1e-9)
    u_new = rng.normal(size=(50, 15))
    np.testing.assert_allclose(enc.predict(u_new), PolynomialFeatures(2)(u_new) @ coef,
                               atol=1e-8)
    # the ridge path (standardised monomials) converges to the same function
    ridge = PolynomialEncoder.fit(u, y, degree=2, ridge=1e-12)
    np.testing.assert_allclose(ridge.predict(u_new), enc.predict(u_new), atol=1e-5)
    # a linear encoder cannot: its residual stays large
    lin = PolynomialEncoder.fit(u, y, degree=1)
    assert np.abs(lin.predict(u) - y).mean() > 1.0


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_blocked_batch_evaluation_equals_one_product(degree):
    rng = np.random.default_rng(2)
    enc = PolynomialEncoder(degree, rng.normal(size=(n_features(degree), 27)))
    u = rng.normal(size=(2 * PREDICT_BLOCK + 37, 15))
    whole = PolynomialFeatures(degree)(u) @ enc.coef
    np.testing.assert_allclose(enc.predict(u), whole, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(enc.predict(u[:5]), whole[:5], rtol=1e-12, atol=1e-9)
    with pytest.raises(InputError):
        enc.predict(u[0])


def test_fit_rejects_bad_data():
    u = np.zeros((10, 15))
    with pytest.raises(InputError):
        PolynomialEncoder.fit(u, np.zeros((9, 27)), 2)
    u[0, 0] = np.nan
    with pytest.raises(InputError):
        PolynomialEncoder.fit(u, np.zeros((10, 27)), 2)
    with pytest.raises(ConfigError):
        PolynomialEncoder(2, np.zeros((16, 27)))


def test_encode_input_relative_to_leftmost_contact_in_inches():
    pads = np.zeros((5, 2))
    pads[1] = (0.10, 0.05)     # index
    pads[2] = (0.0746, 0.0754)  # middle: leftmost of the contacts
    pads[4] = (0.5, 0.5)       # little, lifted: its position must not matter
    contact = np.array([False, True, True, False, False])
    u, origin = encode_input(pads, contact)
    np.testing.assert_allclose(origin, pads[2])
    assert u.shape == (15,)
    np.testing.assert_allclose(u[2:4], (pads[1] - pads[2]) / INCH)
    np.testing.assert_allclose(u[4:6], 0.0)
    np.testing.assert_allclose(u[[0, 1, 6, 7, 8, 9]], -1.0)  # lifted fingers: (-1, -1)
    np.testing.assert_array_equal(u[10:], contact.astype(float))
    # translation invariance
    u2, _ = encode_input(pads + (0.03, -0.01), contact)
    np.testing.assert_allclose(u2, u)


def test_encode_input_rejects_bad_input():
    pads = np.zeros((5, 2))
    with pytest.raises(InputError, match="at least one"):
        encode_input(pads, np.zeros(5, bool))
    pads[0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        encode_input(pads, np.array([True, True, False, False, False]))
    # NaN of a lifted finger is irrelevant
    encode_input(pads, np.array([False, True, True, False, False]))
    with pytest.raises(InputError):
        encode_input(np.zeros((4, 2)), np.ones(4, bool))


def test_relative_and_absolute_pose_are_inverse_in_the_table_frame():
    q = np.random.default_rng(2).normal(size=(3, 27))
    origin = np.array([0.05, 0.08])  # surface coordinates: y grows towards the user
    rel = relative_pose(q, origin)
    np.testing.assert_allclose(rel[:, :2], q[:, :2] - (0.05, -0.08))
    np.testing.assert_allclose(absolute_pose(rel, origin), q)
    np.testing.assert_array_equal(rel[:, 2:], q[:, 2:])


def test_model_file_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    encs = {name: PolynomialEncoder(d, rng.normal(size=(n_features(d), 27)))
            for name, d in (("linear", 1), ("quadratic", 2))}
    ref = rng.normal(size=(50, 27))
    path = TouchModel(encs, ref, {"seed": "0"}).save(tmp_path / "m.npz", max_reference=20)
    back = TouchModel.load(path)
    assert set(back.encoders) == {"linear", "quadratic"} and back.meta["seed"] == "0"
    np.testing.assert_allclose(back.encoder("quadratic").coef, encs["quadratic"].coef)
    assert back.reference_poses.shape == (20, 27)
    with pytest.raises(ConfigError, match="cubic"):
        back.encoder("cubic")
    with pytest.raises(ConfigError, match="not found"):
        TouchModel.load(tmp_path / "missing.npz")


def test_shipped_model_file_loads_and_is_small():
    model = TouchModel.load()
    assert set(model.encoders) == {"linear", "quadratic", "cubic"}
    assert model.encoder("quadratic").coef.shape == (136, 27)
    from hand_capture.touch.touch_model import default_model_path

    assert default_model_path().stat().st_size < 1_000_000


def test_pcaik_components_per_contact_count():
    # sec. 3: 3, 6, 9, 12 principal components for 2, 3, 4, 5 contacts
    assert [components_for(n) for n in (2, 3, 4, 5)] == [3, 6, 9, 12]


def test_shipped_model_file_was_trained_on_the_current_hand_model():
    from hand_capture.touch.datagen import build_model, model_fingerprint

    meta = TouchModel.load().meta
    assert meta.get("hand_model") == model_fingerprint(build_model(-1)), (
        "data/touch/touch_model.npz is stale: the hand model changed; regenerate it with "
        "'python -m hand_capture.touch.train'")


# --- the contacts' frame (issue #13) ------------------------------------------------------

def _turn_surface(p: np.ndarray, deg: float, centre: np.ndarray, shift: np.ndarray
                  ) -> np.ndarray:
    """Surface points (..., 2) turned by ``deg`` about ``centre`` (table-frame sense), then
    shifted."""
    a = np.radians(deg)
    rot = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])  # y points down
    return (p - centre) @ rot.T + centre + shift


def test_contact_frame_turns_and_shifts_with_the_hand():
    """Three or more contacts turned and moved on the surface give the same u, and the
    reconstructed wrist turns and moves with them (the paper's leftmost-contact frame does
    not: its u changes)."""
    model = TouchModel.load()
    assert model.frame is not None
    enc = model.encoder("quadratic")
    pads = np.array([[0.05, 0.10], [0.08, 0.05], [0.10, 0.045], [0.12, 0.05], [0.14, 0.07]])
    contact = np.array([True, True, True, False, True])
    centre = pads[contact].mean(axis=0)
    u0, origin0, phi0 = enc.encode(pads, contact)
    q0 = enc.reconstruct(pads, contact)
    for deg in (-30.0, 20.0):
        moved = _turn_surface(pads, deg, centre, np.array([0.03, -0.01]))
        u1, origin1, phi1 = enc.encode(moved, contact)
        np.testing.assert_allclose(u1, u0, atol=1e-9)
        np.testing.assert_allclose(phi1 - phi0, np.radians(deg), atol=1e-9)
        q1 = enc.reconstruct(moved, contact)
        wrist0 = np.array([q0[0], -q0[1]])  # table -> surface xy
        expect = _turn_surface(wrist0, deg, centre, np.array([0.03, -0.01]))
        np.testing.assert_allclose([q1[0], -q1[1]], expect, atol=1e-9)
        np.testing.assert_allclose(q1[6:], q0[6:], atol=1e-9)  # same finger joints
        u_paper, _ = encode_input(moved, contact)
        assert not np.allclose(u_paper, encode_input(pads, contact)[0], atol=1e-3)


def test_contact_frame_pose_round_trip_and_file():
    from hand_capture.touch.encoding import ContactFrame

    rng = np.random.default_rng(4)
    q = rng.normal(0.0, 0.3, (6, 27))
    q[:, 5] += np.pi / 2
    origin, phi = rng.uniform(0.0, 0.2, (6, 2)), rng.uniform(-1.0, 1.0, 6)
    back = ContactFrame.from_frame(ContactFrame.to_frame(q, origin, phi), origin, phi)
    np.testing.assert_allclose(back, q, atol=1e-9)
    frame = TouchModel.load().frame
    again = ContactFrame.from_arrays(frame.to_arrays())
    np.testing.assert_array_equal(again.layouts, frame.layouts)
    with pytest.raises(ConfigError, match="two_contact_share"):
        ContactFrame(frame.layouts, frame.known, 1.5)
    # two contacts: only a share of the angle; one contact: none
    pads = np.array([[0.05, 0.10], [0.08, 0.05], [0, 0], [0, 0], [0, 0]])
    two = np.array([True, True, False, False, False])
    _, _, phi_two = frame.encode(pads, two)
    turned = _turn_surface(pads, 20.0, pads[two].mean(axis=0), np.zeros(2))
    _, _, phi_turned = frame.encode(turned, two)
    assert phi_turned - phi_two == pytest.approx(frame.two_contact_share * np.radians(20.0))
    _, _, phi_one = frame.encode(pads, np.array([True, False, False, False, False]))
    assert phi_one == 0.0


# --- the ridge weight chosen by cross-validation (issue #13) ------------------------------

def _toy(rows: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u (rows, 15), a smooth quadratic target (rows, 27) plus noise, groups of 4 rows."""
    coef = np.random.default_rng(seed).normal(size=(136, 27)) * 0.1  # the same per seed
    rng = np.random.default_rng([seed, rows])
    u = rng.normal(size=(rows, 15))
    y = PolynomialFeatures(2)(u) @ coef + noise * rng.normal(size=(rows, 27))
    return u, y, np.arange(rows) // 4


def test_trainer_cross_validation_picks_a_ridge_where_plain_least_squares_overfits():
    """Cubic (816 coefficients) on 1,200 noisy rows: plain least squares fits the noise (its
    CV error is several times the best), so the trainer's CV picks a positive weight, and
    that encoder predicts new data better."""
    from hand_capture.touch.encoding import CV_RIDGES
    from hand_capture.touch.train import fit_encoders

    u, y, groups = _toy(1200, 0.5, 5)
    encs, meta = fit_encoders(u, y, groups, degrees=("cubic",))
    chosen = float(meta["ridge_cubic"])
    scores = json.loads(meta["cv_scores_cubic"])
    assert meta["ridge"] == "cv" and chosen > 0.0 and chosen in CV_RIDGES
    assert len(scores) == len(CV_RIDGES) and scores[0] > 2 * min(scores)  # 0 overfits
    assert chosen == CV_RIDGES[int(np.argmin(scores))]
    u_new, y_new, _ = _toy(2000, 0.0, 5)  # the same function, no noise
    plain = PolynomialEncoder.fit(u, y, 3)
    err = [np.abs(e.predict(u_new) - y_new).mean() for e in (encs["cubic"], plain)]
    assert err[0] < 0.7 * err[1]


def test_trainer_cross_validation_keeps_plain_least_squares_where_it_does_not_overfit():
    """An exact quadratic (no noise, 3,000 rows for 136 coefficients): any ridge only adds
    bias, so CV keeps 0 and the encoder is the plain least-squares one."""
    from hand_capture.touch.train import fit_encoders

    u, y, groups = _toy(3000, 0.0, 6)
    encs, meta = fit_encoders(u, y, groups, degrees=("linear", "quadratic"))
    assert float(meta["ridge_quadratic"]) == 0.0
    np.testing.assert_allclose(encs["quadratic"].coef, PolynomialEncoder.fit(u, y, 2).coef,
                               atol=1e-9)
    # a forced weight (hand-suite train touch --ridge R) skips the search
    forced, meta = fit_encoders(u, y, groups, ridge=0.01, degrees=("quadratic",))
    assert meta == {"ridge": "0.01", "ridge_quadratic": "0.01"}
    np.testing.assert_allclose(forced["quadratic"].coef,
                               PolynomialEncoder.fit(u, y, 2, ridge=0.01).coef)


def test_cross_validation_rejects_bad_input():
    from hand_capture.touch.encoding import cross_validate_ridge

    u, y, groups = _toy(40, 0.1, 7)
    with pytest.raises(InputError, match="do not match"):
        cross_validate_ridge(u, y[:-1], 1, groups=groups)
    with pytest.raises(InputError, match="folds"):
        cross_validate_ridge(u, y, 1, groups=np.arange(40) % 3)
    with pytest.raises(ConfigError):
        cross_validate_ridge(u, y, 1, ridges=(-1.0, 0.0), groups=groups)


def test_shipped_model_carries_its_cross_validated_ridges():
    from hand_capture.touch.encoding import CV_RIDGES
    from hand_capture.touch.train import TRAIN, TRAIN_PARTS, shipped_ridges

    meta = TouchModel.load().meta
    assert meta["ridge"] == "cv"
    for name in ("linear", "quadratic", "cubic"):
        scores = json.loads(meta[f"cv_scores_{name}"])
        assert float(meta[f"ridge_{name}"]) == CV_RIDGES[int(np.argmin(scores))]
    # the quick bench reuses them only for the training set they were chosen on
    assert shipped_ridges(TRAIN_PARTS) == {n: float(meta[f"ridge_{n}"])
                                           for n in ("linear", "quadratic", "cubic")}
    assert shipped_ridges((TRAIN,)) is None
