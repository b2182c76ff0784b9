"""Dynamic feasibility test of a grasp: can its contacts hold the object (dissertation III.4.1.3).

Linear programme of eq. (III.10)-(III.16): contact forces ``f_i = B_i lambda_i`` with
``lambda_i >= 0`` in friction pyramids (III.14, III.15), whose resultant force and torque about
the centre of mass balance the object's load (III.11, III.12), minimising the total normal force
``sum_i f_i_perp`` (III.10). Two readings of the printed equations:

* (III.11) is written ``sum_i B_i lambda_i - G = 0``; we use the physical balance
  ``sum_i f_i + m g = m a`` (``a`` an optional desired acceleration, 0 for static holding), i.e.
  the contacts supply ``m (a - g)``.
* (III.13)/(III.14) split each force into its normal magnitude ``f_i_perp = n_i . f_i`` and a
  tangential part; with ``f_i = B_i lambda_i`` both hold by construction (the pyramid edges have
  normal component ``1 / sqrt(1 + mu^2)``), and ``f_i_perp >= 0`` (III.16) follows from
  ``lambda_i >= 0``. So the LP keeps only ``lambda`` as unknowns.

Without more, the LP ignores how hard the hand can press: any load is balanced by squeezing
harder, so every grasp with the load inside its wrench cone counts as feasible. Given the hand's
joint torque limits and the contact Jacobians, it adds the actuators' bound on the contact
forces: the joint torques that apply the forces, ``tau = sum_i J_i^T f_i`` (the map of eq. III.21
/ seed 000 eq. 12, gravity on the hand compensated), must stay within ``|tau_j| <= tau_max,j``.
Then a heavy object, low friction or contacts the fingers cannot press on are infeasible.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linprog

from hand_control.contact.friction import cross_matrices, pyramid_edges
from hand_control.contact.types import ContactSet, as_finite_array
from hand_control.errors import InputError

__all__ = ["FeasibilityResult", "dynamic_feasibility"]


@dataclass(frozen=True, eq=False)
class FeasibilityResult:
    """Outcome of the dynamic feasibility LP.

    Attributes:
        feasible: the contacts can balance the load inside their friction pyramids.
        status: ``"optimal"``, ``"infeasible"`` (no balancing forces in the friction cones),
            ``"torque_limits"`` (balancing forces exist, but not within the joint torque
            limits), ``"no_contacts"``, ``"no_load"`` or the solver's message.
        forces: (K, 3) the minimum-normal-force contact forces on the object [N] (zeros when
            infeasible).
        normal_forces: (K,) their normal magnitudes ``f_i_perp`` [N].
        margin: load-to-squeeze ratio ``|m (a - g)| / sum_i f_i_perp``: 1 for a load carried by
            normal force alone (an object resting on a contact), about ``mu`` for a two-finger
            pinch that holds the load by friction, smaller for grasps that must squeeze harder;
            0 when infeasible, ``inf`` with no load.
        solve_time_s: wall time [s].
        joint_torques: (nv,) the joint torques ``sum_i J_i^T f_i`` that apply the forces [N m]
            when torque limits were given, else ``None``.
    """

    feasible: bool
    status: str
    forces: np.ndarray
    normal_forces: np.ndarray
    margin: float
    solve_time_s: float
    joint_torques: np.ndarray | None = None


def dynamic_feasibility(
    contacts: ContactSet,
    mass: float,
    com: Any,
    gravity: Any = (0.0, 0.0, -9.81),
    acceleration: Any = None,
    friction_edges: int = 4,
    torque_limits: Any = None,
) -> FeasibilityResult:
    """Dynamic feasibility test of eq. (III.10)-(III.16).

    Args:
        contacts: points, normals (hand -> object) and friction coefficients.
        mass: object mass [kg], > 0.
        com: (3,) object centre of mass [m].
        gravity: (3,) gravity acceleration [m/s^2].
        acceleration: (3,) desired linear acceleration of the object [m/s^2], default 0.
        friction_edges: pyramid edges per contact (4 in the dissertation).
        torque_limits: (nv,) joint torque limits ``tau_max`` [N m], >= 0 (``inf``: no
            limit), in the columns of ``contacts.jacp`` (required then): the forces must be
            applicable by the joints, ``|sum_i J_i^T f_i| <= tau_max``. ``None``: unbounded
            forces (the LP of the dissertation as printed).

    Raises:
        InputError: NaN/Inf, wrong shapes, a non-positive mass, fewer than 4 edges, negative
            torque limits, or torque limits without contact Jacobians.
    """
    t0 = time.perf_counter()
    if not isinstance(contacts, ContactSet):
        raise InputError(f"contacts must be a ContactSet, got {type(contacts).__name__}")
    mass = float(as_finite_array("object mass", mass, ()))
    if mass <= 0.0:
        raise InputError(f"object mass must be > 0, got {mass}")
    if not (isinstance(friction_edges, int) and friction_edges >= 4):
        raise InputError(f"friction_edges must be an integer >= 4, got {friction_edges!r}")
    com = as_finite_array("object centre of mass", com, (3,))
    g = as_finite_array("gravity", gravity, (3,))
    acc = np.zeros(3) if acceleration is None else as_finite_array(
        "desired acceleration", acceleration, (3,))
    load = mass * (acc - g)  # what the contacts must supply (III.11)
    k, e = len(contacts), friction_edges
    tau_max = None
    if torque_limits is not None:
        if contacts.jacp is None:
            raise InputError("torque_limits need the contacts' Jacobians (ContactSet.jacp)")
        tau_max = np.asarray(torque_limits, dtype=np.float64)
        if tau_max.shape != (contacts.jacp.shape[2],) or np.isnan(tau_max).any() \
                or (tau_max < 0).any():
            raise InputError(f"torque_limits must be {contacts.jacp.shape[2]} values >= 0 "
                             f"(inf: no limit), got {torque_limits!r}")
    zeros = np.zeros((k, 3)), np.zeros(k)

    def result(feasible: bool, status: str, forces: np.ndarray, normal: np.ndarray,
               margin: float, tau: np.ndarray | None = None) -> FeasibilityResult:
        return FeasibilityResult(feasible, status, forces, normal, margin,
                                 time.perf_counter() - t0, tau)

    load_norm = float(np.linalg.norm(load))
    if load_norm == 0.0:
        return result(True, "no_load", *zeros, math.inf)
    if k == 0:
        return result(False, "no_contacts", *zeros, 0.0)
    edges = pyramid_edges(contacts.normals, contacts.mu, e)  # (K, E, 3)
    force_map = edges.reshape(k * e, 3).T  # f = sum B_i lambda_i
    torque_map = (cross_matrices(contacts.points - com) @ edges.transpose(0, 2, 1))
    a_eq = np.vstack([force_map, torque_map.transpose(1, 0, 2).reshape(3, k * e)])
    b_eq = np.concatenate([load, np.zeros(3)])  # (III.11), (III.12)
    # (III.10): minimise sum of normal forces; every edge has n . b_j = 1 / sqrt(1 + mu^2)
    cost = np.repeat(1.0 / np.sqrt(1.0 + contacts.mu**2), e)
    a_ub = b_ub = torque_map_j = None
    if tau_max is not None:
        # joint torques of every generator: J_i^T b_ij, (nv, K E); rows of bounded joints
        torque_map_j = np.einsum("kjv,kej->vke", contacts.jacp, edges).reshape(-1, k * e)
        bounded = np.isfinite(tau_max)
        if bounded.any():
            rows = torque_map_j[bounded]
            a_ub = np.vstack([rows, -rows])  # -tau_max <= J^T f <= tau_max
            b_ub = np.concatenate([tau_max[bounded], tau_max[bounded]])
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq, bounds=(0.0, None),
                  method="highs")
    if res.status != 0 or res.x is None:
        status = "infeasible" if res.status == 2 else f"solver: {res.message}"
        if status == "infeasible" and a_ub is not None and linprog(
                cost, A_eq=a_eq, b_eq=b_eq, bounds=(0.0, None), method="highs").status == 0:
            status = "torque_limits"  # the cones could hold it; the joints cannot press so
        return result(False, status, *zeros, 0.0)
    lam = res.x.reshape(k, e)
    forces = np.einsum("ke,kej->kj", lam, edges)
    normal = np.einsum("kj,kj->k", forces, contacts.normals)
    total = float(normal.sum())
    return result(True, "optimal", forces, normal,
                  load_norm / total if total > 0 else math.inf,
                  None if torque_map_j is None else torque_map_j @ res.x)
