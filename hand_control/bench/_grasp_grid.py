"""Lift-and-carry grid: composite control vs PD-only trajectory tracking, in simulation.

Every cell (object x mass x friction) runs the same scenario twice in lockstep
(:mod:`hand_control.sim.lockstep`): reach, close onto the grasp found by fingertip IK, lift the
object 10 cm and carry it 10 cm sideways, hold. Once with the composite controller (PD servos
+ grasp torques from the contact-force QP, seed 000 eq. 8-13 / dissertation III.19-III.23),
once with PD-only trajectory tracking (the dissertation's baseline, sec. III.8.2: the same
servo targets, no grasp torques). A run succeeds when the object ends within 3 cm of its target
and at least half-way up. Success rates are counted over the cells where the dynamic
feasibility LP (III.10-III.16, with the hand's joint torque limits through the contact
Jacobians) says the planned contacts can hold the object; the object tracking error (mm, deg)
is averaged over lifting, carrying and holding.

Validation and test split: the QP's regularisation weights (alpha3 = alpha4 of eq. III.23)
are chosen on the box's cells (composite success, then tracking error) and the figures are
reported on the ball's and the cylinder's cells, which the choice never saw.

This module is the grid section of ``hand-suite bench contact``; it can run alone:
``python -m hand_control.bench._grasp_grid [--quick | --smoke]``.
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
from hand_control.control import CompositeControlConfig
from hand_control.errors import HandSuiteError
from hand_control.sim.lockstep import LockstepRunner
from hand_control.sim.scenario import ScenarioSpec

#: beyond what the hand's actuators can hold at low friction: the feasibility LP with the
#: joint torque limits says no at mu 0.3 (the planned grasps hold 5.9-6.8 kg there, ~15 kg at 1.0)
HEAVY_MASS = 8.0
#: cells per size: (validation objects, test objects, masses, frictions). The settings (the
#: QP's regularisation weights) are chosen on the validation object's cells and reported on
#: the other objects' cells, which they were not chosen on.
SIZES = {
    "full": (("box",), ("ball", "cylinder"), (0.05, 0.2, 0.5, 1.0, HEAVY_MASS),
             (0.3, 0.5, 0.75, 1.0)),
    "quick": (("box",), ("ball",), (0.05, 1.0, HEAVY_MASS), (0.3, 1.0)),
    "smoke": (("box",), ("ball",), (0.2,), (1.0,)),
}
#: candidate alpha3 = alpha4 of eq. (III.23): the dissertation's 0.1 and smaller
ALPHAS = {"full": (0.1, 1e-2, 1e-3, 1e-4), "quick": (0.1, 1e-3), "smoke": (0.1, 1e-3)}


def grid_spec(kind: str, mass: float, mu: float, quick: bool) -> ScenarioSpec:
    """The lift-and-carry scenario of one cell (shorter phases when ``quick``)."""
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


def _controller_config(mode: str, alpha: float) -> CompositeControlConfig:
    """The controller's gains and QP settings for a grid run, with QP weights alpha3 = alpha4 =
    ``alpha`` (everything else the controller's defaults)."""
    return CompositeControlConfig(mode=mode, alpha3=alpha, alpha4=alpha)


class _Grid:
    """Runs cells, caching the grasp plan per object and the feasibility LP per cell."""

    def __init__(self, size: str) -> None:
        self.size = size
        self.quick = size != "full"
        self.plans: dict[str, Any] = {}
        self.lp: dict[tuple[str, float, float], Any] = {}

    def run(self, kind: str, mass: float, mu: float, mode: str, alpha: float,
            record: list | None = None) -> tuple[bool, float, float, Any] | None:
        """One run: ``(success, position error mm, rotation error deg, feasibility result)``,
        ``None`` when no grasp can be planned for the object."""
        spec = grid_spec(kind, mass, mu, self.quick)
        try:
            runner = LockstepRunner(spec, gains=_controller_config(mode, alpha),
                                    control_every=2 if self.quick else 1,
                                    plan=self.plans.get(kind))
        except HandSuiteError as e:
            print(f"  {kind}: cannot plan a grasp: {e}", file=sys.stderr)
            return None
        self.plans[kind] = runner.plan
        key = (kind, mass, mu)
        if key not in self.lp:
            self.lp[key] = grasp_feasibility(runner)
        if record is not None and mode == "composite":
            qp = runner.controller.qp
            record.append((qp.config, []))
            _record_qp(qp, record[-1][1])
        try:
            r = runner.run()
            return r.success, r.pos_err_mean_mm, r.rot_err_mean_deg, self.lp[key]
        except HandSuiteError as e:  # a divergence counts as a failure, reported
            print(f"  {kind} m={mass} mu={mu} {mode}: {e}", file=sys.stderr)
            return False, math.nan, math.nan, self.lp[key]


def _mean(v: list[float]) -> float:
    a = np.asarray(v, dtype=float)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else math.nan


def run_grid(quick: bool = False, record: list | None = None, size: str | None = None
             ) -> dict[str, Any]:
    """Run the grid; returns the figures (keys ``composite_success``, ``pd_only_success``,
    tracking errors, cell counts: on the test split; ``alpha_chosen`` and the validation
    figures). ``size``: ``"full"``, ``"quick"`` or ``"smoke"`` (default from ``quick``).
    ``record``: a list that gets, per composite run of the test split, ``(the QP's config,
    the list of contact-QP problems the controller solved, in order)`` (for the QP
    benchmark)."""
    size = size or ("quick" if quick else "full")
    val_objects, test_objects, masses, frictions = SIZES[size]
    grid = _Grid(size)
    t0 = time.perf_counter()
    # -- validation: choose alpha3 = alpha4 on the validation object's feasible cells
    val_rows, val_rate, val_err = [], {}, {}
    for alpha in ALPHAS[size]:
        ok, err = [], []
        for kind, mass, mu in itertools.product(val_objects, masses, frictions):
            r = grid.run(kind, mass, mu, "composite", alpha)
            if r is not None and r[3].feasible:
                ok.append(float(r[0]))
                err.append(r[1])
        val_rate[alpha], val_err[alpha] = (float(np.mean(ok)) if ok else math.nan), _mean(err)
        val_rows.append([alpha, len(ok), val_rate[alpha], val_err[alpha]])
    # the highest success rate, then the smallest position error
    chosen = min(ALPHAS[size], key=lambda a: (-np.nan_to_num(val_rate[a], nan=-1.0),
                                              np.nan_to_num(val_err[a], nan=math.inf)))
    print_table(f"validation split ({', '.join(val_objects)}): composite control per QP "
                "weight alpha3 = alpha4 (feasible cells)",
                ["alpha3=alpha4", "cells", "success", "err mm"], val_rows)
    print(f"chosen on the validation split: alpha3 = alpha4 = {chosen:g}")
    # -- test: the other objects, composite (chosen alpha) vs PD-only
    rows = []
    stats: dict[str, dict[str, list[float]]] = {m: {"ok": [], "pos": [], "rot": []}
                                                for m in ("composite", "pd_only")}
    infeasible_ok: list[float] = []
    cells = feasible_cells = 0
    for kind, mass, mu in itertools.product(test_objects, masses, frictions):
        row: list[Any] = [kind, mass, mu]
        lp = None
        for mode in ("composite", "pd_only"):
            r = grid.run(kind, mass, mu, mode, chosen, record)
            if r is None:
                break
            ok, pos, rot, lp = r
            if lp.feasible:
                stats[mode]["ok"].append(float(ok))
                stats[mode]["pos"].append(pos)
                stats[mode]["rot"].append(rot)
            elif mode == "composite":
                infeasible_ok.append(float(ok))
            row += ["yes" if ok else "no", pos, rot]
        if lp is None:
            continue
        cells += 1
        feasible_cells += int(lp.feasible)
        row.insert(3, "yes" if lp.feasible else f"no ({lp.status})")
        rows.append(row)
    print_table(
        f"test split ({', '.join(test_objects)}), alpha3 = alpha4 = {chosen:g}: success; object "
        "tracking error over lift/carry/hold",
        ["object", "mass kg", "mu", "LP feasible", "composite", "err mm", "err deg",
         "PD-only", "err mm", "err deg"], rows)

    def rate(mode: str) -> float:
        v = stats[mode]["ok"]
        return float(np.mean(v)) if v else math.nan

    out = {
        "composite_success": rate("composite"),
        "pd_only_success": rate("pd_only"),
        "success_ratio": (rate("composite") / rate("pd_only")
                          if rate("pd_only") > 0 else math.inf),
        "composite_err_mm": _mean(stats["composite"]["pos"]),
        "pd_only_err_mm": _mean(stats["pd_only"]["pos"]),
        "composite_err_deg": _mean(stats["composite"]["rot"]),
        "pd_only_err_deg": _mean(stats["pd_only"]["rot"]),
        "grid_split": {"validation": list(val_objects), "test": list(test_objects)},
        "grid_cells": cells,
        "feasible_cells": feasible_cells,
        # what the LP's "no" is worth: composite success on the cells it rejects
        "infeasible_cells_composite_success": (float(np.mean(infeasible_ok))
                                               if infeasible_ok else math.nan),
        "alpha_chosen": chosen,
        "val_composite_success_by_alpha": {f"{a:g}": val_rate[a] for a in ALPHAS[size]},
        "val_cells": len(val_objects) * len(masses) * len(frictions),
        "grid_wall_s": time.perf_counter() - t0,
    }
    print_table("summary, test split (LP-feasible cells)",
                ["controller", "success", "err mm", "err deg"], [
                    ["composite", out["composite_success"], out["composite_err_mm"],
                     out["composite_err_deg"]],
                    ["PD-only", out["pd_only_success"], out["pd_only_err_mm"],
                     out["pd_only_err_deg"]]])
    return out


if __name__ == "__main__":
    print(json_line({"bench": "grasp_grid", **run_grid(
        size="smoke" if "--smoke" in sys.argv else "quick" if "--quick" in sys.argv else "full")}))
