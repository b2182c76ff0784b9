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
import operator
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.linalg.lapack import dposv as _dposv
from scipy.optimize import nnls

from hand_capture.config import param, validate
from hand_control.contact.friction import (
    contact_frames,
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
        1e-9,
        "relative optimality (KKT) tolerance that accepts a solution: the gradient of the "
        "least-squares objective must vanish to kkt_tol x |A| |b| (the column norms of the "
        "stacked matrix times the norm of the weighted target), so the test does not depend "
        "on the scale of the target",
        lo=0.0, hi=1e-2,
    )
    unreachable_residual: float = param(
        0.9,
        "a solution whose net wrench misses the target by this fraction of |target| or more "
        "(residual >= ratio |(f, tau)|) is reported 'unreachable' with found=False: the "
        "contacts cannot apply the target (e.g. a pull through unilateral contacts)",
        lo=1e-6, hi=1.0,
    )
    fallback: str = param(
        "nnls",
        "when the warm-started active-set solver fails (iteration cap, singular or inaccurate "
        "step): 'nnls' = scipy's compiled Lawson-Hanson from scratch, 'osqp' = OSQP finds the "
        "active set and the exact solve on it is KKT-checked, 'none' = report the failure",
        choices=("nnls", "osqp", "none"),
    )

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True, eq=False)
class ContactForceResult:
    """Outcome of one contact-force solve; arrays are never NaN.

    Attributes:
        found: a solution that passed the optimality check and reaches the target (False:
            forces are zero, except for status ``"unreachable"``).
        status: ``"optimal"``, ``"unreachable"`` (the exact optimum, but its net wrench misses
            the target by ``config.unreachable_residual`` x |target| or more: the contacts
            cannot apply it; ``residual`` says by how much), ``"no_contacts"``,
            ``"max_iter"``, ``"non_finite"``, ``"inaccurate"`` or a cvxpy status (reference
            path).
        forces: (K, 3) contact forces on the object [N] (for ``"unreachable"``: the optimum,
            the closest wrench the contacts can apply).
        torsion: (K,) torsional torque magnitudes ``l_k`` [N m]; the torque is ``l_k n_k``.
        wrench_error: (6,) net wrench of the solution minus the target (force, torque).
        residual: Euclidean norm of ``wrench_error``.
        objective: value of the objective (eq. III.23, or eq. 10 + eq. 11).
        solve_time_s: wall time of the whole solve, building included [s].
        method: the formulation used.
        contact_wrench: (K, 6) each contact's force and its moment about the centre of mass,
            ``(f_k, r_k x f_k + l_k n_k)``, when the solver formed it on the way (the fast
            path of eq. III.23); ``None`` otherwise.
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
    contact_wrench: np.ndarray | None = None


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
    unreachable: float = math.inf,
) -> ContactForceResult:
    """The result of a solve; ``solution = (forces, torsion, objective)``, None if not found.

    ``residual``: the norm of ``wrench_error`` when the caller has it already.
    ``unreachable``: ``config.unreachable_residual``; an optimal solution whose residual is at
    least that fraction of the target's norm gets status ``"unreachable"``, found False.
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
    found = solution is not None
    if found and status == "optimal" and _unreachable(residual, targets, unreachable):
        found, status = False, "unreachable"
    return _new_result(found, status, forces, torsion, wrench_error, residual,
                       float(objective), time.perf_counter() - t0, method, None)


def _unreachable(residual: float, targets: tuple[Any, Any], ratio: float) -> bool:
    """Whether a net wrench error of norm ``residual`` [N, N m] is at least ``ratio`` times the
    norm of the target ``(force_target, torque_target)`` (and the target is not zero)."""
    t2 = math.fsum(float(v) * float(v) for part in targets for v in part)
    return t2 > 0.0 and residual * residual >= ratio * ratio * t2


_RESULT_FIELDS = tuple(f.name for f in fields(ContactForceResult))


class _FastResult(ContactForceResult):
    """A solution of the fast path of eq. (III.23) whose diagnostics (``wrench_error``,
    ``residual``, ``objective``) are computed when first read: the control loop never reads
    them. Everything else is a :class:`ContactForceResult`."""

    def __new__(cls, *args: Any, **kwargs: Any) -> ContactForceResult:
        # built with field values (dataclasses.replace): a plain ContactForceResult
        if args or kwargs:
            return ContactForceResult(*args, **kwargs)
        return super().__new__(cls)

    @property
    def wrench_error(self) -> np.ndarray:
        return self._diagnose()[0]

    @property
    def residual(self) -> float:
        return self._diagnose()[1]

    @property
    def objective(self) -> float:
        return self._diagnose()[2]

    def _diagnose(self) -> tuple[np.ndarray, float, float]:
        d = self.__dict__
        out = d.get("_diagnosed")
        if out is None:
            cfg, s6, z, zz, sub, reg_p = d["_diagnostics"]
            # the net wrench error: the weighted residual A_P z - b of eq. (III.23)'s first
            # two terms, unweighted
            if zz is None:
                zz = np.concatenate((z, _MINUS_ONE))
            err = zz.dot(sub) / s6
            e0, e1, e2, e3, e4, e5 = err.tolist()
            ef, et = e0 * e0 + e1 * e1 + e2 * e2, e3 * e3 + e4 * e4 + e5 * e5
            # a3 sum |f_k|^2 + a4 sum l_k^2 = |reg_P z|^2 (the regulariser rows in the contact
            # frames: a rotation keeps |f_k|)
            reg = reg_p.dot(z)
            objective = cfg.alpha1 * ef + cfg.alpha2 * et + float(reg.dot(reg))
            out = d["_diagnosed"] = (err, math.sqrt(ef + et), objective)
        return out


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
    #: called with ``(contacts, com, force_target, torque_target)`` by every solve (both entry
    #: points, :meth:`solve` and :meth:`solve_arrays`) before it runs: a benchmark records the
    #: problems the control loop met. The arrays may be the simulator's live views: copy them.
    recorder: Callable[[ContactSet, np.ndarray, np.ndarray, np.ndarray], None] | None = None

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
        if self.recorder is not None:
            self.recorder(contacts, com, tf, tt)
        return self._solve(contacts, com, tf, tt, t0)

    def _solve(
        self, contacts: ContactSet, com: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        """:meth:`solve` after the checks (and the recorder)."""
        method = self.config.method
        r = contacts.points - com
        if len(contacts) == 0:
            return _result("no_contacts", contacts, r, (tf, tt), t0, method)
        if method == "seed000":
            if contacts.forces is None:
                raise InputError("method 'seed000' (eq. 10) needs the simulator's contact forces")
            return self._solve_seed000(contacts, r, tf, tt, t0)
        return self._solve_dissertation(contacts, r, tf, tt, t0)

    def solve_arrays(
        self, points: np.ndarray, normals: np.ndarray, mu: np.ndarray, com: np.ndarray,
        wrench: list[float],
    ) -> ContactForceResult:
        """:meth:`solve` of ``ContactSet.trusted(points, normals, mu)`` without the checks
        (``check=False``), the target wrench given as six floats ``force_target +
        torque_target``: the in-process control loop's path (unit normals, finite arrays of
        matching shapes, ``mu >= 0``; the caller vouches)."""
        t0 = time.perf_counter()
        if self.recorder is not None or self.config.method != "dissertation" \
                or points.shape[0] == 0:
            contacts, tf, tt = (ContactSet.trusted(points, normals, mu),
                                np.array(wrench[0:3]), np.array(wrench[3:6]))
            if self.recorder is not None:
                self.recorder(contacts, com, tf, tt)
                if self.config.method == "dissertation" and points.shape[0]:
                    return self._dissertation(points, normals, mu, (points - com).tolist(),
                                              wrench[0:3], wrench[3:6], t0)
            return self._solve(contacts, com, tf, tt, t0)
        # the lever arms r_k = p_k - com as rows of floats (the same subtractions as numpy's,
        # without its per-call overhead on a few contacts)
        cx, cy, cz = com.tolist()
        rl = [[x - cx, y - cy, z - cz] for x, y, z in points.tolist()]
        return self._dissertation(points, normals, mu, rl, wrench[0:3], wrench[3:6], t0)

    def _solve_dissertation(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        return self._dissertation(contacts.points, contacts.normals, contacts.mu, r,
                                  tf.tolist(), tt.tolist(), t0)

    def _dissertation(
        self, points: np.ndarray, normals: np.ndarray, mu: np.ndarray,
        r: np.ndarray | list[list[float]], tfl: list[float], ttl: list[float], t0: float,
    ) -> ContactForceResult:
        """:meth:`_solve_dissertation` on the contacts' arrays, the targets as lists of three
        floats; ``r``: the (K, 3) lever arms ``p_k - com`` [m], an array or rows of floats."""
        raise NotImplementedError

    def _solve_seed000(
        self, contacts: ContactSet, r: np.ndarray, tf: np.ndarray, tt: np.ndarray, t0: float
    ) -> ContactForceResult:
        raise NotImplementedError


class _Layout:
    """Constant parts of one problem shape: K contacts with given friction coefficients.

    The generators and the regularisation rows of the stacked least-squares matrix depend on
    ``mu`` only, so their share of the normal matrix is computed once; the six wrench rows
    change at every solve.

    The solver works on the bordered normal matrix ``[[A'A, A'b], [b'A, b'b]]`` (n + 1
    square, n = K G generators): one product gives ``H = A'A``, ``g = A'b`` and ``b'b``, and
    one gather of the rows/columns ``P + [n]`` gives what a least-squares solve on the
    passive set ``P`` needs (``H_PP``, ``g_P``).
    """

    __slots__ = ("c", "g", "gen_l", "hb", "hbt", "k", "n", "pack", "reg", "sets")

    _MAX_SETS = 256

    def __init__(self, h: np.ndarray, reg_weights: np.ndarray) -> None:
        k, _, g = h.shape
        n = self.n = k * g
        # (4K, K G) block diagonal: column k G + j is generator j of contact k in the local
        # coordinates (f_t1, f_t2, f_n, l) of contact k
        self.hb = (h[:, :, None, :] * _block_eye(k)).reshape(4 * k, n)
        # [hb' 0; 0 1]: maps the rows of [m; b] (local coordinates' wrench rows, then the
        # target) to [every generator's wrench row; the target]
        self.hbt = np.zeros((n + 1, 4 * k + 1))
        self.hbt[:n, :4 * k] = self.hb.T
        self.hbt[n, 4 * k] = 1.0
        # sqrt(a3) f_k and sqrt(a4) l_k rows: diag(reg_1..reg_K) hb, and their normal matrix
        w = np.tile(reg_weights[0, :, 0], k)
        self.reg = w[:, None] * self.hb
        self.c = np.zeros((n + 1, n + 1))
        self.c[:n, :n] = self.reg.T @ self.reg
        self.gen_l = self.hb[3::4].sum(axis=0).tolist()  # torsion of each generator
        self.k, self.g = k, g
        # struct packing the (4K + 1, 6) rows of _contact_rows and the target as doubles
        self.pack = struct.Struct(f"{24 * k + 6}d").pack
        # passive set -> what does not depend on the step (a control loop keeps its passive
        # set for long runs): see gathers()
        self.sets: dict[tuple[int, ...], tuple[Any, ...]] = {}

    def gathers(self, p: list[int]) -> tuple[Any, ...]:
        """For the passive set ``p``: ``(P + [n]`` as an index array, ``c[:, P + [n]]``, the
        (K, |P|) 0/1 matrix of the contact of each generator in ``P``, the torsion per unit
        of each generator in ``P``, the regulariser's columns ``reg[:, P]``, a function that
        picks the entries of ``P`` from a list of n values (a tuple, or a list for
        ``|P| <= 1``))."""
        key = tuple(p)
        ent = self.sets.get(key)
        if ent is None:
            if len(self.sets) >= self._MAX_SETS:
                self.sets.clear()
            idx = np.array(p + [self.n])
            contact = np.zeros((self.k, len(p)))
            contact[np.array(p, dtype=np.int64) // self.g, np.arange(len(p))] = 1.0
            torsion = np.array([self.gen_l[i] for i in p])
            # picks the entries of P from a list of all n (a list for |P| <= 1)
            pick = operator.itemgetter(*p) if len(p) > 1 else operator.itemgetter(
                slice(p[0], p[0] + 1) if p else slice(0, 0))
            ent = self.sets[key] = (idx, self.c.take(idx, 1), contact, torsion,
                                    self.reg.take(idx[:-1], 1), pick)
        return ent


def _contact_rows(
    normals: list[list[float]], r: list[list[float]], wf: float, wt: float,
    copysign: Any = math.copysign,
) -> list[float]:
    """The map from every contact's local ``(f_t1, f_t2, f_n, l)`` to the weighted wrench on
    the object about its COM, ``[wf R_k, 0; wt [r_k]x R_k, wt n_k]``, transposed: a flat
    list of the (4K, 6) matrix, one row per local coordinate.

    ``R = [t1 t2 n]`` is :func:`contact_frames`'s Householder frame, written out on floats:
    for a few contacts, plain arithmetic costs less than numpy's per-call overhead.
    """
    out: list[float] = []
    if wf == 1.0 and wt == 1.0:  # the default weights (alpha1 = alpha2 = 1): no products
        for (nx, ny, nz), (rx, ry, rz) in zip(normals, r, strict=True):
            sg = copysign(1.0, nz)
            vz = nz + sg
            c = 2.0 / (nx * nx + ny * ny + vz * vz)
            ax, ay, az = (1.0 - c * (nx * nx)) * sg, -(c * (ny * nx)) * sg, -(c * (vz * nx)) * sg
            bx, by, bz = -(c * (nx * ny)), 1.0 - c * (ny * ny), -(c * (vz * ny))
            out += (ax, ay, az, ry * az - rz * ay, rz * ax - rx * az, rx * ay - ry * ax,
                    bx, by, bz, ry * bz - rz * by, rz * bx - rx * bz, rx * by - ry * bx,
                    nx, ny, nz, ry * nz - rz * ny, rz * nx - rx * nz, rx * ny - ry * nx,
                    0.0, 0.0, 0.0, nx, ny, nz)
        return out
    for (nx, ny, nz), (rx, ry, rz) in zip(normals, r, strict=True):
        sg = math.copysign(1.0, nz)
        vz = nz + sg
        c = 2.0 / (nx * nx + ny * ny + vz * vz)
        # I - c v v^T with v = n + sign(n_z) e_z; first column times the sign (handedness)
        ax, ay, az = (1.0 - c * (nx * nx)) * sg, -(c * (ny * nx)) * sg, -(c * (vz * nx)) * sg
        bx, by, bz = -(c * (nx * ny)), 1.0 - c * (ny * ny), -(c * (vz * ny))
        out += (wf * ax, wf * ay, wf * az, wt * (ry * az - rz * ay), wt * (rz * ax - rx * az),
                wt * (rx * ay - ry * ax),
                wf * bx, wf * by, wf * bz, wt * (ry * bz - rz * by), wt * (rz * bx - rx * bz),
                wt * (rx * by - ry * bx),
                wf * nx, wf * ny, wf * nz, wt * (ry * nz - rz * ny), wt * (rz * nx - rx * nz),
                wt * (rx * ny - ry * nx),
                0.0, 0.0, 0.0, wt * nx, wt * ny, wt * nz)
    return out


_MINUS_ONE = np.array([-1.0])


def _rows_array(rows: list[list[float]]) -> np.ndarray:
    """(K, 3) array of K rows of three floats (the lever arms of a failed solve's result)."""
    return np.array(rows, dtype=np.float64).reshape(len(rows), 3)


def _ls(
    a6t: np.ndarray, lay: _Layout, p: list[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Least squares on the passive set ``p``: ``H_pp z = g_p`` by Cholesky (LAPACK dposv).

    ``a6t`` (n + 1, 6): the weighted wrench rows of every generator, then the target ``b6``;
    ``lay.c``: the constant (regulariser) part of the bordered normal matrix. Only the columns
    ``p + [n]`` of ``[[H, g], [g', b'b]] = a6t a6t' + c`` are formed (the rest is never
    needed). Returns ``(sub, cols, zz)`` with ``sub = a6t[p + [n]]``, ``cols`` those columns
    (for the gradient) and ``zz = [z, -1]`` (``cols zz`` is the gradient, ``zz sub`` the
    weighted wrench residual ``A_p z - b``), or ``None`` if ``H_pp`` is not positive definite
    (dependent generators on ``p``).
    """
    gathers = lay.sets.get(tuple(p)) or lay.gathers(p)  # cached per passive set
    idx, c_cols = gathers[0], gathers[1]
    sub = a6t.take(idx, 0)
    cols = a6t.dot(sub.T)
    cols += c_cols
    s = cols.take(idx, 0)
    zz = s[-1].copy()  # [g_p, b'b] (s is symmetric), then z solved in its place
    zz[-1] = -1.0
    # (lower=0, overwrite_a=0, overwrite_b=1) positionally: f2py parses keywords slower
    info = _dposv(s[:-1, :-1], zz[:-1], 0, 0, 1)[2]
    return None if info else (sub, cols, zz)


def _active_set(
    a6t: np.ndarray, lay: _Layout, passive: Any, tol: float, maxiter: int
) -> tuple[list[int], np.ndarray, str, int, np.ndarray | None, np.ndarray | None]:
    """``argmin 1/2 x'Hx - g'x, x >= 0`` (``= argmin |A x - b|^2`` for ``H = A'A, g = A'b``,
    given through ``a6t`` and ``lay.c``, see :func:`_ls`) by the Lawson-Hanson active-set method
    on the normal equations, warm-started.

    ``passive``: the indices expected to be positive (the last solve's passive set). The
    least-squares solution on it, shrunk until every coefficient is positive, is the feasible
    start; when the problem moved little it already passes the KKT test and no iteration
    runs. Returns ``(P, x_P, status, iterations, a6t[P + [n]], [x_P, -1])``; the status is
    ``"optimal"`` only when the exact KKT conditions hold at ``x``: ``H x - g >= -tol``
    everywhere (gradient >= 0), ``|H x - g| <= tol`` where ``x > 0``, and ``x_P > 0``.
    """
    n = a6t.shape[0] - 1
    enter_tol = 1e-4 * tol  # kkt_tol 1e-9 -> 1e-13 x |A| |b|
    p: list[int] = list(passive)
    z = _EMPTY
    sub = cols = zz = None
    for _ in range(2):  # the warm set, then its positive part; else start from nothing
        if not p:
            break
        sol = _ls(a6t, lay, p)
        if sol is None:
            p = []
            break
        sub, cols, zz = sol
        z = zz[:-1]
        zl = z.tolist()
        if min(zl) > 0.0:
            break
        p = [i for i, v in zip(p, zl, strict=True) if v > 0.0]
    else:
        p = []
    if not p:
        z, sub, zz = _EMPTY, None, None
    it = 0
    while True:
        # the gradient H x - g (and, last, g_P' z - b'b, dropped)
        if p:
            vl = cols.dot(zz).tolist()
        else:
            vl = (-a6t.dot(a6t[n])).tolist()
        vl.pop()
        if not math.isfinite(sum(vl)):
            return p, z, "non_finite", it, sub, zz
        vmin = min(vl)
        # stop only when no generator can still lower the objective (down to rounding, as
        # scipy's NNLS): the weak curvature of the regulariser (alpha3 = 1e-3) turns a
        # gradient left at the acceptance tolerance into ~1e-3 N of force error
        if vmin >= -enter_tol or (it >= maxiter and vmin >= -tol):
            if p and max([abs(vl[i]) for i in p]) > tol:
                return p, z, "inaccurate", it, sub, zz
            return p, z, "optimal", it, sub, zz
        j = vl.index(vmin)
        if j in p:
            return p, z, "inaccurate", it, sub, zz
        xl = z.tolist()
        p.append(j)
        xl.append(0.0)
        while True:  # Lawson-Hanson inner loop: keep the coefficients positive
            it += 1
            if it > maxiter:
                return p, z, "max_iter", it, None, None
            sol = _ls(a6t, lay, p)
            if sol is None:
                return p, z, "inaccurate", it, None, None
            sub, cols, zz = sol
            z = zz[:-1]
            zl = z.tolist()
            if min(zl) > 0.0:
                break
            # the longest step from x toward z that keeps every coefficient >= 0
            alpha, drop = min((xi / (xi - zi) if xi > zi else 0.0, q)
                              for q, (xi, zi) in enumerate(zip(xl, zl, strict=True))
                              if zi <= 0.0)
            if alpha <= 0.0 and p[drop] == j:
                return p, z, "inaccurate", it, None, None  # the new generator cannot enter
            xl = [xi + alpha * (zi - xi) for xi, zi in zip(xl, zl, strict=True)]
            xl[drop] = 0.0
            keep = [q for q, v in enumerate(xl) if v > 0.0]
            p = [p[q] for q in keep]
            xl = [xl[q] for q in keep]
            if not p:
                z = _EMPTY
                sub = zz = None
                break


_EMPTY = np.zeros(0)


def _warm_hit(
    a6t: np.ndarray, lay: _Layout, p: list[int], tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, ...]] | None:
    """The first step of :func:`_active_set` from the passive set ``p`` when it ends there:
    the least squares on ``p`` is positive and passes the KKT test (the control loop's usual
    case). Returns ``(x_P, [x_P, -1], a6t[P + [n]], lay.gathers(p))``, else ``None`` (then
    :func:`_active_set` takes it from the start: the same steps, the same result)."""
    ent = lay.sets.get(tuple(p)) or lay.gathers(p)
    idx = ent[0]
    sub = a6t.take(idx, 0)  # :func:`_ls`, inline
    cols = a6t.dot(sub.T)
    cols += ent[1]
    s = cols.take(idx, 0)
    zz = s[-1].copy()
    zz[-1] = -1.0
    if _dposv(s[:-1, :-1], zz[:-1], 0, 0, 1)[2]:
        return None
    z = zz[:-1]
    if min(z.tolist()) <= 0.0:
        return None
    vl = cols.dot(zz).tolist()
    vl.pop()
    # _active_set's acceptance (the gradient, finite, >= -enter_tol everywhere, within tol of
    # zero on p: max |v_p| = max(max(v_p), -min(v_p)), the entries of p picked once)
    vp = ent[5](vl)
    if not (min(vl) >= -1e-4 * tol and math.isfinite(sum(vl))
            and max(vp) <= tol and -min(vp) <= tol):
        return None
    return z, zz, sub, ent


class ContactForceQP(_ContactForceSolver):
    """Fast contact-force solver for the control loop (exact, warm-started active set).

    Each contact contributes non-negative generators ``(f, l)`` of its admissible set: the
    pyramid edges ``(b_j, 0)`` and, for a free torsion, ``(0, +1)`` and ``(0, -1)``; for a
    bounded torsion ``(b_j, +-mu_t n.b_j)`` (the cone these span is exactly ``{f in pyramid,
    |l| <= mu_t n.f}``). Every term of eq. (III.23) is linear in the generator coefficients, so
    the problem is ``min |A x - b|^2, x >= 0`` with ``A`` = [weighted wrench rows; weighted
    regularisation rows], a box/cone-constrained least-squares problem. It is solved by a
    Lawson-Hanson active-set method on its normal equations ``A'A x = A'b`` (the
    regularisation's share of ``A'A`` is constant per contact layout) and accepted only if it
    passes the exact KKT check.

    Warm start: in a control loop the set of generators in use (the passive set) rarely
    changes between steps. The solver starts from the last passive set of the same contact
    count: the least-squares solution on it is the exact optimum whenever the KKT check passes,
    otherwise a few active-set iterations move from there. When the active-set method fails
    (iteration cap, dependent generators), ``config.fallback`` decides: scipy's compiled
    Lawson-Hanson from scratch, OSQP to find the active set (the solution is then the exact
    one on that set, KKT-checked), or a failure status.
    """

    _MAX_LAYOUTS = 32

    def __init__(self, config: ContactQPConfig | None = None) -> None:
        self.config = cfg = config or ContactQPConfig()
        s1, s2, s3, s4 = (math.sqrt(a) for a in (cfg.alpha1, cfg.alpha2, cfg.alpha3, cfg.alpha4))
        self._s12 = (s1, s2)
        self._s6 = np.array([s1, s1, s1, s2, s2, s2])
        self._reg_weights = np.array([s3, s3, s3, s4])[None, :, None]
        self._basis = _local_generator_basis(
            cfg.friction_edges, cfg.torsion_bound, cfg.torsional_friction
        )
        self._n_gen = self._basis.shape[1] // 4
        # bound of the column norms of the stacked matrix: see _dissertation
        lmax = max(1.0, cfg.torsional_friction)
        self._col_a = cfg.alpha1 + cfg.alpha3 + cfg.alpha4 * lmax * lmax
        self._col_b, self._col_l = cfg.alpha2, lmax
        self._maxiter = cfg.max_iter or None
        self._layouts: dict[tuple[int, bytes], _Layout] = {}
        self._last_layout: tuple[bytes | None, _Layout | None] = (None, None)
        self._passive: dict[Any, Any] = {}  # warm start: last passive set per shape
        self.warm_hits = 0  # solves the warm start answered without an iteration
        self.fallback_solves = 0  # solves the fallback answered (diagnostics)

    def _layout(self, mu: np.ndarray) -> _Layout:
        mu_bytes = mu.tobytes()
        last = self._last_layout
        if last[0] == mu_bytes:  # the last step's contacts (the control loop's usual case)
            return last[1]
        key = (mu.shape[0], mu_bytes)
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
        self._last_layout = (mu_bytes, lay)
        return lay

    # -- eq. (III.23) ---------------------------------------------------------------------
    def _dissertation(
        self, points: np.ndarray, normals: np.ndarray, mu: np.ndarray,
        r: np.ndarray | list[list[float]], tfl: list[float], ttl: list[float], t0: float,
    ) -> ContactForceResult:
        rl = r if type(r) is list else r.tolist()  # rows of floats from solve_arrays
        last = self._last_layout
        lay = last[1] if last[0] == mu.tobytes() else self._layout(mu)
        k = lay.k
        s1, s2 = self._s12
        b6 = [s1 * tfl[0], s1 * tfl[1], s1 * tfl[2], s2 * ttl[0], s2 * ttl[1], s2 * ttl[2]]
        # (4K + 1, 6): the weighted wrench (eq. III.23's first two terms) of every contact's
        # local (f_t1, f_t2, f_n, l), then the target; through the generators: (K G + 1, 6)
        nl = normals.tolist()
        rows = _contact_rows(nl, rl, s1, s2)
        a6t = lay.hbt.dot(np.ndarray((4 * k + 1, 6), buffer=lay.pack(*rows, *b6)))
        b0, b1, b2, b3, b4, b5 = b6
        bb = math.fsum((b0 * b0, b1 * b1, b2 * b2, b3 * b3, b4 * b4, b5 * b5))
        if not math.isfinite(bb):  # an overflow while the problem was built
            return _result("non_finite", ContactSet.trusted(points, normals, mu),
                           _rows_array(rl), (tfl, ttl), t0, "dissertation")
        # The gradient A'(A x - b) of every generator is at most |a_j| |b| at the optimum:
        # the tolerance scales with both (scale-invariant: a target s times larger gives an
        # s times larger solution, gradient and tolerance). |a_j|^2 <= a1 + a2 (|r| + l)^2
        # + a3 + a4 l^2 for a unit generator with torsion l (l <= 1 here: see _col_bound).
        r2 = max([x * x + y * y + z * z for x, y, z in rl])
        tol = self.config.kkt_tol * math.sqrt(bb * (self._col_a + self._col_b * (
            math.sqrt(r2) + self._col_l) ** 2))
        maxiter = self._maxiter or 3 * lay.n
        warm = self._passive.get(k)
        hit = _warm_hit(a6t, lay, warm, tol) if warm else None
        if hit is not None:  # the loop's usual case: the last passive set is still optimal
            z, zz, sub, ent = hit
            passive, status = warm, "optimal"
            self.warm_hits += 1
        else:
            passive, z, status, sub, zz = self._solve_active_set(a6t, lay, warm, tol, maxiter)
            ent = None
        if status != "optimal":
            return _result(status, ContactSet.trusted(points, normals, mu), _rows_array(rl),
                           (tfl, ttl), t0, "dissertation")
        self._passive[k] = passive
        cfg = self.config
        if passive and s1 > 0.0 and s2 > 0.0:
            # Forces and torsions from the generators in use: row p of a6t holds the weighted
            # world wrench of generator p, s1 x its force first; torsion[p] its torsion per
            # unit; contact[c, p] = 1 for the generators of contact c.
            if ent is None:
                ent = lay.sets.get(tuple(passive)) or lay.gathers(passive)
            contact, torsion, reg_p = ent[2], ent[3], ent[4]
            per_contact = contact * z
            # (K, 6): s1 f_k and s2 (r_k x f_k + l_k n_k) of every contact
            wrench = per_contact.dot(sub[:-1])
            if s1 != 1.0 or s2 != 1.0:
                wrench /= self._s6
            res = object.__new__(_FastResult)  # the frozen dataclass, no __init__
            res.__dict__.update(
                found=True, status=status, forces=wrench[:, 0:3],
                torsion=per_contact.dot(torsion), solve_time_s=time.perf_counter() - t0,
                method="dissertation", contact_wrench=wrench,
                _diagnostics=(cfg, self._s6, z, zz, sub, reg_p))
            if zz is None:
                zz = np.concatenate((z, _MINUS_ONE))
            err = zz.dot(sub)  # s6 x the net wrench error A_P z - b
            if s1 != 1.0 or s2 != 1.0:
                err /= self._s6
            residual = math.sqrt(float(err.dot(err)))
            if _unreachable(residual, (tfl, ttl), cfg.unreachable_residual):
                return _new_result(False, "unreachable", res.forces, res.torsion, err,
                                   residual, res.objective, time.perf_counter() - t0,
                                   "dissertation", wrench)
            return res
        # the same on floats (a weight alpha1 or alpha2 of zero, no generator in use): row p of
        # a6t holds s1 x the world force of generator p; lay.gen_l[p] its torsion per unit
        g = self._n_gen
        fk = [0.0] * (3 * k)
        lk = [0.0] * k
        if passive and s1 > 0.0:
            gen_l = lay.gen_l
            for i, zi, row in zip(passive, z.tolist(), sub.tolist(), strict=False):
                c = i // g
                fk[3 * c] += zi * row[0]
                fk[3 * c + 1] += zi * row[1]
                fk[3 * c + 2] += zi * row[2]
                lk[c] += zi * gen_l[i]
            if s1 != 1.0:
                fk = [v / s1 for v in fk]
        elif passive:  # alpha1 = 0: the force rows are zero; through the contact frames
            y = z.dot(lay.hbt.take(passive, 0)[:, :4 * k]).reshape(k, 4)
            fk = np.einsum("kij,kj->ki", contact_frames(normals), y[:, :3]).ravel()
            fk, lk = fk.tolist(), y[:, 3].tolist()
        # net wrench error and objective (eq. III.23) on floats
        fx = fy = fz = mx = my = mz = fsq = lsq = 0.0
        for c, ((rx, ry, rz), (nx, ny, nz)) in enumerate(zip(rl, nl, strict=True)):
            f0, f1, f2, lc = fk[3 * c], fk[3 * c + 1], fk[3 * c + 2], lk[c]
            fx, fy, fz = fx + f0, fy + f1, fz + f2
            mx += ry * f2 - rz * f1 + lc * nx
            my += rz * f0 - rx * f2 + lc * ny
            mz += rx * f1 - ry * f0 + lc * nz
            fsq += f0 * f0 + f1 * f1 + f2 * f2
            lsq += lc * lc
        err = [fx - tfl[0], fy - tfl[1], fz - tfl[2], mx - ttl[0], my - ttl[1], mz - ttl[2]]
        e0, e1, e2, e3, e4, e5 = err
        ef, et = e0 * e0 + e1 * e1 + e2 * e2, e3 * e3 + e4 * e4 + e5 * e5
        objective = cfg.alpha1 * ef + cfg.alpha2 * et + cfg.alpha3 * fsq + cfg.alpha4 * lsq
        residual = math.sqrt(ef + et)
        if _unreachable(residual, (tfl, ttl), cfg.unreachable_residual):
            status = "unreachable"
        # what _result makes of the solution, inline (one result per control step)
        return _new_result(status == "optimal", status, np.array(fk).reshape(k, 3), np.array(lk),
                           np.array(err), residual, float(objective),
                           time.perf_counter() - t0, "dissertation", None)

    def _solve_active_set(
        self, a6t: np.ndarray, lay: _Layout, warm: list[int] | None, tol: float, maxiter: int,
    ) -> tuple[list[int], np.ndarray, str, np.ndarray | None, np.ndarray | None]:
        """The solve when the last passive set ``warm`` is not the optimum as it is (or there
        is none): ``(passive set, x on it, status, a6t[P + [n]], [x, -1] or None)``."""
        if warm is None and self.config.fallback == "nnls":
            # cold (first problem of this contact count): scipy's compiled Lawson-Hanson
            # beats the Python iterations from an empty set; it seeds the warm start
            passive, z, status = self._fallback(a6t, lay, tol, maxiter, "cold")
            self.fallback_solves -= int(status == "optimal")  # not a fallback
            it, sub, zz = 0, a6t.take(passive + [lay.n], 0), None
        else:
            status = "cold"
        if status != "optimal":
            # a few active-set iterations from the last passive set (the loop's usual case
            # needs none); beyond that scipy's compiled Lawson-Hanson is quicker
            short = self.config.fallback == "nnls" and maxiter > 2
            passive, z, status, it, sub, zz = _active_set(
                a6t, lay, () if warm is None else warm, tol, 2 if short else maxiter)
            if status == "max_iter" and short:
                passive, z, status = self._fallback(a6t, lay, tol, maxiter, status)
                self.fallback_solves -= int(status == "optimal")  # the planned path
                it, sub, zz = 1, a6t.take(passive + [lay.n], 0), None
        if status == "optimal":
            self.warm_hits += int(it == 0 and warm is not None)
        elif self.config.fallback != "none":
            passive, z, status = self._fallback(a6t, lay, tol, maxiter, status)
            sub, zz = a6t.take(passive + [lay.n], 0), None
        return passive, z, status, sub, zz

    def _fallback(
        self, a6t: np.ndarray, lay: _Layout, tol: float, maxiter: int, status: str,
    ) -> tuple[list[int], np.ndarray, str]:
        """The solve when the warm-started active set failed (see ``config.fallback``):
        ``(passive set, x on it, status)``."""
        n = lay.n
        if self.config.fallback == "nnls":
            a = np.concatenate((a6t[:n].T, lay.reg))
            b = np.zeros(a.shape[0])
            b[0:6] = a6t[n]
            x, st, _ = self._nnls(a, b)
            if x is None:
                return [], _EMPTY, st
            self.fallback_solves += 1
            p = np.flatnonzero(x > 0.0)
            return p.tolist(), x[p], st
        import osqp
        import scipy.sparse as sp

        hext = a6t.dot(a6t.T)
        hext += lay.c
        prob = osqp.OSQP()
        prob.setup(P=sp.csc_matrix(np.triu(hext[:n, :n])), q=-hext[:n, n],
                   A=sp.identity(n, format="csc"), l=np.zeros(n), u=np.full(n, np.inf),
                   eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000,
                   verbose=False)
        res = prob.solve(raise_error=False)  # the status is checked below
        if res.info.status != "solved" or res.x is None or not np.isfinite(res.x).all():
            return [], _EMPTY, "osqp_" + str(res.info.status).replace(" ", "_")
        # OSQP's support as the warm start of the exact active-set solve (KKT-checked)
        seed = np.flatnonzero(res.x > 1e-12 * max(1.0, float(res.x.max()))).tolist()
        p, z, st, _, _, _ = _active_set(a6t, lay, seed, tol, maxiter)
        if st == "optimal":
            self.fallback_solves += 1
        return p, z, st

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
                       (forces, torsion, objective), err,
                       unreachable=cfg.unreachable_residual)

    def _nnls(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray | None, str, float]:
        """``argmin |a x - b|^2, x >= 0`` by scipy's Lawson-Hanson and its objective, checked
        against the KKT conditions. Returns ``(None, status, inf)`` when the solver fails or
        the check does not pass.
        """
        try:
            x, _ = nnls(a, b, maxiter=self._maxiter)
        except RuntimeError:
            return None, "max_iter", math.inf
        except ValueError:  # NaN/Inf in the data (e.g. an overflow while building it)
            return None, "non_finite", math.inf
        status, objective = self._kkt(a, b, x, np.flatnonzero(x > 0.0))
        if status != "optimal":
            return None, status, math.inf
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
        # |grad_j| <= |a_j| |b| at the optimum: the tolerance scales with both (a target s
        # times larger gives an s times larger x, gradient and tolerance)
        col = float(np.sqrt(np.einsum("ij,ij->j", a, a).max())) if a.size else 0.0
        tol = self.config.kkt_tol * col * math.sqrt(float(b.dot(b)))
        if not (math.isfinite(objective) and math.isfinite(violation) and math.isfinite(tol)):
            return "non_finite", math.inf
        if violation > tol:
            return "inaccurate", math.inf
        return "optimal", objective


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
                       (np.array(var["f"].value), np.array(var["l"].value), float(prob.value)),
                       unreachable=self.config.unreachable_residual)

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
                       (forces, np.array(var["l"].value), float(p10.value + p11.value)),
                       unreachable=cfg.unreachable_residual)
