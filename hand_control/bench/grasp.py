"""``hand-suite bench grasp``: synthesised grasps (dissertation III.4) lifting objects the grasp
database never saw, in simulation, against the fingertip-IK substitute and Fig. III.9's ablations.

Cases: objects not in the database (its objects are boxes, balls and upright cylinders): a mug
with a handle, a bottle, a thick flat plate, a torus, random convex meshes and composites (an L
of boxes with a ball), each at several placements (position and yaw on the table) and masses.
Beside them, in-distribution cases (a box, a ball and a cylinder of sizes like the database's).

For every case the grasp is synthesised (eq. III.4 by PSO from the prior, the feasibility LP
on the last generation, IK refinement) and executed by the composite controller in the lockstep
simulation: reach, close, lift 10 cm, hold 2 s. Success: the object ends within 3 cm of its
target and at least 8 cm up. ``synth_success`` counts the cases whose feasibility LP admitted
the synthesised grasp (the acceptance figure); the same cases are run with the grasp
synthesised without the collision term (w_k = 0), without the contact-polygon term (w1 = 0)
and without the friction-cone term (w2 = 0), the rest of the pipeline (the feasibility LP among
it) unchanged; ``*_best_particle_feasible``: how often the swarm's best particle already passed
the LP (the terms' own effect on grasp quality, before the filter).
``ik_baseline_success``: the fingertip-IK substitute (``sim.grasp.plan_grasp``) on the
object's primitive proxy (mug and bottle: an upright cylinder, plate: a box), where it has one;
a plan its IK cannot reach counts as a failure (``indist_ik_success``: the same on the
in-distribution primitives, where it was built for). ``synth_ms_p50``: synthesis wall time
per grasp (the swarm, the LPs, the refinement); ``synth_cpu_ms_p50`` its CPU time (the wall
time on an idle core: the shared machine's load stretches the wall time, not the CPU time).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from hand_capture.bench import print_table
from hand_control.errors import HandSuiteError
from hand_control.grasp.objects import GraspObject, parse_object
from hand_control.grasp.synthesis import (
    EnergyWeights,
    SynthesisConfig,
    plan_in_world,
    with_weights,
)
from hand_control.sim import lockstep
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import ScenarioSpec

#: objects the database never saw (evaluation) and like it (in distribution)
NOVEL = ("mug", "bottle", "plate", "torus", "convex:1", "convex:2", "convex:3",
         "composite:1", "composite:2")
IN_DIST = ("box:0.025,0.03,0.03", "sphere:0.033", "cylinder:0.028,0.055")
#: (x, y, yaw) on the table [m, m, rad]
PLACEMENTS = ((0.12, 0.0, 0.0), (0.14, 0.03, 0.6), (0.11, -0.03, -0.5))
MASSES = (0.1, 0.4)
SIZES = {
    "full": (NOVEL, IN_DIST, PLACEMENTS, MASSES),
    "quick": (("mug", "bottle", "convex:2", "composite:1", "torus"), ("sphere:0.033",),
              PLACEMENTS[:1], (0.2,)),
    "smoke": (("bottle",), (), PLACEMENTS[:1], (0.2,)),
}
ABLATIONS = ("no_collision", "no_polygon", "no_cone")
LIFT_OK_MM = 80.0


def _spec(shape: str, mass: float, place: tuple[float, float, float], quick: bool
          ) -> ScenarioSpec:
    t = dict(t_reach=0.4, t_close=0.5, t_settle=0.25, t_lift=0.8, t_hold=2.0) if quick else \
        dict(t_reach=0.5, t_close=0.5, t_settle=0.3, t_lift=1.0, t_hold=2.0)
    return ScenarioSpec(name=f"bench_{shape}", object_shape=shape, object_mass=mass,
                        object_friction=0.75, object_xy=place[:2], object_yaw=place[2],
                        t_carry=0.0, carry_offset=(0.0, 0.0, 0.0), lift_height=0.10, **t)


def _episode(spec: ScenarioSpec, plan: Any) -> tuple[bool, float]:
    try:
        r = LockstepRunner(spec, plan=plan).run()
    except HandSuiteError:
        return False, float("nan")
    return bool(r.success and r.object_lift_mm >= LIFT_OK_MM), float(r.object_lift_mm)


def _ik_episode(spec: ScenarioSpec, world: Any, mobj: Any) -> tuple[bool, float]:
    """The fingertip-IK substitute on the object's primitive proxy (no plan: a failure)."""
    try:
        plan = lockstep.scenario_plan(spec.with_(grasp_source="ik"), world, mobj,
                                      tuple(mobj.size))
    except HandSuiteError:
        return False, float("nan")
    return _episode(spec, plan)


def _object(shape: str, mass: float, cache: dict[str, GraspObject]) -> GraspObject:
    if shape not in cache:
        cache[shape] = parse_object(shape, 1.0, 0.75, name="object")
    base = cache[shape]
    return dataclasses.replace(base, mass=mass, inertia=base.inertia * mass / base.mass)


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """Run the benchmark; returns the figures of the last JSON line."""
    size = "smoke" if smoke else "quick" if quick else "full"
    novel, indist, placements, masses = SIZES[size]
    short = size != "full"
    cache: dict[str, GraspObject] = {}
    cfg = SynthesisConfig()
    rows, synth_ms, synth_cpu = [], [], []
    out: dict[str, list] = {k: [] for k in ("synth", "ik", "indist", "indist_ik", *ABLATIONS)}
    feasible_cases = 0
    first: dict[str, list] = {k: [] for k in ("full", *ABLATIONS)}
    for shape in (*novel, *indist):
        for mass in masses:
            for place in placements:
                spec = _spec(shape, mass, place, short)
                obj = _object(shape, mass, cache)
                lockstep._GRASP_OBJECTS[(shape, mass, 0.75)] = obj
                world, mobj, _ = lockstep.build_world(spec)
                pose = world.object_pose(mobj.name)
                plan, res = plan_in_world(obj, mobj.name, pose.position, pose.quaternion,
                                          config=cfg)
                synth_ms.append(res.synth_ms)
                synth_cpu.append(res.cpu_ms)
                row = [shape, mass, f"{place[0]:.2f},{place[1]:.2f},{place[2]:.1f}",
                       res.grip_mode, res.feasible, round(res.synth_ms)]
                if not res.feasible:
                    rows.append(row + ["-"] * 5)
                    continue
                ok, lift = _episode(spec, plan)
                row.append(f"{ok} ({lift:.0f} mm)")
                if shape in indist:
                    out["indist"].append(ok)
                    ik_ok, ik_lift = _ik_episode(spec, world, mobj)
                    out["indist_ik"].append(ik_ok)
                    rows.append(row + ["-"] * 3 + [f"{ik_ok} ({ik_lift:.0f})"])
                    continue
                feasible_cases += 1
                out["synth"].append(ok)
                first["full"].append(res.feasible and res.lp_tried == 1)
                for ab in ABLATIONS:
                    p2, r2 = plan_in_world(obj, mobj.name, pose.position, pose.quaternion,
                                           config=cfg, weights=with_weights(EnergyWeights(), ab))
                    first[ab].append(r2.feasible and r2.lp_tried == 1)
                    ok2, lift2 = _episode(spec, p2) if r2.feasible else (False, float("nan"))
                    out[ab].append(ok2)
                    row.append(f"{ok2} ({lift2:.0f})")
                if obj.ik_proxy is not None:
                    ik_ok, ik_lift = _ik_episode(spec, world, mobj)
                    out["ik"].append(ik_ok)
                    row.append(f"{ik_ok} ({ik_lift:.0f})")
                else:
                    row.append("n/a")
                rows.append(row)
    print_table("grasp synthesis: lift 10 cm and hold 2 s (composite controller)",
                ["object", "kg", "x,y,yaw", "grip", "LP ok", "synth ms", "synthesised",
                 "no collision", "no polygon", "no cone", "IK substitute"], rows)

    def rate(v: list) -> float:
        return float(np.mean(v)) if v else float("nan")

    figures = {
        "cases": len(rows), "lp_feasible_cases": feasible_cases,
        "synth_success": rate(out["synth"]),
        "ik_baseline_success": rate(out["ik"]), "ik_baseline_cases": len(out["ik"]),
        "no_collision_success": rate(out["no_collision"]),
        "no_polygon_success": rate(out["no_polygon"]),
        "no_cone_success": rate(out["no_cone"]),
        "indist_success": rate(out["indist"]), "indist_cases": len(out["indist"]),
        "indist_ik_success": rate(out["indist_ik"]),
        **{f"{k}_best_particle_feasible": rate(v) for k, v in first.items()},
        "synth_ms_p50": float(np.median(synth_ms)),
        "synth_ms_p90": float(np.percentile(synth_ms, 90)),
        "synth_cpu_ms_p50": float(np.median(synth_cpu)),
    }
    print_table("summary", ["figure", "value"], [[k, v] for k, v in figures.items()])
    return figures


if __name__ == "__main__":  # pragma: no cover
    import sys

    t0 = time.perf_counter()
    run(quick="--quick" in sys.argv, smoke="--smoke" in sys.argv)
    print(f"{time.perf_counter() - t0:.0f} s")
