"""Fit the touch encoders on generated training data and write ``data/touch/touch_model.npz``.

    hand-suite train touch [--out PATH] [--max-reference N] [--ridge R] [--no-wider]

The training set (:data:`TRAIN_PARTS`) is generated with the hand model and cached
(``data/touch/cache/``): the template right hand (seed 0, about 6,800 valid frames like the
paper's 7,083) and, so that the encoder does not learn one hand size, eight sampled subjects
(``sample_shape(1..8)``, scales 0.90-1.12; 700 sequences each, seeds 11-18, wrist yaw +-45
deg and roll sd 8 deg instead of +-35 and 5) and eight more (``sample_shape(9..16)``, seeds
29-36) over a wider wrist pitch (-12 +- 10 deg), roll (sd 10 deg) and finger curl (0-0.9).
The encodings are fitted on these and on sixteen more subjects (:data:`WIDER_PARTS`,
``sample_shape(23..38)``, seeds 60-75) over a wider wrist pitch / roll, finger curl, spread
and thumb range still, so that they generalise to postures unlike the generator's usual ones
(issue #13; ``--no-wider`` leaves them out); the contacts' frame, the labelling's reference
poses and its layout prior come from :data:`TRAIN_PARTS` alone, as before.
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
from dataclasses import asdict
from pathlib import Path

import numpy as np

from hand_capture.errors import ConfigError
from hand_capture.touch.datagen import (
    GenConfig,
    TouchDataset,
    build_model,
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
#: Issue #13 (the encodings on hands and postures unlike the training's): sixteen more subjects
#: (``sample_shape(23..38)``, seeds 60-75) over a wider wrist pitch (-15 +- 13 deg) and roll
#: (sd 14 deg), finger curl (0-0.9, sd 0.14), spread (-0.5..1.2) and thumb range (TM
#: abduction -5..50, flexion -20..45 deg) than any part of :data:`TRAIN_PARTS`. Only the
#: encodings are fitted on them (:data:`ENCODER_PARTS`); chosen on validation frames of the
#: training generator (scripts/touch_encoding_validation.py), not on the held-out family.
WIDER_PARTS: tuple[GenConfig, ...] = tuple(
    GenConfig(sequences=700, frames=8, seed=60 + i, shape_seed=23 + i, yaw_deg=45.0,
              roll_sd_deg=14.0, pitch_deg=(-15.0, 13.0), curl=(0.0, 0.9), curl_sd=0.14,
              spread=(-0.5, 1.2), thumb_abd_deg=(-5.0, 50.0), thumb_flex_deg=(-20.0, 45.0))
    for i in range(16))
#: The encodings' training set: :data:`TRAIN_PARTS` (first, so its rows lead) and the wider
#: subjects.
ENCODER_PARTS: tuple[GenConfig, ...] = TRAIN_PARTS + WIDER_PARTS


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


def shipped_ridges(parts: tuple[GenConfig, ...] = TRAIN_PARTS,
                   encoder_parts: tuple[GenConfig, ...] = ENCODER_PARTS
                   ) -> dict[str, float] | None:
    """The cross-validated ridge weights of the shipped model file by encoding, when it was
    made from ``parts`` (frame, reference, layout prior) and ``encoder_parts`` (the
    encodings) with the current hand model (else None: cross-validate again)."""
    try:
        shipped = TouchModel.load()
    except ConfigError:
        return None
    meta = shipped.meta
    if (shipped.frame is None or meta.get("ridge") != "cv"
            or meta.get("parts") != _parts_json(parts)
            or meta.get("encoder_parts", meta.get("parts")) != _parts_json(encoder_parts)
            or meta.get("hand_model") != model_fingerprint(build_model(-1))):
        return None
    return {n: float(meta[f"ridge_{n}"]) for n in DEGREES}


def _parts_json(parts: tuple[GenConfig, ...]) -> str:
    return json.dumps([asdict(c) for c in parts])


def fit_model(ds: TouchDataset, ridge: float | dict[str, float] | None = None,
              degrees: tuple[str, ...] = tuple(DEGREES), contact_frame: bool = True,
              encoder_data: TouchDataset | None = None) -> TouchModel:
    """Encoders for ``degrees`` fitted on ``encoder_data`` (default ``ds``;
    :func:`fit_encoders`: ``ridge`` None, the default, cross-validates each degree's weight on
    the same frames); every pose of ``ds`` is kept as reference; the labelling's layout prior
    from ``ds`` too. ``contact_frame``: u and the poses in the contacts' frame
    (:class:`~hand_capture.touch.encoding.ContactFrame`, fitted on ``ds``), else relative to
    the leftmost contact (the paper)."""
    frame = ContactFrame.fit(ds.pads, ds.contact) if contact_frame else None
    u, poses = ds.inputs(frame)
    enc_ds = ds if encoder_data is None else encoder_data
    u_enc, poses_enc = (u, poses) if encoder_data is None else enc_ds.inputs(frame)
    encoders, meta = fit_encoders(u_enc, poses_enc, enc_ds.sequence, ridge, degrees, frame)
    return TouchModel(encoders, poses, {"frames": str(len(ds)),
                                        "encoder_frames": str(len(enc_ds)), **meta},
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
    ap.add_argument("--no-wider", action="store_true",
                    help="fit the encodings on the frame / reference parts alone, without "
                    "the wider subjects (WIDER_PARTS; the model before issue #13's change)")
    a = ap.parse_args(argv)
    parts = (TRAIN,) if a.template_only else TRAIN_PARTS
    encoder_parts = parts if (a.template_only or a.no_wider) else ENCODER_PARTS
    t0 = time.perf_counter()
    ds = training_set(parts)
    enc_ds = None if encoder_parts == parts else training_set(encoder_parts)
    t1 = time.perf_counter()
    model = fit_model(ds, a.ridge, contact_frame=not a.leftmost, encoder_data=enc_ds)
    model.meta.update({"parts": _parts_json(parts),
                       "encoder_parts": _parts_json(encoder_parts),
                       "seed": str(TRAIN.seed),
                       "hand_model": model_fingerprint(build_model(-1))})
    out = model.save(a.out or default_model_path(), max_reference=a.max_reference)
    print(f"{len(ds)} training frames from {len(parts)} parts, encodings on "
          f"{model.meta['encoder_frames']} from {len(encoder_parts)} ({t1 - t0:.1f} s), fitted "
          f"{sorted(model.encoders)} (ridges "
          f"{ {n: float(model.meta[f'ridge_{n}']) for n in sorted(model.encoders)} }) "
          f"in {time.perf_counter() - t1:.1f} s -> {out} "
          f"({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
