"""Interacting simulated annealing (ISA) over the scene parameters (seed 000 sec. 4.3).

Seed 000 tracks the hand and object frame by frame by minimising its image cost, eq. (3)
(:mod:`hand_capture.multiview.imageterms`), plus a smoothness term on the accelerations,
``|q_t - 2 q_{t-1} + q_{t-2}|^2``, with ISA (Gall et al. 2008): particles are sampled around
the previous frame's estimate (or, as an option, its constant-velocity prediction), weighted
by the annealed cost, resampled and diffused, 25 times with 300 particles; the estimate is
the weighted mean of the last particle set (here: or the best particle, when its cost is
lower).

:func:`isa_minimise` is the optimiser for any batch cost function; :func:`isa_track` runs it
over a sequence of synchronised colour groups with seed 000's cost (the sampling baseline
that seed 002 compares its local optimiser with at 64 and 128 particles).

The annealing follows Gall et al.'s interacting particle system, with these choices:

* the inverse temperature ``beta_k`` of iteration k is set so that the normalised weights
  ``exp(-beta_k (E - E_min))`` have an effective sample size of ``survival`` x N (the
  annealing rate adapts to the cost's scale), never lower than the previous ``beta``;
* selection keeps particle i with probability ``w_i / max w`` and replaces the others by
  draws proportional to ``w`` (ISA's selection kernel with ``eps_k = 1 / max w``);
* mutation adds Gaussian noise whose per-parameter deviation is ``diffusion`` times the
  weighted spread of the particles (floored at ``min_sigma`` x the initial deviation), so the
  search narrows as the particles agree; parameters stay inside the box ``[lo, hi]``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import InputError

__all__ = ["ISAConfig", "ISAResult", "ISATrackResult", "default_sigma", "isa_minimise",
           "isa_track", "smoothness_term"]


@dataclass(frozen=True)
class ISAConfig:
    """Settings of ISA (seed 000 sec. 4.3: 25 iterations, 300 particles)."""

    n_particles: int = param(300, "particles per iteration", lo=2, hi=100_000)
    n_iters: int = param(25, "annealing iterations per frame", lo=1, hi=1000)
    survival: float = param(0.5, "effective sample size / particles each beta aims at",
                            lo=0.01, hi=0.99)
    diffusion: float = param(0.6, "mutation deviation / weighted particle spread", lo=0.01,
                             hi=5.0)
    min_sigma: float = param(0.03, "floor of the mutation deviation / initial deviation",
                             lo=0.0, hi=1.0)
    w_smooth: float = param(1.0, "weight of the smoothness term (sum over the parameters "
                            "of the squared acceleration / its scale)", lo=0.0, hi=100.0)
    acc_pos_m: float = param(0.01, "acceleration scale of positions [m / frame^2]",
                             lo=1e-5, hi=1.0)
    acc_ang_rad: float = param(0.15, "acceleration scale of angles [rad / frame^2]",
                               lo=1e-4, hi=3.0)
    start: str = param("previous", "where a frame's particles start: the previous estimate "
                       "(seed 000) or its constant-velocity prediction",
                       choices=("previous", "prediction"))
    sigma_pos_m: float = param(0.01, "initial sampling deviation of positions [m]",
                               lo=1e-5, hi=0.5)
    sigma_root_rad: float = param(0.1, "initial deviation of hand / object angles [rad]",
                                  lo=1e-4, hi=3.0)
    sigma_finger_rad: float = param(0.15, "initial deviation of finger joints [rad]",
                                    lo=1e-4, hi=3.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class ISAResult:
    """What :func:`isa_minimise` found.

    Attributes:
        x: (D,) the weighted mean of the last particle set (seed 000's estimate).
        cost: its cost (one extra evaluation).
        best_x, best_cost: the best particle ever evaluated.
        n_evals: cost evaluations (particles) spent.
        history: (n_iters,) the lowest cost of each iteration.
    """

    x: np.ndarray
    cost: float
    best_x: np.ndarray
    best_cost: float
    n_evals: int
    history: np.ndarray = field(repr=False)


def _beta_for(e: np.ndarray, target: float, beta_min: float) -> float:
    """Inverse temperature whose weights have an ESS of ``target`` (fraction), >= beta_min."""
    d = e - e.min()
    if not np.any(d > 0):
        return beta_min

    def ess(b: float) -> float:
        w = np.exp(-b * d)
        return float(w.sum() ** 2 / (np.sum(w * w) * len(w)))

    lo, hi = 0.0, 1.0 / max(float(np.median(d[d > 0])), 1e-12)
    while ess(hi) > target and hi < 1e12:
        hi *= 4.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if ess(mid) > target:
            lo = mid
        else:
            hi = mid
    return max(0.5 * (lo + hi), beta_min)


def isa_minimise(cost: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
                 sigma: np.ndarray, lo: np.ndarray | None = None, hi: np.ndarray | None = None,
                 *, config: ISAConfig | None = None, seed: int | np.random.Generator = 0
                 ) -> ISAResult:
    """Minimise a batch cost with ISA around ``x0``.

    Args:
        cost: maps particles (N, D) to costs (N,) (lower is better; inf/NaN = rejected).
        x0: (D,) the start (kept as the first particle of the first set).
        sigma: (D,) initial sampling deviation per parameter (0 = held fixed).
        lo, hi: (D,) box bounds (None = unbounded).
        config: particles, iterations and the annealing settings.
        seed: random seed or generator.
    """
    cfg = config or ISAConfig()
    rng = np.random.default_rng(seed)
    x0 = np.asarray(x0, float).reshape(-1)
    D = len(x0)
    sig0 = np.broadcast_to(np.asarray(sigma, float), (D,)).copy()
    if not (np.all(np.isfinite(x0)) and np.all(np.isfinite(sig0)) and np.all(sig0 >= 0)):
        raise InputError("isa_minimise: x0 and sigma must be finite, sigma >= 0")
    lo = np.full(D, -np.inf) if lo is None else np.asarray(lo, float)
    hi = np.full(D, np.inf) if hi is None else np.asarray(hi, float)
    N = cfg.n_particles

    def evaluate(X: np.ndarray) -> np.ndarray:
        e = np.asarray(cost(X), float).reshape(-1)
        if e.shape != (len(X),):
            raise InputError(f"cost returned {e.shape} for {len(X)} particles")
        return np.where(np.isfinite(e), e, np.inf)

    X = np.clip(x0 + rng.standard_normal((N, D)) * sig0, lo, hi)
    X[0] = np.clip(x0, lo, hi)
    beta = 0.0
    best_x, best_e = X[0].copy(), np.inf
    history = np.empty(cfg.n_iters)
    n_evals = 0
    w = np.full(N, 1.0 / N)
    for k in range(cfg.n_iters):
        E = evaluate(X)
        n_evals += N
        i_best = int(np.argmin(E))
        history[k] = E[i_best]
        if E[i_best] < best_e:
            best_e, best_x = float(E[i_best]), X[i_best].copy()
        finite = np.isfinite(E)
        if not finite.any():
            raise InputError("isa_minimise: every particle's cost is infinite")
        Ef = np.where(finite, E, np.max(E[finite]) + 1e9)
        beta = _beta_for(Ef[finite], cfg.survival, beta)
        w = np.where(finite, np.exp(-beta * (Ef - Ef[finite].min())), 0.0)
        w /= w.sum()
        if k == cfg.n_iters - 1:
            break
        # selection (ISA): keep i with probability w_i / max w, else redraw by the weights
        keep = rng.random(N) < w / w.max()
        src = np.where(keep, np.arange(N), rng.choice(N, size=N, p=w))
        src[0] = i_best  # the best particle survives unchanged
        # mutation: diffusion scaled by the weighted spread of the particles
        mean = w @ X
        spread = np.sqrt(np.maximum(w @ (X - mean) ** 2, 0.0))
        sig = np.maximum(cfg.diffusion * spread, cfg.min_sigma * sig0)
        sig = np.minimum(sig, sig0)
        Xn = X[src] + rng.standard_normal((N, D)) * sig
        Xn[0] = X[i_best]
        X = np.clip(Xn, lo, hi)
    x = np.clip(w @ X, lo, hi)  # the weighted combination of the last set
    e = float(evaluate(x[None])[0])
    n_evals += 1
    if e < best_e:
        best_e, best_x = e, x.copy()
    return ISAResult(x, e, best_x, best_e, n_evals, history)


# ---------------------------------------------------------------- scene-level tracking
def default_sigma(scene: object, config: ISAConfig | None = None) -> np.ndarray:
    """(n_params,) initial deviations: positions, hand roots and object angles, fingers."""
    cfg = config or ISAConfig()
    s = np.empty(scene.n_params)
    for name in scene.part_names:
        sl = scene.slices[name]
        block = np.full(sl.stop - sl.start, cfg.sigma_finger_rad)
        block[:3] = cfg.sigma_pos_m
        block[3:6] = cfg.sigma_root_rad
        s[sl] = block
    return s


def _acc_scale(scene: object, config: ISAConfig) -> np.ndarray:
    a = np.full(scene.n_params, config.acc_ang_rad)
    for name in scene.part_names:
        sl = scene.slices[name]
        a[sl.start: sl.start + 3] = config.acc_pos_m
    return a


def smoothness_term(params: np.ndarray, prev: np.ndarray, prev2: np.ndarray,
                    scale: np.ndarray) -> np.ndarray:
    """Seed 000 sec. 4.3: ``|q_t - 2 q_{t-1} + q_{t-2}|^2`` per particle (B,), each parameter
    divided by its acceleration scale (metres and radians made comparable)."""
    a = (np.atleast_2d(params) - 2.0 * prev + prev2) / scale
    return np.sum(a * a, axis=1)


@dataclass
class ISATrackResult:
    """Per-frame estimates of :func:`isa_track`.

    Attributes:
        params: (T, n_params) estimates (row 0: the initial configuration).
        seconds: (T,) wall time per frame [s] (row 0: learning the colour model).
        costs: (T,) eq. (3) + smoothness of each estimate.
    """

    params: np.ndarray
    seconds: np.ndarray
    costs: np.ndarray

    @property
    def s_per_frame(self) -> float:
        """Mean wall time of the tracked frames (1..T-1) [s]."""
        return float(np.mean(self.seconds[1:])) if len(self.seconds) > 1 else 0.0


def _rgb_group(group: Mapping[str, object]) -> dict[str, np.ndarray]:
    """name -> rgb of a group whose values are images or objects with an ``rgb``."""
    return {k: np.asarray(getattr(v, "rgb", v)) for k, v in group.items()}


def first_frame_masks(scene: object, rig: object, params: np.ndarray,
                      names: Sequence[str]) -> list[np.ndarray]:
    """Hand masks (H, W) bool of the cameras ``names``: the scene rendered at ``params``."""
    state = scene.pose(params)
    out = []
    for n in names:
        r = scene.render(rig.camera(n), state)
        out.append((r.labels >= 1) & (r.labels <= scene.n_hands))
    return out


def isa_track(frames: Sequence[Mapping[str, object]], rig: object, scene: object,
              n_particles: int = 300, n_iters: int = 25, seed: int = 0, *,
              init_params: np.ndarray, config: ISAConfig | None = None,
              terms: object | None = None) -> ISATrackResult:
    """Track a sequence with ISA on seed 000's cost (eq. 3 + smoothness).

    Args:
        frames: T groups, each camera name -> (H, W, 3) uint8 image (or a studio view with
            an ``rgb``); cameras missing from a group are left out of that frame's cost.
        rig: the :class:`~hand_capture.multiview.rig.Rig`.
        scene: the :class:`~hand_capture.multiview.scene_model.SceneModel`.
        n_particles, n_iters: ISA's size (seed 000: 300 x 25; seed 002's baselines 64/128).
        seed: random seed (the run is reproducible).
        init_params: (n_params,) configuration of the first frame (from
            :func:`hand_capture.multiview.hull.initialise` or ground truth); the colour
            models (eq. 4 and the vertex colours of eq. 6) are learned on it.
        config: ISA settings (its particle and iteration counts are overridden by the
            arguments).
        terms: :class:`~hand_capture.multiview.imageterms.ImageTermsConfig` (default:
            seed 000's weights).

    Returns:
        the estimates, seconds per frame and costs.
    """
    from dataclasses import replace

    from hand_capture.multiview.imageterms import (
        ColourModel,
        ImageCost,
        hand_rois,
        observe_group,
    )

    if not frames:
        raise InputError("isa_track needs at least one frame")
    cfg = replace(config or ISAConfig(), n_particles=n_particles, n_iters=n_iters)
    rng = np.random.default_rng(seed)
    p0 = scene.clip(scene.check(init_params))
    t0 = time.perf_counter()
    g0 = _rgb_group(frames[0])
    names = [c.name for c in rig.cameras if c.name in g0]
    if not names:
        raise InputError("the first group holds none of the rig's cameras")
    colour = ColourModel.fit([g0[n] for n in names], first_frame_masks(scene, rig, p0, names),
                             seed=seed, margin_px=3)
    cost_fn = ImageCost(scene, terms)
    views0 = observe_group(g0, rig, colour, cost_fn.config, hand_rois(scene, rig, p0))
    cost_fn.learn_colours(p0, views0)
    sig = default_sigma(scene, cfg)
    acc = _acc_scale(scene, cfg)
    out = [p0]
    costs = [float(cost_fn(p0[None], views0)[0])]
    secs = [time.perf_counter() - t0]
    for t in range(1, len(frames)):
        t0 = time.perf_counter()
        prev = out[-1]
        prev2 = out[-2] if len(out) > 1 else out[-1]
        views = observe_group(_rgb_group(frames[t]), rig, colour, cost_fn.config,
                              hand_rois(scene, rig, prev))

        def cost(X: np.ndarray, views: list = views, prev: np.ndarray = prev,
                 prev2: np.ndarray = prev2) -> np.ndarray:
            e = cost_fn(X, views) if views else np.zeros(len(X))
            return e + cfg.w_smooth * smoothness_term(X, prev, prev2, acc)

        # particles start around the previous estimate (or its constant-velocity
        # prediction); the estimate is the weighted mean, or the best particle if lower
        start = scene.clip(2.0 * prev - prev2) if cfg.start == "prediction" else prev
        res = isa_minimise(cost, start, sig, scene.lo, scene.hi, config=cfg, seed=rng)
        x, e = (res.x, res.cost) if res.cost <= res.best_cost else (res.best_x, res.best_cost)
        out.append(x)
        costs.append(e)
        secs.append(time.perf_counter() - t0)
    return ISATrackResult(np.array(out), np.array(secs), np.array(costs))
