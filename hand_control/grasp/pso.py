"""Particle swarm optimisation (Kennedy and Eberhart; dissertation III.4.1.4, ref. [55]).

A plain global-best swarm with Clerc's constriction coefficients, over a box; the objective
takes the whole swarm at once (an (N, D) array -> (N,) costs), so it can be vectorised.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_control.errors import InputError

__all__ = ["PSOConfig", "PSOResult", "pso"]


@dataclass(frozen=True)
class PSOConfig:
    """Swarm settings."""

    particles: int = param(32, "swarm size", lo=2, hi=10000)
    iterations: int = param(16, "generations after the initial one", lo=0, hi=10000)
    inertia: float = param(0.7298, "velocity inertia (Clerc's constriction)", lo=0.0, hi=1.0)
    cognitive: float = param(1.49618, "pull to the particle's own best", lo=0.0, hi=4.0)
    social: float = param(1.49618, "pull to the swarm's best", lo=0.0, hi=4.0)
    max_velocity: float = param(0.5, "velocity cap as a fraction of the box", lo=0.01, hi=2.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True, eq=False)
class PSOResult:
    """The swarm after its last generation.

    Attributes:
        best_x (D,), best_cost: the swarm's best position and cost.
        positions (N, D), costs (N,): the last generation.
        personal_best (N, D), personal_cost (N,): each particle's best.
        evaluations: objective evaluations (particles); wall_s: time [s].
    """

    best_x: np.ndarray
    best_cost: float
    positions: np.ndarray
    costs: np.ndarray
    personal_best: np.ndarray
    personal_cost: np.ndarray
    evaluations: int
    wall_s: float


def pso(objective: Callable[[np.ndarray], np.ndarray], initial: np.ndarray, lo: np.ndarray,
        hi: np.ndarray, config: PSOConfig | None = None,
        rng: np.random.Generator | None = None) -> PSOResult:
    """Minimise ``objective`` from the swarm ``initial`` (N, D) inside the box [lo, hi].

    Raises:
        InputError: mismatched shapes, an empty box, or non-finite initial positions.
    """
    t0 = time.perf_counter()
    cfg = config or PSOConfig()
    rng = rng or np.random.default_rng(0)
    x = np.array(initial, dtype=np.float64)
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if x.ndim != 2 or lo.shape != (x.shape[1],) or hi.shape != lo.shape:
        raise InputError(f"pso: initial must be (N, D) with bounds (D,), got {x.shape}, "
                         f"{lo.shape}, {hi.shape}")
    if not (np.isfinite(x).all() and np.isfinite(lo).all() and np.isfinite(hi).all()) \
            or (hi < lo).any():
        raise InputError("pso: non-finite positions or bounds, or hi < lo")
    x = np.clip(x, lo, hi)
    span = hi - lo
    vmax = cfg.max_velocity * span
    v = rng.uniform(-1.0, 1.0, x.shape) * 0.1 * span
    cost = np.asarray(objective(x), dtype=np.float64)
    cost = np.where(np.isfinite(cost), cost, np.inf)
    pbest, pcost = x.copy(), cost.copy()
    evals = len(x)
    for _ in range(cfg.iterations):
        g = pbest[np.argmin(pcost)]
        r1 = rng.random(x.shape)
        r2 = rng.random(x.shape)
        v = cfg.inertia * v + cfg.cognitive * r1 * (pbest - x) + cfg.social * r2 * (g - x)
        v = np.clip(v, -vmax, vmax)
        x = np.clip(x + v, lo, hi)
        cost = np.asarray(objective(x), dtype=np.float64)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        evals += len(x)
        better = cost < pcost
        pbest[better], pcost[better] = x[better], cost[better]
    i = int(np.argmin(pcost))
    return PSOResult(pbest[i].copy(), float(pcost[i]), x, cost, pbest, pcost, evals,
                     time.perf_counter() - t0)
