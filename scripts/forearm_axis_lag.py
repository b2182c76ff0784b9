"""How far the depth tracker falls behind a hand moving along its own axis, with and without
a forearm in view (issue 13; analysis, never shipped).

Exact renders (no noise) of the suite's mesh, with a cylindrical forearm (the training
renders' :func:`~hand_capture.tracking.train.forearm_mesh`, radius 30 mm) or without one,
moving ``--step-mm`` a 30 fps frame along the wrist-to-middle-MCP direction (towards the
fingers); tracked from the first frame's true pose with the forearm cut alone (no arm
classifier, no regressor: the pool is the previous pose and ``shift_previous``'s start).
Per frame: the tracked wrist's error along that axis [mm] (negative: behind, towards the
arm) and the mean keypoint error [mm]. The fifty-third session found the fit held back by
the forearm's points up to the cut (docs/experiments/depth_tracking.md).

    PYTHONPATH=. .venv/bin/python scripts/forearm_axis_lag.py
    PYTHONPATH=. .venv/bin/python scripts/forearm_axis_lag.py --config forearm_margin_m=0.02

Printed: a row per pose and scene; the last line is a JSON object with each scene's mean
final lag (``lag_arm_mm``, ``lag_hand_mm``: the wrist's error along the axis on the last
frame, averaged over the poses) and mean keypoint error over all frames.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from hand_capture.bench._tracking_heldout import SurfaceVariant
from hand_capture.cameras.render import make_renderer
from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.config import from_overrides
from hand_capture.errors import ConfigError
from hand_capture.model import HandModel
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker
from hand_capture.tracking.train import default_intrinsics, forearm_mesh, random_pose


def track_along_axis(cfg: TrackerConfig, seed: int, step_m: float, frames: int,
                     arm: bool) -> tuple[np.ndarray, np.ndarray]:
    """One pose (``random_pose`` of ``seed``) moving ``step_m`` [m] a frame along the hand's
    axis for ``frames`` frames, with or without the forearm; returns the tracked wrist's
    error along the axis (frames,) [mm] and the mean keypoint error (frames,) [mm]."""
    m = HandModel()
    renderer, hand = make_renderer("zbuffer"), SurfaceVariant().mesh_fn(m)
    q0 = random_pose(np.random.default_rng(seed), m)
    kp = m.joint_positions(q0)
    axis = (kp[9] - kp[0]) / np.linalg.norm(kp[9] - kp[0])        # wrist -> middle MCP
    tr = HybridTracker(m, cfg, None)
    tr.reset(q0)
    lag, err = np.zeros(frames), np.zeros(frames)
    for k in range(frames):
        q = q0.copy()
        q[0:3] += k * step_m * axis
        meshes = [hand(q)] + ([forearm_mesh(m, q, 0.03, 0.3)] if arm else [])
        depth = np.rint(renderer.render(meshes, default_intrinsics()).depth * 1000.0)
        res = tr.process(depth.astype(np.uint16), default_intrinsics())
        kt, kq = m.joint_positions(res.pose), m.joint_positions(q)
        lag[k] = float((kt[0] - kq[0]) @ axis) * 1e3
        err[k] = float(np.linalg.norm(kt - kq, axis=1).mean()) * 1e3
    return lag, err


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5],
                    help="poses (random_pose seeds; default 3 4 5)")
    ap.add_argument("--step-mm", type=float, default=8.0,
                    help="motion a frame along the hand's axis [mm] (default 8)")
    ap.add_argument("--frames", type=int, default=6, help="frames a sequence (default 6)")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="TrackerConfig override (repeatable)")
    a = ap.parse_args(argv)
    if a.frames < 2:
        print("--frames must be at least 2", file=sys.stderr)
        return 2
    try:
        cfg = from_overrides(TrackerConfig, ["arm_classifier=false", *a.config])
    except ConfigError as e:
        print(e, file=sys.stderr)
        return 2
    limit_blas_threads(1)
    out: dict[str, float] = {}
    for arm in (False, True):
        scene = "arm" if arm else "hand"
        lags, errs = [], []
        for seed in a.seeds:
            lag, err = track_along_axis(cfg, seed, a.step_mm * 1e-3, a.frames, arm)
            lags.append(lag[-1])
            errs.append(err.mean())
            print(f"seed {seed} {scene:4s} lag along the axis [mm] "
                  + " ".join(f"{x:+6.1f}" for x in lag)
                  + "   keypoints [mm] " + " ".join(f"{x:5.1f}" for x in err))
        out[f"lag_{scene}_mm"] = round(float(np.mean(lags)), 2)
        out[f"error_{scene}_mm"] = round(float(np.mean(errs)), 2)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
