"""Finger labelling: which finger made which contact (Chung et al., sec. 2).

A multi-touch surface does not say which finger touches where. When contacts appear, every
labelling (injective assignment of the n contacts to the 5 fingers: 20, 60, 120, 120 candidates
for n = 2, 3, 4, 5) is reconstructed with the encoder in one batch, and the labelling whose
reconstructed pose has the nearest neighbour in the training set is kept. While the same
contacts stay down the labels are kept as they are; a contact that lifts frees its finger.

The nearest-neighbour search (:class:`BoundedIndex`) is exact but skips most of the work: a
lower bound from k-means cells of the training set proves most labellings farther than the best
one found, and only the few left are compared with every training pose.

For the PCA-IK baseline (sec. 3) the search compares the encoder inputs u themselves with the
training inputs instead of reconstructed poses (``mode="input"``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.touch.encoding import (
    N_FINGERS,
    POSE_DIM,
    U_DIM,
    PolynomialEncoder,
    absolute_pose,
)


@dataclass(frozen=True)
class LabellerConfig:
    """How labellings are compared and when they are searched."""

    position_weight: float = param(
        10.0, "weight of the wrist position against joint angles in the pose distance "
        "[rad/m] (10: 1 cm counts as 0.1 rad)", lo=0.0, hi=1e4)
    relabel: str = param(
        "all", "when a new contact appears: 'all' searches labels for every contact (as the "
        "paper), 'new' keeps the labels of contacts that stay down", choices=("all", "new"))

    def __post_init__(self) -> None:
        validate(self)


def pose_weights(position_weight: float) -> np.ndarray:
    """Per-DoF weights of the pose distance: root position x weight, angles x 1."""
    w = np.ones(POSE_DIM)
    w[:3] = position_weight
    return w


@dataclass
class LabelResult:
    """Outcome of one labelling search."""

    labels: np.ndarray      # (n,) finger index of each contact
    pose: np.ndarray | None  # (27,) absolute reconstructed pose (mode "pose"), else None
    distance: float         # nearest-neighbour distance of the chosen labelling
    candidates: int         # labellings tried


class FingerLabeller:
    """Searches and keeps finger labels.

    Args:
        encoder: reconstructs poses from inputs u.
        reference: (M, 27) training poses (mode "pose", root relative to the leftmost
            contact) or (M, 15) training inputs u (mode "input").
        config: see :class:`LabellerConfig`.
        mode: ``"pose"`` (the paper's labelling for encodings) or ``"input"`` (PCA-IK).
    """

    def __init__(self, encoder: PolynomialEncoder, reference: np.ndarray,
                 config: LabellerConfig | None = None, mode: str = "pose") -> None:
        if mode not in ("pose", "input"):
            raise InputError(f"mode must be 'pose' or 'input', got {mode!r}")
        self.encoder = encoder
        self.config = config or LabellerConfig()
        self.mode = mode
        ref = np.asarray(reference, np.float64)
        dim = POSE_DIM if mode == "pose" else U_DIM
        if ref.ndim != 2 or ref.shape[1] != dim or len(ref) == 0:
            raise InputError(f"reference for mode {mode!r} must be (M, {dim}), got {ref.shape}")
        self.weights = pose_weights(self.config.position_weight) if mode == "pose" \
            else np.ones(U_DIM)
        self.index = BoundedIndex(ref * self.weights)
        #: every labelling of n contacts: row k gives the finger of each contact (P, n)
        self.perms = {n: np.array(list(itertools.permutations(range(N_FINGERS), n)),
                                   dtype=np.intp) for n in range(1, N_FINGERS + 1)}
        self.labels: dict[int, int] = {}  # session id -> finger

    # --- search -------------------------------------------------------------------------
    def candidate_inputs(self, positions: np.ndarray,
                         perms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inputs u (P, 15) of every labelling in ``perms`` (P, n), and the origin (2,)."""
        enc = self.encoder
        p = np.asarray(positions, np.float64)
        origin = p[np.argmin(p[:, 0])]
        rel = (p - origin) * enc.input_scale
        n_cand = len(perms)
        u = np.full((n_cand, U_DIM), enc.lifted_value)
        u[:, 2 * N_FINGERS:] = 0.0
        rows = (np.arange(n_cand) * U_DIM)[:, None]  # flat offset of each candidate's row
        uf = u.reshape(-1)
        uf[rows + 2 * perms] = rel[:, 0]
        uf[rows + 2 * perms + 1] = rel[:, 1]
        uf[rows + 2 * N_FINGERS + perms] = 1.0
        return u, origin

    def search(self, positions: np.ndarray,
               fixed: dict[int, int] | None = None) -> LabelResult:
        """Best labelling of contacts at ``positions`` (n, 2) [m].

        Args:
            fixed: contact index -> finger for contacts whose label must be kept.

        Raises:
            InputError: no contact, more than 5, or non-finite positions.
        """
        p = _check_contacts(positions)
        perms = self.perms[len(p)]
        if fixed:
            keep = np.ones(len(perms), bool)
            for k, f in fixed.items():
                keep &= perms[:, k] == f
            if keep.any():
                perms = perms[keep]
        u, origin = self.candidate_inputs(p, perms)
        q = self.encoder.predict(u) if self.mode == "pose" else None
        best, dist = self._nearest(q * self.weights if q is not None else u)
        pose = None if q is None else absolute_pose(q[best], origin)
        return LabelResult(perms[best].copy(), pose, dist, len(perms))

    def nearest_distance(self, points: np.ndarray) -> np.ndarray:
        """Nearest-reference distances (n,) of poses (mode "pose", root relative to the
        leftmost contact) or inputs u (mode "input"), (n, dim) or (dim,), in the search's
        weighted metric."""
        return self.index.distances(np.atleast_2d(points) * self.weights)[0]

    def _nearest(self, points: np.ndarray) -> tuple[int, float]:
        """Index of the (weighted) point with the nearest reference neighbour, and that
        distance (exact; see :class:`BoundedIndex`)."""
        return self.index.best(points)

    # --- tracking of labels over frames ------------------------------------------------
    def reset(self) -> None:
        self.labels.clear()

    def update(self, session_ids: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, bool]:
        """Labels of the contacts now down, searched only when a new contact appeared.

        Args:
            session_ids: (n,) ids of the contacts in contact; positions: (n, 2) [m].

        Returns:
            (labels (n,), searched): finger of each contact, and whether a search ran.

        Raises:
            InputError: see :meth:`search`; the kept labels are left unchanged then.
        """
        ids = [int(i) for i in np.asarray(session_ids).reshape(-1)]
        p = _check_contacts(positions)
        if len(ids) != len(p):
            raise InputError(f"{len(ids)} session ids for {len(p)} positions")
        self.labels = {i: f for i, f in self.labels.items() if i in ids}
        if all(i in self.labels for i in ids):
            return np.array([self.labels[i] for i in ids], np.intp), False
        fixed = None
        if self.config.relabel == "new":
            fixed = {k: self.labels[i] for k, i in enumerate(ids) if i in self.labels}
        res = self.search(p, fixed)
        self.labels = {i: int(f) for i, f in zip(ids, res.labels, strict=True)}
        return res.labels, True


def _check_contacts(positions: np.ndarray) -> np.ndarray:
    p = np.asarray(positions, np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise InputError(f"contact positions must be (n, 2), got {p.shape}")
    if not 1 <= len(p) <= N_FINGERS:
        raise InputError(f"{len(p)} contacts: a hand makes 1 to {N_FINGERS}")
    if not np.isfinite(p).all():
        raise InputError("non-finite contact position")
    return p


class BoundedIndex:
    """Exact nearest-neighbour search for the one member of a batch nearest the reference.

    The labelling needs only the candidate whose nearest reference neighbour is closest, not
    every candidate's distance, and a k-d tree prunes badly in 27-D. The reference is split
    into k-means cells with centre c and radius r (farthest member); by the triangle
    inequality no reference point is nearer to x than ``min_k (|x - c_k| - r_k)``. Candidates
    are searched in order of that bound, ``chunk`` at a time (one matrix product against every
    reference point), until the bound of every candidate left is >= the best distance found:
    those cannot be nearer. The result is the exhaustive argmin.

    Squared distances are expanded, ``|x|^2 + |y|^2 - 2 x.y``. The search runs in float32
    with a bound on its error (:data:`_F32_REL`); every candidate that could be the best
    within that bound is settled in float64 from the differences to its nearest few points,
    so the chosen candidate and its distance are exact.
    """

    def __init__(self, points: np.ndarray, clusters: int = 48, iterations: int = 12,
                 seed: int = 0) -> None:
        pts = np.ascontiguousarray(points, np.float64)
        if pts.ndim != 2 or len(pts) == 0 or not np.isfinite(pts).all():
            raise InputError(f"reference points must be finite (M, dim), got {pts.shape}")
        self.points = pts
        self.sq = np.einsum("ij,ij->i", pts, pts)
        # |x - y|^2 - |x|^2 = (x, 1) . (-2 y, |y|^2): one matrix product, no further passes
        self._aug = np.ascontiguousarray(np.vstack([-2.0 * pts.T, self.sq]))
        self._aug32 = self._aug.astype(np.float32)
        centres, member = _kmeans(pts, min(clusters, len(pts)), iterations, seed)
        self.radii = np.zeros(len(centres))
        np.maximum.at(self.radii, member, np.linalg.norm(pts - centres[member], axis=1))
        self.centres = centres
        centre_sq = np.einsum("ij,ij->i", centres, centres)
        self._centres_aug = np.ascontiguousarray(np.vstack([-2.0 * centres.T, centre_sq]))
        #: largest |y|^2 of a reference point or centre: scales the rounding bounds
        self._ref_scale = float(max(self.sq.max(), centre_sq.max()))

    def distances(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest distances (n,) and reference indices (n,) of every row of ``x`` (n, dim)
        (float64; the distance is recomputed from the difference)."""
        x = np.atleast_2d(np.asarray(x, np.float64))
        j = np.argmin(_augment(x) @ self._aug, axis=1)
        return np.linalg.norm(x - self.points[j], axis=1), j

    def lower_bounds(self, x: np.ndarray, x_sq: np.ndarray) -> np.ndarray:
        """(n,) lower bounds of the nearest distance of each row of ``x`` (n, dim);
        ``x_sq`` (n,) its squared norms."""
        d2 = _augment(x) @ self._centres_aug
        d2 += x_sq[:, None]
        np.maximum(d2, 0.0, out=d2)
        bound = np.sqrt(d2, out=d2)
        bound -= self.radii
        lb = bound.min(axis=1)
        # float64 rounding e of d2 (< 1e-14 (|x|^2 + |c|^2)) moves sqrt(d2) by <= sqrt(e)
        lb -= np.sqrt(1e-13 * (x_sq + self._ref_scale)) + 1e-12
        return lb

    def best(self, x: np.ndarray, chunk: int = 8) -> tuple[int, float]:
        """Row of ``x`` (n, dim) with the nearest reference neighbour, and that distance.

        Raises:
            InputError: ``x`` is empty or not finite.
        """
        x = np.asarray(x, np.float64)
        if len(x) == 0 or not np.isfinite(x).all():
            raise InputError("nearest-neighbour search of an empty or non-finite batch")
        x_sq = np.einsum("ij,ij->i", x, x)
        tol = _F32_REL * (x_sq + self._ref_scale)  # bound of the float32 error of each d^2
        if len(x) <= chunk:
            order, lb = np.arange(len(x)), np.full(len(x), -np.inf)
        else:
            lb = self.lower_bounds(x, x_sq)
            order = np.argsort(lb)
        x32 = _augment(x, np.float32)
        upper = np.inf  # an upper bound of the best squared distance; bound = its root
        bound = np.inf
        searched: list[tuple[np.ndarray, np.ndarray]] = []
        start = 0
        while start < len(order) and lb[order[start]] < bound:
            rows = order[start:start + chunk]
            rows = rows[lb[rows] < bound]
            d2 = x32[rows] @ self._aug32  # squared distances less |x|^2
            searched.append((rows, d2))
            upper = min(upper, float((d2.min(axis=1) + x_sq[rows] + tol[rows]).min()))
            bound = np.sqrt(max(upper, 0.0))
            start += chunk
        best, best_d = -1, np.inf
        for rows, d2 in searched:
            m = d2.min(axis=1).astype(np.float64)
            for k in np.flatnonzero(m + x_sq[rows] - tol[rows] <= upper):  # could be the best
                near = np.flatnonzero(d2[k] <= m[k] + 2.0 * tol[rows[k]])
                d = float(np.sqrt(((self.points[near] - x[rows[k]]) ** 2).sum(axis=1).min()))
                if d < best_d or (d == best_d and rows[k] < best):  # ties: first row
                    best, best_d = int(rows[k]), d
        return best, best_d


#: Bound of the float32 error of ``(x, 1) . (-2 y, |y|^2)`` against the exact
#: ``|x - y|^2 - |x|^2``, relative to ``|x|^2 + |y|^2``: rounding x, y and |y|^2 to float32
#: (<= 5u) and a 28-term dot product whose terms sum to <= 2 (|x|^2 + |y|^2) in magnitude
#: (<= 56u); u = 2^-24, about 3.6e-6 in all, here x 5.5.
_F32_REL = 2e-5


def _augment(x: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """(n, dim) -> (n, dim + 1): the rows of ``x`` with a 1 appended."""
    out = np.empty((len(x), x.shape[1] + 1), dtype)
    out[:, :-1] = x
    out[:, -1] = 1.0
    return out


def _kmeans(points: np.ndarray, k: int, iterations: int, seed: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means with k-means++ seeding (deterministic for a seed).

    Returns:
        centres (k', dim) and the cell of every point (M,); empty cells are dropped (k' <= k).
    """
    rng = np.random.default_rng(seed)
    m, dim = points.shape
    idx = [int(rng.integers(m))]
    d2 = ((points - points[idx[0]]) ** 2).sum(axis=1)
    for _ in range(1, k):
        total = d2.sum()
        if total <= 0.0:  # fewer distinct points than cells
            break
        idx.append(int(rng.choice(m, p=d2 / total)))
        np.minimum(d2, ((points - points[idx[-1]]) ** 2).sum(axis=1), out=d2)
    centres = points[idx]

    def assign(c: np.ndarray) -> np.ndarray:
        return np.argmin(np.einsum("ij,ij->i", c, c) - 2.0 * points @ c.T, axis=1)

    for _ in range(iterations):
        member = assign(centres)
        counts = np.bincount(member, minlength=len(centres))
        used = counts > 0
        sums = np.stack([np.bincount(member, points[:, j], len(centres)) for j in range(dim)],
                        axis=1)
        centres = sums[used] / counts[used, None]
    member = assign(centres)
    used = np.bincount(member, minlength=len(centres)) > 0
    return centres[used], np.cumsum(used)[member] - 1
