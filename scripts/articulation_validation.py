"""Validation of the depth tracker on fingers that move on their own (issue 13; analysis,
never shipped).

The bench's validation families move the fingers as the suite's clips do (counting, a fist,
a pinch), so a finger's joints move together. A user's fingers need not: a hooked finger
(MCP straight, PIP and DIP bent) or a thumb folded across the palm is a posture those clips
never show. This family keeps the suite's clips' wrist paths (shapes 21-24 of the synthetic
camera; ``wrist_rotation``, ``translation``, ``finger_counting``, ``pinch``) and gives every
finger joint its own smooth motion: a sinusoid of 0.2-0.8 Hz around a point 20-60 % up its
range, amplitude 5-30 % of the range (abductions halved), clipped to the joint limits. Drawn
by this script's own generator and rendered by the bench's validation sequences
(``suite_surface_sequence``: the suite's model, renderer and noise model, 320x240, frames up
to the clip's end); nothing of :mod:`hand_capture.evaldata`. Two surfaces: the suite's own
mesh and its collision capsules (:class:`~hand_capture.bench._tracking_heldout.
CapsuleSurface`). Each sequence is
calibrated from the calibration poses rendered the same way, then tracked through with the
product settings (``--config`` overrides them) by the bench's own scoring.

``--mid LO HI`` centres the sinusoids anywhere from LO to HI up each range (default 0.2
0.6; ``--mid 0 0.6`` reaches the MCPs' hyperextension to their lower limit, -30 deg, which
the default centres reach only at the troughs); ``--shapes FIRST LAST`` takes other shapes.

    PYTHONPATH=. .venv/bin/python scripts/articulation_validation.py [--frames 40] \\
        [--config smooth_weight=20] [--artifacts] [--mid 0 0.6] [--shapes 25 32]

Printed: mean keypoint error [mm] and success@20 mm per surface; the last line is their JSON
(with every sequence's mean error, ``<surface>_sequences_mm``, for paired comparisons).
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from hand_capture.bench._tracking_heldout import (
    ARM_VAL_SEEDS,
    CapsuleSurface,
    SurfaceVariant,
    _score,
    bench_calibrate,
    suite_surface_sequence,
    with_artifacts,
)
from hand_capture.bench.tracking import _summary
from hand_capture.cameras.threads import limit_blas_threads
from hand_capture.config import from_overrides
from hand_capture.errors import ConfigError
from hand_capture.model import JOINT_LIMITS, HandModel
from hand_capture.model.joints import JOINT_NAMES
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import HybridTracker, load_regressor

#: the suite's clips whose wrist paths the sequences follow
CLIPS = ("wrist_rotation", "translation", "finger_counting", "pinch")
#: every second frame of the 30 fps clip
STEP = 2
#: where each joint's sinusoid is centred, as shares of its range (``--mid``; 0 is the
#: lower limit: the MCPs' hyperextension of -30 deg, which the default range reaches only at
#: the sinusoids' troughs)
MID_SHARE = (0.2, 0.6)


def finger_motion(rng: np.random.Generator, n: int, step: int = STEP,
                  mid_share: tuple[float, float] = MID_SHARE) -> np.ndarray:
    """(n, 21) finger joint angles [rad] of every ``step``-th frame at 30 fps: each joint on a
    sinusoid of its own (module doc) around a point ``mid_share`` up its range, clipped to
    the joint limits."""
    lo, hi = JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1]
    k = len(lo)
    mid = lo + (hi - lo) * rng.uniform(*mid_share, k)
    amp = (hi - lo) * rng.uniform(0.05, 0.3, k)
    freq = rng.uniform(0.2, 0.8, k)
    phase = rng.uniform(0.0, 2.0 * math.pi, k)
    t = np.arange(n)[:, None] * step / 30.0
    q = mid + amp * np.sin(2.0 * math.pi * freq * t + phase)
    abd = np.array(["abd" in name for name in JOINT_NAMES[6:]])
    q[:, abd] *= 0.5
    return np.clip(q, lo, hi)


def sequence(seed: int, clip: str, n: int, capsules: bool, artifacts: bool,
             mid_share: tuple[float, float] = MID_SHARE) -> tuple[list, list, list]:
    """``(frames, keypoints, calibration frames)`` of shape ``seed`` on ``clip``'s wrist path
    with independent finger motion (module doc): the bench's
    :func:`~hand_capture.bench._tracking_heldout.suite_surface_sequence` with these fingers."""
    fingers = finger_motion(np.random.default_rng(seed * 100 + len(clip)), n,
                            mid_share=mid_share)
    surface = CapsuleSurface() if capsules else SurfaceVariant()   # the default: own mesh
    _, _, frames, kps, _, cal = suite_surface_sequence(seed, clip, n, STEP, surface, fingers)
    if artifacts:
        frames = with_artifacts(frames, seed * 7 + len(clip))
        cal = with_artifacts(cal, seed * 7 + len(clip) + 1)
    return frames, kps, cal


def run(cfg: TrackerConfig, n: int, artifacts: bool,
        mid_share: tuple[float, float] = MID_SHARE,
        shapes: tuple[int, ...] = ARM_VAL_SEEDS) -> dict[str, object]:
    """Mean error [mm] and success@20 of both surfaces (module doc), and every sequence's
    mean error [mm] (``<surface>_sequences_mm``, for paired comparisons)."""
    reg = load_regressor(cfg)   # the regressors cfg asks for (ensemble: both)
    base = HandModel()
    out: dict[str, object] = {}
    for name, capsules in (("own", False), ("capsule", True)):
        errs = []
        for seed in shapes:
            for clip in CLIPS:
                frames, kps, cal = sequence(seed, clip, n, capsules, artifacts, mid_share)
                tracker = HybridTracker(base, cfg, reg)
                tracker.set_calibration(bench_calibrate(cal, model=base, config=cfg))
                errs.append(_score(tracker, frames, kps)["errs"])
        s = _summary(np.concatenate(errs))
        out[f"{name}_mean_mm"] = s["mean"]
        out[f"{name}_success_20mm"] = s["s20"]
        out[f"{name}_sequences_mm"] = [float(e.mean()) for e in errs]
        print(f"{name:8s} mean {s['mean']:6.2f} mm  success@20 {s['s20']:.3f}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40, help="frames per sequence")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="a TrackerConfig field")
    ap.add_argument("--artifacts", action="store_true",
                    help="the suite's stereo artifacts (tracking/augment.py) on every frame")
    ap.add_argument("--mid", type=float, nargs=2, default=MID_SHARE, metavar=("LO", "HI"),
                    help="the sinusoids' centres, shares of each joint's range (default "
                    f"{MID_SHARE[0]} {MID_SHARE[1]}; 0 0.6 reaches the MCPs' hyperextension)")
    ap.add_argument("--shapes", type=int, nargs=2, default=None, metavar=("FIRST", "LAST"),
                    help=f"shape seeds (default {ARM_VAL_SEEDS[0]}-{ARM_VAL_SEEDS[-1]})")
    args = ap.parse_args(argv)
    try:
        cfg = from_overrides(TrackerConfig, args.config)
    except ConfigError as e:
        print(e, file=sys.stderr)
        return 2
    limit_blas_threads(1)
    if not 0.0 <= args.mid[0] <= args.mid[1] <= 1.0:
        print("--mid needs 0 <= LO <= HI <= 1", file=sys.stderr)
        return 2
    shapes = (tuple(range(args.shapes[0], args.shapes[1] + 1)) if args.shapes
              else ARM_VAL_SEEDS)
    out = run(cfg, args.frames, args.artifacts, tuple(args.mid), shapes)
    print(json.dumps({**out, "frames": args.frames, "artifacts": args.artifacts,
                      "mid": list(args.mid), "shapes": list(shapes), "config": args.config}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
