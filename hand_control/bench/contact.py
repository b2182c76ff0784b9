"""``hand-suite bench contact``: the contact-force QP of the composite controller.

QP section: random hand-object contact sets with 2-5 contacts (points on a 4 cm sphere around
the centre of mass, normals roughly towards it, mu in [0.2, 1.0], a target wrench around the
weight of a 50-500 g object). The control-loop path (:class:`ContactForceQP`, active-set NNLS)
is timed against its baseline measured in the same run, the same problem stated in cvxpy with
Parameters (:class:`ReferenceContactQP`, polished OSQP), and the largest difference of their
forces/torsional torques is reported. Both methods are covered: eq. (III.23) of the
dissertation (the headline figures) and seed 000's eq. (10)+(11).

Later sections (the lift-and-carry grid in simulation) add their own keys to :func:`run`.
"""

from __future__ import annotations

import gc
import itertools
from collections.abc import Callable
from typing import Any

import numpy as np

from hand_capture.bench import print_table, time_calls
from hand_control.contact import (
    ContactForceQP,
    ContactQPConfig,
    ContactSet,
    ReferenceContactQP,
    dynamic_feasibility,
)

Problem = tuple[ContactSet, np.ndarray, np.ndarray, np.ndarray]
CONTACT_COUNTS = (2, 3, 4, 5)


def random_problem(rng: np.random.Generator, k: int) -> Problem:
    """One random contact-force problem: ``(contacts, com, force_target, torque_target)``.

    The contacts carry plausible simulator forces (inside their friction cones) for the
    seed-000 method.
    """
    d = rng.standard_normal((k, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    com = 0.005 * rng.standard_normal(3)
    points = com + 0.04 * d
    normals = -d + 0.3 * rng.standard_normal((k, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    mu = rng.uniform(0.2, 1.0, k)
    tangent = rng.standard_normal((k, 3))
    tangent -= np.einsum("kj,kj->k", tangent, normals)[:, None] * normals
    tangent *= (mu * rng.uniform(0, 1, k) / np.linalg.norm(tangent, axis=1))[:, None]
    forces = rng.uniform(0.2, 2.0, k)[:, None] * (normals + tangent)
    contacts = ContactSet(points, normals, mu, forces=forces)
    mass = rng.uniform(0.05, 0.5)
    force_target = np.array([0.0, 0.0, 9.81 * mass]) + 0.3 * rng.standard_normal(3)
    torque_target = 0.01 * rng.standard_normal(3)
    return contacts, com, force_target, torque_target


def random_problems(seed: int, n: int) -> list[Problem]:
    """``n`` problems, contact counts cycling through 2-5."""
    rng = np.random.default_rng(seed)
    return [random_problem(rng, CONTACT_COUNTS[i % len(CONTACT_COUNTS)]) for i in range(n)]


def _timed(solve: Callable[..., Any], problems: list[Problem], repeats: int) -> np.ndarray:
    """Per-call wall times [us] of ``solve`` over ``problems``, ``repeats`` passes, GC off."""
    it = itertools.cycle(problems)
    gc.collect()
    gc.disable()
    try:
        return 1e6 * time_calls(lambda: solve(*next(it)), len(problems) * repeats,
                                warmup=len(problems))
    finally:
        gc.enable()


def _max_diff(fast: list[Any], ref: list[Any]) -> tuple[float, int]:
    """Largest |difference| of forces and torsions where both were found; count of misses."""
    worst, misses = 0.0, 0
    for a, b in zip(fast, ref, strict=True):
        if not (a.found and b.found):
            misses += 1
            continue
        worst = max(worst, float(np.abs(a.forces - b.forces).max()),
                    float(np.abs(a.torsion - b.torsion).max()))
    return worst, misses


def qp_section(quick: bool) -> dict[str, Any]:
    """Fast path vs cvxpy reference on random contact sets with 2-5 contacts."""
    n, repeats = (80, 5) if quick else (400, 10)
    problems = random_problems(seed=5, n=n)
    figures: dict[str, Any] = {"qp_problems": n, "qp_contacts": "2-5"}
    rows = []
    for method in ("dissertation", "seed000"):
        cfg = ContactQPConfig(method=method)
        fast, ref = ContactForceQP(cfg), ReferenceContactQP(cfg)
        t_fast = _timed(fast.solve, problems, repeats)
        t_ref = _timed(ref.solve, problems, 1)
        diff, misses = _max_diff([fast.solve(*p) for p in problems],
                                 [ref.solve(*p) for p in problems])
        p50, p99 = np.percentile(t_fast, [50, 99])
        r50, r99 = np.percentile(t_ref, [50, 99])
        rows.append([method, "all", p50, p99, r50, r99, r50 / p50, diff, misses])
        by_k = {}
        for k in CONTACT_COUNTS:
            sub = [p for p in problems if len(p[0]) == k]
            by_k[k] = float(np.median(_timed(fast.solve, sub, repeats)))
            rows.append([method, k, by_k[k], "", "", "", "", "", ""])
        pre = "" if method == "dissertation" else "seed000_"
        figures.update({
            f"{pre}qp_p50_us": p50,
            f"{pre}qp_p99_us": p99,
            f"{pre}qp_p50_us_by_contacts": {str(k): v for k, v in by_k.items()},
            f"{pre}cvxpy_p50_us": r50,
            f"{pre}cvxpy_p99_us": r99,
            f"{pre}speedup_vs_cvxpy": r50 / p50,
            f"{pre}max_abs_diff_vs_cvxpy": diff,
            f"{pre}qp_not_found": misses,
        })
    print_table(
        f"contact-force QP, {n} random contact sets (2-5 contacts); times in us",
        ["method", "contacts", "fast p50", "fast p99", "cvxpy p50", "cvxpy p99", "speedup",
         "max |diff| [N]", "not found"],
        rows,
    )
    # The dynamic feasibility LP (eq. III.10-III.16) on the same contact sets, 0.2 kg object.
    t_lp = _timed(lambda c, com, *_: dynamic_feasibility(c, 0.2, com), problems, 1)
    figures["feasibility_lp_p50_us"] = float(np.median(t_lp))
    print_table("dynamic feasibility LP (HiGHS), same contact sets; times in us",
                ["p50", "p99"], [[float(np.median(t_lp)), float(np.percentile(t_lp, 99))]])
    return figures


def control_section(quick: bool) -> dict[str, Any]:
    """One composite-controller step (27 hand DoFs) with 2-5 contacts, vs PD only.

    Each step builds its :class:`ContactSet` from arrays (validation included), computes the
    virtual object wrench, solves the QP and maps the forces through the Jacobians.
    """
    from hand_capture.model.joints import JOINT_NAMES
    from hand_control.control import (
        CompositeControlConfig,
        CompositeController,
        ObjectState,
        ObjectTarget,
    )

    n, repeats = (40, 10) if quick else (200, 20)
    rng = np.random.default_rng(6)
    nv = len(JOINT_NAMES)
    steps = []
    for contacts, com, _, _ in random_problems(seed=7, n=n):
        k = len(contacts)
        arrays = dict(points=contacts.points, normals=contacts.normals, mu=contacts.mu,
                      jacp=rng.standard_normal((k, 3, nv)), jacr=rng.standard_normal((k, 3, nv)))
        obj = ObjectState(com, [1.0, 0, 0, 0], 0.05 * rng.standard_normal(3),
                          0.1 * rng.standard_normal(3), rng.uniform(0.05, 0.5))
        target = ObjectTarget(com + 0.01 * rng.standard_normal(3), [1.0, 0, 0, 0])
        steps.append((rng.standard_normal(nv), rng.standard_normal(nv),
                      rng.standard_normal(nv), obj, target, arrays))
    times = {}
    for mode in ("composite", "pd_only"):
        ctrl = CompositeController(CompositeControlConfig(mode=mode))

        def step(q, qd, qt, obj, target, arrays, ctrl=ctrl):
            return ctrl.compute(q, qd, qt, obj, target, ContactSet(**arrays), np.zeros(nv))

        times[mode] = _timed(step, steps, repeats)
        assert ctrl.fallbacks == 0
    c50, p50 = float(np.median(times["composite"])), float(np.median(times["pd_only"]))
    print_table(f"controller step, {nv} DoFs, 2-5 contacts, {n} states; times in us",
                ["mode", "p50", "p99"],
                [[m, float(np.median(t)), float(np.percentile(t, 99))] for m, t in times.items()])
    return {"control_step_p50_us": c50, "control_step_p99_us":
            float(np.percentile(times["composite"], 99)), "pd_only_step_p50_us": p50}


def grid_section(quick: bool) -> dict[str, Any]:
    """Lift-and-carry grid in simulation, composite vs PD-only (see ``_grasp_grid``)."""
    from hand_control.bench._grasp_grid import run_grid

    return run_grid(quick)


SECTIONS: tuple[Callable[[bool], dict[str, Any]], ...] = (qp_section, control_section,
                                                          grid_section)


def run(quick: bool = False) -> dict[str, Any]:
    """Run every section; returns the figures for the last-line JSON."""
    figures: dict[str, Any] = {}
    for section in SECTIONS:
        figures.update(section(quick))
    return figures
