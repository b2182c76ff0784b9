"""Grip-dependent deformable motion model of the closing phase (dissertation III.4.1.1).

Per grip mode, the closing segments of the database are registered to a reference segment by
DTW (:mod:`hand_control.grasp.dtw`), which splits each one into a *warped motion* on the
reference's canonical timeline and a *time warp*. Functional PCA of each set gives

* eq. (III.1): ``P(alpha) = p0 + [p_1 .. p_M] alpha`` (the warped motions, (T, 27));
* eq. (III.2): ``H(t; gamma) = sum_{i<=t} exp(b0(i) + [b_1(i) .. b_K(i)] gamma)`` (the warps,
  fitted in log-increment space, so every ``H`` is strictly increasing);
* eq. (III.3): ``x = P(alpha) (x) H(gamma)``: the canonical motion played on the warped
  timeline;

and a Gaussian mixture over ``params = (alpha, gamma)`` fitted by EM is the prior of eq.
(III.5). Eigen vectors are scaled by their standard deviations, so the parameters of the
training motions have unit variance per component (a natural scale for a particle swarm).

Motions are 27-DoF hand pose vectors (``JOINT_NAMES`` order) in the object frame of III.3;
positions in metres, angles in radians. Position and angle dimensions are made comparable by
:data:`FEATURE_SCALE` (10 cm of wrist motion counts like 1 rad of a joint) for DTW and PCA.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.model.joints import N_DOF
from hand_control.errors import InputError, SolverError
from hand_control.grasp.dtw import log_increments, register, warp_motion

__all__ = ["FEATURE_SCALE", "ClosingModel", "fit_closing_model", "resample"]

#: per-DoF weights of the pose vector in DTW costs and PCA (root position: 1 / 0.1 m)
FEATURE_SCALE: np.ndarray = np.r_[np.full(3, 10.0), np.ones(N_DOF - 3)]
FEATURE_SCALE.setflags(write=False)

_LOG_2PI = math.log(2.0 * math.pi)
#: log increments of a warp are clipped to this range (no underflow to a zero increment, no
#: overflow): every decoded warp stays strictly increasing, far outside the data too
_LOG_INC_RANGE = (-12.0, 12.0)


def resample(motion: np.ndarray, n: int) -> np.ndarray:
    """``motion`` (m, D) at ``n`` frames uniformly spaced over its own timeline."""
    m = np.asarray(motion, dtype=np.float64)
    return warp_motion(m, np.linspace(0.0, m.shape[0] - 1.0, n))


def _check_motion(motion: object, name: str) -> np.ndarray:
    m = np.asarray(motion, dtype=np.float64)
    if m.ndim != 2 or m.shape[1] != N_DOF or m.shape[0] < 3:
        raise InputError(f"{name}: a motion is (T >= 3, {N_DOF}), got shape {np.shape(motion)}")
    if not np.isfinite(m).all():
        raise InputError(f"{name}: the motion has NaN or infinite values")
    return m


@dataclass(frozen=True, eq=False)
class ClosingModel:
    """The closing-phase model of one grip mode (see the module docstring).

    Attributes:
        grip_mode: one of ``GRIP_MODES``.
        fps: frame rate of the database motions [Hz] (``duration`` is in seconds).
        reference: (T, 27) the reference segment of the DTW registration.
        p0: (T, 27) mean warped motion; ``p_basis`` (T, 27, M) eigen motions times their
            standard deviations (raw units).
        b0: (T-1,) mean log increment of the warps; ``b_basis`` (T-1, K) likewise scaled.
        gmm_weights (C,), gmm_means (C, M+K), gmm_covariances (C, M+K, M+K): the prior.
        contacts: the grip mode's contact points, ``(bone, point in the bone's frame [m])``
            (MuJoCo body names of the hand; averaged over the database's demonstrations).
        train_params: (N, M+K) the parameters of the training motions.
    """

    grip_mode: str
    fps: float
    reference: np.ndarray
    p0: np.ndarray
    p_basis: np.ndarray
    b0: np.ndarray
    b_basis: np.ndarray
    gmm_weights: np.ndarray
    gmm_means: np.ndarray
    gmm_covariances: np.ndarray
    contacts: tuple[tuple[str, tuple[float, float, float]], ...] = ()
    train_params: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def __post_init__(self) -> None:
        t = self.p0.shape[0]
        if self.p0.shape != (t, N_DOF) or self.p_basis.shape[:2] != (t, N_DOF):
            raise InputError(f"ClosingModel {self.grip_mode!r}: p0/p_basis shapes "
                             f"{self.p0.shape}/{self.p_basis.shape} do not match")
        if self.b0.shape != (t - 1,) or self.b_basis.shape[0] != t - 1:
            raise InputError(f"ClosingModel {self.grip_mode!r}: b0/b_basis shapes do not "
                             f"match {t} frames")
        n = self.n_params
        c = self.gmm_weights.shape[0]
        if self.gmm_means.shape != (c, n) or self.gmm_covariances.shape != (c, n, n):
            raise InputError(f"ClosingModel {self.grip_mode!r}: GMM shapes do not match "
                             f"{n} parameters")
        chol = np.linalg.cholesky(self.gmm_covariances)
        inv_chol = np.linalg.inv(chol)
        logdet = 2.0 * np.log(np.diagonal(chol, axis1=1, axis2=2)).sum(axis=1)
        object.__setattr__(self, "_chol", chol)
        object.__setattr__(self, "_inv_chol", inv_chol)
        object.__setattr__(self, "_log_norm",
                           np.log(self.gmm_weights) - 0.5 * (logdet + n * _LOG_2PI))
        # (M, T*27), C-contiguous: alpha @ it is a plain GEMM (a transposed view of the
        # (T*27, M) basis makes OpenBLAS take a path 1000x slower on this shape)
        object.__setattr__(self, "_p_rows",
                           np.ascontiguousarray(self.p_basis.reshape(t * N_DOF, -1).T))

    # ---- sizes -------------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        """Frames of a decoded closing motion (the reference segment's length)."""
        return int(self.p0.shape[0])

    @property
    def n_alpha(self) -> int:
        return int(self.p_basis.shape[2])

    @property
    def n_gamma(self) -> int:
        return int(self.b_basis.shape[1])

    @property
    def n_params(self) -> int:
        """``len((alpha, gamma))``."""
        return self.n_alpha + self.n_gamma

    # ---- the deformable model ----------------------------------------------------------
    def _params(self, params: object) -> np.ndarray:
        p = np.asarray(params, dtype=np.float64)
        if p.shape[-1:] != (self.n_params,) or p.ndim > 2:
            raise InputError(f"{self.grip_mode}: params must be ({self.n_params},) or "
                             f"(N, {self.n_params}), got shape {p.shape}")
        if not np.isfinite(p).all():
            raise InputError(f"{self.grip_mode}: params have NaN or infinite values")
        return p

    def canonical(self, params: object) -> np.ndarray:
        """eq. (III.1): the motion on the canonical timeline, (T, 27) or (N, T, 27)."""
        p = self._params(params)
        a = p[..., : self.n_alpha]
        flat = a @ self._p_rows  # (..., T*27)
        return self.p0 + flat.reshape(p.shape[:-1] + (self.n_frames, N_DOF))

    def warp(self, params: object) -> np.ndarray:
        """eq. (III.2): the time warp ``H`` (T,) or (N, T) [frames], ``H(0) = 0``, strictly
        increasing for every parameter vector."""
        p = self._params(params)
        g = p[..., self.n_alpha:]
        inc = np.exp(np.clip(self.b0 + g @ self.b_basis.T, *_LOG_INC_RANGE))
        zeros = np.zeros(p.shape[:-1] + (1,))
        return np.concatenate([zeros, np.cumsum(inc, axis=-1)], axis=-1)

    def duration(self, params: object) -> float | np.ndarray:
        """Length of the decoded closing motion [s] (``H(T-1) / fps``)."""
        h = self.warp(params)
        return h[..., -1] / self.fps

    def decode(self, params: object) -> np.ndarray:
        """eq. (III.3): the closing motion (n_frames, 27) in the object frame, sampled at
        ``n_frames`` instants evenly spaced over its duration (:meth:`duration`).

        ``params`` may also be (N, n_params): then (N, n_frames, 27).
        """
        p = self._params(params)
        one = p.ndim == 1
        p = np.atleast_2d(p)
        canon = self.canonical(p)  # (N, T, 27)
        h = self.warp(p)  # (N, T), strictly increasing rows
        n, t = h.shape
        s = np.linspace(0.0, 1.0, t)[None, :] * h[:, -1:]  # evenly spaced actual times
        # the canonical time of each sample, u = H^-1(s), for every row at once: one
        # searchsorted over the rows laid end to end
        off = (np.arange(n) * (float(h[:, -1].max()) + 1.0))[:, None]
        k = np.searchsorted((h + off).ravel(), (s + off).ravel(), side="right").reshape(n, t)
        k = np.clip(k - np.arange(n)[:, None] * t, 1, t - 1)
        rows = np.arange(n)[:, None]
        h0, h1 = h[rows, k - 1], h[rows, k]
        dh = h1 - h0
        a = np.clip(np.divide(s - h0, dh, out=np.zeros_like(dh), where=dh > 0), 0.0, 1.0)
        a = a[..., None]
        c0 = canon[rows, k - 1]
        out = c0 + a * (canon[rows, k] - c0)
        return out[0] if one else out

    def final_pose(self, params: object) -> np.ndarray:
        """The grasping pose (27,) = ``decode(params)[-1]`` (or (N, 27) for (N, n_params));
        the warp keeps the end points, so this is ``P(alpha)``'s last frame."""
        p = self._params(params)
        a = p[..., : self.n_alpha]
        last = self.p_basis[-1]  # (27, M)
        return self.p0[-1] + a @ last.T

    # ---- the prior ---------------------------------------------------------------------
    def log_prior(self, params: object) -> float | np.ndarray:
        """``ln pr(alpha, gamma)`` of the Gaussian mixture (scalar or (N,))."""
        p = self._params(params)
        x = np.atleast_2d(p)
        d = x[:, None, :] - self.gmm_means[None]  # (N, C, n)
        y = np.einsum("cij,ncj->nci", self._inv_chol, d)
        comp = self._log_norm[None] - 0.5 * (y * y).sum(axis=2)
        mx = comp.max(axis=1)
        out = mx + np.log(np.exp(comp - mx[:, None]).sum(axis=1))
        return float(out[0]) if p.ndim == 1 else out

    def neg_log_prior(self, params: object) -> float | np.ndarray:
        """eq. (III.5): ``E_p = -ln pr(alpha, gamma)`` (scalar, or (N,) for (N, n_params))."""
        return -self.log_prior(params)

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """(n, n_params) draws from the Gaussian mixture."""
        if n < 0:
            raise InputError(f"sample: n must be >= 0, got {n}")
        rng = np.random.default_rng(rng)
        comp = rng.choice(len(self.gmm_weights), size=n, p=self.gmm_weights)
        z = rng.standard_normal((n, self.n_params))
        return self.gmm_means[comp] + np.einsum("nij,nj->ni", self._chol[comp], z)

    def mean(self) -> np.ndarray:
        """The mixture's mean (n_params,)."""
        return self.gmm_weights @ self.gmm_means

    def bounds(self, n_sd: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
        """A box holding the prior's mass: the mean +- ``n_sd`` of the mixture's marginal
        standard deviations (for initialising / clamping a swarm)."""
        m = self.mean()
        d = self.gmm_means - m
        var = (self.gmm_weights[:, None] * (np.diagonal(self.gmm_covariances, axis1=1,
                                                        axis2=2) + d * d)).sum(axis=0)
        sd = np.sqrt(var)
        return m - n_sd * sd, m + n_sd * sd

    # ---- analysis ----------------------------------------------------------------------
    def encode(self, motion: object) -> np.ndarray:
        """The parameters (n_params,) of a closing motion (n >= 3, 27) of any length: DTW
        registration to the reference, then projection of the warped motion and of the
        warp's log increments on the eigen bases (least squares)."""
        m = _check_motion(motion, f"{self.grip_mode}.encode")
        w, warped = register(self.reference, m, FEATURE_SCALE)
        return self.encode_registered(warped, w)

    def encode_registered(self, warped: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Parameters of an already registered motion (warped (T, 27), warp (T,))."""
        y = ((warped - self.p0) * FEATURE_SCALE).ravel()
        basis = (self.p_basis * FEATURE_SCALE[None, :, None]).reshape(-1, self.n_alpha)
        alpha = np.linalg.lstsq(basis, y, rcond=None)[0] if self.n_alpha else np.zeros(0)
        return np.r_[alpha, warp_params(w, self.b0, self.b_basis)]

    # ---- files -------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the model to an ``.npz`` file."""
        bones = np.array([b for b, _ in self.contacts], dtype=str)
        pts = np.array([p for _, p in self.contacts], dtype=np.float64).reshape(-1, 3)
        np.savez_compressed(
            Path(path), grip_mode=np.array(self.grip_mode), fps=np.array(self.fps),
            reference=self.reference.astype(np.float32), p0=self.p0, p_basis=self.p_basis,
            b0=self.b0, b_basis=self.b_basis, gmm_weights=self.gmm_weights,
            gmm_means=self.gmm_means, gmm_covariances=self.gmm_covariances,
            contact_bones=bones, contact_points=pts, train_params=self.train_params)

    @classmethod
    def load(cls, path: str | Path) -> ClosingModel:
        """Read a model written by :meth:`save`.

        Raises:
            InputError: the file is missing or is not a closing model.
        """
        p = Path(path)
        try:
            with np.load(p, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read closing model {p}: {e}") from e
        try:
            contacts = tuple((str(b), tuple(float(v) for v in pt))
                             for b, pt in zip(d["contact_bones"], d["contact_points"],
                                              strict=True))
            return cls(str(d["grip_mode"]), float(d["fps"]),
                       d["reference"].astype(np.float64), d["p0"], d["p_basis"], d["b0"],
                       d["b_basis"], d["gmm_weights"], d["gmm_means"], d["gmm_covariances"],
                       contacts, d["train_params"])
        except KeyError as e:
            raise InputError(f"{p} is not a closing model (no {e})") from e


def warp_params(w: np.ndarray, b0: np.ndarray, b_basis: np.ndarray, iterations: int = 8
                ) -> np.ndarray:
    """The weights ``gamma`` (K,) whose warp ``H(gamma)`` (eq. III.2) is nearest to ``w``
    (T,): the projection of the log increments, then Gauss-Newton on ``H(gamma) - w`` (the
    projection alone loses the total duration when components are dropped)."""
    k = b_basis.shape[1]
    if k == 0:
        return np.zeros(0)
    g = np.linalg.lstsq(b_basis, log_increments(w) - b0, rcond=None)[0]
    target = np.asarray(w, dtype=np.float64)[1:]

    def resid(gg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        inc = np.exp(np.clip(b0 + b_basis @ gg, *_LOG_INC_RANGE))
        return np.cumsum(inc) - target, inc

    r, inc = resid(g)
    cost = float(r @ r)
    for _ in range(iterations):
        jac = np.cumsum(inc[:, None] * b_basis, axis=0)
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        for _ in range(12):  # halve the step until the fit improves
            r_new, inc_new = resid(g + step)
            c_new = float(r_new @ r_new)
            if c_new < cost:
                break
            step = step / 2.0
        else:
            break
        g, r, inc, cost = g + step, r_new, inc_new, c_new
        if np.abs(step).max() < 1e-8:
            break
    return g


def _pca(y: np.ndarray, keep: float, max_components: int
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA of the rows of ``y`` (N, D): ``(mean (D,), unit eigen vectors (D, M), standard
    deviations (M,))`` keeping the fewest components explaining ``keep`` of the variance."""
    mean = y.mean(axis=0)
    yc = y - mean
    n = y.shape[0]
    if n < 2:
        return mean, np.zeros((y.shape[1], 0)), np.zeros(0)
    u, s, vt = np.linalg.svd(yc, full_matrices=False)
    var = s ** 2 / (n - 1)
    total = var.sum()
    if total <= 1e-18:
        return mean, np.zeros((y.shape[1], 0)), np.zeros(0)
    m = int(np.searchsorted(np.cumsum(var) / total, keep) + 1)
    m = max(1, min(m, max_components, n - 1))
    return mean, vt[:m].T, np.sqrt(var[:m])


def fit_closing_model(grip_mode: str, segments: Sequence[np.ndarray], fps: float,
                      contacts: tuple[tuple[str, tuple[float, float, float]], ...] = (),
                      keep: float = 0.99, max_alpha: int = 8, max_gamma: int = 4,
                      max_mixture: int = 3, reg_covar: float = 0.3,
                      seed: int = 0) -> ClosingModel:
    """Fit the closing-phase model of one grip mode to its closing segments.

    Args:
        segments: closing motions (n_i >= 3, 27) in the object frame, any lengths.
        fps: their frame rate [Hz].
        keep: fraction of variance the functional PCAs keep (eq. III.1, III.2).
        max_alpha, max_gamma: caps on the numbers of components M and K.
        max_mixture: most Gaussian components; the number is chosen by BIC.
        reg_covar: added to the mixture's covariance diagonals (the parameters have unit
            variance per component; a few demonstrations per mode need the regulariser).

    Raises:
        SolverError: fewer than 3 segments.
    """
    from sklearn.mixture import GaussianMixture

    segs = [_check_motion(s, f"{grip_mode} segment {i}") for i, s in enumerate(segments)]
    if len(segs) < 3:
        raise SolverError(f"{grip_mode}: a closing model needs >= 3 segments, got {len(segs)}")
    lengths = np.array([s.shape[0] for s in segs])
    ref_i = int(np.argsort(lengths)[len(lengths) // 2])  # the median-length segment
    ref = segs[ref_i]
    t = ref.shape[0]
    warps, warped = [], []
    for s in segs:
        w, x = register(ref, s, FEATURE_SCALE)
        warps.append(w)
        warped.append(x)
    # eq. (III.1): functional PCA of the warped motions (scaled features)
    y = np.stack([(x * FEATURE_SCALE).ravel() for x in warped])
    mean, vecs, sd = _pca(y, keep, max_alpha)
    p0 = mean.reshape(t, N_DOF) / FEATURE_SCALE
    p_basis = (vecs * sd).reshape(t, N_DOF, -1) / FEATURE_SCALE[None, :, None]
    # eq. (III.2): functional PCA of the warps' log increments
    z = np.stack([log_increments(w) for w in warps])
    b0, bvecs, bsd = _pca(z, keep, max_gamma)
    b_basis = bvecs * bsd
    alpha = ((y - mean) @ vecs) / np.where(sd > 0, sd, 1.0)
    gamma = np.array([warp_params(w, b0, b_basis) for w in warps]).reshape(len(warps), -1)
    params = np.hstack([alpha, gamma])
    # the prior pr(alpha, gamma): a Gaussian mixture fitted by EM, components by BIC
    best = None
    for c in range(1, max(1, min(max_mixture, len(segs) // 4)) + 1):
        gm = GaussianMixture(c, covariance_type="full", reg_covar=reg_covar, random_state=seed,
                             n_init=2).fit(params)
        bic = gm.bic(params)
        if best is None or bic < best[0]:
            best = (bic, gm)
    gm = best[1]
    return ClosingModel(grip_mode, float(fps), ref, p0, p_basis, b0, b_basis,
                        gm.weights_.copy(), gm.means_.copy(), gm.covariances_.copy(),
                        contacts, params)
