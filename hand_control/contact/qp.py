"""Contact forces and torsional torques that realise a target wrench on the object.

Two formulations, chosen by ``ContactQPConfig.method``:

* ``"dissertation"`` -- eq. (III.23) of dissertation 003::

      min  a1 |sum_k f_k + G - f_v|^2 + a2 |sum_k (r_k x f_k + l_k n_k) - tau_v|^2
           + a3 sum_k |f_k|^2 + a4 sum_k l_k^2
      s.t. f_k = B_k lambda_k, lambda_k >= 0     (friction pyramid)

  with ``a1..a4 = 1, 1, 0.1, 0.1``. The torsional torques ``l_k`` are free: the dissertation
  (like seed 000, eq. 11) only regularises them. ``torsion_bound`` optionally adds the
  soft-contact limit ``|l_k| <= torsional_friction * (n_k . f_k)``.
* ``"seed000"`` -- eq. (10) then eq. (11) of seed 000: scale the simulator's contact forces,
  ``f_aug,i = w_i f_c,i`` with ``w_i >= 0``, then fit the torsional torques to the remaining
  torque, ``lambda1 = lambda2 = 1``.

The caller passes the net wrench the contacts must apply on the object, ``force_target =
f_v - G`` (virtual force of eq. 9 / III.22 with the weight compensated) and ``torque_target =
tau_v``.

:class:`ContactForceQP` is the control-loop path: the problem is stacked as a non-negative
least-squares problem and solved exactly by the Lawson-Hanson active-set method
(``scipy.optimize.nnls``). :class:`ReferenceContactQP` states the same problem once in cvxpy
with Parameters (DPP) and is the reference the tests and the benchmark compare against. The
objective is strictly convex in the forces and torsional torques, so both paths must return
the same ``f_k, l_k`` (the pyramid coefficients ``lambda_k`` themselves are not unique).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.linalg.lapack import dposv as _dposv
from scipy.optimize import nnls

from hand_capture.config import param, validate
from hand_control.contact.friction import (
    cross,
    cross_matrices,
    edge_directions,
    pyramid_edges,
)
from hand_control.contact.types import ContactSet, as_finite_array
from hand_control.errors import InputError, SolverError

__all__ = [
    "ContactForceQP",
    "ContactForceResult",
    "ContactQPConfig",
    "ReferenceContactQP",
]

METHODS = ("dissertation", "seed000")
_EYE3 = np.eye(3)


@dataclass(frozen=True)
class ContactQPConfig:
    """Parameters of the contact-force QP (dissertation eq. III.23, seed 000 eq. 10-11)."""

    method: str = param(
        "dissertation",
        "contact-force formulation: 'dissertation' = eq. (III.23), 'seed000' = eq. (10)+(11)",
        choices=METHODS,
    )
    friction_edges: int = param(
        4, "edges of each friction pyramid (4 in dissertation sec. III.4.1.3)", lo=4, hi=64
    )
    alpha1: float = param(1.0, "weight of the net force error, eq. (III.23)", lo=0.0)
    alpha2: float = param(1.0, "weight of the net torque error, eq. (III.23)", lo=0.0)
    alpha3: float = param(
        0.1, "weight of sum |f_k|^2, eq. (III.23); > 0 keeps the forces unique", lo=1e-9
    )
    alpha4: float = param(
        0.1, "weight of sum l_k^2, eq. (III.23); > 0 keeps the torsions unique", lo=1e-9
    )
    lambda1: float = param(1.0, "weight of sum (w_i - 1)^2, seed 000 eq. (10)", lo=1e-9)
    lambda2: float = param(1.0, "weight of sum l_i^2, seed 000 eq. (11)", lo=1e-9)
    torsion_bound: bool = param(
        False,
        "bound |l_k| <= torsional_friction * normal force (method 'dissertation'; the papers "
        "only regularise l_k)",
    )
    torsional_friction: float = param(
        0.005, "torsional friction coefficient [m] used when torsion_bound is set", lo=0.0
    )
    max_iter: int = param(
        0, "iteration cap of the active-set solver; 0 = 3 x number of unknowns", lo=0
    )
    kkt_tol: float = param(
        1e-9, "relative optimality (KKT) tolerance that accepts a solution", lo=0.0, hi=1e-2
    )

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True, eq=False)
class ContactForceResult:
    """Outcome of one contact-force solve; arrays are never NaN.

    Attributes:
        found: a solution that passed the optimality check (False: forces are zero).
        status: ``"optimal"``, ``"no_contacts"``, ``"max_iter"``, ``"non_finite"``,
            ``"inaccurate"`` or a cvxpy status (reference path).
        forces: (K, 3) contact forces on the object [N].
        torsion: (K,) torsional torque magnitudes ``l_k`` [N m]; the torque is ``l_k n_k``.
        wrench_error: (6,) net wrench of the solution minus the target (force, torque).
        residual: Euclidean norm of ``wrench_error``.
        objective: value of the objective (eq. III.23, or eq. 10 + eq. 11).
        solve_time_s: wall time of the whole solve, building included [s].
        method: the formulation used.
    """

    found: bool
    status: str
    forces: np.ndarray
    torsion: np.ndarray
    wrench_error: np.ndarray
    residual: float
    objective: float
    solve_time_s: float
    method: str


def _check_targets(
    contacts: ContactSet, com: Any, force_target: Any, torque_target: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not isinstance(contacts, ContactSet):
        raise InputError(f"contacts must be a ContactSet, got {type(contacts).__name__}")
    try:  # one stacked check on the hot path; the named checks below only for the message
        stacked = np.array((com, force_target, torque_target), dtype=np.float64)
        if stacked.shape == (3, 3) and np.isfinite(stacked).all():
            return stacked[0], stacked[1], stacked[2]
    except (TypeError, ValueError):
        pass
    return (
        as_finite_array("object centre of mass", com, (3,)),
        as_finite_array("force target", force_target, (3,)),
        as_finite_array("torque target", torque_target, (3,)),
    )


def _net_wrench_error(
    contacts: ContactSet, r: np.ndarray, forces: np.ndarray, torsion: np.ndarray,
    force_target: np.ndarray, torque_target: np.ndarray,
) -> np.ndarray:
    net_f = forces.sum(axis=0)
    net_t = (cross(r, forces) + torsion[:, None] * contacts.normals).sum(axis=0)
    return np.concatenate([net_f - force_target, net_t - torque_target])


def _result(
    status: str, contacts: ContactSet, r: np.ndarray, targets: tuple[np.ndarray, np.ndarray],
    t0: float, method: str, solution: tuple[np.ndarray, np.ndarray, float] | None = None,
    wrench_error: np.ndarray | None = None, residual: float | None = None,
) -> ContactForceResult:
    """The result of a solve; ``solution = (forces, torsion, objective)``, None if not found.

    ``residual``: the norm of ``wrench_error`` when the caller has it already.
    """
    if solution is None:
        forces, torsion, objective = np.zeros((len(r), 3)), np.zeros(len(r)), math.inf
        wrench_error = residual = None
    else:
        forces, torsion, objective = solution
    if wrench_error is None:
        wrench_error = _net_wrench_error(contacts, r, forces, torsion, *targets)
    if residual is None:
        residual = math.sqrt(float(wrench_error @ wrench_error))
    return _new_result(solution is not None, status, forces, torsion, wrench_error, residual,
                       float(objective), time.perf_counter() - t0, method)


_RESULT_FIELDS = tuple(f.name for f in fields(ContactForceResult))


def _new_result(*values: Any) -> ContactForceResult:
    """A :class:`ContactForceResult` from its field values in order, without the
    frozen-dataclass ``__init__`` (one per control step)."""
    res = object.__new__(ContactForceResult)
    res.__dict__.update(zip(_RESULT_FIELDS, values, strict=True))
    return res


@lru_cache(maxsize=64)
def _block_eye(k: int) -> np.ndarray:
    """(K, 1, K, 1) identity that spreads (K, R, 1, G) blocks onto a block diagonal."""
    eye = np.eye(k)[:, None, :, None]
    eye.setflags(write=False)
    return eye


def _local_generator_basis(
    n_edges: int, torsion_bound: bool, torsional_friction: float
) -> np.ndarray:
    """(3, 4 G) basis of the local generators: ``H_k = [mu/s, 1/s, 1] @ basis`` (s = sqrt(1+mu^2)).

    ``H_k`` reshaped to (4, G) holds one generator ``(f_t1, f_t2, f_n, l)`` per column in the
    contact frame ``(t1, t2, n)``: the unit pyramid edges ``(mu cos th_j, mu sin th_j, 1) / s``
    with no torsion, plus ``(0, 0, 0, +-1)`` for a free torsion; for a bounded torsion each
    edge twice, with ``l = +-mu_t / s`` (its normal force times ``mu_t``).
    """
    dirs = edge_directions(n_edges)
    g = 2 * n_edges if torsion_bound else n_edges + 2
    basis = np.zeros((3, 4, g))  # rows: coefficient of mu/s, of 1/s, constant
    if torsion_bound:
        basis[0, 0:2] = np.hstack([dirs, dirs])
        basis[1, 2] = 1.0
        basis[1, 3] = np.repeat([torsional_friction, -torsional_friction], n_edges)
    else:
        basis[0, 0:2, :n_edges] = dirs
        basis[1, 2, :n_edges] = 1.0
        basis[2, 3, n_edges:] = 1.0, -1.0
    return basis.reshape(3, 4 * g)


class _ContactForceSolver:
    """What both solvers share: input checks, the empty case and the choice of method."""

    config: ContactQPConfig

    def solve(
        self, contacts: ContactSet, com: Any, force_target: Any, torque_target: Any,
        check: bool = True,
    ) -> ContactForceResult:
        """Contact forces/torsions whose net wrench about ``com`` approaches the target.

        Args:
            contacts: the contacts (``forces`` required for method ``"seed000"``).
            com: (3,) object centre of mass [m]; ``r_k = p_k - com``.
            force_target: (3,) net force the contacts must apply [N] (``f_v - G``).
            torque_target: (3,) net torque about ``com`` [N m] (``tau_v``).
            check: validate the targets (the API boundary). ``False``: the caller vouches
                for (3,) finite float64 arrays (the controller's fast path).

        Raises:
            InputError: NaN/Inf or wrong shapes, or ``seed000`` without contact forces.
        """
        t0 = time.perf_counter()
        if check:
            com, tf, tt = _check_targets(contacts, com, force_target, torque_target)
        else:
            tf, tt = force_target, torque_target
        method = self.config.method
        r = contacts.points - com
        if len(contacts) == 0:
            return _result("no_contacts", contacts, r, (tf, tt), t0, method)
        if method == "seed000":
            if contacts.forces is None:
                raise InputError("method 'seed000' (eq. 10) needs the simulator's contact forces")
            return self._solve_seed000(contacts, r, tf, tt, t0)
        return self._solve_dissertation(contacts, r, tf, tt, t0)

    def _solve_dissertation(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        raise NotImplementedError

    def _solve_seed000(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        raise NotImplementedError


class _Layout:
    """Buffers of one problem shape: K contacts with given friction coefficients.

    The generators and the regularisation rows of the stacked matrix depend on ``mu`` only;
    the six wrench rows are rewritten in place at every solve.
    """

    __slots__ = ("a", "a6", "b", "hb")

    def __init__(self, h: np.ndarray, reg_weights: np.ndarray) -> None:
        k, _, g = h.shape
        # (4K, K G) block diagonal: column k G + j is generator j of contact k in the local
        # coordinates (f_t1, f_t2, f_n, l) of contact k
        self.hb = (h[:, :, None, :] * _block_eye(k)).reshape(4 * k, k * g)
        self.a = np.zeros((6 + 4 * k, k * g))
        # sqrt(a3) f_k and sqrt(a4) l_k rows: diag(reg_1..reg_K)
        self.a[6:] = np.tile(reg_weights[0], (k, 1)) * self.hb
        self.a6 = self.a[0:6]  # the six weighted wrench rows (a contiguous view)
        self.b = np.zeros(6 + 4 * k)


def _contact_maps(
    normals: list[list[float]], r: list[list[float]], wf: float, wt: float
) -> tuple[list[list[float]], list[tuple[float, ...]]]:
    """The map from every contact's local ``(f_t1, f_t2, f_n, l)`` to the weighted wrench on
    the object about its COM, ``[wf R_k, 0; wt [r_k]x R_k, wt n_k]``, as the six rows of a
    (6, 4K) matrix, and each contact's frame ``R_k``.

    ``R = [t1 t2 n]`` is :func:`contact_frames`'s Householder frame, written out on floats:
    for a few contacts, plain arithmetic costs less than numpy's per-call overhead.
    """
    rows: list[list[float]] = [[], [], [], [], [], []]
    r0, r1, r2, r3, r4, r5 = rows
    frames = []
    for (nx, ny, nz), (rx, ry, rz) in zip(normals, r, strict=True):
        sg = math.copysign(1.0, nz)
        vz = nz + sg
        c = 2.0 / (nx * nx + ny * ny + vz * vz)
        # I - c v v^T with v = n + sign(n_z) e_z; first column times the sign (handedness)
        ax, ay, az = (1.0 - c * (nx * nx)) * sg, -(c * (ny * nx)) * sg, -(c * (vz * nx)) * sg
        bx, by, bz = -(c * (nx * ny)), 1.0 - c * (ny * ny), -(c * (vz * ny))
        frames.append((ax, ay, az, bx, by, bz, nx, ny, nz))
        # force rows wf R, torque rows wt [r x t1, r x t2, r x n, n]
        r0 += (wf * ax, wf * bx, wf * nx, 0.0)
        r1 += (wf * ay, wf * by, wf * ny, 0.0)
        r2 += (wf * az, wf * bz, wf * nz, 0.0)
        r3 += (wt * (ry * az - rz * ay), wt * (ry * bz - rz * by), wt * (ry * nz - rz * ny),
               wt * nx)
        r4 += (wt * (rz * ax - rx * az), wt * (rz * bx - rx * bz), wt * (rz * nx - rx * nz),
               wt * ny)
        r5 += (wt * (rx * ay - ry * ax), wt * (rx * by - ry * bx), wt * (rx * ny - ry * nx),
               wt * nz)
    return rows, frames


class ContactForceQP(_ContactForceSolver):
    """Fast contact-force solver for the control loop (exact active-set NNLS).

    Each contact contributes non-negative generators ``(f, l)`` of its admissible set: the
    pyramid edges ``(b_j, 0)`` and, for a free torsion, ``(0, +1)`` and ``(0, -1)``; for a
    bounded torsion ``(b_j, +-mu_t n.b_j)`` (the cone these span is exactly ``{f in pyramid,
    |l| <= mu_t n.f}``). Every term of eq. (III.23) is linear in the generator coefficients, so
    the problem is ``min |A x - b|^2, x >= 0``, solved by Lawson-Hanson (exact up to rounding)
    and accepted only if it passes a KKT check.

    Warm start: in a control loop the set of generators in use (the passive set) rarely
    changes between steps. The solver first solves the least-squares problem on the last
    passive set of the same contact count; that is the exact optimum whenever the KKT check
    passes (all coefficients positive, gradient >= 0 elsewhere). Otherwise the full
    Lawson-Hanson solve runs, so the result is the same either way.
    """

    _MAX_LAYOUTS = 32

    def __init__(self, config: ContactQPConfig | None = None) -> None:
        self.config = cfg = config or ContactQPConfig()
        s1, s2, s3, s4 = (math.sqrt(a) for a in (cfg.alpha1, cfg.alpha2, cfg.alpha3, cfg.alpha4))
        self._s12 = (s1, s2)
        self._reg_weights = np.array([s3, s3, s3, s4])[None, :, None]
        self._basis = _local_generator_basis(
            cfg.friction_edges, cfg.torsion_bound, cfg.torsional_friction
        )
        self._n_gen = self._basis.shape[1] // 4
        self._maxiter = cfg.max_iter or None
        self._layouts: dict[tuple[int, bytes], _Layout] = {}
        self._passive: dict[Any, np.ndarray] = {}  # warm start: last passive set per shape
        self.warm_hits = 0  # solves the warm start answered (diagnostics)

    def _layout(self, mu: np.ndarray) -> _Layout:
        key = (mu.shape[0], mu.tobytes())
        lay = self._layouts.get(key)
        if lay is None:
            k, g = mu.shape[0], self._n_gen
            inv_s = 1.0 / np.sqrt(1.0 + mu * mu)
            coef = np.empty((k, 3))
            coef[:, 0], coef[:, 1], coef[:, 2] = mu * inv_s, inv_s, 1.0
            h = (coef @ self._basis).reshape(k, 4, g)  # generators in the contact frames
            if len(self._layouts) >= self._MAX_LAYOUTS:
                self._layouts.clear()
            lay = self._layouts[key] = _Layout(h, self._reg_weights)
        return lay

    # -- eq. (III.23) ---------------------------------------------------------------------
    def _solve_dissertation(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        k = len(contacts)
        lay = self._layout(contacts.mu)
        s1, s2 = self._s12
        rl = r.tolist()
        maps, frames = _contact_maps(contacts.normals.tolist(), rl, s1, s2)
        # Least-squares rows: sqrt(a1) net force, sqrt(a2) net torque (the wrench of every
        # generator about the COM: maps @ generators), then per contact sqrt(a3) f_k and
        # sqrt(a4) l_k (|f_k| is frame-invariant: local coordinates serve; constant rows).
        np.array(maps).dot(lay.hb, out=lay.a6)
        tfl, ttl = tf.tolist(), tt.tolist()
        a, b = lay.a, lay.b
        b[0:6] = [s1 * tfl[0], s1 * tfl[1], s1 * tfl[2], s2 * ttl[0], s2 * ttl[1], s2 * ttl[2]]
        x, status, objective = self._nnls(a, b, k)
        if x is None:
            return _result(status, contacts, r, (tf, tt), t0, "dissertation")
        # local (f_t1, f_t2, f_n, l) of every contact, then world forces f = R f_local
        y = lay.hb.dot(x).tolist()
        forces, torsion = [], []
        fx = fy = fz = mx = my = mz = 0.0  # net wrench
        for i, ((ax, ay, az, bx, by, bz, nx, ny, nz), (rx, ry, rz)) in enumerate(
                zip(frames, rl, strict=True)):
            y0, y1, y2, y3 = y[4 * i:4 * i + 4]
            f0 = ax * y0 + bx * y1 + nx * y2
            f1 = ay * y0 + by * y1 + ny * y2
            f2 = az * y0 + bz * y1 + nz * y2
            forces.append((f0, f1, f2))
            torsion.append(y3)
            fx, fy, fz = fx + f0, fy + f1, fz + f2
            mx += ry * f2 - rz * f1 + y3 * nx
            my += rz * f0 - rx * f2 + y3 * ny
            mz += rx * f1 - ry * f0 + y3 * nz
        err = [fx - tfl[0], fy - tfl[1], fz - tfl[2], mx - ttl[0], my - ttl[1], mz - ttl[2]]
        return _result(status, contacts, r, (tf, tt), t0, "dissertation",
                       (np.array(forces), np.array(torsion), objective), np.array(err),
                       math.hypot(*err))

    # -- eq. (10) then eq. (11) -----------------------------------------------------------
    def _solve_seed000(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        cfg = self.config
        k = len(contacts)
        fc = contacts.forces
        s1 = math.sqrt(cfg.lambda1)
        # eq. (10): min |f_v - sum w_i f_c,i|^2 + lambda1 sum (w_i - 1)^2, w >= 0
        a = np.concatenate((fc.T, s1 * _block_eye(k)[:, 0, :, 0]))
        b = np.empty(3 + k)
        b[0:3], b[3:] = tf, s1
        w, status, obj10 = self._nnls(a, b)
        if w is None:
            return _result(status, contacts, r, (tf, tt), t0, "seed000")
        forces = w[:, None] * fc
        # eq. (11): min |sum (r_i x f_aug,i + l_i n_i) - tau_v|^2 + lambda2 sum l_i^2, a ridge
        # regression solved through its 3x3 dual: l = N^T (N N^T + lambda2 I)^-1 rest
        rest = tt - np.add.reduce(cross_matrices(r) @ forces[:, :, None], axis=0)[:, 0]
        nmat = contacts.normals.T
        torsion = nmat.T @ np.linalg.solve(nmat @ contacts.normals + cfg.lambda2 * _EYE3, rest)
        fit = nmat @ torsion - rest
        objective = obj10 + float(fit @ fit + cfg.lambda2 * torsion @ torsion)
        if not (math.isfinite(objective) and np.isfinite(torsion).all()):
            return _result("non_finite", contacts, r, (tf, tt), t0, "seed000")
        # net torque error = sum r x f + N l - tau_v = N l - rest = fit
        err = np.concatenate((np.add.reduce(forces, axis=0) - tf, fit))
        return _result(status, contacts, r, (tf, tt), t0, "seed000",
                       (forces, torsion, objective), err)

    def _nnls(
        self, a: np.ndarray, b: np.ndarray, warm_key: Any = None
    ) -> tuple[np.ndarray | None, str, float]:
        """``argmin |a x - b|^2, x >= 0`` and its objective, checked against the KKT conditions.

        ``warm_key`` names the problem shape whose last passive set is tried first (``None``:
        no warm start). Returns ``(None, status, inf)`` when the solver fails or the check does
        not pass.
        """
        if warm_key is not None:
            passive = self._passive.get(warm_key)
            if passive is not None:
                x = _ls_on_passive_set(a, b, passive)
                if x is not None:
                    status, objective = self._kkt(a, b, x, passive)
                    if status == "optimal":
                        self.warm_hits += 1
                        return x, status, objective
        try:
            x, _ = nnls(a, b, maxiter=self._maxiter)
        except RuntimeError:
            return None, "max_iter", math.inf
        except ValueError:  # NaN/Inf in the data (e.g. an overflow while building it)
            return None, "non_finite", math.inf
        passive = np.flatnonzero(x > 0.0)
        status, objective = self._kkt(a, b, x, passive)
        if status != "optimal":
            return None, status, math.inf
        if warm_key is not None:
            self._passive[warm_key] = passive
        return x, "optimal", objective

    def _kkt(
        self, a: np.ndarray, b: np.ndarray, x: np.ndarray, passive: np.ndarray
    ) -> tuple[str, float]:
        """``("optimal", |a x - b|^2)`` if ``x`` passes the KKT check, else the failure.

        ``passive``: the indices where ``x > 0``.
        """
        res = a.dot(x)
        res -= b
        grad = res.dot(a).tolist()
        objective = float(res.dot(res))
        # KKT of min |a x - b|^2, x >= 0: gradient >= 0 everywhere and = 0 where x > 0, i.e.
        # max(|grad_i| for x_i > 0, -grad_i for x_i = 0) = max(-min(grad), max(grad_passive))
        violation = -min(grad)
        if passive.size:
            violation = max(violation, max([grad[i] for i in passive.tolist()]))
        # |grad| <= |a| |b| at the optimum, and the entries of a are O(1) (unit generators,
        # lever arms well under 1 m): scale the tolerance with |b|^2 (>= |b| when |b| >= 1).
        tol = self.config.kkt_tol * max(1.0, float(b.dot(b)))
        if not (math.isfinite(objective) and math.isfinite(violation) and math.isfinite(tol)):
            return "non_finite", math.inf
        if violation > tol:
            return "inaccurate", math.inf
        return "optimal", objective


def _ls_on_passive_set(a: np.ndarray, b: np.ndarray, passive: np.ndarray) -> np.ndarray | None:
    """Least squares on the columns ``passive`` (normal equations, Cholesky), others zero.

    ``None`` unless every coefficient on the passive set comes out positive and finite (then
    the caller's KKT check decides whether this is the optimum).
    """
    if passive.size == 0:
        return None
    ap = a.take(passive, axis=1)
    apt = ap.T
    _, z, info = _dposv(apt.dot(ap), apt.dot(b))
    zl = z.tolist()
    if info != 0 or not (min(zl) > 0.0 and math.isfinite(sum(zl))):
        return None
    x = np.zeros(a.shape[1])
    x[passive] = z
    return x


class ReferenceContactQP(_ContactForceSolver):
    """The same problem in cvxpy with Parameters (DPP), one compiled problem per contact count.

    Slow (the modelling layer dominates) but independent of the fast path: the tests and the
    benchmark use it as the reference.
    """

    def __init__(
        self, config: ContactQPConfig | None = None, solver: str = "OSQP",
        solver_options: dict[str, Any] | None = None,
    ) -> None:
        self.config = config or ContactQPConfig()
        self.solver = solver
        if solver_options is None:
            # Polished OSQP at 1e-10 agrees with the exact active-set path to ~1e-9 N;
            # interior-point solvers (Clarabel at 1e-10) leave ~1e-6 N on flat directions.
            solver_options = {"eps_abs": 1e-10, "eps_rel": 1e-10, "polishing": True,
                              "max_iter": 200000} if solver == "OSQP" else {}
        self.solver_options = solver_options
        self._problems: dict[int, tuple[Any, dict[str, Any], dict[str, Any]]] = {}

    def _solve_dissertation(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        k, method = len(contacts), "dissertation"
        prob, par, var = self._dissertation_problem(k)
        edges = pyramid_edges(contacts.normals, contacts.mu, self.config.friction_edges)
        skew = cross_matrices(r)
        for i in range(k):
            par["B"][i].value = edges[i].T
            par["R"][i].value = skew[i]
        par["N"].value = contacts.normals.T
        par["tf"].value, par["tt"].value = tf, tt
        if "gn" in par:
            par["gn"].value = self.config.torsional_friction * contacts.normals
        status = self._run(prob)
        if status != "optimal":
            return _result(status, contacts, r, (tf, tt), t0, method)
        return _result(status, contacts, r, (tf, tt), t0, method,
                       (np.array(var["f"].value), np.array(var["l"].value), float(prob.value)))

    def _run(self, prob: Any) -> str:
        import cvxpy as cp

        try:
            prob.solve(solver=self.solver, **self.solver_options)
        except cp.error.SolverError as e:
            raise SolverError(f"cvxpy/{self.solver} failed: {e}") from e
        return str(prob.status)

    def _dissertation_problem(self, k: int) -> tuple[Any, dict[str, Any], dict[str, Any]]:
        if k in self._problems:
            return self._problems[k]
        import cvxpy as cp

        cfg = self.config
        e = cfg.friction_edges
        f = cp.Variable((k, 3))
        lam = cp.Variable((k, e), nonneg=True)
        l_ = cp.Variable(k)
        par: dict[str, Any] = {
            "B": [cp.Parameter((3, e)) for _ in range(k)],
            "R": [cp.Parameter((3, 3)) for _ in range(k)],
            "N": cp.Parameter((3, k)),
            "tf": cp.Parameter(3),
            "tt": cp.Parameter(3),
        }
        cons = [f[i] == par["B"][i] @ lam[i] for i in range(k)]  # friction pyramid
        net_f = cp.sum(f, axis=0)
        net_t = sum(par["R"][i] @ f[i] for i in range(k)) + par["N"] @ l_
        # eq. (III.23)
        obj = (
            cfg.alpha1 * cp.sum_squares(net_f - par["tf"])
            + cfg.alpha2 * cp.sum_squares(net_t - par["tt"])
            + cfg.alpha3 * cp.sum_squares(f)
            + cfg.alpha4 * cp.sum_squares(l_)
        )
        if cfg.torsion_bound:
            par["gn"] = cp.Parameter((k, 3))
            for i in range(k):
                normal_force = par["gn"][i] @ f[i]
                cons += [l_[i] <= normal_force, -l_[i] <= normal_force]
        prob = cp.Problem(cp.Minimize(obj), cons)
        if not prob.is_dpp():  # a modelling slip would make every solve recompile
            raise SolverError("the reference contact QP is not DPP")
        self._problems[k] = (prob, par, {"f": f, "l": l_})
        return self._problems[k]

    def _solve_seed000(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        import cvxpy as cp

        cfg = self.config
        k = len(contacts)
        key = -k  # seed-000 problems share the cache with negative keys
        if key not in self._problems:
            w = cp.Variable(k, nonneg=True)
            l_ = cp.Variable(k)
            par = {"Fc": cp.Parameter((3, k)), "tf": cp.Parameter(3),
                   "N": cp.Parameter((3, k)), "rest": cp.Parameter(3)}
            p10 = cp.Problem(cp.Minimize(  # eq. (10)
                cp.sum_squares(par["Fc"] @ w - par["tf"]) + cfg.lambda1 * cp.sum_squares(w - 1)
            ))
            p11 = cp.Problem(cp.Minimize(  # eq. (11)
                cp.sum_squares(par["N"] @ l_ - par["rest"]) + cfg.lambda2 * cp.sum_squares(l_)
            ))
            self._problems[key] = ((p10, p11), par, {"w": w, "l": l_})
        (p10, p11), par, var = self._problems[key]
        par["Fc"].value, par["tf"].value = contacts.forces.T, tf
        status = self._run(p10)
        if status != "optimal":
            return _result(status, contacts, r, (tf, tt), t0, "seed000")
        forces = np.asarray(var["w"].value)[:, None] * contacts.forces
        par["N"].value = contacts.normals.T
        par["rest"].value = tt - cross(r, forces).sum(axis=0)
        status = self._run(p11)
        if status != "optimal":
            return _result(status, contacts, r, (tf, tt), t0, "seed000")
        return _result(status, contacts, r, (tf, tt), t0, "seed000",
                       (forces, np.array(var["l"].value), float(p10.value + p11.value)))
