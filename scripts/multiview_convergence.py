"""Validation of the multi-view local optimiser's convergence on the tracker's own mesh.

Renders the bench's studio sequences (``fingers``, ``ball``, ``box``;
:mod:`hand_capture.bench.multiview`'s rig and renderer) at VALIDATION render seeds (default
7 and 8; the bench uses 1, 2 and 5) with the tracker's own mesh, with and without seed 002's
100 circles, and tracks them with the bench's own loop (``_track``: from the first frame's
truth, the circles' flow features left out) at the given LO seeds, with ``--lo KEY=VALUE``
overriding ``LOConfig`` (e.g. ``iterations=25``). Prints the mean joint error [mm] of every
sequence x render seed x circles x LO seed and the seconds a frame; ``--diag`` adds, per
sequence, the error of the estimate each frame started from (the previous frame's) and after
the solve, the error after each outer iteration (mean over frames) and the error by keypoint
(wrist, fingertips, per hand); ``--start-truth`` starts every frame's solve at its truth.
Renders are cached under ``--cache`` (default ``out/mv_convergence``). Last line: one JSON
object.

    PYTHONPATH=. python scripts/multiview_convergence.py [--seeds 7 8] [--lo-seeds 0 1]
        [--sequences fingers ball box] [--frames 10] [--circles 100 0] [--diag]
        [--start-truth] [--lo iterations=25 ...]
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

#: keypoints 0..20 of a hand: the wrist and the fingertips (thumb .. little)
WRIST, TIPS = 0, (4, 8, 12, 16, 20)


def _frames(name: str, n: int, rig: object, seed: int, circles: int, cache: Path,
            circle_scale: float = 1.0) -> list:
    """The rendered frames of sequence ``name`` (own mesh), from the cache when there."""
    from hand_capture.multiview.sequences import make_sequence, render_sequence

    tag = "" if circle_scale == 1.0 else f"_r{circle_scale:.4f}"
    f = cache / f"{name}_{n}_s{seed}_c{circles}{tag}.pkl"
    if f.exists():
        with f.open("rb") as fh:
            return pickle.load(fh)
    fr = list(render_sequence(make_sequence(name, n), rig, surface="own", circles=circles,
                              circle_scale=circle_scale,
                              seed=seed))
    cache.mkdir(parents=True, exist_ok=True)
    with f.open("wb") as fh:
        pickle.dump(fr, fh)
    return fr


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "osmesa")
    from hand_capture.bench.multiview import RIG, _track
    from hand_capture.config import from_overrides
    from hand_capture.multiview.lo import LOConfig
    from hand_capture.multiview.rig import load_rig
    from hand_capture.multiview.sequences import make_sequence

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8])
    ap.add_argument("--lo-seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--sequences", nargs="+", default=["fingers", "ball", "box"])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--circles", type=int, nargs="+", default=[100, 0])
    ap.add_argument("--circle-scale", type=float, default=1.0,
                    help="the circles' radii times this (1/3: seed 002's image share at 640 px)")
    ap.add_argument("--diag", action="store_true")
    ap.add_argument("--start-truth", action="store_true")
    ap.add_argument("--flow-truth", action="store_true",
                    help="oracle: each frame's flow from the previous frame's truth")
    ap.add_argument("--cache", default="out/mv_convergence")
    ap.add_argument("--lo", nargs="*", default=[], help="LOConfig overrides KEY=VALUE")
    a = ap.parse_args(argv)
    base = from_overrides(LOConfig, a.lo)
    rig = load_rig(RIG)
    rows, secs = [], []
    for name in a.sequences:
        seq = make_sequence(name, a.frames)
        model = seq.model()
        for circles in a.circles:
            for seed in a.seeds:
                frames = _frames(name, a.frames, rig, seed, circles, Path(a.cache),
                                 a.circle_scale)
                for lo_seed in a.lo_seeds:
                    cfg = replace(base, seed=lo_seed)
                    r = _track(seq, model, rig, frames, cfg, diag=a.diag,
                               start_truth=a.start_truth, flow_truth=a.flow_truth)
                    mm = float(np.mean(r["joint"]))
                    rows.append({"seq": name, "circles": circles, "seed": seed,
                                 "lo_seed": lo_seed, "mm": mm, "s": r["s"]})
                    if name == "ball":
                        secs.append(r["s"])
                    print(f"{name:8s} circles {circles:3d} render seed {seed} LO seed "
                          f"{lo_seed}: {mm:5.2f} mm, {r['s']:.2f} s/frame", flush=True)
                    if a.diag:
                        _diag(r, model.n_hands)
    out: dict[str, object] = {"lo": a.lo, "circle_scale": a.circle_scale,
                              "start_truth": a.start_truth, "flow_truth": a.flow_truth,
                              "rows": rows}
    for circles in a.circles:
        for lo_seed in a.lo_seeds:
            v = [r["mm"] for r in rows if r["circles"] == circles and r["lo_seed"] == lo_seed]
            out[f"mean_c{circles}_lo{lo_seed}"] = float(np.mean(v))
        v = [r["mm"] for r in rows if r["circles"] == circles]
        out[f"mean_c{circles}"] = float(np.mean(v))
        out[f"max_c{circles}"] = float(np.max(v))
    out["ball_s_per_frame"] = float(np.mean(secs)) if secs else float("nan")
    print("summary: " + ", ".join(f"{k} {v:.2f}" for k, v in out.items()
                                  if isinstance(v, float)))
    print(json.dumps(out))
    return 0


def _diag(r: dict, n_hands: int) -> None:
    """Per-frame start / end error, error by outer iteration, error by keypoint group."""
    print("   frame start -> end mm: " + ", ".join(
        f"{s:.1f}->{e:.1f}" for s, e in zip(r["start_mm"], r["frame_mm"], strict=True)))
    it = np.array([x for x in r["iter_mm"] if len(x)])
    if len(it):
        m = it.mean(axis=0)
        print("   by outer iteration mm: " + " ".join(f"{v:.2f}" for v in m))
    jf = r["joint_frames"].reshape(len(r["joint_frames"]), n_hands, 21)
    for h in range(n_hands):
        print(f"   hand {h}: mean {jf[:, h].mean():.2f} wrist {jf[:, h, WRIST].mean():.2f} "
              f"tips {jf[:, h, list(TIPS)].mean():.2f} mm")


if __name__ == "__main__":
    sys.exit(main())
