"""A random regression forest in numpy (dissertation ch. II.4: one forest per cascade stage).

Each tree splits on one feature column against a threshold (``x[f] < t`` goes left), chosen
among ``n_try`` random columns and ``n_thresholds`` random thresholds per column by the
largest reduction of the squared error of the (multi-output) targets. A leaf stores the mean
target and, when ``leaf_modes > 1``, the centres and weights of a k-means clustering of its
training targets, so that prediction can keep several modes (II.4.3) instead of one mean.

All trees of a forest live in flat arrays (feature, threshold, left, right, leaf), so a forest
saves to and loads from plain ``.npz`` arrays and predicts a sample with a few vectorised
steps per tree level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError

__all__ = ["ForestGroup", "RegressionForest", "weighted_kmeans"]


def weighted_kmeans(x: np.ndarray, w: np.ndarray, k: int, iters: int = 8
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Centres (k', D) and weights (k',) of a weighted k-means (k' <= k, farthest-point init)."""
    n = len(x)
    if n == 0:
        return np.zeros((0, x.shape[1] if x.ndim == 2 else 0)), np.zeros(0)
    k = min(k, n)
    centres = [x[int(np.argmax(w))]]
    for _ in range(1, k):
        d = np.min(np.stack([np.sum((x - c) ** 2, axis=1) for c in centres]), axis=0)
        if d.max() <= 1e-18:
            break
        centres.append(x[int(np.argmax(d * w))])
    c = np.array(centres)
    ww = w + 1e-12
    prev = None
    for _ in range(iters + 1):
        d = np.sum((x[:, None, :] - c[None]) ** 2, axis=2)
        a = np.argmin(d, axis=1)
        if prev is not None and np.array_equal(a, prev):
            break  # same assignment: the centres are a fixed point
        if _ == iters:
            break
        prev = a
        # weighted mean of each cluster (one product for all clusters)
        onehot = (a[:, None] == np.arange(len(c))[None, :]) * ww[:, None]   # (n, k)
        tot = onehot.sum(axis=0)
        used = np.bincount(a, minlength=len(c)) > 0
        c[used] = (onehot.T @ x)[used] / tot[used, None]
    weights = np.bincount(a, weights=w, minlength=len(c))
    keep = weights > 0
    return c[keep], weights[keep]


@dataclass
class RegressionForest:
    """Flat arrays of all trees (see the module docstring)."""

    feature: np.ndarray    # (nodes,) int32 column, -1 for a leaf
    threshold: np.ndarray  # (nodes,) float32
    left: np.ndarray       # (nodes,) int32 child index (absolute)
    right: np.ndarray      # (nodes,) int32
    leaf: np.ndarray       # (nodes,) int32 leaf index, -1 for a split
    roots: np.ndarray      # (T,) int32 root node of each tree
    depth: int             # deepest level (for the traversal loop)
    value: np.ndarray      # (L, D) float32 mean target per leaf
    modes: np.ndarray      # (L, M, D) float32 mode centres per leaf
    mode_w: np.ndarray     # (L, M) float32 mode weights (0 = unused)

    # ------------------------------------------------------------------------------ train
    @classmethod
    def fit(cls, X: np.ndarray, Y: np.ndarray, *, n_trees: int = 5, max_depth: int = 12,
            min_leaf: int = 6, n_try: int = 40, n_thresholds: int = 6, leaf_modes: int = 1,
            bootstrap: float = 0.8, rng: np.random.Generator | int | None = 0
            ) -> RegressionForest:
        """Grow ``n_trees`` trees on features ``X`` (n, F) and targets ``Y`` (n, D)."""
        rng = np.random.default_rng(rng)
        X = np.asarray(X, np.float32)
        Y = np.asarray(Y, np.float64)
        n, F = X.shape
        feat: list[int] = []
        thr: list[float] = []
        left: list[int] = []
        right: list[int] = []
        leaf: list[int] = []
        values: list[np.ndarray] = []
        modes: list[np.ndarray] = []
        mode_w: list[np.ndarray] = []
        roots = []
        deepest = 0
        M = max(1, leaf_modes)

        def new_node() -> int:
            feat.append(-1)
            thr.append(0.0)
            left.append(-1)
            right.append(-1)
            leaf.append(-1)
            return len(feat) - 1

        def make_leaf(node: int, idx: np.ndarray) -> None:
            y = Y[idx]
            leaf[node] = len(values)
            values.append(y.mean(axis=0))
            cm = np.zeros((M, Y.shape[1]))
            cw = np.zeros(M)
            if M > 1 and len(idx) > 1:
                c, w = weighted_kmeans(y, np.ones(len(y)), M, iters=5)
                cm[:len(c)] = c
                cw[:len(c)] = w / w.sum()
            else:
                cm[0] = y.mean(axis=0)
                cw[0] = 1.0
            modes.append(cm)
            mode_w.append(cw)

        for _ in range(n_trees):
            m = max(2 * min_leaf, int(round(bootstrap * n)))
            sample = rng.choice(n, size=min(m, n), replace=False) if bootstrap < 1 else \
                np.arange(n)
            root = new_node()
            roots.append(root)
            stack = [(root, sample, 0)]
            while stack:
                node, idx, d = stack.pop()
                deepest = max(deepest, d)
                if d >= max_depth or len(idx) < 2 * min_leaf:
                    make_leaf(node, idx)
                    continue
                split = _best_split(X, Y, idx, n_try, n_thresholds, min_leaf, rng)
                if split is None:
                    make_leaf(node, idx)
                    continue
                f, t = split
                go_left = X[idx, f] < t
                lnode, rnode = new_node(), new_node()
                feat[node], thr[node] = f, t
                left[node], right[node] = lnode, rnode
                stack.append((rnode, idx[~go_left], d + 1))
                stack.append((lnode, idx[go_left], d + 1))
        return cls(np.array(feat, np.int32), np.array(thr, np.float32),
                   np.array(left, np.int32), np.array(right, np.int32),
                   np.array(leaf, np.int32), np.array(roots, np.int32), int(deepest),
                   np.array(values, np.float32), np.array(modes, np.float32),
                   np.array(mode_w, np.float32))

    # ---------------------------------------------------------------------------- predict
    @property
    def n_trees(self) -> int:
        return len(self.roots)

    @property
    def used_features(self) -> np.ndarray:
        return np.unique(self.feature[self.feature >= 0])

    def _walk_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(feature, threshold, left) with leaves turned into self-loops (threshold +inf,
        left = itself), so traversal needs no branch: ``node = left + (x >= threshold)``
        (a split's right child is always ``left + 1``)."""
        tab = getattr(self, "_tables", None)
        if tab is None:
            leaf = self.feature < 0
            f = np.where(leaf, 0, self.feature).astype(np.intp)
            t = np.where(leaf, np.float32(np.inf), self.threshold).astype(np.float32)
            left = np.where(leaf, np.arange(len(leaf)), self.left).astype(np.intp)
            tab = (f, t, left)
            self._tables = tab
        return tab

    def apply(self, X: np.ndarray) -> np.ndarray:
        """Leaf index of every sample in every tree: (n, T)."""
        X = np.atleast_2d(np.asarray(X, np.float32))
        n = len(X)
        f, t, left = self._walk_tables()
        node = np.broadcast_to(self.roots.astype(np.intp)[None, :], (n, self.n_trees)).copy()
        rows = np.arange(n)[:, None]
        for _ in range(self.depth):
            node = left[node] + (X[rows, f[node]] >= t[node])
        return self.leaf[node]

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Mean of the trees' leaf means: (n, D)."""
        return self.value[self.apply(X)].mean(axis=1)

    def predict_modes(self, x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to ``k`` modes (k', D) and their weights for one sample (II.4.3): the leaf
        modes of every tree clustered by weighted k-means."""
        leaves = self.apply(x[None])[0]
        pts = self.modes[leaves].reshape(-1, self.modes.shape[2]).astype(np.float64)
        w = self.mode_w[leaves].reshape(-1).astype(np.float64)
        keep = w > 0
        c, cw = weighted_kmeans(pts[keep], w[keep], k)
        order = np.argsort(-cw)
        return c[order], cw[order] / max(cw.sum(), 1e-12)

    # ------------------------------------------------------------------------------- I/O
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}feature": self.feature, f"{prefix}threshold": self.threshold,
                f"{prefix}left": self.left, f"{prefix}right": self.right,
                f"{prefix}leaf": self.leaf, f"{prefix}roots": self.roots,
                f"{prefix}depth": np.array(self.depth), f"{prefix}value": self.value,
                f"{prefix}modes": self.modes, f"{prefix}mode_w": self.mode_w}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> RegressionForest:
        """The forest saved by :meth:`to_arrays` under ``prefix``, structure checked
        (:meth:`check`).

        Raises:
            KeyError: an array is missing.
            InputError: the arrays do not form a forest.
        """
        g = lambda k: np.asarray(arrays[prefix + k])
        forest = cls(g("feature"), g("threshold"), g("left"), g("right"), g("leaf"),
                     g("roots"), int(g("depth")), g("value"), g("modes"), g("mode_w"))
        forest.check()
        return forest

    def check(self, n_features: int | None = None, n_outputs: int | None = None) -> None:
        """Check that the flat arrays form a forest the traversal can walk: equal node
        counts, split children and roots inside the node arrays, leaves inside the leaf
        arrays, and (when given) at most ``n_features`` feature columns read and
        ``n_outputs`` targets per leaf.

        Raises:
            InputError: naming the first problem found.
        """
        n = len(self.feature)
        for name in ("threshold", "left", "right", "leaf"):
            if len(getattr(self, name)) != n:
                raise InputError(f"forest array {name} has {len(getattr(self, name))} "
                                 f"nodes, feature has {n}")
        if self.value.ndim != 2:
            raise InputError(f"forest leaf values must be (L, D), got {self.value.shape}")
        if n_outputs is not None and self.value.shape[1] != n_outputs:
            raise InputError(f"forest must have {n_outputs} output(s), got "
                             f"{self.value.shape[1]}")
        if n_features is not None and n and int(self.feature.max()) >= n_features:
            raise InputError(f"forest reads feature {int(self.feature.max())} of "
                             f"{n_features}")
        split = self.feature >= 0
        for name in ("left", "right"):
            a = getattr(self, name)[split]
            if np.any((a < 0) | (a >= n)):
                raise InputError(f"forest has {name} children outside its {n} nodes")
        leaves = self.leaf[~split]
        if np.any((leaves < 0) | (leaves >= len(self.value))):
            raise InputError(f"forest has leaves outside its {len(self.value)} leaf values")
        if len(self.roots) == 0 or np.any((self.roots < 0) | (self.roots >= n)):
            raise InputError("forest has no trees or roots outside its nodes")


def _best_split(X: np.ndarray, Y: np.ndarray, idx: np.ndarray, n_try: int, n_thr: int,
                min_leaf: int, rng: np.random.Generator) -> tuple[int, float] | None:
    """The (feature, threshold) with the largest squared-error reduction, or None."""
    F = X.shape[1]
    feats = rng.choice(F, size=min(n_try, F), replace=False)
    x = X[np.ix_(idx, feats)]                                     # (m, K)
    m = len(idx)
    # thresholds: values of random samples (midpoints would need sorting)
    pick = rng.integers(0, m, size=(n_thr, len(feats)))
    t = x[pick, np.arange(len(feats))[None, :]]                    # (n_thr, K)
    mask = (x[:, None, :] < t[None, :, :]).reshape(m, -1)          # (m, n_thr*K)
    y = Y[idx]
    maskf = mask.astype(np.float64)
    n_l = maskf.sum(axis=0)
    n_r = m - n_l
    s_l = maskf.T @ y                                               # (n_thr*K, D)
    s_r = y.sum(axis=0)[None, :] - s_l
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = (s_l ** 2).sum(1) / n_l + (s_r ** 2).sum(1) / n_r
    ok = (n_l >= min_leaf) & (n_r >= min_leaf)
    if not ok.any():
        return None
    gain = np.where(ok, gain, -np.inf)
    best = int(np.argmax(gain))
    base = (y.sum(axis=0) ** 2).sum() / m
    if not gain[best] > base + 1e-12:
        return None
    ti, fi = divmod(best, len(feats))
    return int(feats[fi]), float(t[ti, fi])


class ForestGroup:
    """Several forests evaluated together (the five finger forests of a cascade stage): one
    traversal of all their trees at once, each forest reading its own block of columns.

    ``predict(X)`` with X (n, G, F) (forest g reads ``X[:, g]``) gives (n, G, D), the same
    as ``forests[g].predict(X[:, g])`` for every g (forests of equal tree count and output
    size)."""

    def __init__(self, forests: list[RegressionForest]) -> None:
        if len({f.n_trees for f in forests}) != 1 or len({f.value.shape[1] for f in forests}) != 1:
            raise ValueError("ForestGroup needs forests of equal tree count and output size")
        self.n_forests = len(forests)
        self.n_trees = forests[0].n_trees
        fs, ts, ls, leaves, roots, values = [], [], [], [], [], []
        node_off = leaf_off = 0
        self._col_off = []
        for f in forests:
            ff, tt, ll = f._walk_tables()
            fs.append(ff)
            ts.append(tt)
            ls.append(ll + node_off)
            leaves.append(np.where(f.leaf >= 0, f.leaf + leaf_off, -1))
            roots.append(f.roots.astype(np.intp) + node_off)
            values.append(f.value)
            node_off += len(ff)
            leaf_off += len(f.value)
        self._f = np.concatenate(fs)
        self._feat_forest = np.concatenate([np.full(len(x), g, np.intp)
                                            for g, x in enumerate(fs)])
        self._t = np.concatenate(ts)
        self._left = np.concatenate(ls)
        self._leaf = np.concatenate(leaves)
        self._roots = np.concatenate(roots)
        self._value = np.concatenate(values)
        self.depth = max(f.depth for f in forests)

    def predict(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, np.float32)
        n, G, F = X.shape
        flat = X.reshape(n, G * F)
        col = self._f + self._feat_forest * F       # column of every node in ``flat``
        node = np.broadcast_to(self._roots[None, :], (n, len(self._roots))).copy()
        rows = np.arange(n)[:, None]
        t, left = self._t, self._left
        for _ in range(self.depth):
            node = left[node] + (flat[rows, col[node]] >= t[node])
        vals = self._value[self._leaf[node]]         # (n, G * T, D)
        return vals.reshape(n, G, self.n_trees, -1).mean(axis=2)
