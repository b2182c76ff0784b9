"""Fit the touch encoders on generated training data and write ``data/touch/touch_model.npz``.

    hand-suite train touch [--out PATH] [--max-reference N] [--ridge R]

The training set (:data:`TRAIN_PARTS`) is generated with the hand model and cached
(``data/touch/cache/``): the template right hand (seed 0, about 6,800 valid frames like the
paper's 7,083) and, so that the encoder does not learn one hand size, eight sampled subjects
(``sample_shape(1..8)``, scales 0.90-1.12; 700 sequences each, seeds 11-18, wrist yaw +-45
deg and roll sd 8 deg instead of +-35 and 5) and eight more (``sample_shape(9..16)``, seeds
29-36) over a wider wrist pitch (-12 +- 10 deg), roll (sd 10 deg) and finger curl (0-0.9).
u and the poses are expressed in the contacts' frame
(:class:`~hand_capture.touch.encoding.ContactFrame`; ``--leftmost`` for the paper's). The linear,
quadratic and cubic encodings (eq. 1-3) are fitted by least squares, each with the ridge weight
that 5-fold cross-validation on the training set picks for it
(:func:`~hand_capture.touch.encoding.cross_validate_ridge`, folds by sequence; a departure
from the paper's plain least squares, which ``--ridge 0`` fits; the chosen weights are in the
file's meta ``ridge_<encoding>``), and saved with a subsample of the training poses and the
layout prior for the labelling search, and with a fingerprint of the hand model's
kinematics: a test fails when the model changes and the file is stale (run this command
again then). Same inputs, same file: the generator, the folds and the subsample are seeded.

Nothing here may come from :mod:`hand_capture.touch.heldout` (the evaluation family).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from hand_capture.errors import ConfigError
from hand_capture.touch.datagen import (
    GenConfig,
    TouchDataset,
    build_model,
    config_params,
    load_or_generate,
    model_fingerprint,
)
from hand_capture.touch.encoding import (
    CV_RIDGES,
    DEGREES,
    ContactFrame,
    PolynomialEncoder,
    cross_validate_ridge,
)
from hand_capture.touch.labelling import LayoutPrior
from hand_capture.touch.touch_model import MAX_REFERENCE, TouchModel, default_model_path

#: The template-hand part of the training set: seed 0 (the set of the first shipped model).
TRAIN = GenConfig(sequences=1100, frames=8, seed=0, shape_seed=-1)
assert TRAIN == GenConfig()
#: The whole training set of the shipped model: the template hand and eight subjects, these
#: with a wider wrist yaw (+-45 deg) and roll (sd 8 deg) than the template part's.
TRAIN_PARTS: tuple[GenConfig, ...] = (TRAIN,) + tuple(
    GenConfig(sequences=700, frames=8, seed=10 + k, shape_seed=k, yaw_deg=45.0,
              roll_sd_deg=8.0) for k in range(1, 9)) + tuple(
    # issue #13: eight more subjects over wider wrist pitch / roll and finger curl
    GenConfig(sequences=700, frames=8, seed=20 + k, shape_seed=k, yaw_deg=45.0,
              roll_sd_deg=10.0, pitch_deg=(-12.0, 10.0), curl=(0.0, 0.9), curl_sd=0.12)
    for k in range(9, 17))


def training_set(parts: tuple[GenConfig, ...] = TRAIN_PARTS) -> TouchDataset:
    """The generated (cached) frames of ``parts``, concatenated; sequence ids stay unique."""
    sets, offset = [], 0
    for cfg in parts:
        ds = load_or_generate(cfg, model=build_model(cfg.shape_seed))
        sets.append(TouchDataset(ds.poses, ds.pads, ds.contact, ds.sequence + offset,
                                 ds.frame, ds.motion))
        offset += cfg.sequences
    return TouchDataset.concatenate(sets)


def fit_encoders(u: np.ndarray, poses: np.ndarray, sequence: np.ndarray,
                 ridge: float | dict[str, float] | None = None,
                 degrees: tuple[str, ...] = tuple(DEGREES), frame: ContactFrame | None = None
                 ) -> tuple[dict[str, PolynomialEncoder], dict[str, str]]:
    """Encoders for ``degrees`` fitted on (u (M, 15), poses (M, 27)).

    ``ridge``: one weight for every degree (0 = plain least squares, the paper's fit), the
    weight of each degree by name (e.g. :func:`shipped_ridges`), or None to choose each
    degree's weight out of :data:`CV_RIDGES` by 5-fold cross-validation with folds by
    ``sequence`` (M,) (the shipped fit).

    Returns:
        the encoders by name, and meta entries: ``ridge`` ("cv", "given" or the forced
        weight), ``ridge_<name>`` (the weight used) and, with cross-validation,
        ``cv_scores_<name>`` (JSON list, one score per candidate of :data:`CV_RIDGES`).
    """
    meta = {"ridge": "cv" if ridge is None else "given" if isinstance(ridge, dict)
            else str(ridge)}
    encoders = {}
    for name in degrees:
        r = ridge[name] if isinstance(ridge, dict) else ridge
        if r is None:
            r, scores = cross_validate_ridge(u, poses, DEGREES[name], CV_RIDGES, sequence)
            meta[f"cv_scores_{name}"] = json.dumps([float(x) for x in scores])
        encoders[name] = PolynomialEncoder.fit(u, poses, DEGREES[name], ridge=r, frame=frame)
        meta[f"ridge_{name}"] = str(r)
    return encoders, meta


def shipped_ridges(parts: tuple[GenConfig, ...] = TRAIN_PARTS) -> dict[str, float] | None:
    """The cross-validated ridge weights of the shipped model file by encoding, when it was
    fitted on ``parts`` and the current hand model (else None: cross-validate again)."""
    try:
        shipped = TouchModel.load()
    except ConfigError:
        return None
    meta = shipped.meta
    if (shipped.frame is None or meta.get("ridge") != "cv"
            or meta.get("parts") != _parts_json(parts)
            or meta.get("hand_model") != model_fingerprint(build_model(-1))):
        return None
    return {n: float(meta[f"ridge_{n}"]) for n in DEGREES}


def _parts_json(parts: tuple[GenConfig, ...]) -> str:
    return json.dumps([config_params(c) for c in parts])


def fit_model(ds: TouchDataset, ridge: float | dict[str, float] | None = None,
              degrees: tuple[str, ...] = tuple(DEGREES), contact_frame: bool = True
              ) -> TouchModel:
    """Encoders for ``degrees`` fitted on ``ds`` (:func:`fit_encoders`: ``ridge`` None, the
    default, cross-validates each degree's weight on ``ds``); every training pose is kept as
    reference; the labelling's layout prior from the same frames. ``contact_frame``: u and
    the poses in the contacts' frame (:class:`~hand_capture.touch.encoding.ContactFrame`,
    fitted on ``ds``), else relative to the leftmost contact (the paper)."""
    frame = ContactFrame.fit(ds.pads, ds.contact) if contact_frame else None
    u, poses = ds.inputs(frame)
    encoders, meta = fit_encoders(u, poses, ds.sequence, ridge, degrees, frame)
    return TouchModel(encoders, poses, {"frames": str(len(ds)), **meta},
                      LayoutPrior.fit(ds.pads, ds.contact), frame)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hand_capture.touch.train",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="model file (default: "
                    "data/touch/touch_model.npz)")
    ap.add_argument("--template-only", action="store_true",
                    help="train on the template hand's part alone (the first shipped set)")
    ap.add_argument("--ridge", type=float, default=None,
                    help="one ridge weight for every encoding (0 = plain least squares, as in "
                    "the paper; default: each encoding's weight chosen by 5-fold "
                    "cross-validation on the training set)")
    ap.add_argument("--max-reference", type=int, default=MAX_REFERENCE)
    ap.add_argument("--leftmost", action="store_true",
                    help="u relative to the leftmost contact, unturned (the paper) instead of "
                    "the contacts' frame")
    a = ap.parse_args(argv)
    parts = (TRAIN,) if a.template_only else TRAIN_PARTS
    t0 = time.perf_counter()
    ds = training_set(parts)
    t1 = time.perf_counter()
    model = fit_model(ds, a.ridge, contact_frame=not a.leftmost)
    model.meta.update({"parts": _parts_json(parts),
                       "seed": str(TRAIN.seed),
                       "hand_model": model_fingerprint(build_model(-1))})
    out = model.save(a.out or default_model_path(), max_reference=a.max_reference)
    print(f"{len(ds)} training frames from {len(parts)} parts ({t1 - t0:.1f} s), fitted "
          f"{sorted(model.encoders)} (ridges "
          f"{ {n: float(model.meta[f'ridge_{n}']) for n in sorted(model.encoders)} }) "
          f"in {time.perf_counter() - t1:.1f} s -> {out} "
          f"({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
