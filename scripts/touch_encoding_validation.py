"""Choice of the touch encodings' training set on validation frames (issue #13; no held-out frame).

The quadratic encoding (Chung et al., eq. 1) is fitted on candidate training sets and measured
on frames of the TRAINING generator that no candidate was made from:

* ``validation``: the labelling study's set (``scripts/touch_label_ceiling.py --validation``:
  seeds 52-54, ``sample_shape(17..19)``, the wide wrist / curl settings of the training's third
  part);
* ``wider``: seeds 55-57, ``sample_shape(20..22)``, a wider wrist yaw (+-50 deg), pitch
  (-15 +- 14), roll (sd 15), curl (sd 0.15), finger spread (-0.6..1.3) and thumb range
  (abduction -5..50, flexion -20..45 deg) than any part of ``TRAIN_PARTS``;
* ``test``: the bench's in-distribution frames (seeds 1 and 2, ``sample_shape(101)``).

Candidates: ``before`` (the encodings on ``TRAIN_PARTS``, as shipped before), ``wider8`` and
``wider16`` (with the first 8 / all 16 subjects of ``WIDER_PARTS``). The contacts' frame, the
labelling's reference poses and layout prior always come from ``TRAIN_PARTS``; each
candidate's quadratic takes the ridge that 5-fold cross-validation on its own set picks.
Printed per candidate and set: wrist error [cm] / mean joint angle error [deg] with true
labels, and the shipped labeller's accuracy [%] for 2 / 3 / 4 / 5 contacts (``--frames``
frames per set, contacts shuffled, searched from scratch).

    PYTHONPATH=. .venv/bin/python scripts/touch_encoding_validation.py   # about 10 min
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

from hand_capture.bench.touch import TEST_SEEDS, TEST_SHAPE_SEED, errors
from hand_capture.touch.datagen import GenConfig, TouchDataset, build_model, load_or_generate
from hand_capture.touch.labelling import FingerLabeller
from hand_capture.touch.train import TRAIN_PARTS, WIDER_PARTS, fit_model, training_set

#: the wider validation variant: seeds and hands no training part uses
WIDER_VALIDATION = tuple(
    GenConfig(sequences=500, frames=8, seed=s, shape_seed=h, yaw_deg=50.0, roll_sd_deg=15.0,
              pitch_deg=(-15.0, 14.0), curl=(0.0, 0.9), curl_sd=0.15, spread=(-0.6, 1.3),
              thumb_abd_deg=(-5.0, 50.0), thumb_flex_deg=(-20.0, 45.0))
    for s, h in ((55, 20), (56, 21), (57, 22)))
CANDIDATES = {"before": TRAIN_PARTS, "wider8": TRAIN_PARTS + WIDER_PARTS[:8],
              "wider16": TRAIN_PARTS + WIDER_PARTS}


def _label_validation() -> tuple[GenConfig, ...]:
    """``VALIDATION`` of scripts/touch_label_ceiling.py (one copy of those settings)."""
    path = Path(__file__).resolve().parent / "touch_label_ceiling.py"
    spec = importlib.util.spec_from_file_location("touch_label_ceiling", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.VALIDATION


def validation_sets() -> dict[str, TouchDataset]:
    """The three measuring sets by name (generated and cached on first use)."""
    def load(parts: tuple[GenConfig, ...]) -> TouchDataset:
        return TouchDataset.concatenate([load_or_generate(c, model=build_model(c.shape_seed))
                                         for c in parts])
    test = tuple(GenConfig(sequences=210, frames=8, seed=s, shape_seed=TEST_SHAPE_SEED)
                 for s in TEST_SEEDS)
    return {"validation": load(_label_validation()), "wider": load(WIDER_VALIDATION),
            "test": load(test)}


def label_accuracy(labeller: FingerLabeller, ds: TouchDataset, frames: int) -> list[float]:
    """Accuracy [%] for 2..5 contacts on ``frames`` rows of ``ds`` (contacts shuffled)."""
    rows = np.sort(np.random.default_rng(1).choice(len(ds), min(frames, len(ds)), False))
    rng = np.random.default_rng(5)
    hits: dict[int, list[bool]] = {n: [] for n in range(2, 6)}
    for i in rows:
        fingers = np.flatnonzero(ds.contact[i])[rng.permutation(ds.n_contacts[i])]
        res = labeller.search(ds.pads[i, fingers])
        hits[len(fingers)].append(bool(np.array_equal(res.labels, fingers)))
    return [100.0 * float(np.mean(hits[n])) for n in range(2, 6)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2000, help="labelling frames per set")
    ap.add_argument("--candidates", nargs="*", default=list(CANDIDATES),
                    choices=list(CANDIDATES))
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    sets = validation_sets()
    base = training_set(TRAIN_PARTS)
    out: dict[str, dict] = {}
    for name in a.candidates:
        parts = CANDIDATES[name]
        model = fit_model(base, degrees=("quadratic",),
                          encoder_data=None if parts == TRAIN_PARTS else training_set(parts))
        quad = model.encoder("quadratic")
        lab = FingerLabeller(quad, model.reference_poses[np.sort(np.random.default_rng(0)
                             .choice(len(model.reference_poses), 4000, False))],
                             layout=model.layout)
        res: dict[str, dict] = {"ridge": float(model.meta["ridge_quadratic"])}
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
