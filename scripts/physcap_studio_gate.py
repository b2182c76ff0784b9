"""Downstream gate of the multi-view tracker's defaults: the physics capture's studio lifts.

Tracks studio-family truths of ``hand-suite bench physcap`` (default the ``lift_box`` at its
own mass, render seed 40, and the 1 kg ``lift_ball``, seed 48; ``--only`` a comma list of
any of the 9: each light lift at its own mass and at 500 g / 1 kg, the bench's seeds) with
``hand_control.physcap.studio.studio_capture`` (the multi-view tracker at its default
settings, ``--lo`` / ``--tracker`` overriding them) and prints the tracked object's position
error and the hand's joint (21 keypoints) error against the truth [mm], mean and max over
frames. Run it once with PYTHONPATH on the old code and once on the new, in different cache
folders (the cache's key holds the settings, not the code), and compare; the LO's ``seed``
(``--lo seed=1``) gives the run-to-run spread.

    PYTHONPATH=TREE python scripts/physcap_studio_gate.py CACHE_DIR
        [--only lift_box,lift_cylinder_1000g] [--lo KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from hand_capture.model.hand import HandModel
    from hand_control.bench.physcap import STUDIO_SEED0, studio_specs
    from hand_control.physcap.studio import studio_capture
    from hand_control.physcap.synth import scenario_capture

    ap = argparse.ArgumentParser()
    ap.add_argument("cache_dir")
    ap.add_argument("--only", default="")
    ap.add_argument("--lo", nargs="*", default=[], help="LOConfig overrides KEY=VALUE")
    ap.add_argument("--tracker", nargs="*", default=[],
                    help="MultiviewTrackerConfig overrides KEY=VALUE")
    a = ap.parse_args(argv)
    from hand_capture.config import from_overrides
    from hand_capture.multiview.lo import LOConfig
    from hand_capture.multiview.tracker import MultiviewTrackerConfig

    lo = from_overrides(LOConfig, a.lo)
    over = from_overrides(MultiviewTrackerConfig, a.tracker)
    # the bench's seeds: STUDIO_SEED0 + the index in the family (all 9 feasible)
    cases = {spec.name: (spec, STUDIO_SEED0 + i) for i, (_, spec) in enumerate(studio_specs())}
    only = [n for n in a.only.split(",") if n] or ["lift_box", "lift_ball_1000g"]
    unknown = sorted(set(only) - set(cases))
    if unknown:
        raise SystemExit(f"unknown --only {unknown}; valid: {sorted(cases)}")
    hand = HandModel()
    out: dict = {}
    for name, (spec, seed) in cases.items():
        if name not in only:
            continue
        truth = scenario_capture(spec)
        sc = studio_capture(truth, seed=seed, images=False, cache_dir=a.cache_dir,
                            lo_config=lo, tracker_config=over)
        tr = sc.synthetic.capture
        obj = np.linalg.norm(tr.object_pose[1:, :3] - truth.object_pose[1:, :3], axis=1) * 1e3
        jt = np.array([np.mean(np.linalg.norm(hand.forward(q).joint_positions -
                                              hand.forward(g).joint_positions, axis=1))
                       for q, g in zip(tr.hand_q[1:], truth.hand_q[1:], strict=True)]) * 1e3
        out[name] = {"frames": len(truth.times), "object_mm": float(obj.mean()),
                     "object_max_mm": float(obj.max()), "joint_mm": float(jt.mean()),
                     "joint_max_mm": float(jt.max()), "s_per_frame": sc.track_s_per_frame}
        print(name, json.dumps(out[name]), flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
