"""Hand / forearm separation learned per pixel (issue 13; an addition to ch. II.2).

The dissertation's segmentation assumes the hand alone in the depth band; every real hand has
a forearm, and the geometric cut (:func:`~hand_capture.tracking.preprocess.cut_forearm`) is
weakest exactly where it matters most: after a lost frame, with no tracked wrist to cut at.
:class:`ArmClassifier` labels every pixel of the segmented cloud hand or arm from the depth
image alone, with the pixel-pair depth features of Shotton et al. (body parts from single
depth images, the dissertation's pixel features of eq. II.15 without the shape index):

    f(x) = d(x + o_1 / d(x)) - d(x + o_2 / d(x))

(offsets ``o`` in metres, so a feature probes the same metric neighbourhood at any distance
and any focal length; ``o_2 = 0`` for half of them: the probe against the pixel itself).
Off the segment a probe reads the pixel's own depth plus ``BACKGROUND_REL_M`` (the
regressor's, :data:`~hand_capture.tracking.regressor.BACKGROUND_REL_M`), so no
feature depends on how far the hand is (format 1 read a constant 2 m there: ``2 - d(x)``
made the distance a cue, and a hand 0.2 m farther than the training renders was called arm
on 85 % of its pixels); off the image it reads the image border (an arm running out of the
image continues there). A random forest (the suite's
:class:`~hand_capture.tracking.forest.RegressionForest` regressing the 0/1 arm label)
gives the arm probability.

Run time: the features are evaluated on a grid of the segment's pixels (about
``arm_grid_mm`` apart on the hand), the probabilities smoothed over 3x3 grid cells
(normalised convolution) and read back at every pixel, so a 320x240 frame costs a few ms.

Training (:func:`train_arm_classifier`, a step of ``hand-suite train tracker``): the suite's
own generator only (:func:`~hand_capture.tracking.train.render_samples`: its hand mesh,
rasteriser and noise model, forearms of radius 24-40 mm bent +-0.4 rad, surfaces offset),
with the renderer's per-pixel labels (hand mesh / forearm mesh). The model is a small
``.npz`` of plain arrays (no pickles), checked when loaded.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.tracking.forest import RegressionForest
from hand_capture.tracking.regressor import BACKGROUND_REL_M

__all__ = ["ArmClassifier", "default_arm_path", "load_arm_classifier", "remove_arm",
           "train_arm_classifier"]

#: format version of the saved model (2: the background read relative to the pixel)
FORMAT = 2


def default_arm_path() -> Path:
    """``data/tracker/arm.npz`` in the source tree or the installed share folder."""
    from hand_capture.paths import data_dir

    return data_dir() / "tracker" / "arm.npz"


def _padded(depth: np.ndarray) -> np.ndarray:
    """The segment's depth with the background marked (-1 off the segment: read as the
    probed pixel's depth + ``BACKGROUND_REL_M`` by :func:`_probe_difference`)."""
    return np.where(depth > 0, depth, np.float32(-1.0)).astype(np.float32)


def _probe_difference(flat: np.ndarray, H: int, W: int, u: np.ndarray, v: np.ndarray,
                      off: np.ndarray, su: np.ndarray, sv: np.ndarray, z: np.ndarray
                      ) -> np.ndarray:
    """``d(probe 1) - d(probe 2)`` of pixels (u, v) at depths ``z`` [m] for metric offsets
    ``off`` (..., 2, 2) [m] (probe, (du, dv)), scaled to pixels by ``su`` = fx / z and
    ``sv`` = fy / z; probes off the image read its border, off the segment (marked < 0,
    :func:`_padded`) ``z + BACKGROUND_REL_M``. Shapes broadcast: u, v, su, sv, z (n, 1)
    against ``off``'s leading dimensions."""
    back = z + np.float32(BACKGROUND_REL_M)
    vals = []
    for k in range(2):
        uu = np.clip(np.rint(u + off[..., k, 0] * su).astype(np.intp), 0, W - 1)
        vv = np.clip(np.rint(v + off[..., k, 1] * sv).astype(np.intp), 0, H - 1)
        d = flat[vv * W + uu]
        vals.append(np.where(d < 0, back, d))
    return vals[0] - vals[1]


def pixel_features(img: np.ndarray, v: np.ndarray, u: np.ndarray, z: np.ndarray,
                   offsets: np.ndarray, fx: float, fy: float) -> np.ndarray:
    """Depth-difference features of pixels (Shotton et al.; see the module docstring).

    Args:
        img: (H, W) float32 segment depth [m], background marked (:func:`_padded`).
        v, u: (N,) pixel rows and columns; z: (N,) their depths [m].
        offsets: (F, 2, 2) metric offsets [m] (feature, probe, (du, dv)).
        fx, fy: focal lengths [px].

    Returns:
        (N, F) float32 ``d(probe 1) - d(probe 2)`` [m].
    """
    H, W = img.shape
    zc = np.asarray(z, np.float32)[:, None]
    inv = (1.0 / np.maximum(zc, 1e-3)).astype(np.float32)
    return _probe_difference(img.reshape(-1), H, W, u[:, None], v[:, None], offsets[None],
                             fx * inv, fy * inv, zc)


@dataclass
class ArmClassifier:
    """Per-pixel arm probability from depth features (module docstring).

    Attributes:
        offsets: (F, 2, 2) float32 metric probe offsets [m] of the features the forest uses.
        forest: regression forest over those F features, one output (arm probability).
        info: training metadata (seed, sample counts, accuracy), strings.
    """

    offsets: np.ndarray
    forest: RegressionForest
    info: dict[str, str]

    def __post_init__(self) -> None:
        off = np.asarray(self.offsets)
        if off.ndim != 3 or off.shape[1:] != (2, 2) or len(off) == 0:
            raise InputError(f"arm classifier offsets must be (F, 2, 2), got {off.shape}")
        if not np.all(np.isfinite(off)) or np.abs(off).max() > 1.0:
            raise InputError("arm classifier offsets must be finite and within 1 m")
        try:
            self.forest.check(n_features=len(off), n_outputs=1)
        except InputError as e:
            raise InputError(f"arm classifier: {e}") from e
        self.offsets = off.astype(np.float32)

    # ------------------------------------------------------------------------- predict
    def probability(self, img: np.ndarray, v: np.ndarray, u: np.ndarray, z: np.ndarray,
                    intr: Intrinsics) -> np.ndarray:
        """(N,) arm probability of pixels (v, u) at depths z [m] in the filled segment
        depth ``img`` (:func:`_padded`)."""
        # the forest walked with each node's feature computed for the pixels that reach it
        # only (depth x trees probes per pixel instead of every feature)
        f, t, left = self.forest._walk_tables()
        H, W = img.shape
        flat = img.reshape(-1)
        n, T = len(v), self.forest.n_trees
        node = np.broadcast_to(self.forest.roots.astype(np.intp)[None, :], (n, T)).copy()
        zc = np.asarray(z, np.float32)[:, None]
        inv = (1.0 / np.maximum(zc, 1e-3)).astype(np.float32)
        su, sv = intr.fx * inv, intr.fy * inv
        vi, ui = v[:, None].astype(np.float32), u[:, None].astype(np.float32)
        for _ in range(self.forest.depth):
            diff = _probe_difference(flat, H, W, ui, vi, self.offsets[f[node]], su, sv, zc)
            node = left[node] + (diff >= t[node])                # offsets: (n, T, 2, 2)
        return self.forest.value[self.forest.leaf[node], 0].mean(axis=1)

    def segment_probability(self, depth: np.ndarray, mask: np.ndarray, box: tuple[int, ...],
                            v: np.ndarray, u: np.ndarray, intr: Intrinsics,
                            grid_mm: float) -> np.ndarray:
        """Arm probability (N,) of the segment's pixels (v, u), evaluated on a grid about
        ``grid_mm`` apart on the hand and smoothed over 3x3 grid cells.

        Args:
            depth: (H, W) float32 segment depth [m] (0 off the segment).
            mask: (H, W) bool segment.
            box: ``(row0, row1, col0, col1)`` bounding the segment.
            v, u: (N,) the segment's pixels.
            intr: the image's pinhole.
            grid_mm: grid spacing on the hand [mm] (1 px at least).
        """
        r0, r1, c0, c1 = box
        z_med = float(np.median(depth[v, u])) if len(v) else 0.5
        s = max(1, int(round(grid_mm * 1e-3 * intr.fx / max(z_med, 1e-3))))
        sub = mask[r0:r1:s, c0:c1:s]
        gv, gu = np.nonzero(sub)
        img = _padded(depth)
        p_grid = np.zeros(sub.shape, np.float32)
        if len(gv):
            vv, uu = gv * s + r0, gu * s + c0
            p_grid[gv, gu] = self.probability(img, vv, uu, depth[vv, uu], intr)
        w = sub.astype(np.float32)
        num = cv2.blur(p_grid * w, (3, 3), borderType=cv2.BORDER_CONSTANT)
        den = cv2.blur(w, (3, 3), borderType=cv2.BORDER_CONSTANT)
        smooth = np.where(den > 0, num / np.maximum(den, 1e-6), 0.0)
        iv = np.clip(np.rint((v - r0) / s).astype(np.int64), 0, sub.shape[0] - 1)
        iu = np.clip(np.rint((u - c0) / s).astype(np.int64), 0, sub.shape[1] - 1)
        return smooth[iv, iu]

    # ------------------------------------------------------------------------------- I/O
    def save(self, path: str | Path) -> None:
        arrays = {"format": np.array(FORMAT), "offsets": self.offsets,
                  "info_keys": np.array(list(self.info.keys()), dtype=str),
                  "info_values": np.array(list(self.info.values()), dtype=str),
                  **self.forest.to_arrays("f_")}
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(p, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> ArmClassifier:
        """Load and check a saved classifier.

        Raises:
            InputError: unreadable file, wrong format version, missing or malformed arrays.
        """
        p = Path(path)
        try:
            a = dict(np.load(p, allow_pickle=False))
        except (OSError, ValueError, EOFError) as e:
            raise InputError(f"cannot read arm classifier {p}: {e}") from e
        try:
            fmt = int(a["format"])
            if fmt != FORMAT:
                raise InputError(f"arm classifier {p} has format {fmt}, expected {FORMAT} "
                                 f"(retrain with `hand-suite train tracker --arm-only`)")
            forest = RegressionForest.from_arrays(a, "f_")
            info = dict(zip(a["info_keys"].tolist(), a["info_values"].tolist(), strict=True))
            return cls(a["offsets"], forest, info)
        except KeyError as e:
            raise InputError(f"arm classifier {p} lacks {e}") from e
        except (ValueError, TypeError, IndexError) as e:
            raise InputError(f"arm classifier {p} is malformed: {e}") from e


@lru_cache(maxsize=4)
def _load_cached(path: str, mtime: float) -> ArmClassifier:
    return ArmClassifier.load(path)


def load_arm_classifier(path: str | Path | None = None) -> ArmClassifier | None:
    """The classifier at ``path`` (default :func:`default_arm_path`), loaded once per file
    version; None when the default file is missing.

    Raises:
        InputError: a named file that is missing, or any file that is malformed.
    """
    p = Path(path).expanduser() if path else default_arm_path()
    if not p.exists():
        if path:
            raise InputError(f"arm classifier {p} does not exist")
        return None
    return _load_cached(str(p), p.stat().st_mtime)


def remove_arm(obs, clf: ArmClassifier, threshold: float = 0.5, grid_mm: float = 4.0,
               min_pixels: int = 60, keep_ratio: float = 0.2, margin_m: float = 0.0,
               reach_m: float = 0.0):
    """The segmented hand without the pixels ``clf`` calls arm.

    With ``reach_m`` > 0 the classifier is asked only where the segment shows a forearm
    (as :func:`~hand_capture.tracking.preprocess.cut_forearm`'s cloud test): it runs out of
    the image, or it is longer than ``reach_m`` along its principal axis (longer than a
    hand can be). A hand alone keeps every pixel whatever the classifier would say about
    a surface unlike its training renders.

    The pixels of arm probability above ``threshold`` are dropped; of the rest, the largest
    8-connected component is kept with every other holding at least ``keep_ratio`` of its
    pixels (a finger cut off the palm by noise stays, a stray blob on the arm goes); then
    the arm points within ``margin_m`` (3D) of the hand's pixels bordering the arm are kept
    again.

    Args:
        obs: :class:`~hand_capture.tracking.preprocess.HandObservation` (found).
        clf: the classifier.
        threshold: arm probability above which a pixel is dropped.
        grid_mm: evaluation grid spacing on the hand [mm].
        min_pixels: fewer pixels left than this: the input is returned unchanged.
        keep_ratio: smallest kept component, relative to the largest.
        margin_m: arm kept next to the hand [m].
        reach_m: the forearm evidence test's length [m]; 0 = always classify.

    Returns:
        ``(observation, prob, cut)``: the hand, the (N,) arm probability of the input's
        pixels (None when not classified), and whether pixels were dropped.
    """
    from hand_capture.tracking.preprocess import _keep, principal_extent, touches_border

    v, u, _ = obs.vuz
    if reach_m > 0 and not touches_border(obs):
        pts, _ = obs.subsample(400)
        _, _, lo, hi = principal_extent(pts)
        if hi - lo <= reach_m:   # no sign of a forearm: the classifier is not asked
            return obs, None, False
    prob = clf.segment_probability(obs.depth_m, obs.mask, obs.box, v, u, obs.intrinsics,
                                   grid_mm)
    keep = prob <= threshold
    if keep.all() or not keep.any():
        return obs, prob, False
    r0, r1, c0, c1 = obs.box
    sub = np.zeros((r1 - r0, c1 - c0), np.uint8)
    sub[v[keep] - r0, u[keep] - c0] = 1
    n, lab, stats, _ = cv2.connectedComponentsWithStats(sub, connectivity=8)
    if n > 2:
        area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)
        area[0] = 0.0
        good = area >= keep_ratio * area.max()
        good[0] = False
        keep &= good[lab[v - r0, u - c0]]
    if margin_m > 0 and keep.any() and not keep.all():
        # the arm next to the hand stays: the hand model's wrist reaches beyond the skin's
        # visible end into the arm's silhouette (as the tracked cut's forearm_margin_m):
        # arm points within margin_m (3D) of the hand pixels bordering the arm
        arm = np.zeros((r1 - r0, c1 - c0), np.uint8)
        arm[v[~keep] - r0, u[~keep] - c0] = 1
        near_arm = cv2.dilate(arm, np.ones((3, 3), np.uint8))
        edge = keep & (near_arm[v - r0, u - c0] > 0)
        if edge.any():
            # candidates: arm pixels whose image distance to the edge, at their depth, is
            # within the margin (with slack); their 3D distance decides
            not_edge = np.ones_like(arm)
            not_edge[v[edge] - r0, u[edge] - c0] = 0
            dt = cv2.distanceTransform(not_edge, cv2.DIST_L2, 3)
            z = obs.depth_m[v, u]
            cand = ~keep & (dt[v - r0, u - c0] * z / obs.intrinsics.fx <= 1.25 * margin_m)
            if cand.any():
                d, _ = cKDTree(obs.points_at(edge)).query(obs.points_at(cand),
                                                          distance_upper_bound=margin_m)
                keep[cand] = d <= margin_m
    out = _keep(obs, keep, min_pixels)
    return (obs, prob, False) if out is None else (out, prob, True)


# ------------------------------------------------------------------------------- training
def sample_offsets(n: int, radius_m: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 2, 2) metric probe offsets [m]: uniform in a disc of ``radius_m`` (denser near the
    centre: radius ~ U^1.5); the second probe is the pixel itself in half of them."""
    out = np.zeros((n, 2, 2), np.float32)
    for k in range(2):
        ang = rng.uniform(0, 2 * np.pi, n)
        r = radius_m * rng.random(n) ** 1.5
        out[:, k] = np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
    out[rng.random(n) < 0.5, 1] = 0.0
    return out


def labelled_pixels(samples: list, intr: Intrinsics, offsets: np.ndarray, per_frame: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Features (n, F) and arm labels (n,) of up to ``per_frame`` segment pixels per training
    sample (:class:`~hand_capture.tracking.train.TrainingSample` with labels), half hand and
    half arm where the frame has both; pixels the renderer did not label are left out."""
    from hand_capture.tracking.train import ARM_LABEL, HAND_LABEL

    Xs, ys = [], []
    for s in samples:
        h, w = s.crop.shape
        img = np.full((intr.height, intr.width), np.float32(-1.0), np.float32)
        img[s.v0:s.v0 + h, s.u0:s.u0 + w] = _padded(s.crop)
        picks = []
        for lab in (HAND_LABEL, ARM_LABEL):
            vv, uu = np.nonzero((s.crop > 0) & (s.label == lab))
            if len(vv):
                k = rng.choice(len(vv), min(len(vv), per_frame // 2), replace=False)
                picks.append((vv[k] + s.v0, uu[k] + s.u0, lab == ARM_LABEL))
        for vv, uu, arm in picks:
            Xs.append(pixel_features(img, vv, uu, img[vv, uu], offsets, intr.fx, intr.fy))
            ys.append(np.full(len(vv), float(arm)))
    return np.concatenate(Xs).astype(np.float32), np.concatenate(ys)


def _compact(offsets: np.ndarray, forest: RegressionForest
             ) -> tuple[np.ndarray, RegressionForest]:
    """Only the features the forest reads, its split columns renumbered."""
    used = forest.used_features
    remap = np.full(len(offsets), -1, np.int32)
    remap[used] = np.arange(len(used), dtype=np.int32)
    feat = np.where(forest.feature >= 0, remap[np.maximum(forest.feature, 0)], -1)
    f = RegressionForest(feat.astype(np.int32), forest.threshold, forest.left, forest.right,
                         forest.leaf, forest.roots, forest.depth, forest.value, forest.modes,
                         forest.mode_w)
    return offsets[used], f


def train_arm_classifier(out_path: str | Path | None, seed: int = 0, n_frames: int = 700, *,
                         n_shapes: int = 20, per_frame: int = 160, n_features: int = 240,
                         radius_m: float = 0.16, n_trees: int = 4, max_depth: int = 14,
                         min_leaf: int = 20, forearm_prob: float = 0.8,
                         surface_mm: tuple[float, float] = (-1.0, 2.5),
                         intrinsics: Intrinsics | None = None,
                         log: Callable[[str], None] | None = None) -> ArmClassifier:
    """Train the per-pixel arm classifier on the suite's renders, reproducibly from ``seed``.

    Args:
        out_path: where to save it (``.npz``); None = do not save.
        seed: seeds shapes, poses, forearms, noise, pixel and feature sampling, the forest.
        n_frames: rendered frames (``forearm_prob`` of them with a forearm, kept uncut).
        n_shapes: random subject shapes (the first is the default).
        per_frame: labelled pixels per frame (half hand, half arm).
        n_features, radius_m: candidate features and their probe radius [m].
        n_trees, max_depth, min_leaf: forest size.
        forearm_prob, surface_mm: as :func:`~hand_capture.tracking.train.render_samples`.
        intrinsics: camera of the renders (default 320x240, 70 deg).
        log: progress callback.

    Returns:
        The trained :class:`ArmClassifier` (``info["train_acc"]``: pixel accuracy on a
        quarter of the frames held back from fitting).
    """
    from hand_capture.model import HandModel, default_shape, sample_shape
    from hand_capture.tracking.train import default_intrinsics, render_samples

    t0 = time.perf_counter()
    say = log or (lambda s: None)
    rng = np.random.default_rng([seed, 13])
    intr = intrinsics or default_intrinsics()
    base = HandModel(default_shape())
    models = [base] + [base.with_shape(sample_shape(rng, f"arm{k}"))
                       for k in range(1, n_shapes)]
    samples = render_samples(n_frames, rng, models, intr, forearm_prob=forearm_prob,
                             surface_mm=surface_mm, cut_arm=False)
    say(f"arm classifier: rendered {len(samples)} frames in {time.perf_counter() - t0:.0f} s")
    offsets = sample_offsets(n_features, radius_m, rng)
    n_fit = (3 * len(samples)) // 4
    X, y = labelled_pixels(samples[:n_fit], intr, offsets, per_frame, rng)
    Xv, yv = labelled_pixels(samples[n_fit:], intr, offsets, per_frame, rng)
    forest = RegressionForest.fit(X, y[:, None], n_trees=n_trees, max_depth=max_depth,
                                  min_leaf=min_leaf, n_try=60, n_thresholds=8, rng=rng)
    acc = float(np.mean((forest.predict(Xv)[:, 0] > 0.5) == (yv > 0.5)))
    offsets, forest = _compact(offsets, forest)
    clf = ArmClassifier(offsets, forest, {
        "seed": str(seed), "n_frames": str(len(samples)), "n_pixels": str(len(y)),
        "n_shapes": str(n_shapes), "forearm_prob": str(forearm_prob),
        "train_acc": f"{acc:.4f}", "train_s": f"{time.perf_counter() - t0:.0f}"})
    say(f"arm classifier: {len(y)} pixels, {len(offsets)} features used, "
        f"{forest.value.shape[0]} leaves, pixel accuracy on held-back frames {acc:.3f} "
        f"({time.perf_counter() - t0:.0f} s)")
    if out_path is not None:
        clf.save(out_path)
        say(f"saved {out_path}")
    return clf
