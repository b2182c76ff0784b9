"""Sample selection and the sampling loop of seed 000 sec. 6 (after Liu et al. 2010).

At every time step each saved sample (a simulation state with its accumulated energy, eq. 2
summed over the frames so far) spawns new samples: controls drawn around the reference, each
simulated over one step from its parent's state. The new samples' energies are the parents'
plus the cost of the new frame. :func:`select_samples` then keeps ``m`` of them: the upper half
by energy is discarded and the rest thinned so that the kept energies follow
``s(x) = (E_high - E_low) x^6 + E_low`` (mostly low energies, still the whole range). At the
end the lowest-energy sample's chain of parents is the optimised motion.

:func:`sampling_optimise` is that loop, independent of what a state, a control or a
simulation is (the physics capture plugs in MuJoCo; the tests a toy system).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SamplingPath", "sampling_optimise", "select_samples"]


def select_samples(energies: np.ndarray, m: int) -> np.ndarray:
    """Indices of the ``m`` samples kept at one step (seed 000 sec. 6, sample selection).

    1. discard the samples in the top 50 % of the energy distribution (non-finite energies
       first);
    2. of the rest (``E_low`` .. ``E_high``), keep for ``x = i / m, i = 0..m-1`` the sample
       whose energy is closest to ``s(x) = (E_high - E_low) x^6 + E_low``, each sample at most
       once (the next closest unused one when taken), so the kept set covers the range and
       crowds its low end.

    Args:
        energies: (N,) energies (accumulated cost).
        m: how many to keep (all the remaining when fewer remain).

    Returns:
        (min(m, remaining),) sample indices, ascending energy; the lowest energy is always
        kept.
    """
    e = np.asarray(energies, dtype=np.float64).reshape(-1)
    finite = np.flatnonzero(np.isfinite(e))
    if finite.size == 0:  # every sample failed: keep the first m (they are all equal)
        return np.arange(min(m, e.size))
    order = finite[np.argsort(e[finite], kind="stable")]
    keep_n = max(1, int(math.ceil(order.size / 2)))  # discard the upper half
    rest = order[:keep_n]
    if m >= rest.size:
        return rest
    er = e[rest]
    lo, hi = er[0], er[-1]
    targets = (hi - lo) * (np.arange(m) / m) ** 6 + lo  # s(x), ascending
    chosen: list[int] = []
    j = 0  # next unused position in rest (targets ascend, so the choice moves right)
    n = rest.size
    for i, s in enumerate(targets):
        last = n - (m - i)  # leave enough samples for the targets still to come
        k = j + int(np.argmin(np.abs(er[j:last + 1] - s)))
        chosen.append(k)
        j = k + 1
    return rest[np.array(chosen)]


@dataclass
class SamplingPath:
    """The optimised chain: per frame the state, the control that led to it (``None`` for
    frame 0), its cost and the simulation's extra output; plus figures of the search."""

    states: list[Any]
    controls: list[Any]
    costs: np.ndarray
    infos: list[Any]
    energy: float
    step_seconds: np.ndarray
    samples_per_step: int


#: propose(step, parent_states, parent_index (N,), rng) -> controls (list of N)
Propose = Callable[[int, Sequence[Any], np.ndarray, np.random.Generator], Sequence[Any]]
#: simulate(step, parent_states, parent_index (N,), controls) -> (states, costs (N,), infos)
Simulate = Callable[[int, Sequence[Any], np.ndarray, Sequence[Any]],
                    tuple[Sequence[Any], np.ndarray, Sequence[Any]]]


def sampling_optimise(initial_state: Any, initial_cost: float, n_steps: int,
                      propose: Propose, simulate: Simulate, n_samples: int, n_keep: int,
                      rng: np.random.Generator,
                      progress: Callable[[int, int], None] | None = None) -> SamplingPath:
    """Seed 000 sec. 6's search over ``n_steps`` steps.

    Each step, the saved samples share ``n_samples`` new ones (the first ``n_samples mod
    saved`` parents, in energy order, one more); ``propose`` draws their controls,
    ``simulate`` advances them one step and returns the new frame's cost (``inf`` = failed);
    :func:`select_samples` keeps ``n_keep``. Deterministic for a given ``rng`` state.
    """
    parents: list[Any] = [initial_state]
    energy = np.array([float(initial_cost)])
    # per step: (parent index (K,), controls, costs, infos) of the kept samples
    history: list[tuple[np.ndarray, list[Any], np.ndarray, list[Any], list[Any]]] = []
    seconds = np.zeros(n_steps)
    for step in range(n_steps):
        t0 = time.perf_counter()
        p = len(parents)
        per = np.full(p, n_samples // p)
        per[: n_samples % p] += 1
        parent_idx = np.repeat(np.arange(p), per)
        controls = list(propose(step, parents, parent_idx, rng))
        states, costs, infos = simulate(step, parents, parent_idx, controls)
        costs = np.asarray(costs, dtype=np.float64)
        total = energy[parent_idx] + costs
        keep = select_samples(total, n_keep)
        history.append((parent_idx[keep], [controls[k] for k in keep], costs[keep],
                        [infos[k] for k in keep], [states[k] for k in keep]))
        parents = [states[k] for k in keep]
        energy = total[keep]
        seconds[step] = time.perf_counter() - t0
        if progress is not None:
            progress(step + 1, n_steps)
    # backtrack from the lowest energy
    k = int(np.argmin(np.where(np.isfinite(energy), energy, np.inf))) if len(energy) else 0
    states_out: list[Any] = []
    controls_out: list[Any] = []
    costs_out: list[float] = []
    infos_out: list[Any] = []
    for step in range(n_steps - 1, -1, -1):
        pidx, ctl, cst, inf, sts = history[step]
        states_out.append(sts[k])
        controls_out.append(ctl[k])
        costs_out.append(float(cst[k]))
        infos_out.append(inf[k])
        k = int(pidx[k])
    states_out.append(initial_state)
    controls_out.append(None)
    costs_out.append(float(initial_cost))
    infos_out.append(None)
    return SamplingPath(states_out[::-1], controls_out[::-1], np.array(costs_out[::-1]),
                        infos_out[::-1], float(np.sum(costs_out)), seconds, n_samples)
