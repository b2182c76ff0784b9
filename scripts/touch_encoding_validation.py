"""Touch encodings on wider training subjects, measured on validation frames (issue #13).

An experiment, not shipped (docs/experiments/touch.md): the quadratic encoding
(Chung et al., eq. 1) is fitted on candidate training sets and measured on frames of the
TRAINING generator that no candidate was made from (no held-out frame):

* ``validation``: the labelling study's set (``scripts/touch_label_ceiling.py --validation``:
  seeds 52-54, ``sample_shape(17..19)``, the wide wrist / curl settings of the training's third
  part);
* ``wider``: seeds 55-57, ``sample_shape(20..22)``, a wider wrist yaw (+-50 deg), pitch
  (-15 +- 14), roll (sd 15), curl (sd 0.15), finger spread (-0.6..1.3) and thumb range
  (abduction -5..50, flexion -20..45 deg) than any part of ``TRAIN_PARTS``;
* ``test``: the bench's in-distribution frames (seeds 1 and 2, ``sample_shape(101)``).

Candidates: ``shipped`` (the encodings on ``TRAIN_PARTS``), ``wider8`` and ``wider16`` (with
the first 8 / all 16 subjects of :data:`WIDER_PARTS` too). The contacts' frame, the
labelling's reference poses and layout prior always come from ``TRAIN_PARTS``; each
candidate's quadratic takes the ridge that 5-fold cross-validation on its own set picks.
``wider16`` was the best on these sets (validation 3.223 -> 3.205 cm, wider 3.683 -> 3.632,
test 2.489 -> 2.490) but raised the bench's held-out quadratic from 3.006 to 3.060 cm, so the
shipped encodings stay on ``TRAIN_PARTS``.
Printed per candidate and set: wrist error [cm] / mean joint angle error [deg] with true
labels, and the shipped labeller's accuracy [%] for 2 / 3 / 4 / 5 contacts (``--frames``
frames per set, contacts shuffled, searched from scratch).

    PYTHONPATH=. .venv/bin/python scripts/touch_encoding_validation.py   # about 10 min
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

from hand_capture.bench.touch import TEST_SEEDS, TEST_SHAPE_SEED, errors
from hand_capture.touch.datagen import GenConfig, TouchDataset, build_model, load_or_generate
from hand_capture.touch.labelling import FingerLabeller
from hand_capture.touch.touch_model import MAX_REFERENCE
from hand_capture.touch.train import TRAIN_PARTS, fit_encoders, fit_model, training_set

#: the wider validation variant: seeds and hands no training part uses
WIDER_VALIDATION = tuple(
    GenConfig(sequences=500, frames=8, seed=s, shape_seed=h, yaw_deg=50.0, roll_sd_deg=15.0,
              pitch_deg=(-15.0, 14.0), curl=(0.0, 0.9), curl_sd=0.15, spread=(-0.6, 1.3),
              thumb_abd_deg=(-5.0, 50.0), thumb_flex_deg=(-20.0, 45.0))
    for s, h in ((55, 20), (56, 21), (57, 22)))
#: Sixteen candidate training subjects (``sample_shape(23..38)``, seeds 60-75) over a wider
#: wrist pitch (-15 +- 13 deg) and roll (sd 14 deg), finger curl (0-0.9, sd 0.14), spread
#: (-0.5..1.2) and thumb range (TM abduction -5..50, flexion -20..45 deg) than any part of
#: ``TRAIN_PARTS``.
WIDER_PARTS: tuple[GenConfig, ...] = tuple(
    GenConfig(sequences=700, frames=8, seed=60 + i, shape_seed=23 + i, yaw_deg=45.0,
              roll_sd_deg=14.0, pitch_deg=(-15.0, 13.0), curl=(0.0, 0.9), curl_sd=0.14,
              spread=(-0.5, 1.2), thumb_abd_deg=(-5.0, 50.0), thumb_flex_deg=(-20.0, 45.0))
    for i in range(16))
CANDIDATES = {"shipped": TRAIN_PARTS, "wider8": TRAIN_PARTS + WIDER_PARTS[:8],
              "wider16": TRAIN_PARTS + WIDER_PARTS}


@functools.cache
def _ceiling() -> object:
    """scripts/touch_label_ceiling.py as a module: its ``VALIDATION`` settings and
    ``label_accuracy`` (one copy of each)."""
    path = Path(__file__).resolve().parent / "touch_label_ceiling.py"
    spec = importlib.util.spec_from_file_location("touch_label_ceiling", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def validation_sets() -> dict[str, TouchDataset]:
    """The three measuring sets by name (generated and cached on first use)."""
    def load(parts: tuple[GenConfig, ...]) -> TouchDataset:
        return TouchDataset.concatenate([load_or_generate(c, model=build_model(c.shape_seed))
                                         for c in parts])
    test = tuple(GenConfig(sequences=210, frames=8, seed=s, shape_seed=TEST_SHAPE_SEED)
                 for s in TEST_SEEDS)
    return {"validation": load(_ceiling().VALIDATION), "wider": load(WIDER_VALIDATION),
            "test": load(test)}


def label_accuracy(labeller: FingerLabeller, ds: TouchDataset, frames: int) -> list[float]:
    """Accuracy [%] for 2..5 contacts on ``frames`` rows of ``ds`` (contacts shuffled)."""
    return _ceiling().label_accuracy(labeller, ds, frames)[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2000, help="labelling frames per set")
    ap.add_argument("--candidates", nargs="*", default=list(CANDIDATES),
                    choices=list(CANDIDATES))
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    sets = validation_sets()
    # frame, reference poses and layout prior of the shipped model (TRAIN_PARTS)
    model = fit_model(training_set(TRAIN_PARTS), degrees=("quadratic",))
    reference = model.reference_poses[np.sort(np.random.default_rng(0).choice(
        len(model.reference_poses), MAX_REFERENCE, False))]  # what the file keeps
    out: dict[str, dict] = {}
    for name in a.candidates:
        parts = CANDIDATES[name]
        if parts == TRAIN_PARTS:
            quad, ridge = model.encoder("quadratic"), float(model.meta["ridge_quadratic"])
        else:
            data = training_set(parts)
            u, poses = data.inputs(model.frame)
            encoders, meta = fit_encoders(u, poses, data.sequence, degrees=("quadratic",),
                                          frame=model.frame)
            quad, ridge = encoders["quadratic"], float(meta["ridge_quadratic"])
        lab = FingerLabeller(quad, reference, layout=model.layout)
        res: dict[str, dict] = {"ridge": ridge}
        for set_name, ds in sets.items():
            w, ang = errors(ds.poses, quad.reconstruct(ds.pads, ds.contact))
            res[set_name] = {"wrist_cm": float(w.mean()), "angle_deg": float(ang.mean()),
                             "label_acc": label_accuracy(lab, ds, a.frames)}
            print(f"{name:8s} {set_name:10s} {w.mean():.3f} cm / {ang.mean():.2f} deg, "
                  "labels " + " / ".join(f"{x:.1f}" for x in res[set_name]["label_acc"])
                  + f"  ({len(ds)} frames, ridge {res['ridge']:g})", flush=True)
        out[name] = res
    print(json.dumps({"encoding_validation": out, "seconds": time.perf_counter() - t0}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
