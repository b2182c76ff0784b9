"""Run scenarios in lockstep: ``python -m hand_control.sim [NAME ...] [--mode composite|pd_only]
[--method dissertation|seed000]``.

Prints per scenario whether the object was carried, its tracking error and the real-time factor.
"""

from __future__ import annotations

import argparse
import sys

from hand_control.control import CompositeControlConfig
from hand_control.errors import HandSuiteError
from hand_control.sim.lockstep import run_episode
from hand_control.sim.scenario import load_scenario, scenario_names


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hand_control.sim", description=__doc__)
    p.add_argument("names", nargs="*", help=f"scenarios (default: all of {scenario_names()})")
    p.add_argument("--mode", default="composite", choices=("composite", "pd_only", "both"))
    p.add_argument("--method", default="dissertation", choices=("dissertation", "seed000"),
                   help="contact-force QP: eq. (III.23) or seed 000's eq. (10)-(11)")
    p.add_argument("--control-every", type=int, default=1, help="physics steps per control step")
    a = p.parse_args(argv)
    modes = ("composite", "pd_only") if a.mode == "both" else (a.mode,)
    print(f"{'scenario':16s} {'mode':10s} {'carried':8s} {'final mm':>9s} {'mean mm':>8s} "
          f"{'mean deg':>8s} {'lift mm':>8s} {'RTF':>6s}")
    code = 0
    for name in a.names or scenario_names():
        for mode in modes:
            try:
                r = run_episode(load_scenario(name), mode, a.control_every,
                                gains=CompositeControlConfig(method=a.method))
            except HandSuiteError as e:
                print(f"{name:16s} {mode:10s} error: {e}")
                code = 1
                continue
            print(f"{name:16s} {mode:10s} {str(r.success):8s} {r.final_error_mm:9.1f} "
                  f"{r.pos_err_mean_mm:8.1f} {r.rot_err_mean_deg:8.1f} {r.object_lift_mm:8.1f} "
                  f"{r.rtf:6.2f}", flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
