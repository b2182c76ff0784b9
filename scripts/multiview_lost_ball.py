"""Validation of the multi-view tracker's lost-object handling: the ball passed between hands.

Renders the ``ball`` sequence (``hand_capture.multiview.sequences``, the bench's 10 frames of
the 16-frame pass: the ball leaves the right palm at frame 5 and flies 41-65 mm a frame) at a
VALIDATION render seed (default 7; the bench uses 1 and 2), the tracker's own mesh, with seed
002's circles, tracks it from the first frame's truth with the defaults (``--tracker``
overrides ``MultiviewTrackerConfig``, e.g. ``object_colours=False`` for edge support alone,
main's behaviour) and prints per frame: the ball's true motion, its position error, status,
edge support and region score (the tracker's), the region score and edge support at the
TRUE configuration (the thresholds' evidence) and the hands' mean keypoint error. Last line:
one JSON object.

``--sequence box``: the same rows for the box the hand grasps, lifts and turns (a held
object: a false LOST flag's check).

    PYTHONPATH=. python scripts/multiview_lost_ball.py [--seed 7] [--circles 100]
        [--surface own] [--frames 10] [--sequence ball] [--tracker KEY=VALUE ...]
        [--lo KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "osmesa")    # the studio renders off-screen
    from hand_capture.config import from_overrides
    from hand_capture.multiview.lo import LOConfig
    from hand_capture.multiview.rig import load_rig
    from hand_capture.multiview.sequences import make_sequence, render_sequence
    from hand_capture.multiview.tracker import MultiviewTracker, MultiviewTrackerConfig

    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--circles", type=int, default=100)
    ap.add_argument("--surface", default="own")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--sequence", default="ball", help="ball or box (its object's rows)")
    ap.add_argument("--lo-seed", type=int, default=0)
    ap.add_argument("--tracker", nargs="*", default=[], help="overrides KEY=VALUE")
    ap.add_argument("--lo", nargs="*", default=[], help="LOConfig overrides KEY=VALUE")
    a = ap.parse_args(argv)
    config = from_overrides(MultiviewTrackerConfig, a.tracker)
    lo = from_overrides(LOConfig, [*a.lo, f"seed={a.lo_seed}"])
    rig = load_rig("studio6")
    seq = make_sequence(a.sequence, a.frames)
    model = seq.model()
    frames = list(render_sequence(seq, rig, surface=a.surface, circles=a.circles,
                                  seed=a.seed))
    tr = MultiviewTracker(model, rig, lo, config)
    tr.reset(seq.truth(model, 0))
    print(f"{a.sequence}, render seed {a.seed}, {a.surface} mesh, {a.circles} circles, "
          f"tracker overrides {a.tracker or 'none'}, LO overrides {a.lo or 'none'}")
    print(f"{'t':>2} {'moved mm':>8} {'err mm':>7} {'status':>10} {'support':>7} "
          f"{'region':>6} | truth: {'support':>7} {'region':>6}  s  hands mm")
    rows = track_rows(tr, seq, frames)
    for r in rows:
        print(f"{r['t']:2d} {r['moved_mm']:8.1f} {r['err_mm']:7.1f} {r['status']:>10} "
              f"{r['support']:7.2f} {r['region']:6.2f} | truth: {r['truth_support']:7.2f} "
              f"{r['truth_region']:6.2f}  {r['s']:.1f}  {r['hands_mm']:.1f}")
    later = rows[1:]
    errs = [r["err_mm"] for r in later]
    out = {"script": "multiview_lost_ball", "sequence": a.sequence, "seed": a.seed,
           "circles": a.circles, "surface": a.surface, "overrides": a.tracker, "lo": a.lo,
           "object_err_mm": [round(e, 1) for e in errs],
           "object_mean_mm": float(np.mean(errs)),
           "hands_mean_mm": float(np.mean([r["hands_mm"] for r in later])),
           "frames_lost": sum(r["status"] == "lost" for r in later),
           "s_per_frame": float(np.mean([r["s"] for r in later]))}
    print(json.dumps(out))
    return 0


def track_rows(tr: object, seq: object, frames: list) -> list[dict]:
    """Track ``frames`` with ``tr`` (the caller resets it at the first frame's truth); per frame
    the estimate (``params``), the object's true motion and position error [mm], status,
    support and region score,
    the support and region score at the TRUE configuration, the seconds and the hands' mean
    keypoint error [mm]. The evidence at the truth is evaluated with the local optimiser's
    random draws put back (``MultiviewTracker._draws_kept``): it takes edge subsamples, and
    without that the tracking of the frames after it would differ from the tracker's own."""
    model = tr.model
    obj = model.n_hands          # the sequence's object
    sl = model.slices[model.part_names[obj]]
    hands = list(range(model.n_hands))
    rows = []
    for t, fr in enumerate(frames):
        res = tr.step(fr.images, fr.detections)
        truth = seq.truth(model, t)
        kt = model.pose(truth).keypoints
        pe = res.parts[obj]
        with tr._draws_kept():   # the evidence at the truth (the hands at the truth too)
            ts, _ = tr.lo.support(truth, tr.lo.prepare(fr.images), [obj, *hands])
            maps = tr.regions.maps(fr.images)
            tr_region = (tr.regions.score(truth, maps, obj)[0] if obj in maps
                         else float("nan"))
        rows.append({
            "t": t, "params": res.params.copy(),
            "moved_mm": 0.0 if t == 0 else float(
                np.linalg.norm(truth[sl][:3] - seq.truth(model, t - 1)[sl][:3]) * 1e3),
            "err_mm": float(np.linalg.norm(res.params[sl][:3] - truth[sl][:3]) * 1e3),
            "status": pe.status, "support": pe.support, "region": pe.region,
            "truth_support": float(ts[obj]), "truth_region": float(tr_region),
            "s": res.seconds,
            "hands_mm": float(np.mean([np.linalg.norm(res.state.keypoints[h] - kt[h],
                                                      axis=1).mean() for h in hands]) * 1e3)})
    return rows


if __name__ == "__main__":
    sys.exit(main())
