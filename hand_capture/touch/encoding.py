"""Polynomial encodings of hand pose from multi-touch input (Chung et al., sec. 2).

Input vector (sec. 2): ``u = (p_1 .. p_5, s_1 .. s_5)`` in R^15, ``p_i = (x_i, y_i)`` the
position of fingertip i on the surface, ``s_i`` = 1 while it touches, else 0. As in the paper's
experiments (sec. 4): positions in inches, relative to the leftmost contact (translation
invariance), and ``(-1, -1)`` for a finger that does not touch.

Every degree of freedom n of the pose is a polynomial of u:

* linear,    eq. (2): ``q_n = sum_i a_in u_i + d_n``                          16 coefficients
* quadratic, eq. (1): ``q_n = sum_{i<=j} a_ijn u_i u_j + sum_i b_in u_i + d_n``  136 coefficients
  (120 products i <= j + 15 linear + 1 constant, as the paper counts)
* cubic,     eq. (3): adds ``sum_{i<=j<=k} a_ijkn u_i u_j u_k``                816 coefficients

The coefficients are found by least squares over a training set of (u, pose) pairs (the paper
uses MATLAB's lsqcurvefit; here a direct solve), optionally ridge-regularised on standardised
monomials. Evaluation is one matrix product per batch.

Frames. Touch positions are in the surface frame S of ``TouchFrame`` (origin at the top-left
corner, x right, y down the screen towards the user, z into the surface). Pose vectors (the
suite's 27 DoF, ``hand_capture.model.joints.JOINT_NAMES``) are in the *table frame*
T = (x_S, -y_S, -z_S): z up out of the surface, y away from the user. A right hand lying palm
down with its fingers pointing away from the user then has root angles near (0, 0, pi/2), far
from the wrap of the Euler angles, which a polynomial could not follow. The root position of
an encoded pose is relative to the leftmost contact (the same translation invariance as u);
:func:`absolute_pose` adds the contact back.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from pathlib import Path

import numpy as np

from hand_capture.errors import ConfigError, InputError
from hand_capture.model.joints import JOINT_NAMES

N_FINGERS = 5
U_DIM = 3 * N_FINGERS  # 10 coordinates + 5 contact flags
POSE_DIM = len(JOINT_NAMES)
INCH = 0.0254  # [m]
#: Units of u per metre (the paper gives positions in inches).
INPUT_SCALE = 1.0 / INCH
#: Coordinate value of a finger that does not touch (sec. 4).
LIFTED_VALUE = -1.0
DEGREES = {"linear": 1, "quadratic": 2, "cubic": 3}
#: Rows per block of a batched evaluation (:meth:`PolynomialEncoder.predict`).
PREDICT_BLOCK = 1024
#: Rotation taking table-frame vectors to the surface frame (its own inverse).
TABLE_TO_SURFACE = np.diag([1.0, -1.0, -1.0])
TABLE_TO_SURFACE.setflags(write=False)


def n_features(degree: int, dim: int = U_DIM) -> int:
    """Number of monomials of total degree <= ``degree`` in ``dim`` variables."""
    return comb(dim + degree, degree)


def encode_input(positions: np.ndarray, contact: np.ndarray,
                 input_scale: float = INPUT_SCALE,
                 lifted_value: float = LIFTED_VALUE) -> tuple[np.ndarray, np.ndarray]:
    """Build u from labelled fingertip positions (sec. 2 and 4).

    Args:
        positions: (..., 5, 2) fingertip positions on the surface [m], finger order
            thumb..little (``hand_capture.model.joints.FINGERS``); ignored where not in contact.
        contact: (..., 5) bool contact flags; at least one per row must be set.

    Returns:
        u: (..., 15) encoder input.
        origin: (..., 2) position [m] of the leftmost contact that u is relative to.

    Raises:
        InputError: wrong shapes, a row without contact, or non-finite contact positions.
    """
    p = np.asarray(positions, dtype=np.float64)
    s = np.asarray(contact, dtype=bool)
    if p.shape[-2:] != (N_FINGERS, 2) or s.shape != p.shape[:-1]:
        raise InputError(f"positions must be (..., 5, 2) and contact (..., 5); got {p.shape} "
                         f"and {s.shape}")
    if not s.any(axis=-1).all():
        raise InputError("every input needs at least one finger in contact")
    if not np.isfinite(p[s]).all():
        raise InputError("non-finite contact position")
    x = np.where(s, p[..., 0], np.inf)
    lead = np.argmin(x, axis=-1)  # leftmost contact
    origin = np.take_along_axis(p, lead[..., None, None], axis=-2)[..., 0, :]
    rel = (p - origin[..., None, :]) * input_scale
    rel = np.where(s[..., None], rel, lifted_value)
    u = np.concatenate([rel.reshape(*p.shape[:-2], 2 * N_FINGERS), s.astype(np.float64)],
                       axis=-1)
    return u, origin


def surface_to_table_xy(xy: np.ndarray) -> np.ndarray:
    """Surface-plane coordinates (..., 2) [m] -> table-frame (x, y) (..., 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    return np.stack([xy[..., 0], -xy[..., 1]], axis=-1)


def relative_pose(pose: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The pose with its root position made relative to the contact ``origin`` (surface
    coordinates [m])."""
    q = np.array(pose, dtype=np.float64, copy=True)
    q[..., 0:2] -= surface_to_table_xy(origin)
    return q


def absolute_pose(pose: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Inverse of :func:`relative_pose`."""
    q = np.array(pose, dtype=np.float64, copy=True)
    q[..., 0:2] += surface_to_table_xy(origin)
    return q


class PolynomialFeatures:
    """All monomials of u up to a total degree, in the order 1, u_i, u_i u_j (i <= j),
    u_i u_j u_k (i <= j <= k), each group lexicographic.

    The monomials are built row-wise in a (n_features, B) array: for each i the products with
    u_i are one broadcast multiply into a contiguous block (no gathers), which keeps a batched
    evaluation well under the paper's 2.1 us per pose.
    """

    def __init__(self, degree: int, dim: int = U_DIM) -> None:
        if degree not in (1, 2, 3):
            raise ConfigError(f"encoding degree must be 1, 2 or 3, got {degree}")
        self.degree, self.dim = degree, dim
        self.size = n_features(degree, dim)
        # start row of the block u_i * (u_j u_k, i <= j <= k) of pair products, per i
        self._pair_start = 1 + dim + np.r_[0, np.cumsum(np.arange(dim, 1, -1))]
        self._pair_end = 1 + dim + comb(dim + 1, 2)

    def transposed(self, u: np.ndarray) -> np.ndarray:
        """(B, dim) -> (size, B) monomials."""
        u = np.asarray(u, dtype=np.float64)
        if u.ndim != 2 or u.shape[1] != self.dim:
            raise InputError(f"u must have shape (B, {self.dim}), got {u.shape}")
        d = self.dim
        ut = u.T
        out = np.empty((self.size, len(u)))
        out[0] = 1.0
        out[1:d + 1] = ut
        k = d + 1
        if self.degree >= 2:
            for i in range(d):  # u_i u_j, j >= i
                np.multiply(ut[i], ut[i:], out=out[k:k + d - i])
                k += d - i
        if self.degree >= 3:
            for i in range(d):  # u_i u_j u_k, k >= j >= i: u_i times the pair block of i
                a, b = self._pair_start[i], self._pair_end
                np.multiply(ut[i], out[a:b], out=out[k:k + b - a])
                k += b - a
        return out

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(B, dim) -> (B, size) monomials."""
        return self.transposed(np.atleast_2d(u)).T


@dataclass
class PolynomialEncoder:
    """Pose as a polynomial of u, eq. (1)-(3); ``coef`` has one column per degree of freedom."""

    degree: int
    coef: np.ndarray  # (n_features, POSE_DIM)
    input_scale: float = INPUT_SCALE
    lifted_value: float = LIFTED_VALUE

    def __post_init__(self) -> None:
        self.features = PolynomialFeatures(self.degree)
        self.coef = np.ascontiguousarray(self.coef, dtype=np.float64)
        self._coef_t = np.ascontiguousarray(self.coef.T)
        if self.coef.shape != (self.features.size, POSE_DIM):
            raise ConfigError(f"degree-{self.degree} encoder needs coefficients of shape "
                              f"({self.features.size}, {POSE_DIM}), got {self.coef.shape}")

    @property
    def name(self) -> str:
        return {v: k for k, v in DEGREES.items()}[self.degree]

    def predict(self, u: np.ndarray) -> np.ndarray:
        """(B, 15) inputs -> (B, 27) poses (root position relative to the leftmost contact).

        Large batches go in blocks of :data:`PREDICT_BLOCK` rows, so that the monomials of a
        block (136 x block for eq. 1) stay in cache between being made and multiplied.
        """
        u = np.asarray(u, dtype=np.float64)
        if u.ndim != 2 or len(u) <= PREDICT_BLOCK:
            return (self._coef_t @ self.features.transposed(u)).T
        out = np.empty((POSE_DIM, len(u)))
        for s in range(0, len(u), PREDICT_BLOCK):
            np.matmul(self._coef_t, self.features.transposed(u[s:s + PREDICT_BLOCK]),
                      out=out[:, s:s + PREDICT_BLOCK])
        return out.T

    def reconstruct(self, positions: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """Labelled fingertips (..., 5, 2) [m] + flags (..., 5) -> absolute poses (..., 27)."""
        u, origin = encode_input(positions, contact, self.input_scale, self.lifted_value)
        q = self.predict(u.reshape(-1, U_DIM)).reshape(*u.shape[:-1], POSE_DIM)
        return absolute_pose(q, origin)

    @staticmethod
    def fit(u: np.ndarray, poses: np.ndarray, degree: int, ridge: float = 0.0,
            input_scale: float = INPUT_SCALE,
            lifted_value: float = LIFTED_VALUE) -> PolynomialEncoder:
        """Least-squares coefficients of eq. (1)/(2)/(3) for training pairs.

        Args:
            u: (M, 15) inputs; poses: (M, 27) outputs (root relative to the leftmost contact).
            ridge: Tikhonov weight on the standardised non-constant monomials, relative to
                the number of samples (0 = plain least squares, minimum-norm where the
                monomials are dependent, e.g. s_i^2 = s_i).
        """
        u = np.asarray(u, np.float64)
        poses = np.asarray(poses, np.float64)
        if len(u) != len(poses) or poses.shape[1:] != (POSE_DIM,):
            raise InputError(f"u {u.shape} and poses {poses.shape} do not match")
        if not (np.isfinite(u).all() and np.isfinite(poses).all()):
            raise InputError("training data contains non-finite values")
        if ridge < 0:
            raise ConfigError(f"ridge must be >= 0, got {ridge}")
        phi = PolynomialFeatures(degree)(u)
        coef = _solve_ridge(phi, poses, ridge)
        return PolynomialEncoder(degree, coef, input_scale, lifted_value)

    def save(self, path: str | Path) -> None:
        np.savez_compressed(path, **self.to_arrays())

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        return {f"{prefix}degree": np.int64(self.degree), f"{prefix}coef": self.coef,
                f"{prefix}input_scale": np.float64(self.input_scale),
                f"{prefix}lifted_value": np.float64(self.lifted_value)}

    @staticmethod
    def from_arrays(data: dict, prefix: str = "") -> PolynomialEncoder:
        try:
            return PolynomialEncoder(int(data[f"{prefix}degree"]),
                                     np.asarray(data[f"{prefix}coef"]),
                                     float(data[f"{prefix}input_scale"]),
                                     float(data[f"{prefix}lifted_value"]))
        except KeyError as e:
            raise ConfigError(f"encoder arrays lack {e}") from e


def cross_validate_ridge(u: np.ndarray, poses: np.ndarray, degree: int,
                         ridges: tuple[float, ...], groups: np.ndarray, folds: int = 5,
                         seed: int = 0) -> tuple[float, np.ndarray]:
    """Ridge weight of :meth:`PolynomialEncoder.fit` chosen by k-fold cross-validation.

    Folds split ``groups`` (e.g. sequence ids: frames of one motion are not independent).
    The score is the mean squared error of every DoF divided by its variance (unit-free).

    Returns:
        (best ridge, (len(ridges),) scores).
    """
    u = np.asarray(u, np.float64)
    y = np.asarray(poses, np.float64)
    ids = np.unique(groups)
    fold_of = dict(zip(np.random.default_rng(seed).permutation(ids),
                       np.arange(len(ids)) % folds, strict=True))
    fold = np.array([fold_of[g] for g in groups])
    phi = PolynomialFeatures(degree)(u)
    var = y.var(axis=0) + 1e-12
    scores = np.zeros(len(ridges))
    positive = tuple(r for r in ridges if r > 0)
    for k in range(folds):
        tr, te = fold != k, fold == k
        coefs = dict(zip(positive, _ridge_path(phi[tr], y[tr], positive), strict=True))
        for j, r in enumerate(ridges):
            coef = coefs[r] if r > 0 else _solve_ridge(phi[tr], y[tr], 0.0)
            scores[j] += (((phi[te] @ coef - y[te]) ** 2).mean(axis=0) / var).mean() / folds
    return float(ridges[int(np.argmin(scores))]), scores


def _solve_ridge(phi: np.ndarray, y: np.ndarray, ridge: float) -> np.ndarray:
    """argmin ||phi c - y||^2 + ridge * M * ||D c||^2, D = std of each non-constant column."""
    if ridge == 0.0:
        coef, *_ = np.linalg.lstsq(phi, y, rcond=None)
        return coef
    return _ridge_path(phi, y, (ridge,))[0]


def _ridge_path(phi: np.ndarray, y: np.ndarray, ridges: tuple[float, ...]) -> list[np.ndarray]:
    """Ridge solutions for several weights > 0 from one Gram matrix of the standardised,
    centred monomials (the constant column absorbs the means and is not penalised)."""
    import scipy.linalg

    m = len(phi)
    std = phi.std(axis=0)
    mean = phi.mean(axis=0)
    keep = std > 1e-12
    keep[0] = False  # the constant column
    z = (phi[:, keep] - mean[keep]) / std[keep]
    gram = z.T @ z
    rhs = z.T @ (y - y.mean(axis=0))
    out = []
    for r in ridges:
        w = scipy.linalg.solve(gram + r * m * np.eye(len(gram)), rhs, assume_a="pos")
        coef = np.zeros((phi.shape[1], y.shape[1]))
        coef[keep] = w / std[keep, None]
        coef[0] = y.mean(axis=0) - mean[keep] @ coef[keep]
        out.append(coef)
    return out
