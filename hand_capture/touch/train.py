"""Fit the touch encoders on generated training data and write ``data/touch/touch_model.npz``.

    python -m hand_capture.touch.train [--out PATH] [--sequences N] [--frames N] [--seed S]

The training set (:data:`TRAIN`: template right hand, seed 0, about 7,000 valid frames like
the paper's 7,083) is generated with the hand model and cached (``data/touch/cache/``); the
linear, quadratic and cubic encodings (eq. 1-3) are fitted by plain least squares, as in the
paper, and saved with a subsample of the training poses for the labelling search, and with a
fingerprint of the hand model's kinematics: a test fails when the model changes and the file
is stale (run this command again then).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

from hand_capture.touch.datagen import (
    GenConfig,
    TouchDataset,
    build_model,
    load_or_generate,
    model_fingerprint,
)
from hand_capture.touch.encoding import DEGREES, PolynomialEncoder
from hand_capture.touch.touch_model import MAX_REFERENCE, TouchModel, default_model_path

#: The training set of the shipped model: the template hand, seed 0.
TRAIN = GenConfig(sequences=1100, frames=8, seed=0, shape_seed=-1)
assert TRAIN == GenConfig()


def fit_model(ds: TouchDataset, ridge: float = 0.0,
              degrees: tuple[str, ...] = tuple(DEGREES)) -> TouchModel:
    """Encoders for ``degrees`` fitted on ``ds``; every training pose is kept as reference."""
    u, poses = ds.inputs()
    encoders = {name: PolynomialEncoder.fit(u, poses, DEGREES[name], ridge=ridge)
                for name in degrees}
    return TouchModel(encoders, poses, {"frames": str(len(ds)), "ridge": str(ridge)})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hand_capture.touch.train",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="model file (default: "
                    "data/touch/touch_model.npz)")
    ap.add_argument("--sequences", type=int, default=TRAIN.sequences)
    ap.add_argument("--frames", type=int, default=TRAIN.frames)
    ap.add_argument("--seed", type=int, default=TRAIN.seed)
    ap.add_argument("--ridge", type=float, default=0.0,
                    help="ridge weight (0 = plain least squares, as in the paper)")
    ap.add_argument("--max-reference", type=int, default=MAX_REFERENCE)
    a = ap.parse_args(argv)
    cfg = replace(TRAIN, sequences=a.sequences, frames=a.frames, seed=a.seed)
    t0 = time.perf_counter()
    hand = build_model(cfg.shape_seed)
    ds = load_or_generate(cfg, model=hand)
    t1 = time.perf_counter()
    model = fit_model(ds, a.ridge)
    model.meta.update({"sequences": str(cfg.sequences), "frames_per_sequence": str(cfg.frames),
                       "seed": str(cfg.seed), "hand_model": model_fingerprint(hand)})
    out = model.save(a.out or default_model_path(), max_reference=a.max_reference)
    print(f"{len(ds)} training frames ({t1 - t0:.1f} s), fitted "
          f"{sorted(model.encoders)} in {time.perf_counter() - t1:.1f} s -> {out} "
          f"({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
