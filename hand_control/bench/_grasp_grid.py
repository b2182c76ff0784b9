"""Lift-and-carry grid: composite control vs PD-only trajectory tracking, in simulation.

Every cell (object x mass x friction) runs the same scenario twice in lockstep
(:mod:`hand_control.sim.lockstep`): reach, close onto the grasp found by fingertip IK, lift the
object 10 cm and carry it 10 cm sideways, hold. Once with the composite controller (PD servos
+ grasp torques from the contact-force QP, seed 000 eq. 8-13 / dissertation III.19-III.23),
once with PD-only trajectory tracking (the dissertation's baseline, sec. III.8.2: the same
servo targets, no grasp torques). A run succeeds when the object ends within 3 cm of its target
and at least half-way up. Success rates are counted over the cells where the dynamic
feasibility LP (III.10-III.16) says the planned contacts can hold the object; the object
tracking error (mm, deg) is averaged over lifting, carrying and holding.

This module is the grid section of ``hand-suite bench contact``; it can run alone:
``python -m hand_control.bench._grasp_grid [--quick]``.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from typing import Any

import numpy as np

from hand_capture.bench import json_line, print_table
from hand_capture.model.joints import JOINT_NAMES
from hand_control.errors import HandSuiteError
from hand_control.sim.control_loop import ControllerNodeConfig
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import ScenarioSpec

OBJECTS = ("box", "ball", "cylinder")
#: beyond what the hand's actuators can hold at low friction: the feasibility LP with the
#: joint torque limits says no at mu 0.3 (the planned grasps hold ~4.4 kg there, ~11 kg at 1.0)
HEAVY_MASS = 5.0
MASSES = (0.05, 0.2, 0.5, 1.0, HEAVY_MASS)
FRICTIONS = (0.3, 0.5, 0.75, 1.0)
QUICK_OBJECTS = ("box", "ball")
QUICK_MASSES = (0.05, 1.0)
QUICK_FRICTIONS = (0.3, 1.0)



def grid_spec(kind: str, mass: float, mu: float, quick: bool) -> ScenarioSpec:
    t = dict(t_reach=0.3, t_close=0.4, t_settle=0.2, t_lift=0.6, t_carry=0.6, t_hold=0.4) \
        if quick else dict(t_reach=0.5, t_close=0.5, t_settle=0.3, t_lift=1.0, t_carry=1.0,
                           t_hold=0.7)
    return ScenarioSpec(name=f"grid_{kind}", object_kind=kind, object_mass=mass,
                        object_friction=mu, **t)


def _record_qp(qp: Any, seq: list) -> None:
    """Make ``qp`` append a copy of every problem ``(contacts, com, force_target,
    torque_target)`` it solves to ``seq``, whichever entry point the control loop calls (the
    solver's ``recorder`` hook; the contacts without their Jacobians: the QP needs none)."""
    from hand_control.contact import ContactSet

    def recording(contacts: Any, com: Any, force_target: Any, torque_target: Any) -> None:
        seq.append((ContactSet.trusted(contacts.points.copy(), contacts.normals.copy(),
                                       np.array(contacts.mu, dtype=np.float64)),
                    np.array(com, dtype=np.float64), np.array(force_target, dtype=np.float64),
                    np.array(torque_target, dtype=np.float64)))

    qp.recorder = recording


def joint_torque_limits(model: Any, joint_ids: Any) -> np.ndarray:
    """(n,) torque limits [N m] of the joints ``joint_ids`` as the simulated model applies them:
    the force range of the actuator driving each joint (a motor without one: its control
    range), times its gear; ``inf`` for a joint no limited actuator drives."""
    import mujoco

    lim = np.full(len(joint_ids), np.inf)
    col = {int(j): i for i, j in enumerate(joint_ids)}
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            continue
        i = col.get(int(model.actuator_trnid[a, 0]))
        if i is None:
            continue
        if model.actuator_forcelimited[a]:
            lo, hi = model.actuator_forcerange[a]
        elif model.actuator_ctrllimited[a] and model.actuator_gaintype[a] == \
                mujoco.mjtGain.mjGAIN_FIXED and model.actuator_biastype[a] == \
                mujoco.mjtBias.mjBIAS_NONE:  # a motor: force = control
            lo, hi = model.actuator_ctrlrange[a] * model.actuator_gainprm[a, 0]
        else:
            continue
        lim[i] = min(lim[i], abs(float(model.actuator_gear[a, 0])) * min(-lo, hi))
    return np.maximum(lim, 0.0)


def grasp_feasibility(runner: Any, mu: float | None = None, mass: float | None = None
                      ) -> Any:
    """Dynamic feasibility LP (III.10-III.16) of the runner's planned grasp with the hand's
    joint torque limits: the contact Jacobians of the fingertips at the planned grasp pose map
    the contact forces to joint torques, bounded by the actuators' limits (a
    :class:`FeasibilityResult`)."""
    import mujoco

    from hand_control.contact import ContactSet, dynamic_feasibility

    spec, plan, w = runner.spec, runner.plan, runner.world
    mu = spec.object_friction if mu is None else mu
    mass = spec.object_mass if mass is None else mass
    m = w.model
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    for name, adr in zip(w.joint_names, w.qpos_adr.tolist(), strict=True):
        d.qpos[adr] = plan.q_grasp[JOINT_NAMES.index(name)]
    mujoco.mj_fwdPosition(m, d)
    k = len(plan.fingers)
    jacp = np.empty((k, 3, len(w.dof_adr)))
    full = np.empty((3, m.nv))
    for i, finger in enumerate(plan.fingers):
        body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{finger}_distal")
        mujoco.mj_jac(m, d, full, None, np.asarray(plan.points[i], dtype=np.float64), body)
        jacp[i] = full[:, w.dof_adr]
    joint_ids = [int(m.dof_jntid[a]) for a in w.dof_adr.tolist()]
    contacts = ContactSet(plan.points, plan.normals, mu, jacp=jacp)
    return dynamic_feasibility(contacts, mass, w.object_pose(runner.obj.name).position,
                               torque_limits=joint_torque_limits(m, joint_ids))


def run_grid(quick: bool = False, record: list | None = None) -> dict[str, Any]:
    """Run the grid; returns the figures (keys ``composite_success``, ``pd_only_success``,
    tracking errors, cell counts). ``record``: a list that gets, per composite run, the list
    of contact-QP problems the controller solved, in order (for the QP benchmark)."""
    objects = QUICK_OBJECTS if quick else OBJECTS
    masses = QUICK_MASSES if quick else MASSES
    frictions = QUICK_FRICTIONS if quick else FRICTIONS
    control_every = 2 if quick else 1
    rows = []
    stats: dict[str, dict[str, list[float]]] = {m: {"ok": [], "pos": [], "rot": []}
                                                for m in ("composite", "pd_only")}
    feasible_cells = 0
    cells = 0
    t0 = time.perf_counter()
    plans: dict[str, Any] = {}
    for kind, mass, mu in itertools.product(objects, masses, frictions):
        spec = grid_spec(kind, mass, mu, quick)
        cells += 1
        row = [kind, mass, mu]
        feasible = None
        for mode in ("composite", "pd_only"):
            # contact-QP weights: ControllerNodeConfig's defaults (alpha3 = alpha4 = 1e-3, see
            # config/controller.yaml), the same as the controller node
            cfg = ControllerNodeConfig(scenario=spec.name, mode=mode)
            try:
                runner = LockstepRunner(spec, controller_config=cfg,
                                        control_every=control_every, plan=plans.get(kind))
            except HandSuiteError as e:
                print(f"  {kind}: cannot plan a grasp: {e}", file=sys.stderr)
                break
            plans[kind] = runner.plan
            if record is not None and mode == "composite":
                record.append([])
                _record_qp(runner.controller.qp, record[-1])
            if feasible is None:
                lp = grasp_feasibility(runner)
                feasible = lp.feasible
                feasible_cells += int(feasible)
            try:
                r = runner.run()
                ok, pos, rot = r.success, r.pos_err_mean_mm, r.rot_err_mean_deg
            except HandSuiteError as e:  # a divergence counts as a failure, reported
                print(f"  {kind} m={mass} mu={mu} {mode}: {e}", file=sys.stderr)
                ok, pos, rot = False, math.nan, math.nan
            if feasible:
                stats[mode]["ok"].append(float(ok))
                stats[mode]["pos"].append(pos)
                stats[mode]["rot"].append(rot)
            row += ["yes" if ok else "no", pos, rot]
        row.insert(3, "yes" if feasible else f"no ({lp.status})")
        rows.append(row)
    print_table(
        "lift-and-carry grid (success; object tracking error over lift/carry/hold)",
        ["object", "mass kg", "mu", "LP feasible", "composite", "err mm", "err deg",
         "PD-only", "err mm", "err deg"], rows)

    def rate(mode: str) -> float:
        v = stats[mode]["ok"]
        return float(np.mean(v)) if v else math.nan

    def mean(mode: str, key: str) -> float:
        v = np.asarray(stats[mode][key], dtype=float)
        v = v[np.isfinite(v)]
        return float(v.mean()) if v.size else math.nan

    out = {
        "composite_success": rate("composite"),
        "pd_only_success": rate("pd_only"),
        "success_ratio": (rate("composite") / rate("pd_only")
                          if rate("pd_only") > 0 else math.inf),
        "composite_err_mm": mean("composite", "pos"),
        "pd_only_err_mm": mean("pd_only", "pos"),
        "composite_err_deg": mean("composite", "rot"),
        "pd_only_err_deg": mean("pd_only", "rot"),
        "grid_cells": cells,
        "feasible_cells": feasible_cells,
        "grid_wall_s": time.perf_counter() - t0,
    }
    print_table("summary (feasible cells)", ["controller", "success", "err mm", "err deg"], [
        ["composite", out["composite_success"], out["composite_err_mm"],
         out["composite_err_deg"]],
        ["PD-only", out["pd_only_success"], out["pd_only_err_mm"], out["pd_only_err_deg"]]])
    return out


if __name__ == "__main__":
    print(json_line({"bench": "grasp_grid", **run_grid("--quick" in sys.argv)}))
