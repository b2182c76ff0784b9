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
import time
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


def _grid_qp_config() -> ContactQPConfig:
    """The contact QP as the grid's controller runs it (the controller config's defaults)."""
    from hand_control.control import CompositeControlConfig

    return CompositeControlConfig().qp_config()


def _timed_sequences(cfg: ContactQPConfig, runs: list[list[Problem]]
                     ) -> tuple[np.ndarray, np.ndarray, list[Any], int]:
    """Per-call wall and CPU (thread) times [us] of the fast path over the grid's problem
    sequences, each in the order the control loop met it, with a fresh solver per run (so the
    warm start is the loop's); the results and the warm-start hits. GC off."""
    times, cpu, results, warm = [], [], [], 0
    perf, thread = time.perf_counter, time.thread_time
    gc.collect()
    gc.disable()
    try:
        for seq in runs:
            qp = ContactForceQP(cfg)
            for c, com, tf, tt in seq:
                c0 = thread()
                t0 = perf()
                res = qp.solve(c, com, tf, tt, check=False)
                t1 = perf()
                cpu.append(thread() - c0)
                times.append(t1 - t0)
                results.append(res)
            warm += qp.warm_hits
    finally:
        gc.enable()
    return 1e6 * np.array(times), 1e6 * np.array(cpu), results, warm


def qp_section(quick: bool, grid_runs: list[list[Problem]] | None = None) -> dict[str, Any]:
    """Fast path vs cvxpy reference: on the contact sets met in the lift-and-carry grid (the
    headline figures: every QP the composite runs solved, timed in their order), and on
    random contact sets with 2-5 contacts (cold problems, both methods)."""
    n, repeats = (80, 5) if quick else (400, 10)
    problems = random_problems(seed=5, n=n)
    figures: dict[str, Any] = {"qp_problems": n, "qp_contacts": "2-5"}
    rows = []
    random_diff = 0.0
    for method in ("dissertation", "seed000"):
        cfg = ContactQPConfig(method=method)
        fast, ref = ContactForceQP(cfg), ReferenceContactQP(cfg)
        t_fast = _timed(fast.solve, problems, repeats)
        t_ref = _timed(ref.solve, problems, 1)
        diff, misses = _max_diff([fast.solve(*p) for p in problems],
                                 [ref.solve(*p) for p in problems])
        p50, p99 = np.percentile(t_fast, [50, 99])
        r50, r99 = np.percentile(t_ref, [50, 99])
        rows.append([method, "random", "all", p50, p99, r50, r99, r50 / p50, diff, misses])
        by_k = {}
        for k in CONTACT_COUNTS:
            sub = [p for p in problems if len(p[0]) == k]
            by_k[k] = float(np.median(_timed(fast.solve, sub, repeats)))
            rows.append([method, "random", k, by_k[k], "", "", "", "", "", ""])
        if method == "dissertation":
            random_diff = diff
            figures.update({
                "qp_random_p50_us": p50, "qp_random_p99_us": p99,
                "qp_random_p50_us_by_contacts": {str(k): v for k, v in by_k.items()},
                "cvxpy_random_p50_us": r50, "max_abs_diff_vs_cvxpy_random": diff,
                "qp_random_not_found": misses})
        else:
            figures.update({
                "seed000_qp_p50_us": p50,
                "seed000_qp_p99_us": p99,
                "seed000_qp_p50_us_by_contacts": {str(k): v for k, v in by_k.items()},
                "seed000_cvxpy_p50_us": r50,
                "seed000_cvxpy_p99_us": r99,
                "seed000_speedup_vs_cvxpy": r50 / p50,
                "seed000_max_abs_diff_vs_cvxpy": diff,
                "seed000_qp_not_found": misses,
            })
    if grid_runs:
        cfg = _grid_qp_config()
        seq = [p for run in grid_runs for p in run]
        t_fast, c_fast, fast_res, warm = _timed_sequences(cfg, grid_runs)
        # cvxpy on an evenly spread sample of the same problems (it takes milliseconds each)
        pick = np.unique(np.linspace(0, len(seq) - 1, min(len(seq), 150 if quick else 600))
                         .astype(int)).tolist()
        ref = ReferenceContactQP(cfg)
        t_ref = _timed(ref.solve, [seq[i] for i in pick], 1)
        diff, misses = _max_diff([fast_res[i] for i in pick], [ref.solve(*seq[i]) for i in pick])
        p50, p99 = np.percentile(t_fast, [50, 99])
        r50, r99 = np.percentile(t_ref, [50, 99])
        ks = np.array([len(p[0]) for p in seq])
        not_found = sum(not r.found for r in fast_res)
        rows.append(["dissertation", "grid", "all", p50, p99, r50, r99, r50 / p50, diff,
                     misses])
        by_k = {}
        for k in np.unique(ks).tolist():
            by_k[k] = float(np.median(t_fast[ks == k]))
            rows.append(["dissertation", "grid", f"{k} ({int((ks == k).sum())})", by_k[k], "",
                         "", "", "", "", ""])
        figures.update({
            "qp_grid_problems": len(seq),
            "qp_grid_runs": len(grid_runs),
            "qp_grid_cvxpy_checked": len(pick),
            "qp_grid_warm_hits": warm / max(len(seq), 1),
            "qp_grid_not_found": not_found,
            "qp_p50_us": p50,
            "qp_p99_us": p99,
            # CPU time of the same calls (thread clock): what other load on the machine
            # does not inflate by preemption
            "qp_p50_cpu_us": float(np.median(c_fast)),
            "qp_p50_us_by_contacts": {str(k): v for k, v in by_k.items()},
            "cvxpy_p50_us": r50,
            "cvxpy_p99_us": r99,
            "speedup_vs_cvxpy": r50 / p50,
            "max_abs_diff_vs_cvxpy": max(diff, random_diff),
            "max_abs_diff_vs_cvxpy_grid": diff,
            "qp_not_found": misses,
        })
    else:  # no grid run: the random problems stand in
        figures.update({"qp_p50_us": figures["qp_random_p50_us"],
                        "qp_p99_us": figures["qp_random_p99_us"],
                        "max_abs_diff_vs_cvxpy": random_diff})
    print_table(
        "contact-force QP: the grid's contact sets (in the loop's order, warm start as in the "
        f"loop; cvxpy on a sample) and {n} random contact sets (2-5 contacts, cold); times in us",
        ["method", "problems", "contacts", "fast p50", "fast p99", "cvxpy p50", "cvxpy p99",
         "speedup", "max |diff| [N]", "not found"],
        rows,
    )
    # The dynamic feasibility LP (eq. III.10-III.16) on the same contact sets, 0.2 kg object.
    t_lp = _timed(lambda c, com, *_: dynamic_feasibility(c, 0.2, com), problems, 1)
    figures["feasibility_lp_p50_us"] = float(np.median(t_lp))
    print_table("dynamic feasibility LP (HiGHS), the random contact sets; times in us",
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


def grid_section(quick: bool, record: list[list[Problem]] | None = None) -> dict[str, Any]:
    """Lift-and-carry grid in simulation, composite vs PD-only (see ``_grasp_grid``);
    ``record`` collects the contact QPs of every composite run."""
    from hand_control.bench._grasp_grid import run_grid

    return run_grid(quick, record=record)


def run(quick: bool = False) -> dict[str, Any]:
    """Run every section; returns the figures for the last-line JSON. The grid runs first: the
    QP section times the contact sets it met."""
    figures: dict[str, Any] = {}
    runs: list[list[Problem]] = []
    grid = grid_section(quick, record=runs)
    figures.update(qp_section(quick, runs))
    figures.update(control_section(quick))
    figures.update(grid)
    return figures
