"""Is a held-out miss the search's or the cost's? (issue 13; diagnosis, never chooses anything)

Tracks the bench's six held-out sequences a row (``hand-suite bench tracking``'s cases,
calibrated as there, product settings or ``--config`` overrides) while one more candidate
joins every frame's pool (as the deferred regression's carry does: screened, refined and
selected like the regressor's; it takes the place of a deferred regression's carry
under ``--config defer_regression=true``):

* ``product``: none;
* ``truth``: the true pose;
* ``root``: the previous pose with the true root (6 DoF);
* ``fingers``: the previous pose with the true finger joints;
* ``noisy``: the true pose perturbed by ``--noise`` times (5 mm, 3 deg) at the root and 5 deg
  at each finger joint.

If eq. II.20 prefers the truth, the ``truth`` rows fall far below the product's: the search,
not the cost, misses. Prints each sequence and each row's mean [mm] / success@20 mm.

    PYTHONPATH=. .venv/bin/python scripts/tracking_oracle.py --modes product truth
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from hand_capture.config import from_overrides
from hand_capture.errors import ConfigError
from hand_capture.tracking.config import TrackerConfig

MODES = ("product", "truth", "root", "fingers", "noisy")


def _extra(mode: str, truth: np.ndarray, prev: np.ndarray | None, rng: np.random.Generator,
           noise: float) -> np.ndarray | None:
    """The candidate ``mode`` adds to a frame's pool (None: none)."""
    q = np.asarray(truth, float).copy()
    if mode == "truth":
        return q
    if mode == "noisy":
        q[:3] += rng.normal(0.0, 0.005 * noise, 3)
        q[3:6] += rng.normal(0.0, np.radians(3.0) * noise, 3)
        q[6:] += rng.normal(0.0, np.radians(5.0) * noise, q.size - 6)
        return q
    if mode in ("root", "fingers") and prev is not None:
        out = prev.copy()
        sl = slice(0, 6) if mode == "root" else slice(6, None)
        out[sl] = q[sl]
        return out
    return None


def main(argv: list[str] | None = None) -> int:
    from hand_capture.bench._tracking_heldout import HELDOUT, heldout_case, track_with_candidate
    from hand_capture.bench.tracking import _summary
    from hand_capture.cameras.threads import limit_blas_threads
    from hand_capture.model import HandModel
    from hand_capture.tracking.hybrid import HybridTracker, load_regressor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument("--noise", type=float, default=1.0, help="scale of the noisy mode")
    ap.add_argument("--forearm", choices=("no", "yes", "both"), default="both")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE")
    a = ap.parse_args(argv)
    try:
        cfg = from_overrides(TrackerConfig, a.config)
    except ConfigError as e:
        ap.error(str(e))
    limit_blas_threads(1)
    reg = load_regressor(cfg)
    arms = {"no": (False,), "yes": (True,), "both": (False, True)}[a.forearm]
    for arm in arms:
        rows: dict[str, list[np.ndarray]] = {m: [] for m in a.modes}
        for k, (cam, clutter, seed) in enumerate(HELDOUT):
            seq, _, cal = heldout_case(k, cam, clutter, seed + (100 if arm else 0), arm, 60, 1)
            for mode in a.modes:
                rng = np.random.default_rng(5)
                tr = HybridTracker(HandModel(), cfg, reg)
                tr.set_calibration(cal)
                e = track_with_candidate(
                    tr, seq.frames, seq.poses, seq.keypoints,
                    lambda q, prev: _extra(mode, q, prev, rng, a.noise))  # noqa: B023
                rows[mode].append(e)
                s = _summary(e)
                print(f"{'forearm' if arm else 'heldout'} {cam} clutter {clutter!s:5} "
                      f"{mode:8} {s['mean']:6.2f} mm  success@20 {s['s20']:.3f}", flush=True)
        for mode, es in rows.items():
            s = _summary(np.concatenate(es))
            print(f"ROW {'forearm' if arm else 'heldout'} {mode:8} {s['mean']:6.2f} mm  "
                  f"success@20 {s['s20']:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
