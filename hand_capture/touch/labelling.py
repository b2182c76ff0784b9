"""Finger labelling: which finger made which contact (Chung et al., sec. 2).

A multi-touch surface does not say which finger touches where. When contacts appear, every
labelling (injective assignment of the n contacts to the 5 fingers: 20, 60, 120, 120 candidates
for n = 2, 3, 4, 5) is reconstructed with the encoder in one batch, and the labelling whose
reconstructed pose has the nearest neighbour in the training set (a k-d tree) is kept. While
the same contacts stay down the labels are kept as they are; a contact that lifts frees its
finger.

For the PCA-IK baseline (sec. 3) the search compares the encoder inputs u themselves with the
training inputs instead of reconstructed poses (``mode="input"``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

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
        self.tree = cKDTree(ref * self.weights)
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

    def _nearest(self, points: np.ndarray, eps: float = 4.0, seeds: int = 2
                 ) -> tuple[int, float]:
        """Index of the point with the nearest reference neighbour, and that distance.

        Exact, but cheaper than querying every point: a (1 + eps)-approximate query ranks
        the points, the best ``seeds`` are queried exactly, and the rest only within that
        distance (the tree prunes almost everything beyond it).
        """
        if len(points) <= seeds:
            d, _ = self.tree.query(points)
            best = int(np.argmin(d))
            return best, float(d[best])
        approx, _ = self.tree.query(points, eps=eps)
        first = np.argsort(approx)[:seeds]
        d_first, _ = self.tree.query(points[first])
        bound = float(d_first.min())
        d, _ = self.tree.query(points, distance_upper_bound=bound * (1 + 1e-9) + 1e-12)
        d[first] = d_first
        best = int(np.argmin(d))
        return best, float(d[best])

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
