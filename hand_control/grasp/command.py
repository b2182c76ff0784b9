"""``hand-suite grasp OBJECT [--grip MODE] [-o OUT] [--play]``: synthesise a grasp of any
object (dissertation III.4) and optionally execute it in the simulation.

OBJECT is a mesh file (OBJ / STL / PLY) or a primitive spec (``box:0.03,0.02,0.04``,
``mug``, ``torus:0.045,0.014``, ...; ``hand_control.grasp.objects``). The output (``.npz``)
holds the world-frame reaching and closing motions (27 values per frame, ``JOINT_NAMES``
order), the grip mode, the contact points and normals and the model parameters.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from hand_capture.model.joints import JOINT_NAMES
from hand_control.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``grasp`` sub-command of ``hand-suite``."""
    g = sub.add_parser("grasp", help="synthesise a grasp of an object (III.4), play it")
    g.add_argument("object", help="mesh file or primitive spec (e.g. mug, bottle:0.03,0.08)")
    g.add_argument("--grip", default=None, help="grip mode (default: the best scoring)")
    g.add_argument("-o", "--output", default=None, help="write the motion to this .npz")
    g.add_argument("--play", action="store_true",
                   help="execute it in the simulation: lift 10 cm, hold 2 s, report")
    g.add_argument("--mass", type=float, default=0.2, help="object mass [kg]")
    g.add_argument("--friction", type=float, default=0.75, help="sliding friction")
    g.add_argument("--xy", default="0.12,0.0", help="object position on the table [m]")
    g.add_argument("--yaw", type=float, default=0.0, help="object turn about z [rad]")
    g.add_argument("--seed", type=int, default=0)
    g.set_defaults(func=cmd_grasp)


def cmd_grasp(a: argparse.Namespace) -> int:
    from hand_capture.bench import print_table
    from hand_control.grasp.synthesis import SynthesisConfig, plan_in_world
    from hand_control.sim import lockstep
    from hand_control.sim.scenario import ScenarioSpec

    try:
        x, y = (float(v) for v in a.xy.split(","))
    except ValueError as e:
        raise InputError(f"--xy must be two numbers x,y [m], got {a.xy!r}") from e
    spec = ScenarioSpec(name="grasp", object_shape=a.object, object_mass=a.mass,
                        object_friction=a.friction, object_xy=(x, y), object_yaw=a.yaw,
                        grasp_source="synthesis", grip_mode=a.grip or "", t_carry=0.0,
                        carry_offset=(0.0, 0.0, 0.0), lift_height=0.10, t_hold=2.0)
    world, mobj, _ = lockstep.build_world(spec)
    pose = world.object_pose(mobj.name)
    obj = lockstep.scenario_object(spec)
    plan, res = plan_in_world(obj, mobj.name, pose.position, pose.quaternion, a.grip,
                              SynthesisConfig(seed=a.seed))
    rows = [["object", obj.spec], ["mass [kg]", obj.mass], ["grip mode", res.grip_mode],
            ["feasible (LP III.10-16)", f"{res.feasible} ({res.status})"],
            ["contacts", ", ".join(res.contact_bones)],
            ["contact residual [mm]", np.round(res.residual * 1e3, 1).tolist()],
            ["synthesis [ms]", round(res.synth_ms, 1)],
            *[[f"  {k}", round(v, 3)] for k, v in res.terms.items()]]
    if obj.hull_only:
        rows.append(["note", "non-convex mesh: the simulation collides with its convex hull"])
    print_table(f"grasp synthesis for {a.object}", ["", ""], rows)
    if a.output:
        out = Path(a.output)
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            out, joint_names=np.array(JOINT_NAMES), closing=plan.closing,
            reaching=plan.reaching if plan.reaching is not None else np.zeros((0, 27)),
            grip_mode=np.array(res.grip_mode), params=res.params, frame_yaw=res.yaw,
            contact_bones=np.array(res.contact_bones), contact_points=plan.points,
            contact_normals=plan.normals, feasible=res.feasible,
            object=np.array(obj.spec), object_position=pose.position,
            object_quaternion=pose.quaternion)
        print(f"\nwrote {out}")
    ok = res.feasible
    if a.play:
        r = lockstep.LockstepRunner(spec, plan=plan).run()
        ok = bool(r.success and r.object_lift_mm >= 80.0)
        print_table("played in the simulation (composite controller)", ["", ""], [
            ["lifted [mm]", round(r.object_lift_mm, 1)],
            ["final error [mm]", round(r.final_error_mm, 1)],
            ["held 2 s at 10 cm", ok]])
    print(json.dumps({"grip_mode": res.grip_mode, "feasible": res.feasible,
                      "synth_ms": round(res.synth_ms, 1), "lifted": ok if a.play else None,
                      "residual_mm": [round(v * 1e3, 2) for v in res.residual
                                      if math.isfinite(v)]}))
    return 0 if ok else 1
