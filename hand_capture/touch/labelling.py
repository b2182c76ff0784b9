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

Departure from the paper (issue #13): with a :class:`LayoutPrior` the pose-mode search scores
each labelling by a geometric prior as well, the log-likelihood of the contact layout under a
Gaussian of the centred fingertip positions of that finger set in the training data (inter-
finger distances and their thumb-to-little ordering) plus the log-frequency of the finger set,
minus ``d^2 / (2 nn_scale^2)`` for the nearest-neighbour distance d of the paper's criterion.
On frames the generator did not make, the nearest-neighbour criterion alone labels two and
three contacts mostly wrong (the wrong finger set, rarely the wrong order).
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
    criterion: str = param(
        "layout", "'nearest': the paper's nearest training neighbour alone; 'layout': plus the "
        "layout prior of the model (when it has one)", choices=("nearest", "layout"))
    nn_scale: float = param(
        1.0, "layout criterion: nearest-neighbour distance d enters as -d^2 / (2 nn_scale^2) "
        "[rad] (1.0 chosen on unseen training-generator frames, seeds 52-54: "
        "scripts/touch_label_ceiling.py --validation)", lo=1e-3, hi=100.0)

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
        reference: (M, 27) training poses (mode "pose", in the encoder's frame: root
            relative to the leftmost contact, or in the contacts' frame when the encoder has
            one, which makes the nearest-neighbour distance blind to where the hand lies and
            how it is turned) or (M, 15) training inputs u (mode "input").
        config: see :class:`LabellerConfig`.
        mode: ``"pose"`` (the paper's labelling for encodings) or ``"input"`` (PCA-IK).
    """

    def __init__(self, encoder: PolynomialEncoder, reference: np.ndarray,
                 config: LabellerConfig | None = None, mode: str = "pose",
                 layout: LayoutPrior | None = None) -> None:
        if mode not in ("pose", "input"):
            raise InputError(f"mode must be 'pose' or 'input', got {mode!r}")
        self.encoder = encoder
        self.config = config or LabellerConfig()
        self.mode = mode
        #: the layout prior used by the search (None: the paper's criterion alone)
        self.layout = layout if (mode == "pose" and self.config.criterion == "layout") \
            else None
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
    def candidate_inputs(self, positions: np.ndarray, perms: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inputs u (P, 15) of every labelling in ``perms`` (P, n), the origins (P, 2) and
        angles (P,) of their frames (:meth:`PolynomialEncoder.encode`)."""
        enc = self.encoder
        p = np.asarray(positions, np.float64)
        if enc.frame is not None:
            full = np.zeros((len(perms), N_FINGERS, 2))
            contact = np.zeros((len(perms), N_FINGERS), bool)
            rows = np.arange(len(perms))[:, None]
            full[rows, perms] = p
            contact[rows, perms] = True
            return enc.encode(full, contact)
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
        return u, np.broadcast_to(origin, (n_cand, 2)), np.zeros(n_cand)

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
        u, origin, phi = self.candidate_inputs(p, perms)
        q = self.encoder.predict(u) if self.mode == "pose" else None
        if q is not None and self.layout is not None and len(p) >= 2:
            d = self.index.distances(q * self.weights)[0]
            score = self.layout.log_likelihood(p, perms) \
                - 0.5 * (d / self.config.nn_scale) ** 2
            best = int(np.argmax(score))
            dist = float(d[best])
            if not np.isfinite(score[best]):  # no finger set of these seen in training
                best, dist = self._nearest(q * self.weights)
        else:
            best, dist = self._nearest(q * self.weights if q is not None else u)
        pose = None if q is None else self.encoder.absolute(q[best], origin[best], phi[best])
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


class LayoutPrior:
    """Gaussian of the contact layout of each finger set (see the module docstring).

    For a finger set S (2-5 fingers) x is the (2 |S|,) vector of the contact positions in
    finger order, less their mean; its mean and covariance over the training frames with that
    set (plus ``floor``^2 on the diagonal) give log N(x), to which the log-frequency of S is
    added. Sets with fewer than ``min_frames`` training frames get -inf (not proposed).

    Arrays (K = 32 finger-set bit masks, D = 10): ``mean`` (K, D), ``basis`` (K, D, D) the
    covariance eigenvectors, ``inv_var`` (K, D) their inverse eigenvalues (0 for the two
    directions the centring removes and for unused rows), ``const`` (K,) the log-normaliser
    plus the log-frequency (-inf: set not seen).
    """

    def __init__(self, mean: np.ndarray, basis: np.ndarray, inv_var: np.ndarray,
                 const: np.ndarray) -> None:
        k, d = 1 << N_FINGERS, 2 * N_FINGERS
        arrays = (np.asarray(mean, np.float64), np.asarray(basis, np.float64),
                  np.asarray(inv_var, np.float64), np.asarray(const, np.float64))
        if [a.shape for a in arrays] != [(k, d), (k, d, d), (k, d), (k,)]:
            raise InputError(f"layout prior arrays have shapes {[a.shape for a in arrays]}")
        self.mean, self.basis, self.inv_var, self.const = arrays
        self._bits = 1 << np.arange(N_FINGERS)

    @staticmethod
    def fit(pads: np.ndarray, contact: np.ndarray, floor: float = 0.002,
            min_frames: int = 20) -> LayoutPrior:
        """From labelled frames: ``pads`` (N, 5, 2) [m], ``contact`` (N, 5)."""
        k, d = 1 << N_FINGERS, 2 * N_FINGERS
        mean, basis = np.zeros((k, d)), np.zeros((k, d, d))
        inv_var, const = np.zeros((k, d)), np.full(k, -np.inf)
        c = np.asarray(contact, bool)
        keys = c @ (1 << np.arange(N_FINGERS))
        for key in np.unique(keys):
            rows = keys == key
            fingers = np.nonzero(c[rows][0])[0]
            n = len(fingers)
            if n < 2 or rows.sum() < min_frames:
                continue
            x = pads[rows][:, fingers]
            x = (x - x.mean(axis=1, keepdims=True)).reshape(len(x), 2 * n)
            mu = x.mean(axis=0)
            w, v = np.linalg.eigh(np.cov(x.T) + floor ** 2 * np.eye(2 * n))
            keep = np.arange(2 * n) >= 2  # the centring removes 2 directions (w ~ floor^2)
            mean[key, :2 * n] = mu
            basis[key, :2 * n, :2 * n] = v
            inv_var[key, :2 * n] = np.where(keep, 1.0 / w, 0.0)
            const[key] = -0.5 * np.log(w[keep]).sum() - (n - 1) * np.log(2 * np.pi) \
                + np.log(rows.mean())
        return LayoutPrior(mean, basis, inv_var, const)

    def log_likelihood(self, positions: np.ndarray, perms: np.ndarray) -> np.ndarray:
        """(P,) log prior of labelling contacts ``positions`` (n, 2) [m] as ``perms`` (P, n)."""
        p = np.asarray(positions, np.float64)
        n = p.shape[0]
        order = np.argsort(perms, axis=1)  # contacts in finger order, per candidate
        x = p[order]                        # (P, n, 2)
        x = (x - x.mean(axis=1, keepdims=True)).reshape(len(perms), 2 * n)
        keys = (self._bits[perms]).sum(axis=1)
        x = x - self.mean[keys, :2 * n]
        z = np.einsum("pi,pij->pj", x, self.basis[keys, :2 * n, :2 * n])
        return -0.5 * (z * z * self.inv_var[keys, :2 * n]).sum(axis=1) + self.const[keys]

    def to_arrays(self, prefix: str = "layout_") -> dict[str, np.ndarray]:
        return {f"{prefix}mean": self.mean, f"{prefix}basis": self.basis,
                f"{prefix}inv_var": self.inv_var, f"{prefix}const": self.const}

    @staticmethod
    def from_arrays(data: dict, prefix: str = "layout_") -> LayoutPrior | None:
        """The prior stored under ``prefix``, or None when the file has none."""
        names = data.files if hasattr(data, "files") else data
        if f"{prefix}mean" not in names:
            return None
        return LayoutPrior(*(np.asarray(data[f"{prefix}{k}"]) for k in
                             ("mean", "basis", "inv_var", "const")))


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
