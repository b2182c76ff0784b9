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

Departure (issue #13): the paper fits plain least squares. The shipped encoders
(``hand-suite train touch``) take, per degree, the ridge weight out of :data:`CV_RIDGES` that
:func:`cross_validate_ridge` scores best on the training set alone (5 folds by sequence; 0,
plain least squares, is one of the candidates); ``--ridge R`` forces one weight for all
degrees, ``--ridge 0`` the paper's fit.

Frames. Touch positions are in the surface frame S of ``TouchFrame`` (origin at the top-left
corner, x right, y down the screen towards the user, z into the surface). Pose vectors (the
suite's 27 DoF, ``hand_capture.model.joints.JOINT_NAMES``) are in the *table frame*
T = (x_S, -y_S, -z_S): z up out of the surface, y away from the user. A right hand lying palm
down with its fingers pointing away from the user then has root angles near (0, 0, pi/2), far
from the wrap of the Euler angles, which a polynomial could not follow. The root position of
an encoded pose is relative to the leftmost contact (the same translation invariance as u);
:func:`absolute_pose` adds the contact back.

Departure (issue #13): the shipped model uses :class:`ContactFrame` instead, origin at the
contacts' centroid and axes turned to the finger set's mean layout; the paper's
leftmost-contact frame stays available (``hand-suite train touch --leftmost``).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from pathlib import Path

import numpy as np

from hand_capture.errors import ConfigError, InputError
from hand_capture.model.joints import JOINT_NAMES, root_angles_from_matrix, root_rotation_matrix

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
    _check_input(p, s)
    x = np.where(s, p[..., 0], np.inf)
    lead = np.argmin(x, axis=-1)  # leftmost contact
    origin = np.take_along_axis(p, lead[..., None, None], axis=-2)[..., 0, :]
    rel = (p - origin[..., None, :]) * input_scale
    rel = np.where(s[..., None], rel, lifted_value)
    u = np.concatenate([rel.reshape(*p.shape[:-2], 2 * N_FINGERS), s.astype(np.float64)],
                       axis=-1)
    return u, origin


def _check_input(p: np.ndarray, s: np.ndarray) -> None:
    if p.shape[-2:] != (N_FINGERS, 2) or s.shape != p.shape[:-1]:
        raise InputError(f"positions must be (..., 5, 2) and contact (..., 5); got {p.shape} "
                         f"and {s.shape}")
    if not s.any(axis=-1).all():
        raise InputError("every input needs at least one finger in contact")
    if not np.isfinite(p[s]).all():
        raise InputError("non-finite contact position")


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


def _rot2(phi: np.ndarray) -> np.ndarray:
    """(..., 2, 2) rotations by ``phi`` [rad] (counter-clockwise in the table frame)."""
    c, s = np.cos(phi), np.sin(phi)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


class ContactFrame:
    """A frame fitted to the contacts, in which u and the pose are expressed (issue #13).

    Departure from the paper (sec. 4 makes positions relative to the leftmost contact only):
    the origin is the centroid of the contacts, and the axes are turned by the angle phi that
    best maps the finger set's mean training layout onto the contacts (2-D Procrustes,
    ``phi = atan2(sum mu x c, sum mu . c)`` over the centred positions c and the mean layout
    mu). With three or more contacts the full angle is used; two contacts fix the hand's
    orientation poorly (a pinch axis turns with the grip), so only ``two_contact_share`` of it;
    one contact, or a finger set without a mean layout, is not turned. The encoding (eq. 1-3)
    is then fitted and evaluated in that frame, and the pose is turned and shifted back. On the
    held-out family this takes the quadratic's wrist error from 3.27 to about 3.0 cm without
    training on it; a hand turned on the surface gives the same u.

    Attributes:
        layouts: (32, 5, 2) mean centred contact positions of each finger set (bit mask of
            the contacting fingers), table frame (x_S, -y_S) [m]; rows of fingers not in the
            set, and sets not seen in training, are zero.
        known: (32,) bool, the sets with a mean layout.
        two_contact_share: fraction of the angle used with two contacts (0..1).
    """

    def __init__(self, layouts: np.ndarray, known: np.ndarray,
                 two_contact_share: float = 0.5) -> None:
        layouts = np.asarray(layouts, np.float64)
        known = np.asarray(known, bool)
        if layouts.shape != (1 << N_FINGERS, N_FINGERS, 2) or known.shape != (1 << N_FINGERS,):
            raise ConfigError(f"contact frame arrays have shapes {layouts.shape}, "
                              f"{known.shape}; expected (32, 5, 2), (32,)")
        if not 0.0 <= two_contact_share <= 1.0:
            raise ConfigError(f"two_contact_share must be in [0, 1], got {two_contact_share}")
        self.layouts, self.known = layouts, known
        self.two_contact_share = float(two_contact_share)
        self._bits = 1 << np.arange(N_FINGERS)

    @staticmethod
    def fit(pads: np.ndarray, contact: np.ndarray, two_contact_share: float = 0.5,
            min_frames: int = 20) -> ContactFrame:
        """Mean layouts from labelled frames: ``pads`` (N, 5, 2) surface [m], ``contact``
        (N, 5); sets with fewer than ``min_frames`` frames stay unknown."""
        c = np.asarray(contact, bool)
        keys = c @ (1 << np.arange(N_FINGERS))
        pt = surface_to_table_xy(pads)
        layouts = np.zeros((1 << N_FINGERS, N_FINGERS, 2))
        known = np.zeros(1 << N_FINGERS, bool)
        for key in np.unique(keys):
            rows = keys == key
            if rows.sum() < min_frames or c[rows][0].sum() < 2:
                continue
            m = c[rows][0]
            x = pt[rows][:, m]
            layouts[key, m] = (x - x.mean(axis=1, keepdims=True)).mean(axis=0)
            known[key] = True
        return ContactFrame(layouts, known, two_contact_share)

    def place(self, positions: np.ndarray, contact: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """Origin (..., 2) surface [m] and angle phi (...,) [rad] of the frame of each row."""
        p = np.asarray(positions, np.float64)
        s = np.asarray(contact, bool)
        n = s.sum(axis=-1)
        origin = np.where(s[..., None], p, 0.0).sum(axis=-2) / np.maximum(n, 1)[..., None]
        key = (s * self._bits).sum(axis=-1)
        x = np.where(s[..., None], surface_to_table_xy(p - origin[..., None, :]), 0.0)
        mu = self.layouts[key]
        cross = (mu[..., 0] * x[..., 1] - mu[..., 1] * x[..., 0]).sum(axis=-1)
        dot = (mu * x).sum(axis=(-2, -1))
        phi = np.arctan2(cross, dot)
        share = np.where(n >= 3, 1.0, np.where(n == 2, self.two_contact_share, 0.0))
        phi = np.where(self.known[key], share * phi, 0.0)
        return origin, phi

    def encode(self, positions: np.ndarray, contact: np.ndarray,
               input_scale: float = INPUT_SCALE, lifted_value: float = LIFTED_VALUE
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """u (..., 15) in the frame, with the frame's origin (..., 2) and angle (...,).

        Raises:
            InputError: as :func:`encode_input`.
        """
        p = np.asarray(positions, dtype=np.float64)
        s = np.asarray(contact, dtype=bool)
        _check_input(p, s)
        origin, phi = self.place(np.where(s[..., None], p, 0.0), s)
        rel = surface_to_table_xy(p - origin[..., None, :])
        rel = np.einsum("...ij,...fj->...fi", _rot2(-phi), rel)
        rel = surface_to_table_xy(rel) * input_scale  # back to surface axes (y flips again)
        rel = np.where(s[..., None], rel, lifted_value)
        u = np.concatenate([rel.reshape(*p.shape[:-2], 2 * N_FINGERS), s.astype(np.float64)],
                           axis=-1)
        return u, origin, phi

    @staticmethod
    def to_frame(pose: np.ndarray, origin: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Absolute table-frame poses (..., 27) -> poses in the frame (origin, phi)."""
        return _turn(relative_pose(pose, origin), -np.asarray(phi, np.float64))

    @staticmethod
    def from_frame(pose: np.ndarray, origin: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_frame`."""
        return absolute_pose(_turn(pose, np.asarray(phi, np.float64)), origin)

    def to_arrays(self, prefix: str = "frame_") -> dict[str, np.ndarray]:
        return {f"{prefix}layouts": self.layouts, f"{prefix}known": self.known,
                f"{prefix}two_contact_share": np.float64(self.two_contact_share)}

    @staticmethod
    def from_arrays(data: dict, prefix: str = "frame_") -> ContactFrame | None:
        """The frame stored under ``prefix``, or None when the file has none."""
        names = data.files if hasattr(data, "files") else data
        if f"{prefix}layouts" not in names:
            return None
        return ContactFrame(np.asarray(data[f"{prefix}layouts"]),
                            np.asarray(data[f"{prefix}known"]),
                            float(data[f"{prefix}two_contact_share"]))


def _turn(pose: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Poses (..., 27) turned by ``phi`` (...,) about the table's z axis through the origin."""
    q = np.array(pose, dtype=np.float64, copy=True)
    r2 = _rot2(phi)
    q[..., 0:2] = np.einsum("...ij,...j->...i", r2, q[..., 0:2])
    rz = np.zeros(r2.shape[:-2] + (3, 3))
    rz[..., :2, :2] = r2
    rz[..., 2, 2] = 1.0
    q[..., 3:6] = root_angles_from_matrix(rz @ root_rotation_matrix(q[..., 3:6]))
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
    #: frame of u and the pose (None: the paper's, relative to the leftmost contact)
    frame: ContactFrame | None = None

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

    def encode(self, positions: np.ndarray, contact: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """u (..., 15) of labelled fingertips (..., 5, 2) [m] + flags (..., 5), with the origin
        (..., 2) [m] and angle (...,) [rad] of the frame (angle 0 without a frame)."""
        if self.frame is not None:
            return self.frame.encode(positions, contact, self.input_scale, self.lifted_value)
        u, origin = encode_input(positions, contact, self.input_scale, self.lifted_value)
        return u, origin, np.zeros(u.shape[:-1])

    def absolute(self, pose: np.ndarray, origin: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Encoded poses (..., 27) back to absolute table-frame poses (see :meth:`encode`)."""
        if self.frame is not None:
            return ContactFrame.from_frame(pose, origin, phi)
        return absolute_pose(pose, origin)

    def reconstruct(self, positions: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """Labelled fingertips (..., 5, 2) [m] + flags (..., 5) -> absolute poses (..., 27)."""
        u, origin, phi = self.encode(positions, contact)
        q = self.predict(u.reshape(-1, U_DIM)).reshape(*u.shape[:-1], POSE_DIM)
        return self.absolute(q, origin, phi)

    @staticmethod
    def fit(u: np.ndarray, poses: np.ndarray, degree: int, ridge: float = 0.0,
            input_scale: float = INPUT_SCALE, lifted_value: float = LIFTED_VALUE,
            frame: ContactFrame | None = None) -> PolynomialEncoder:
        """Least-squares coefficients of eq. (1)/(2)/(3) for training pairs.

        Args:
            u: (M, 15) inputs; poses: (M, 27) outputs (root relative to the leftmost contact,
                or in ``frame``; see :meth:`encode`).
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
        return PolynomialEncoder(degree, coef, input_scale, lifted_value, frame)

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


#: Candidate ridge weights of :func:`cross_validate_ridge` (0 = plain least squares).
CV_RIDGES: tuple[float, ...] = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0)


def cross_validate_ridge(u: np.ndarray, poses: np.ndarray, degree: int,
                         ridges: tuple[float, ...] = CV_RIDGES,
                         groups: np.ndarray | None = None, folds: int = 5,
                         seed: int = 0) -> tuple[float, np.ndarray]:
    """Ridge weight of :meth:`PolynomialEncoder.fit` chosen by k-fold cross-validation.

    Args:
        u: (M, 15) inputs; poses: (M, 27) outputs, as for :meth:`PolynomialEncoder.fit`.
        ridges: candidate weights (>= 0; 0 = plain least squares).
        groups: (M,) group id of each row; folds split whole groups (e.g. sequence ids:
            frames of one motion are not independent). None: every row its own group.

    The score is the mean squared error of every DoF divided by its variance (unit-free),
    averaged over the folds; ties go to the first candidate.

    Returns:
        (best ridge, (len(ridges),) scores).

    Raises:
        InputError: shapes that do not match, fewer groups than folds.
        ConfigError: no candidates, a negative one, or fewer than 2 folds.
    """
    u = np.asarray(u, np.float64)
    y = np.asarray(poses, np.float64)
    groups = np.arange(len(u)) if groups is None else np.asarray(groups)
    if len(u) != len(y) or len(groups) != len(u):
        raise InputError(f"u {u.shape}, poses {y.shape} and groups {groups.shape} do not match")
    if not ridges or min(ridges) < 0 or folds < 2:
        raise ConfigError(f"need candidate ridges >= 0 and folds >= 2; got {ridges}, {folds}")
    ids = np.unique(groups)
    if len(ids) < folds:
        raise InputError(f"{len(ids)} groups cannot make {folds} folds")
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
