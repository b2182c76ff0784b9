"""Validation of the subject calibration (issue 13; analysis, never shipped).

Calibrates (:func:`hand_capture.tracking.calibration.calibrate`) ``N`` validation subjects of
the suite's own generators only (nothing of :mod:`hand_capture.evaldata`, no held-out row):
the suite's mesh, z-buffer rasteriser and depth-noise model at 320x240 (the calibration
poses of :func:`render_calibration_frames`), shapes ``sample_shape`` of seed ``900 + i`` with
the global scale drawn uniformly in 0.85-1.15, and two subjects in three with another
surface on their skeleton (:class:`SurfaceVariant`: palm -1..+3 mm, fingers -1..+1.5 mm,
wrist stub 0..20 mm; subjects ``i % 3 == 0`` keep the suite's own surface).

Printed: per subject the true / fitted global scale and the mean relative bone-length error
(the bench's ``_bone_err_pct``: mean over the 16 bones of |fit - true| / true); the mean and
worst over subjects, per family; the signed bias per bone (fit - true) / true [%] averaged
over the subjects, for the palm, the thumb's three bones and the fingers' proximal / middle /
distal bones (the distal bone runs to the tip; the shape model's bone scales move a digit's
three bones together, so the levels agree), per digit and per family (own surface /
variants); the mean distance of the 21 rest-pose keypoints from the truth's [mm] (the
bench's ``kp err fit``, wrist at the origin for both); and the time per calibration.

    PYTHONPATH=. .venv/bin/python scripts/calibration_validation.py [-n 36] \\
        [--set rounds=20] [--config robust_mm=6] [--forearm [--sleeves
        [--sleeve-wider 0.01 0.025] [--sleeve-start 0.04 0.08]]] [--artifacts]

``--forearm`` renders every subject with the training renders' forearm (radius 24-40 mm,
length 0.25-0.5 m, bent +-0.4 rad, drawn from a generator of its own: the subjects' shapes,
surfaces and noise stay those without it); ``--sleeves`` adds a sleeve to every second one
(by default the hard validation set's: 10-25 mm wider than the arm, from 40-80 mm past the
wrist). ``--set KEY=VALUE`` overrides a keyword argument of ``calibrate`` (value read as YAML),
``--config KEY=VALUE`` a :class:`TrackerConfig` field (``config.from_overrides``). The last
line printed is the JSON of the figures.
"""

from __future__ import annotations

import argparse
import inspect
import json
import sys
import time

import numpy as np
import yaml

from hand_capture.bench._tracking_heldout import (
    SLEEVE_START_M,
    SLEEVE_WIDER_M,
    SurfaceVariant,
    _bone_err_pct,
    with_artifacts,
)
from hand_capture.config import from_overrides
from hand_capture.errors import ConfigError
from hand_capture.model import N_DOF, HandModel, sample_shape
from hand_capture.model.joints import FINGERS
from hand_capture.model.skeleton import LEVELS
from hand_capture.tracking.calibration import calibrate, render_calibration_frames
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.train import default_intrinsics, draw_forearm, forearm_mesh

#: first subject seed (the bench's calibration section uses 300+, the tracking sets < 100)
SEED0 = 900
#: bone groups of the bias table: name -> bone indices (palm 0, then 3 per finger)
GROUPS: dict[str, list[int]] = {
    "palm": [0],
    **{f"thumb {lvl}": [int(LEVELS[k, 0])] for k, lvl in enumerate(("prox", "mid", "dist"))},
    **{f"fingers {lvl}": [int(b) for b in LEVELS[k, 1:]]
       for k, lvl in enumerate(("prox", "mid", "dist"))},
}


def subject(i: int) -> tuple[HandModel, SurfaceVariant | None, np.random.Generator]:
    """Validation subject ``i``: its true model, its surface (None = the suite's own) and the
    generator of its sensor noise."""
    rng = np.random.default_rng(SEED0 + i)
    shape = sample_shape(rng)
    shape = shape.with_params(global_scale=float(rng.uniform(0.85, 1.15)))
    variant = SurfaceVariant.sample(rng) if i % 3 else None
    return HandModel(shape), variant, rng


def subject_meshes(true: HandModel, variant: SurfaceVariant | None, i: int, forearm: bool,
                   sleeves: tuple[tuple[float, float], tuple[float, float]] | None = None):
    """``q (27,) -> Mesh | list[Mesh]`` of subject ``i`` (None: the model's own mesh alone);
    with ``forearm`` the training renders' forearm (:func:`forearm_mesh` of
    :func:`draw_forearm`, from its own generator so that the subjects' shapes, surfaces and
    noise are those without it) is rendered with the hand."""
    from hand_capture.cameras.render import Mesh

    hand = variant.mesh_fn(true) if variant is not None else None
    if not forearm:
        return hand
    g = np.random.default_rng(SEED0 + 5000 + i)
    radius, length, bend = draw_forearm(g)
    # with ``sleeves`` ((min, max) radius beyond the arm's, (min, max) start past the wrist
    # [m]), odd subjects also wear a sleeve
    sleeve = ((radius + float(g.uniform(*sleeves[0])), float(g.uniform(*sleeves[1])))
              if sleeves is not None and i % 2 else None)

    def fn(q: np.ndarray) -> list:
        h = hand(q) if hand is not None else Mesh(true.vertices(q), true.faces, 1, closed=True)
        out = [h, forearm_mesh(true, q, radius, length, bend)]
        if sleeve is not None:
            out.append(forearm_mesh(true, q, sleeve[0], length, bend, start=sleeve[1]))
        return out

    return fn


def parse_sets(items: list[str]) -> dict:
    """``KEY=VALUE`` strings -> keyword arguments of ``calibrate`` (values read as YAML).

    Raises:
        ConfigError: an item without ``=`` or a key that ``calibrate`` does not take.
    """
    keys = sorted(set(inspect.signature(calibrate).parameters)
                  - {"frames", "finger_poses", "model", "config"})
    out = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or key not in keys:
            raise ConfigError(f"bad --set {item!r}; keys: {keys}")
        v = yaml.safe_load(text)
        out[key] = tuple(v) if isinstance(v, list) else v
    return out


def run(n: int, kwargs: dict, cfg: TrackerConfig, verbose: bool = True,
        forearm: bool = False,
        sleeves: tuple[tuple[float, float], tuple[float, float]] | None = None,
        artifacts: bool = False) -> dict:
    """Calibrate the ``n`` validation subjects (``forearm``: each with a forearm in view;
    ``sleeves``: every second one also in a sleeve, see :func:`subject_meshes`;
    ``artifacts``: the suite's stereo artifacts on every frame, :func:`~hand_capture.
    bench._tracking_heldout.with_artifacts`, from a generator of their own); returns the
    figures (see the module doc)."""
    base = HandModel()
    intr = default_intrinsics()
    errs: dict[str, list[float]] = {"own": [], "variant": []}
    bias, times, is_var, kp_err = [], [], [], []
    for i in range(n):
        true, variant, rng = subject(i)
        mesh_fn = subject_meshes(true, variant, i, forearm, sleeves)
        frames = render_calibration_frames(true, intr, rng, mesh_fn=mesh_fn)
        if artifacts:
            frames = with_artifacts(frames, SEED0 + 7000 + i)
        t0 = time.perf_counter()
        cal = calibrate(frames, model=base, config=cfg, **kwargs)
        times.append(time.perf_counter() - t0)
        fit = base.with_shape(cal.shape)
        e = _bone_err_pct(fit, true)
        errs["variant" if variant else "own"].append(e)
        rel = (np.asarray(fit.bone_lengths) / np.asarray(true.bone_lengths) - 1.0) * 100.0
        bias.append(rel)
        is_var.append(variant is not None)
        q0 = np.zeros(N_DOF)
        kp_err.append(float(np.linalg.norm(fit.joint_positions(q0) - true.joint_positions(q0),
                                           axis=1).mean()) * 1e3)
        if verbose:
            surf = (f"palm {variant.palm_mm:+.1f} fing {variant.finger_mm:+.1f} stub "
                    f"{variant.stub_m * 1e3:4.1f}" if variant else "own surface")
            fing = rel[LEVELS[:, 1:].ravel()].mean()
            print(f"{i:3d} s_g {true.shape.global_scale:.3f} fit {cal.shape.global_scale:.3f} "
                  f"err {e:5.2f} % palm {rel[0]:+5.2f} % fingers {fing:+5.2f} % thumb "
                  f"{rel[LEVELS[:, 0]].mean():+5.2f} % {cal.status[:20]:20s} "
                  f"{times[-1]:.2f} s  {surf}", flush=True)
    bias_a = np.array(bias)
    allerr = errs["own"] + errs["variant"]
    out = {"n": n, "mean": float(np.mean(allerr)), "worst": float(np.max(allerr)),
           "mean_own": float(np.mean(errs["own"])) if errs["own"] else float("nan"),
           "mean_variant": float(np.mean(errs["variant"])) if errs["variant"] else float("nan"),
           "worst_variant": float(np.max(errs["variant"])) if errs["variant"] else float("nan"),
           "kp_rest_mm": float(np.mean(kp_err)), "kp_rest_mm_worst": float(np.max(kp_err)),
           "time_s": float(np.mean(times))}
    for g, bones in GROUPS.items():
        out[f"bias_{g.replace(' ', '_')}"] = float(bias_a[:, bones].mean())
        out[f"absbias_{g.replace(' ', '_')}"] = float(np.abs(bias_a[:, bones]).mean())
    for f, fname in enumerate(FINGERS):
        out[f"bias_{fname}"] = float(bias_a[:, LEVELS[:, f]].mean())
    fam = np.array(is_var)
    for name, rows in (("own", ~fam), ("variant", fam)):
        for g, bones in (("palm", [0]), ("thumb", LEVELS[:, 0]),
                         ("fingers", LEVELS[:, 1:].ravel())):
            out[f"bias_{g}_{name}"] = (float(bias_a[rows][:, bones].mean()) if rows.any()
                                       else float("nan"))
    if verbose:
        print(f"\nbone-length error [%]: mean {out['mean']:.2f} worst {out['worst']:.2f}  "
              f"(own surface {out['mean_own']:.2f}, variants {out['mean_variant']:.2f} / worst "
              f"{out['worst_variant']:.2f}); rest-pose keypoints {out['kp_rest_mm']:.2f} mm "
              f"(worst {out['kp_rest_mm_worst']:.2f}); {out['time_s']:.2f} s a calibration")
        print("signed bias (fit - true) / true [%], mean over subjects (mean |.| in brackets):")
        for g in GROUPS:
            k = g.replace(" ", "_")
            print(f"  {g:14s} {out['bias_' + k]:+6.2f} ({out['absbias_' + k]:.2f})")
        print("  per digit: " + ", ".join(f"{f} {out['bias_' + f]:+.2f}" for f in FINGERS))
        for name in ("own", "variant"):
            print(f"  {name}: " + ", ".join(f"{g} {out[f'bias_{g}_{name}']:+.2f}"
                                        for g in ("palm", "thumb", "fingers")))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=36, help="validation subjects")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a keyword argument of calibrate (YAML value)")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="a TrackerConfig field")
    ap.add_argument("-q", "--quiet", action="store_true", help="no per-subject lines")
    ap.add_argument("--forearm", action="store_true",
                    help="every subject with a forearm in view (the training renders' kind)")
    ap.add_argument("--sleeves", action="store_true",
                    help="with --forearm: every second subject also in a sleeve")
    ap.add_argument("--sleeve-wider", type=float, nargs=2, default=SLEEVE_WIDER_M,
                    metavar=("MIN", "MAX"), help="sleeve radius beyond the arm's [m]")
    ap.add_argument("--sleeve-start", type=float, nargs=2, default=SLEEVE_START_M,
                    metavar=("MIN", "MAX"), help="where the sleeve starts past the wrist [m]")
    ap.add_argument("--artifacts", action="store_true",
                    help="the suite's stereo artifacts (tracking/augment.py) on every frame")
    args = ap.parse_args(argv)
    try:
        kwargs = parse_sets(args.set)
        cfg = from_overrides(TrackerConfig, args.config)
    except ConfigError as e:
        print(e, file=sys.stderr)
        return 2
    sleeves = ((tuple(args.sleeve_wider), tuple(args.sleeve_start)) if args.sleeves
               else None)
    out = run(args.n, kwargs, cfg, not args.quiet, args.forearm, sleeves, args.artifacts)
    out["forearm"] = args.forearm
    out["sleeves"] = [args.sleeve_wider, args.sleeve_start] if args.sleeves else False
    out["artifacts"] = args.artifacts
    out["set"] = args.set
    out["config"] = args.config
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
