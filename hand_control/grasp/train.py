"""Build the grasp database and fit the closing-phase models: ``data/grasp/``.

    hand-suite train grasps [--quick] [--out DIR] [--seed N] [--demos N] [--attempts N]
                            [--modes MODE ...]

1. :func:`hand_control.grasp.generate.build_database`: demonstrations of every grip mode,
   each checked in the simulation (the composite controller lifts the object), written to
   ``database.npz`` (the dissertation's Vicon database is not available; see
   :mod:`hand_control.grasp.database`);
2. per grip mode, :func:`hand_control.grasp.closing.fit_closing_model` on the closing segments
   (DTW, functional PCA eq. III.1-III.2, GMM prior), written to ``closing_<mode>.npz``;
3. ``train_report.json``: what was kept, the models' sizes and their reconstruction error on
   the training motions.

Same seed, same database and models (every random draw is seeded; the arrays are equal, the
zip containers' time stamps are not). ``--quick`` builds a small one (4 demonstrations per
mode) in a few minutes; the shipped one is the default (12 per mode, at most 60 attempts).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from hand_control.grasp.closing import ClosingModel, fit_closing_model, resample
from hand_control.grasp.database import (
    DATABASE_FILE,
    GRIP_MODES,
    GraspRecord,
    default_grasp_dir,
    model_file,
    save_grasp_database,
)
from hand_control.grasp.generate import GenConfig, build_database

__all__ = ["fit_models", "main", "mean_contacts", "reconstruction_error"]


def mean_contacts(records: list[GraspRecord]) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """The grip mode's contact points: per bone touched in at least half of the
    demonstrations, the mean contact point in the bone's frame."""
    by_bone: dict[str, list[np.ndarray]] = {}
    for r in records:
        seen: dict[str, list[tuple[float, ...]]] = {}
        for b, p in r.contacts_local:
            seen.setdefault(b, []).append(p)
        for b, ps in seen.items():
            by_bone.setdefault(b, []).append(np.mean(ps, axis=0))
    out = [(b, tuple(float(v) for v in np.mean(ps, axis=0))) for b, ps in by_bone.items()
           if len(ps) * 2 >= len(records)]
    return tuple(sorted(out))


def reconstruction_error(model: ClosingModel, motion: np.ndarray) -> dict[str, float]:
    """encode -> decode of one closing motion: mean / max absolute joint-angle error [rad]
    over the finger DoFs, mean wrist position error [m], relative duration error."""
    p = model.encode(motion)
    dec = model.decode(p)
    ref = resample(motion, model.n_frames)
    fing = np.abs(dec[:, 6:] - ref[:, 6:])
    return {"finger_mean_rad": float(fing.mean()), "finger_max_rad": float(fing.max()),
            "wrist_mean_m": float(np.linalg.norm(dec[:, :3] - ref[:, :3], axis=1).mean()),
            "duration_rel": float(abs(model.duration(p) * model.fps
                                      - (motion.shape[0] - 1)) / (motion.shape[0] - 1))}


def fit_models(records: list[GraspRecord], seed: int = 0) -> dict[str, ClosingModel]:
    """A closing model per grip mode that has at least 3 demonstrations."""
    models = {}
    for g in GRIP_MODES:
        rs = [r for r in records if r.grip_mode == g]
        if len(rs) < 3:
            continue
        models[g] = fit_closing_model(g, [r.closing for r in rs], rs[0].fps,
                                      contacts=mean_contacts(rs), seed=seed)
    return models


def _count(reasons: list[str]) -> dict[str, int]:
    """Rejections by kind (the text before any detail in parentheses)."""
    out: dict[str, int] = {}
    for r in reasons:
        k = r.split(" (")[0]
        out[k] = out.get(k, 0) + 1
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="hand-suite train grasps", description=__doc__.split(
        "\n")[0])
    ap.add_argument("--quick", action="store_true", help="a small database (4 per mode)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (data/grasp)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--demos", type=int, default=None, help="demonstrations per grip mode")
    ap.add_argument("--attempts", type=int, default=None, help="attempts per grip mode")
    ap.add_argument("--modes", nargs="+", default=list(GRIP_MODES), choices=GRIP_MODES,
                    metavar="MODE", help="grip modes to build (default: all ten)")
    a = ap.parse_args(argv)
    demos = a.demos or (4 if a.quick else 12)
    attempts = a.attempts or 5 * demos
    cfg = GenConfig(demos_per_mode=demos, max_attempts=attempts, seed=a.seed)
    out = a.out or default_grasp_dir()
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    reasons: dict[str, list[str]] = {}
    records, stats = build_database(cfg, tuple(a.modes),
                                    progress=lambda s: print(s, file=sys.stderr, flush=True),
                                    reasons=reasons)
    t_db = time.perf_counter() - t0
    save_grasp_database(records, out / DATABASE_FILE)
    models = fit_models(records, seed=a.seed)
    for g in GRIP_MODES:  # no stale model of a mode this run did not fit
        f = out / model_file(g)
        if g in models:
            models[g].save(f)
        elif f.exists() and g in a.modes:
            f.unlink()
    report = {"seed": a.seed, "demos_per_mode": demos, "attempts_per_mode": attempts,
              "database_s": round(t_db, 1), "records": len(records), "modes": {}}
    print(f"{'grip mode':<26}{'kept':>6}{'tries':>6}{'T':>5}{'M':>4}{'K':>4}{'C':>3}"
          f"{'fing err':>10}{'wrist mm':>10}")
    for g in a.modes:
        kept, tries = stats.get(g, (0, 0))
        row = {"kept": kept, "attempts": tries, "rejected": _count(reasons.get(g, []))}
        if g in models:
            m = models[g]
            errs = [reconstruction_error(m, r.closing) for r in records if r.grip_mode == g]
            row.update(n_frames=m.n_frames, n_alpha=m.n_alpha, n_gamma=m.n_gamma,
                       mixture=len(m.gmm_weights),
                       finger_err_rad=float(np.mean([e["finger_mean_rad"] for e in errs])),
                       wrist_err_mm=1e3 * float(np.mean([e["wrist_mean_m"] for e in errs])))
            print(f"{g:<26}{kept:>6}{tries:>6}{m.n_frames:>5}{m.n_alpha:>4}{m.n_gamma:>4}"
                  f"{len(m.gmm_weights):>3}{row['finger_err_rad']:>10.4f}"
                  f"{row['wrist_err_mm']:>10.2f}")
        else:
            print(f"{g:<26}{kept:>6}{tries:>6}   (too few demonstrations for a model)")
        report["modes"][g] = row
    (out / "train_report.json").write_text(json.dumps(report, indent=1, sort_keys=True) + "\n")
    print(json.dumps({"train": "grasps", "records": len(records),
                      "models": len(models), "database_s": round(t_db, 1)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
