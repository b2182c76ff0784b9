"""Build the grasp database and fit the closing-phase models: ``data/grasp/``.

    hand-suite train grasps [--quick] [--out DIR] [--seed N] [--demos N] [--attempts N]
                            [--modes MODE ...] [--refit]

1. :func:`hand_control.grasp.generate.build_database`: demonstrations of every grip mode,
   each checked in the simulation (the composite controller lifts the object), written to
   ``database.npz`` (the dissertation's Vicon database is not available; see
   :mod:`hand_control.grasp.database`);
2. per grip mode, :func:`hand_control.grasp.closing.fit_closing_model` on the closing segments
   (DTW, functional PCA eq. III.1-III.2, GMM prior), written to ``closing_<mode>.npz``;
3. ``train_report.json``: what was kept (and why attempts were rejected), the models' sizes,
   their reconstruction error on the training motions and, leave-one-out, on demonstrations
   each model was not fitted to.

Same seed, same database and model files, byte for byte (every random draw is seeded; numpy
writes fixed time stamps into the ``.npz`` containers). ``--quick`` builds a small one (4
demonstrations per mode, about 2 min) into ``out/grasp_quick`` unless ``--out`` is given,
leaving the shipped one alone; the shipped one is the default (12 per mode, at most 60
attempts).
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
    load_grasp_database,
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


def held_out_error(records: list[GraspRecord], seed: int = 0) -> dict[str, float]:
    """Leave-one-out figures of one grip mode's model: each demonstration encoded / decoded
    by the model fitted on the others (motions it was not built from): mean finger-angle
    error [rad], mean wrist error [mm], and the mean ``-ln pr`` of the held-out parameters
    beside that of the training ones."""
    fe, we, de, nlp_out, nlp_in = [], [], [], [], []
    for i, r in enumerate(records):
        rest = records[:i] + records[i + 1:]
        if len(rest) < 3:
            return {}
        m = fit_closing_model(r.grip_mode, [x.closing for x in rest], r.fps, seed=seed)
        e = reconstruction_error(m, r.closing)
        fe.append(e["finger_mean_rad"])
        we.append(e["wrist_mean_m"] * 1e3)
        de.append(e["duration_rel"])
        nlp_out.append(float(m.neg_log_prior(m.encode(r.closing))))
        nlp_in.append(float(np.mean(m.neg_log_prior(m.train_params))))
    return {"finger_err_rad": float(np.mean(fe)), "wrist_err_mm": float(np.mean(we)),
            "duration_err": float(np.mean(de)),
            "neg_log_prior": float(np.median(nlp_out)),
            "neg_log_prior_train": float(np.median(nlp_in))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="hand-suite train grasps", description=__doc__.split(
        "\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="a small database (4 per mode), by default into out/grasp_quick")
    ap.add_argument("--out", type=Path, default=None,
                    help="output folder (default: the shipped data/grasp)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--demos", type=int, default=None, help="demonstrations per grip mode")
    ap.add_argument("--attempts", type=int, default=None, help="attempts per grip mode")
    ap.add_argument("--refit", action="store_true",
                    help="fit the closing models to the database already in --out (no "
                         "simulation)")
    ap.add_argument("--modes", nargs="+", default=list(GRIP_MODES), choices=GRIP_MODES,
                    metavar="MODE", help="grip modes to build (default: all ten)")
    a = ap.parse_args(argv)
    demos = a.demos or (4 if a.quick else 12)
    attempts = a.attempts or 5 * demos
    cfg = GenConfig(demos_per_mode=demos, max_attempts=attempts, seed=a.seed)
    # --quick builds a small database: it never replaces the shipped one unless --out says so
    out = a.out or (Path("out") / "grasp_quick" if a.quick else default_grasp_dir())
    print(f"writing {out}", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    reasons: dict[str, list[str]] = {}
    if a.refit:
        records = [r for r in load_grasp_database(out) if r.grip_mode in a.modes]
        stats = {g: (sum(r.grip_mode == g for r in records), 0) for g in a.modes}
    else:
        records, stats = build_database(
            cfg, tuple(a.modes), progress=lambda s: print(s, file=sys.stderr, flush=True),
            reasons=reasons)
        save_grasp_database(records, out / DATABASE_FILE)
    t_db = time.perf_counter() - t0
    models = fit_models(records, seed=a.seed)
    for g in GRIP_MODES:  # no stale model of a mode this run did not fit
        f = out / model_file(g)
        if g in models:
            models[g].save(f)
        elif f.exists() and g in a.modes:
            f.unlink()
    old: dict = {}
    if a.refit and (out / "train_report.json").is_file():  # the build's own figures stay
        old = json.loads((out / "train_report.json").read_text())
        t_db = float(old.get("database_s", t_db))
        for g in a.modes:
            o = old.get("modes", {}).get(g, {})
            stats[g] = (stats[g][0], int(o.get("attempts", 0)))
            reasons[g] = [k for k, n in o.get("rejected", {}).items() for _ in range(n)]
    report = {"seed": old.get("seed", a.seed), "demos_per_mode": old.get("demos_per_mode", demos),
              "attempts_per_mode": old.get("attempts_per_mode", attempts),
              "database_s": round(t_db, 1), "records": len(records), "modes": {}}
    print(f"{'grip mode':<24}{'kept':>5}{'tries':>6}{'T':>4}{'M':>3}{'K':>3}{'C':>3}"
          f"{'fing rad':>9}{'wrist mm':>9}{'dur %':>6}{'LOO rad':>9}{'LOO mm':>8}"
          f"{'LOO dur':>8}{'-lnp tr':>8}{'-lnp LOO':>9}")
    for g in a.modes:
        kept, tries = stats.get(g, (0, 0))
        row = {"kept": kept, "attempts": tries, "rejected": _count(reasons.get(g, []))}
        if g in models:
            m = models[g]
            errs = [reconstruction_error(m, r.closing) for r in records if r.grip_mode == g]
            loo = held_out_error([r for r in records if r.grip_mode == g], seed=a.seed)
            row.update(n_frames=m.n_frames, n_alpha=m.n_alpha, n_gamma=m.n_gamma,
                       mixture=len(m.gmm_weights),
                       finger_err_rad=float(np.mean([e["finger_mean_rad"] for e in errs])),
                       wrist_err_mm=1e3 * float(np.mean([e["wrist_mean_m"] for e in errs])),
                       duration_err=float(np.mean([e["duration_rel"] for e in errs])),
                       held_out=loo)
            nan = float("nan")
            print(f"{g:<24}{kept:>5}{tries:>6}{m.n_frames:>4}{m.n_alpha:>3}{m.n_gamma:>3}"
                  f"{len(m.gmm_weights):>3}{row['finger_err_rad']:>9.4f}"
                  f"{row['wrist_err_mm']:>9.2f}{100 * row['duration_err']:>6.1f}"
                  f"{loo.get('finger_err_rad', nan):>9.4f}"
                  f"{loo.get('wrist_err_mm', nan):>8.2f}"
                  f"{100 * loo.get('duration_err', nan):>8.1f}"
                  f"{loo.get('neg_log_prior_train', nan):>8.1f}"
                  f"{loo.get('neg_log_prior', nan):>9.1f}")
        else:
            print(f"{g:<24}{kept:>5}{tries:>6}   (too few demonstrations for a model)")
        report["modes"][g] = row
    (out / "train_report.json").write_text(json.dumps(report, indent=1, sort_keys=True) + "\n")
    fitted = [report["modes"][g] for g in a.modes if g in models]

    def _mean(key: str, held: bool = False) -> float | None:
        v = [(r["held_out"] if held else r).get(key) for r in fitted]
        v = [x for x in v if x is not None]
        return round(float(np.mean(v)), 4) if v else None

    print(json.dumps({"train": "grasps", "records": len(records), "models": len(models),
                      "database_s": round(t_db, 1),
                      "finger_err_rad": _mean("finger_err_rad"),
                      "finger_err_rad_heldout": _mean("finger_err_rad", True),
                      "wrist_err_mm_heldout": _mean("wrist_err_mm", True)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
