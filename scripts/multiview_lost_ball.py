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
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import fields

import numpy as np


def _value(kind: type | str, text: str) -> object:
    t = kind if isinstance(kind, str) else kind.__name__
    if t == "bool":
        return text.lower() in ("1", "true", "yes")
    return int(text) if t == "int" else float(text)


def overrides(cls: type, items: list[str]) -> dict[str, object]:
    """``["KEY=VALUE", ...]`` -> the dataclass ``cls``'s fields, typed as its fields are."""
    kinds = {f.name: f.type for f in fields(cls)}
    out = {}
    for kv in items:
        k, v = kv.split("=", 1)
        out[k] = _value(kinds[k], v)
    return out


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "osmesa")    # the studio renders off-screen
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
    a = ap.parse_args(argv)
    over = overrides(MultiviewTrackerConfig, a.tracker)
    rig = load_rig("studio6")
    seq = make_sequence(a.sequence, a.frames)
    model = seq.model()
    frames = list(render_sequence(seq, rig, surface=a.surface, circles=a.circles,
                                  seed=a.seed))
    tr = MultiviewTracker(model, rig, LOConfig(seed=a.lo_seed),
                          MultiviewTrackerConfig(**over))
    tr.reset(seq.truth(model, 0))
    ball = model.n_hands          # the sequence's object
    sl = model.slices[model.part_names[ball]]
    hands = list(range(model.n_hands))
    print(f"{a.sequence}, render seed {a.seed}, {a.surface} mesh, {a.circles} circles, "
          f"tracker overrides {over or 'none'}")
    print(f"{'t':>2} {'moved mm':>8} {'err mm':>7} {'status':>10} {'support':>7} "
          f"{'region':>6} | truth: {'support':>7} {'region':>6}  s  hands mm")
    errs, lost, secs, hand_errs = [], 0, [], []
    for t, fr in enumerate(frames):
        res = tr.step(fr.images, fr.detections)
        truth = seq.truth(model, t)
        err = float(np.linalg.norm(res.params[sl][:3] - truth[sl][:3]) * 1e3)
        moved = 0.0 if t == 0 else float(
            np.linalg.norm(truth[sl][:3] - seq.truth(model, t - 1)[sl][:3]) * 1e3)
        pe = res.parts[ball]
        kt = model.pose(truth).keypoints
        hand = float(np.mean([np.linalg.norm(res.state.keypoints[h] - kt[h], axis=1).mean()
                              for h in hands]) * 1e3)
        # evidence at the truth: the hands at the truth too
        ts, _ = tr.lo.support(truth, tr.lo.prepare(fr.images), [ball, *hands])
        maps = tr.regions.maps(fr.images)
        tr_region = tr.regions.score(truth, maps, ball)[0] if ball in maps else float("nan")
        print(f"{t:2d} {moved:8.1f} {err:7.1f} {pe.status:>10} {pe.support:7.2f} "
              f"{pe.region:6.2f} | truth: {ts[ball]:7.2f} {tr_region:6.2f}  "
              f"{res.seconds:.1f}  {hand:.1f}")
        if t:
            errs.append(err)
            hand_errs.append(hand)
            secs.append(res.seconds)
            lost += pe.status == "lost"
    out = {"script": "multiview_lost_ball", "sequence": a.sequence, "seed": a.seed,
           "circles": a.circles, "surface": a.surface, "overrides": over,
           "object_err_mm": [round(e, 1) for e in errs],
           "object_mean_mm": float(np.mean(errs)),
           "hands_mean_mm": float(np.mean(hand_errs)), "frames_lost": lost,
           "s_per_frame": float(np.mean(secs))}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
