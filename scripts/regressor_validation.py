"""Validation of a trained depth-tracker regressor (issue 13; analysis, never shipped).

Scores a regressor model (``.npz`` of :meth:`HandRegressor.save`) on VALIDATION data of the
suite's own generators only (nothing of :mod:`hand_capture.evaldata`, no held-out row):

* **candidates** (regressor alone, cheap): fresh renders of the training generator
  (:func:`~hand_capture.tracking.train.render_samples`) of the validation shapes 21-24
  (``sample_shape(default_rng(seed))``, as the synthetic camera's ``shape_seed``), the
  validation family's surface offsets (palm -1..+3 mm, fingers -1..+1.5 mm), palm tilt up to
  80 deg and a third of the poses pitched with the fingers 20-60 deg towards the camera (the
  held-out diagnosis' failing views), render seeds unlike any training seed. Per frame the
  regressor's candidates (eq. II.17 palm modes, each with the finger cascade of eq. II.18)
  on the true shape; reported: the best mode's palm keypoint error (6 palm keypoints), the
  finger keypoint error (15 keypoints) of that candidate, the best candidate's whole-hand
  error (mean of 21 keypoints) and the share of frames where it is under 20 mm; all frames
  and those with the fingers >= 20 deg towards the camera.
* **tracker** (product settings, the regressor's candidates in the hybrid tracker): the
  same renders, each from a reset tracker with the true shape (``ff_*``: no previous pose,
  so the regressor's candidates decide); the surface validation family
  (:func:`surface_validation_section`), the capsule validation family
  (:func:`capsule_validation_section`) and the forearm validation
  (:func:`forearm_validation_section`), product only, both the bench's sections.

    PYTHONPATH=. .venv/bin/python scripts/regressor_validation.py data/tracker/regressor.npz \\
        out/other.npz [--quick] [--candidates-only] [--frames 600]

The last line printed is the JSON of every model's figures (model path -> key -> value).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from hand_capture.bench._tracking_heldout import (
    ARM_VAL_SEEDS,
    capsule_validation_section,
    forearm_validation_section,
    surface_validation_section,
)
from hand_capture.errors import InputError
from hand_capture.model import HandModel, sample_shape
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.regressor import (
    FINGER_KP,
    PALM_KP,
    HandRegressor,
    ModelFrames,
)
from hand_capture.tracking.train import (
    TrainingSample,
    default_intrinsics,
    finger_pitch_deg,
    render_samples,
)

#: seed of the validation renders (training uses its own seed, 0 for the shipped model)
RENDER_SEED = 90_021
#: fingers at least this far towards the camera count as "towards" [deg]
TOWARDS_DEG = 20.0


def validation_renders(n: int, seed: int = RENDER_SEED
                       ) -> tuple[list[HandModel], list[TrainingSample]]:
    """``n`` segmented noisy renders of the validation shapes (see the module doc).

    Returns:
        The shape models (:data:`ARM_VAL_SEEDS` order) and the samples (``shape_index``
        into them; ``pose`` the truth (27,)).
    """
    if n < 1:
        raise InputError(f"need at least one validation render, got {n}")
    base = HandModel()
    models = [base.with_shape(sample_shape(np.random.default_rng(s))) for s in ARM_VAL_SEEDS]
    samples = render_samples(n, np.random.default_rng(seed), models, default_intrinsics(),
                             surface_mm=(-1.0, 1.5), max_tilt_deg=80.0, towards_prob=1 / 3)
    return models, samples


def candidate_quality(reg: HandRegressor, models: list[HandModel],
                      samples: list[TrainingSample], n_modes: int) -> dict[str, float]:
    """The regressor's candidates on ``samples`` (see the module doc), errors in mm.

    Args:
        reg: the regressor.
        models: the true shapes (indexed by ``TrainingSample.shape_index``).
        samples: the renders.
        n_modes: palm modes per frame (the tracker's ``n_modes``).
    """
    intr = default_intrinsics()
    frames = [ModelFrames(m) for m in models]
    palm, finger, whole, within, pitch = [], [], [], [], []
    t = time.process_time()
    for s in samples:
        m = models[s.shape_index]
        cands = reg.predict(frames[s.shape_index], reg.lookup(s.crop, s.u0, s.v0, intr),
                            s.points, n_modes)
        kp_true = m.joint_positions(s.pose)
        err = np.array([np.linalg.norm(m.joint_positions(c) - kp_true, axis=1)
                        for c in cands]) * 1e3                      # (modes, 21) [mm]
        ep = err[:, PALM_KP].mean(axis=1)
        b = int(np.argmin(ep))
        palm.append(ep[b])
        finger.append(err[b, FINGER_KP.reshape(-1)].mean())
        whole.append(err.mean(axis=1).min())
        within.append(bool(err.mean(axis=1).min() < 20.0))
        pitch.append(finger_pitch_deg(m, s.pose))
    cpu_ms = (time.process_time() - t) / len(samples) * 1e3
    tw = np.array(pitch) >= TOWARDS_DEG
    out: dict[str, float] = {"cand_frames": float(len(samples)),
                             "cand_towards_frames": float(tw.sum()),
                             "cand_cpu_ms": cpu_ms}
    for tag, sel in (("", np.ones(len(samples), bool)), ("_towards", tw)):
        if not sel.any():
            continue
        out.update({f"cand{tag}_palm_mm": float(np.mean(np.array(palm)[sel])),
                    f"cand{tag}_finger_mm": float(np.mean(np.array(finger)[sel])),
                    f"cand{tag}_best_mm": float(np.mean(np.array(whole)[sel])),
                    f"cand{tag}_under20": float(np.mean(np.array(within)[sel]))})
    return out


def first_frames(reg: HandRegressor, models: list[HandModel], samples: list[TrainingSample],
                 config: TrackerConfig) -> dict[str, float]:
    """The product tracker on each render from a reset tracker (no previous pose: the
    regressor's candidates, refined and selected, decide), the true shape: mean keypoint
    error [mm], success@20 (worst keypoint under 20 mm) and CPU ms per frame, for all
    frames and those with the fingers towards the camera (``ff`` keys)."""
    from hand_capture.tracking.hybrid import HybridTracker

    intr = default_intrinsics()
    trackers = [HybridTracker(m, config, reg) for m in models]
    errs, cpu, pitch = [], [], []
    for s in samples:
        tr = trackers[s.shape_index]
        depth = np.zeros((intr.height, intr.width), np.float32)
        h, w = s.crop.shape
        depth[s.v0:s.v0 + h, s.u0:s.u0 + w] = s.crop
        tr.reset()
        c0 = time.process_time()
        r = tr.process(depth, intr)
        cpu.append(time.process_time() - c0)
        m = models[s.shape_index]
        errs.append(np.linalg.norm(m.joint_positions(r.pose) - m.joint_positions(s.pose),
                                   axis=1) * 1e3)
        pitch.append(finger_pitch_deg(m, s.pose))
    e = np.array(errs)
    out = {"ff_cpu_ms": float(np.mean(cpu)) * 1e3}
    for tag, sel in (("", np.ones(len(e), bool)), ("_towards", np.array(pitch) >= TOWARDS_DEG)):
        if sel.any():
            out.update({f"ff{tag}_mean_mm": float(e[sel].mean()),
                        f"ff{tag}_success_20mm": float(np.mean(e[sel].max(axis=1) < 20.0))})
    return out


def tracker_validation(reg: HandRegressor, quick: bool) -> dict[str, float]:
    """The product tracker with ``reg`` on the surface, capsule and forearm validation
    families (the bench's sections, product settings only)."""
    cfg = TrackerConfig()
    out = surface_validation_section(reg, cfg, quick, variants={"product": ("", cfg)})
    out.update(capsule_validation_section(reg, cfg, quick))
    out.update(forearm_validation_section(reg, cfg, quick, product_only=True))
    return out


def main(argv: list[str] | None = None) -> int:
    from hand_capture.cameras.threads import limit_blas_threads

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="regressor .npz files")
    ap.add_argument("--frames", type=int, default=600, help="validation renders")
    ap.add_argument("--quick", action="store_true", help="the bench sections' quick sets")
    ap.add_argument("--candidates-only", action="store_true")
    a = ap.parse_args(argv)
    limit_blas_threads(1)
    models, samples = validation_renders(a.frames)
    n_modes = TrackerConfig().n_modes
    res: dict[str, dict[str, float]] = {}
    for path in a.models:
        reg = HandRegressor.load(path)
        t = time.perf_counter()
        r = candidate_quality(reg, models, samples, n_modes)
        if not a.candidates_only:
            r.update(first_frames(reg, models, samples, TrackerConfig()))
            r.update(tracker_validation(reg, a.quick))
        r["eval_s"] = time.perf_counter() - t
        res[path] = r
        print(path, {k: round(v, 3) for k, v in r.items()}, flush=True)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
