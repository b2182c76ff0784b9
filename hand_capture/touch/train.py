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
quadratic and cubic encodings (eq. 1-3) are fitted by plain least squares, as in the paper,
and saved with a subsample of the training poses and the layout prior for the labelling
search, and with a fingerprint of the hand model's kinematics: a test fails when the model
changes and the file is stale (run this command again then). Same inputs, same file: the
generator and the subsample are seeded.

Nothing here may come from :mod:`hand_capture.touch.heldout` (the evaluation family).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

from hand_capture.touch.datagen import (
    GenConfig,
    TouchDataset,
    build_model,
    load_or_generate,
    model_fingerprint,
)
from hand_capture.touch.encoding import DEGREES, ContactFrame, PolynomialEncoder
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


def fit_model(ds: TouchDataset, ridge: float = 0.0,
              degrees: tuple[str, ...] = tuple(DEGREES), contact_frame: bool = True
              ) -> TouchModel:
    """Encoders for ``degrees`` fitted on ``ds``; every training pose is kept as reference;
    the labelling's layout prior from the same frames. ``contact_frame``: u and the poses in
    the contacts' frame (:class:`~hand_capture.touch.encoding.ContactFrame`, fitted on ``ds``),
    else relative to the leftmost contact (the paper)."""
    frame = ContactFrame.fit(ds.pads, ds.contact) if contact_frame else None
    u, poses = ds.inputs(frame)
    encoders = {name: PolynomialEncoder.fit(u, poses, DEGREES[name], ridge=ridge)
                for name in degrees}
    return TouchModel(encoders, poses, {"frames": str(len(ds)), "ridge": str(ridge)},
                      LayoutPrior.fit(ds.pads, ds.contact), frame)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hand_capture.touch.train",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="model file (default: "
                    "data/touch/touch_model.npz)")
    ap.add_argument("--template-only", action="store_true",
                    help="train on the template hand's part alone (the first shipped set)")
    ap.add_argument("--ridge", type=float, default=0.0,
                    help="ridge weight (0 = plain least squares, as in the paper)")
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
    model.meta.update({"parts": json.dumps([asdict(c) for c in parts]),
                       "seed": str(TRAIN.seed),
                       "hand_model": model_fingerprint(build_model(-1))})
    out = model.save(a.out or default_model_path(), max_reference=a.max_reference)
    print(f"{len(ds)} training frames from {len(parts)} parts ({t1 - t0:.1f} s), fitted "
          f"{sorted(model.encoders)} in {time.perf_counter() - t1:.1f} s -> {out} "
          f"({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
