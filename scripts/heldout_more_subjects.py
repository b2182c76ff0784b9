"""The depth tracker on more subjects of the held-out family (issue 13; reporting only).

``hand-suite bench tracking`` scores six held-out sequences a row (60 frames each, one
subject per camera and clutter case). One sequence that loses the hand moves such a row by
several millimetres, and the iterative fits land in other local minima on another CPU. This
script scores the same six cases on ``--subjects`` subjects each (seed offsets 0, 1000,
2000, ...; offset 0 is the bench's sequences), with and without a forearm, the product
settings or ``--config`` overrides, in ``--jobs`` processes, and prints every sequence and
the rows' mean / median / success@20 mm. Never used to choose anything.

    PYTHONPATH=. .venv/bin/python scripts/heldout_more_subjects.py            # 4 x 6 x 2
    PYTHONPATH=. .venv/bin/python scripts/heldout_more_subjects.py --config track_roi_m=0
"""

from __future__ import annotations

import argparse
import json
import sys
from multiprocessing import Pool

import numpy as np

from hand_capture.config import from_overrides
from hand_capture.errors import ConfigError
from hand_capture.tracking.config import TrackerConfig


def _track(job: tuple[int, int, bool, TrackerConfig, int]
           ) -> tuple[int, int, bool, np.ndarray]:
    """One held-out sequence of ``n`` frames, as the bench's held-out section makes, calibrates
    and tracks it: (case, offset, forearm, per-frame keypoint errors (n, 21) [mm])."""
    from hand_capture.bench._tracking_heldout import HELDOUT, _score, heldout_case
    from hand_capture.cameras.threads import limit_blas_threads
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker, load_regressor

    k, offset, arm, cfg, n = job
    limit_blas_threads(1)
    cam, clutter, seed = HELDOUT[k]
    seq, _, cal = heldout_case(k, cam, clutter, seed + (100 if arm else 0) + offset, arm, n, 1)
    tracker = HybridTracker(HandModel(), cfg, load_regressor(cfg))
    tracker.set_calibration(cal)
    return k, offset, arm, _score(tracker, seq.frames, seq.keypoints)["errs"]


def main(argv: list[str] | None = None) -> int:
    from hand_capture.bench._tracking_heldout import HELDOUT

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subjects", type=int, default=4, help="subjects per case (default 4)")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="TrackerConfig override (repeatable)")
    ap.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    a = ap.parse_args(argv)
    try:
        cfg = from_overrides(TrackerConfig, a.config)
    except ConfigError as e:
        print(e, file=sys.stderr)
        return 2
    if a.subjects < 1 or a.jobs < 1:
        print("--subjects and --jobs must be at least 1", file=sys.stderr)
        return 2
    jobs = [(k, 1000 * s, arm, cfg, 60) for arm in (False, True) for s in range(a.subjects)
            for k in range(len(HELDOUT))]
    with Pool(a.jobs) as pool:
        res = pool.map(_track, jobs, chunksize=1)
    out = {}
    for arm in (False, True):
        key = "forearm" if arm else "heldout"
        errs = []
        for k, offset, arm_k, e in res:
            if arm_k != arm:
                continue
            errs.append(e)
            print(f"{key:8s} {HELDOUT[k][0]:9s} clutter {HELDOUT[k][1]!s:5s} offset {offset:5d}: "
                  f"{e.mean():7.2f} mm, success@20 {np.mean(e.max(axis=1) < 20.0):.3f}")
        e = np.concatenate(errs)
        out.update({f"{key}_mean_mm": float(e.mean()), f"{key}_median_mm": float(np.median(e)),
                    f"{key}_success_20mm": float(np.mean(e.max(axis=1) < 20.0)),
                    f"{key}_sequences": len(errs)})
    print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
