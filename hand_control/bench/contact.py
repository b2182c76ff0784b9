"""``hand-suite bench contact``: the contact-force QP of the composite controller.

QP section: random hand-object contact sets with 2-5 contacts (points on a 4 cm sphere around
the centre of mass, normals roughly towards it, mu in [0.2, 1.0], a target wrench around the
weight of a 50-500 g object). The control-loop path (:class:`ContactForceQP`, active-set NNLS)
is timed against its baselines measured in the same run: the headline, the same problem of
eq. (III.23) handed to OSQP directly (:class:`DirectOSQP`: the matrices built with numpy, one
OSQP workspace per contact layout updated in place and warm-started, polished at 1e-10 like the
reference, and at OSQP's default 1e-3 as a second row), and, secondary, the same problem
stated in cvxpy with Parameters (:class:`ReferenceContactQP`, polished OSQP under cvxpy's
modelling layer); the largest difference of their forces/torsional torques is reported. Both
methods are covered: eq. (III.23) of the dissertation (the headline figures) and seed 000's
eq. (10)+(11) (cvxpy only).

The grid section (:mod:`hand_control.bench._grasp_grid`) runs first: the QP figures are timed
on every problem the controller solved in its test-split runs, in the loop's order, recorded by
the solver's ``recorder`` hook at whichever entry point the loop calls.
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
from hand_control.contact.friction import cross_matrices, pyramid_edges

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


class DirectOSQP:
    """Eq. (III.23) handed to OSQP directly: the baseline a user would write without the
    active-set solver or a modelling layer.

    Unknowns ``x = (lambda (K E), l (K))``, ``f_k = B_k lambda_k`` (pyramid edges); the
    objective ``|A x - b|^2`` with ``A`` the rows ``sqrt(a1) sum_k f_k``, ``sqrt(a2) (sum_k
    r_k x f_k + l_k n_k)``, ``sqrt(a3) f_k``, ``sqrt(a4) l_k`` and ``b`` the weighted targets,
    i.e. ``P = 2 A'A`` (dense upper triangle), ``q = -2 A'b``; constraints ``lambda >= 0`` and,
    for a bounded torsion, ``|l_k| <= mu_t n_k . f_k``. One OSQP workspace per contact layout
    (count and friction), updated in place (``P``, ``q``) and warm-started from the last
    solution, as a control loop would use it. ``solve`` returns ``(forces, torsion, status)``.
    """

    def __init__(self, config: ContactQPConfig, eps: float = 1e-10, polish: bool = True
                 ) -> None:
        self.config = config
        self.settings = dict(eps_abs=eps, eps_rel=eps, polishing=polish, max_iter=200000,
                             verbose=False)
        self._work: dict[tuple[int, bytes], tuple[Any, tuple[np.ndarray, np.ndarray]]] = {}

    def solve(self, contacts: ContactSet, com: np.ndarray, tf: np.ndarray, tt: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, str]:
        import osqp
        import scipy.sparse as sp

        cfg = self.config
        k, e = len(contacts), cfg.friction_edges
        ne, n = k * e, k * e + k
        s1, s2, s3, s4 = (np.sqrt(a) for a in (cfg.alpha1, cfg.alpha2, cfg.alpha3, cfg.alpha4))
        bf = pyramid_edges(contacts.normals, contacts.mu, e).transpose(0, 2, 1)  # (K, 3, E)
        a = np.zeros((6 + 3 * k + k, n))
        a[0:3, :ne] = s1 * bf.transpose(1, 0, 2).reshape(3, ne)
        a[3:6, :ne] = s2 * (cross_matrices(contacts.points - com) @ bf).transpose(
            1, 0, 2).reshape(3, ne)
        a[3:6, ne:] = s2 * contacts.normals.T
        for i in range(k):
            a[6 + 3 * i:9 + 3 * i, i * e:(i + 1) * e] = s3 * bf[i]
        a[6 + 3 * k:, ne:] = s4 * np.eye(k)
        b = np.zeros(a.shape[0])
        b[0:3], b[3:6] = s1 * tf, s2 * tt
        p = 2.0 * (a.T @ a)
        q = -2.0 * (a.T @ b)
        key = (k, contacts.mu.tobytes())
        ent = self._work.get(key)
        if ent is None:
            cons = [sp.hstack([sp.identity(ne), sp.csc_matrix((ne, k))])]
            lo, hi = [np.zeros(ne)], [np.full(ne, np.inf)]
            if cfg.torsion_bound:  # l_k - mu_t n.f_k <= 0, -l_k - mu_t n.f_k <= 0
                nf = np.zeros((k, n))
                cn = np.einsum("kj,kje->ke", contacts.normals, bf)
                for i in range(k):
                    nf[i, i * e:(i + 1) * e] = cfg.torsional_friction * cn[i]
                ll = np.zeros((k, n))
                ll[:, ne:] = np.eye(k)
                cons += [sp.csc_matrix(ll - nf), sp.csc_matrix(-ll - nf)]
                lo += [np.full(2 * k, -np.inf)]
                hi += [np.zeros(2 * k)]
            rows, cols = np.triu_indices(n)
            pattern = sp.csc_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
            order = (pattern.indices, np.repeat(np.arange(n), np.diff(pattern.indptr)))
            prob = osqp.OSQP()
            prob.setup(P=sp.csc_matrix((p[order], pattern.indices, pattern.indptr),
                                       shape=(n, n)),
                       q=q, A=sp.csc_matrix(sp.vstack(cons)), l=np.concatenate(lo),
                       u=np.concatenate(hi), **self.settings)
            ent = self._work[key] = (prob, order)
        else:
            ent[0].update(Px=p[ent[1]], q=q)
        res = ent[0].solve(raise_error=False)
        status = str(res.info.status)
        if res.x is None or not np.isfinite(res.x).all():
            return np.zeros((k, 3)), np.zeros(k), status
        lam = res.x[:ne].reshape(k, e)
        return np.einsum("kje,ke->kj", bf, lam), res.x[ne:].copy(), status


def _max_diff(fast: list[Any], ref: list[Any]) -> tuple[float, int]:
    """Largest |difference| of forces and torsions where both were solved (an
    ``"unreachable"`` target is solved: its forces are the optimum); count of misses."""
    worst, misses = 0.0, 0
    for a, b in zip(fast, ref, strict=True):
        if not (a.status in ("optimal", "unreachable")
                and b.status in ("optimal", "unreachable")):
            misses += 1
            continue
        worst = max(worst, float(np.abs(a.forces - b.forces).max()),
                    float(np.abs(a.torsion - b.torsion).max()))
    return worst, misses


def _timed_sequences(cfg: ContactQPConfig, runs: list[list[Problem]]
                     ) -> tuple[np.ndarray, np.ndarray, list[Any], int]:
    """Per-call wall and CPU (thread) times [us] of the fast path over the grid's problem
    sequences, each in the order the control loop met it, through the loop's entry point
    (:meth:`ContactForceQP.solve_arrays`), with a fresh solver per run (so the warm start is
    the loop's); the results and the warm-start hits. GC off."""
    times, cpu, results, warm = [], [], [], 0
    perf, thread = time.perf_counter, time.thread_time
    gc.collect()
    gc.disable()
    try:
        for seq in runs:
            qp = ContactForceQP(cfg)
            for c, com, tf, tt in seq:
                wrench = tf.tolist() + tt.tolist()
                c0 = thread()
                t0 = perf()
                res = qp.solve_arrays(c.points, c.normals, c.mu, com, wrench)
                t1 = perf()
                cpu.append(thread() - c0)
                times.append(t1 - t0)
                results.append(res)
            warm += qp.warm_hits
    finally:
        gc.enable()
    return 1e6 * np.array(times), 1e6 * np.array(cpu), results, warm


def _timed_osqp(cfg: ContactQPConfig, runs: list[list[Problem]], eps: float
                ) -> tuple[np.ndarray, list[Any]]:
    """Per-call wall times [us] of :class:`DirectOSQP` over the sequences in order (one solver
    per run, warm-started as in a loop) and its results as ``(forces, torsion, status)``."""
    times, results = [], []
    perf = time.perf_counter
    gc.collect()
    gc.disable()
    try:
        for seq in runs:
            osqp = DirectOSQP(cfg, eps=eps, polish=eps < 1e-6)
            for c, com, tf, tt in seq:
                t0 = perf()
                out = osqp.solve(c, com, tf, tt)
                times.append(perf() - t0)
                results.append(out)
    finally:
        gc.enable()
    return 1e6 * np.array(times), results


def _osqp_diff(fast: list[Any], osqp: list[Any]) -> tuple[float, int]:
    """Largest |difference| of forces/torsions between the fast path and direct OSQP where
    both solved the problem; count of problems one of them did not solve."""
    worst, misses = 0.0, 0
    for a, (f, t, st) in zip(fast, osqp, strict=True):
        if a.status not in ("optimal", "unreachable") or st != "solved":
            misses += 1
            continue
        worst = max(worst, float(np.abs(a.forces - f).max()), float(np.abs(a.torsion - t).max()))
    return worst, misses


QP_SIZES = {"full": (400, 10, 600, 20000), "quick": (80, 5, 150, 8000),
            "smoke": (20, 1, 10, 300)}  # random problems, repeats, cvxpy sample, OSQP cap


def qp_section(size: str, grid_runs: list[tuple[ContactQPConfig, list[Problem]]] | None = None
               ) -> dict[str, Any]:
    """The fast path vs direct OSQP (headline) and cvxpy (secondary): on the contact sets met
    in the lift-and-carry grid (every QP the composite test-split runs solved, timed in their
    order through the loop's entry point), and on random contact sets with 2-5 contacts (cold
    problems, both methods)."""
    n, repeats, n_cvxpy, osqp_cap = QP_SIZES[size]
    problems = random_problems(seed=5, n=n)
    figures: dict[str, Any] = {"qp_problems": n, "qp_contacts": "2-5"}
    rows = []
    random_diff = 0.0
    for method in ("dissertation", "seed000"):
        cfg = ContactQPConfig(method=method)
        fast, ref = ContactForceQP(cfg), ReferenceContactQP(cfg)
        t_fast = _timed(fast.solve, problems, repeats)
        t_ref = _timed(ref.solve, problems, 1)
        fast_res = [fast.solve(*p) for p in problems]
        diff, misses = _max_diff(fast_res, [ref.solve(*p) for p in problems])
        p50, p99 = np.percentile(t_fast, [50, 99])
        r50, r99 = np.percentile(t_ref, [50, 99])
        unreachable = sum(r.status == "unreachable" for r in fast_res)
        rows.append([method, "random", "all", p50, p99, "cvxpy", r50, r99, r50 / p50, diff,
                     misses])
        if method == "dissertation":
            t_osqp, osqp_res = _timed_osqp(cfg, [problems], 1e-10)
            o50, o99 = np.percentile(t_osqp, [50, 99])
            odiff, omiss = _osqp_diff(fast_res, osqp_res)
            rows.append([method, "random", "all", p50, p99, "OSQP direct", o50, o99, o50 / p50,
                         odiff, omiss])
        by_k = {}
        for k in CONTACT_COUNTS:
            sub = [p for p in problems if len(p[0]) == k]
            by_k[k] = float(np.median(_timed(fast.solve, sub, repeats)))
            rows.append([method, "random", k, by_k[k], "", "", "", "", "", "", ""])
        if method == "dissertation":
            random_diff = diff
            figures.update({
                "qp_random_p50_us": p50, "qp_random_p99_us": p99,
                "qp_random_p50_us_by_contacts": {str(k): v for k, v in by_k.items()},
                "osqp_random_p50_us": o50, "speedup_vs_osqp_random": o50 / p50,
                "max_abs_diff_vs_osqp_random": odiff,
                "cvxpy_random_p50_us": r50, "max_abs_diff_vs_cvxpy_random": diff,
                "qp_random_not_found": misses, "qp_random_unreachable": unreachable})
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
                "seed000_qp_unreachable": unreachable,
            })
    if grid_runs:
        # the QP as the grid's controller ran it (its configuration, as recorded)
        cfg = grid_runs[0][0]
        runs = [seq for _, seq in grid_runs]
        seq = [p for run in runs for p in run]
        if not seq:
            raise RuntimeError("the grid recorded no contact-QP problem: the recorder is not "
                               "on the solver the control loop calls")
        t_fast, c_fast, fast_res, warm = _timed_sequences(cfg, runs)
        p50, p99 = np.percentile(t_fast, [50, 99])
        # direct OSQP on whole runs in order (warm-started as in the loop), up to a cap
        head, count = [], 0
        for run in runs:
            if count and count + len(run) > osqp_cap:
                break
            head.append(run[:osqp_cap])
            count += len(head[-1])
        base_rows = {}
        for name, eps in (("OSQP direct", 1e-10), ("OSQP direct eps 1e-3", 1e-3)):
            t_o, res_o = _timed_osqp(cfg, head, eps)
            d_o, m_o = _osqp_diff(fast_res[:count], res_o)
            base_rows[name] = (np.percentile(t_o, 50), np.percentile(t_o, 99), d_o, m_o)
        # cvxpy on an evenly spread sample of the same problems (it takes milliseconds each)
        pick = np.unique(np.linspace(0, len(seq) - 1, min(len(seq), n_cvxpy))
                         .astype(int)).tolist()
        ref = ReferenceContactQP(cfg)
        t_ref = _timed(ref.solve, [seq[i] for i in pick], 1)
        diff, misses = _max_diff([fast_res[i] for i in pick], [ref.solve(*seq[i]) for i in pick])
        base_rows["cvxpy"] = (np.percentile(t_ref, 50), np.percentile(t_ref, 99), diff, misses)
        # the accuracy check without a tolerance of its own: scipy's compiled Lawson-Hanson
        # from scratch (a fresh solver's cold path) on the same sample, KKT-checked
        t_cold = _timed(lambda *p: ContactForceQP(cfg).solve(*p, check=False),
                        [seq[i] for i in pick], 1)
        cold_diff, cold_miss = _max_diff(
            [fast_res[i] for i in pick],
            [ContactForceQP(cfg).solve(*seq[i], check=False) for i in pick])
        base_rows["scipy NNLS, cold"] = (np.percentile(t_cold, 50), np.percentile(t_cold, 99),
                                         cold_diff, cold_miss)
        for name, (b50, b99, d, m) in base_rows.items():
            rows.append(["dissertation", "grid", "all", p50, p99, name, b50, b99, b50 / p50, d,
                         m])
        ks = np.array([len(p[0]) for p in seq])
        by_k = {}
        for k in np.unique(ks).tolist():
            by_k[k] = float(np.median(t_fast[ks == k]))
            rows.append(["dissertation", "grid", f"{k} ({int((ks == k).sum())})", by_k[k], "",
                         "", "", "", "", "", ""])
        o50, _, odiff, omiss = base_rows["OSQP direct"]
        d50, _, ddiff, _ = base_rows["OSQP direct eps 1e-3"]
        r50, r99 = base_rows["cvxpy"][:2]
        figures.update({
            "qp_grid_problems": len(seq),
            "qp_grid_runs": len(runs),
            "qp_grid_alpha": cfg.alpha3,
            "qp_grid_osqp_checked": count,
            "qp_grid_cvxpy_checked": len(pick),
            "qp_grid_warm_hits": warm / max(len(seq), 1),
            "qp_grid_not_found": sum(not r.found for r in fast_res),
            "qp_grid_unreachable": sum(r.status == "unreachable" for r in fast_res),
            "qp_p50_us": p50,
            "qp_p99_us": p99,
            # CPU time of the same calls (thread clock): what other load on the machine
            # does not inflate by preemption
            "qp_p50_cpu_us": float(np.median(c_fast)),
            "qp_p50_us_by_contacts": {str(k): v for k, v in by_k.items()},
            # the headline baseline: the same problem handed to OSQP directly
            "osqp_p50_us": o50,
            "speedup_vs_osqp": o50 / p50,
            "max_abs_diff_vs_osqp": odiff,
            "qp_osqp_not_solved": omiss,
            "osqp_eps1e-3_p50_us": d50,
            "speedup_vs_osqp_eps1e-3": d50 / p50,
            "max_abs_diff_vs_osqp_eps1e-3": ddiff,
            # secondary: cvxpy's modelling layer over polished OSQP
            "cvxpy_p50_us": r50,
            "cvxpy_p99_us": r99,
            "speedup_vs_cvxpy": r50 / p50,
            "max_abs_diff_vs_cvxpy": max(diff, random_diff),
            "max_abs_diff_vs_cvxpy_grid": diff,
            "max_abs_diff_vs_nnls_cold_grid": cold_diff,
            "qp_not_found": misses,
        })
    else:  # no grid run: the random problems stand in
        figures.update({"qp_p50_us": figures["qp_random_p50_us"],
                        "qp_p99_us": figures["qp_random_p99_us"],
                        "osqp_p50_us": figures["osqp_random_p50_us"],
                        "speedup_vs_osqp": figures["speedup_vs_osqp_random"],
                        "max_abs_diff_vs_osqp": figures["max_abs_diff_vs_osqp_random"],
                        "max_abs_diff_vs_cvxpy": random_diff})
    print_table(
        "contact-force QP: the grid's contact sets (in the loop's order, warm start as in the "
        f"loop; baselines on whole runs / a sample) and {n} random contact sets (2-5 "
        "contacts, cold); times in us",
        ["method", "problems", "contacts", "fast p50", "fast p99", "baseline", "base p50",
         "base p99", "speedup", "max |diff| [N]", "not solved"],
        rows,
    )
    # The dynamic feasibility LP (eq. III.10-III.16) on the same contact sets, 0.2 kg object.
    t_lp = _timed(lambda c, com, *_: dynamic_feasibility(c, 0.2, com), problems, 1)
    figures["feasibility_lp_p50_us"] = float(np.median(t_lp))
    print_table("dynamic feasibility LP (HiGHS), the random contact sets; times in us",
                ["p50", "p99"], [[float(np.median(t_lp)), float(np.percentile(t_lp, 99))]])
    return figures


def control_section(size: str) -> dict[str, Any]:
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

    n, repeats = {"full": (200, 20), "quick": (40, 10), "smoke": (8, 2)}[size]
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
    times, fallbacks = {}, {}
    for mode in ("composite", "pd_only"):
        ctrl = CompositeController(CompositeControlConfig(mode=mode))

        def step(q, qd, qt, obj, target, arrays, ctrl=ctrl):
            return ctrl.compute(q, qd, qt, obj, target, ContactSet(**arrays), np.zeros(nv))

        times[mode] = _timed(step, steps, repeats)
        # a step whose random contacts cannot push where the target says (the QP reports
        # it unreachable) falls back to PD
        fallbacks[mode] = ctrl.fallbacks / max(ctrl.steps, 1)
    c50, p50 = float(np.median(times["composite"])), float(np.median(times["pd_only"]))
    print_table(f"controller step, {nv} DoFs, 2-5 contacts, {n} states; times in us",
                ["mode", "p50", "p99"],
                [[m, float(np.median(t)), float(np.percentile(t, 99))] for m, t in times.items()])
    return {"control_step_p50_us": c50, "control_step_p99_us":
            float(np.percentile(times["composite"], 99)), "pd_only_step_p50_us": p50,
            "control_step_fallback_rate": fallbacks["composite"]}


def grid_section(size: str, record: list | None = None) -> dict[str, Any]:
    """Lift-and-carry grid in simulation, composite vs PD-only (see ``_grasp_grid``);
    ``record`` collects the contact QPs of every composite test-split run."""
    from hand_control.bench._grasp_grid import run_grid

    return run_grid(record=record, size=size)


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """Run every section; returns the figures for the last-line JSON. The grid runs first: the
    QP section times the contact sets it met. ``smoke``: a few cells and problems through the
    same code (the test suite's check that the benchmark runs)."""
    size = "smoke" if smoke else "quick" if quick else "full"
    figures: dict[str, Any] = {}
    runs: list[Any] = []
    grid = grid_section(size, record=runs)
    figures.update(qp_section(size, runs))
    figures.update(control_section(size))
    figures.update(grid)
    return figures
