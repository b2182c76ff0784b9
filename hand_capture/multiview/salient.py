"""Learned fingertip (salient point) detector for the multi-view tracker (seed 002 sec. 4.1).

Seed 002 detects finger nails with a Hough forest trained on labelled images and matches the
detections to salient mesh vertices (eq. 3). In the studio the nails are skin-coloured, so the
salient points here are the fingertips (``HandModel.fingertips(pose, 'tip')``), which the
detector learns discriminatively from studio renders of the suite's own MJCF hand (random
poses, objects and a second hand in view, colour noise). It is a
small Hough forest (after Gall et al., seed 002's ref. [30]) in numpy, in two stages:

1. a colour lookup table ``P(hand | colour)`` (16 levels per channel, learned from the
   training labels) picks candidate pixels (every second pixel in each direction);
2. at every candidate, pixel-pair features (values and differences of the hand probability,
   grey level and chromaticity at fixed random offsets around the pixel) go through a
   classification forest (is a fingertip within ``pos_radius`` px?) and an offset forest
   (where is it?); each candidate votes at its predicted fingertip with its probability, the
   vote map is smoothed and its local maxima above ``min_score`` are the detections
   (``min_score`` chosen for the best F1 score on own-hand validation renders).

Both forests are :class:`hand_capture.tracking.forest.RegressionForest` (flat arrays, saved in
``data/salient/salient.npz``, about 1 MB). ``hand-suite train salient [--quick]`` renders the
training set and writes the file (seeded: same inputs, same file); evaluation uses the held-out
surface family of :mod:`hand_capture.evaldata.surface` (other finger and palm shapes, nails,
forearm, sleeve), never seen in training (:func:`evaluate`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, InputError
from hand_capture.paths import data_dir
from hand_capture.tracking.forest import RegressionForest

__all__ = ["DetectorConfig", "LabelledView", "SalientDetector", "choose_min_score",
           "default_detector_path", "evaluate", "load_salient_detector", "main",
           "match_detections", "random_hand_pose", "render_views", "tip_vertices",
           "train_detector"]

_LUT_LEVELS = 16
_N_CHANNELS = 4  # hand probability, grey, chroma r, chroma g


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of the detector (image lengths in full-resolution pixels)."""

    downsample: int = param(1, "image reduction before feature extraction", lo=1, hi=4)
    stride: int = param(2, "candidate pixel stride (reduced image)", lo=1, hi=4)
    candidate_prob: float = param(0.3, "P(hand | colour) a candidate pixel needs", lo=0.0,
                                  hi=1.0)
    patch_radius_px: float = param(20.0, "radius of the feature offsets [px]", lo=4.0, hi=80.0)
    n_offsets: int = param(96, "random offsets per feature kind", lo=8, hi=512)
    pos_radius_px: float = param(4.0, "a training pixel within this of a fingertip is "
                                 "positive [px]", lo=2.0, hi=40.0)
    vote_sigma_px: float = param(1.5, "smoothing of the vote map [px]", lo=0.5, hi=20.0)
    nms_radius_px: float = param(5.0, "non-maximum suppression radius [px]", lo=1.0, hi=50.0)
    min_score: float = param(8.0, "smallest vote mass of a detection", lo=0.0, hi=1e6)
    max_detections: int = param(20, "most detections per image", lo=1, hi=500)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class SalientDetector:
    """A trained fingertip detector; see the module docstring.

    Attributes:
        config: the settings it was trained with (``min_score`` may be changed after).
        lut: (16, 16, 16) float32 P(hand | colour) by quantised R, G, B.
        offsets: (n_offsets, 4) int32 pixel offsets (dy1, dx1, dy2, dx2) at reduced scale.
        channels: (n_offsets, 2) int32 channel of the unary and of the pair feature.
        classifier: forest giving P(fingertip within ``pos_radius_px``) per candidate.
        regressor: forest giving the (dx, dy) offset to the fingertip [reduced px].
        meta: free-form training facts (strings).
    """

    config: DetectorConfig
    lut: np.ndarray
    offsets: np.ndarray
    channels: np.ndarray
    classifier: RegressionForest
    regressor: RegressionForest
    meta: dict[str, str] = field(default_factory=dict)

    # ------------------------------------------------------------------------ features
    @property
    def _pad(self) -> int:
        return int(np.abs(self.offsets).max()) + 1

    def _channel_maps(self, rgb: np.ndarray) -> np.ndarray:
        """(4, h + 2 pad, w + 2 pad) float32 maps at reduced scale, zero-padded."""
        import cv2

        img = _check_rgb(rgb)
        s = self.config.downsample
        if s > 1:
            img = cv2.resize(img, (img.shape[1] // s, img.shape[0] // s),
                             interpolation=cv2.INTER_AREA)
        q = (img >> 4).astype(np.intp)  # 16 levels per channel
        f = cv2.GaussianBlur(img.astype(np.float32), (5, 5), 1.0)  # sensor noise
        tot = f.sum(axis=2) + 1.0
        hand = cv2.GaussianBlur(self.lut[q[..., 0], q[..., 1], q[..., 2]], (5, 5), 1.0)
        maps = np.stack([hand, tot / 765.0,
                         f[..., 0] / tot, f[..., 1] / tot]).astype(np.float32)
        p = self._pad
        return np.pad(maps, ((0, 0), (p, p), (p, p)))

    def _features(self, maps: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """(n, 2 n_offsets) features of the candidates at reduced (ys, xs) (unpadded)."""
        p = self._pad
        y, x = ys[:, None] + p, xs[:, None] + p
        o, c = self.offsets, self.channels
        a = maps[c[None, :, 0], y + o[None, :, 0], x + o[None, :, 1]]
        b1 = maps[c[None, :, 1], y + o[None, :, 0], x + o[None, :, 1]]
        b2 = maps[c[None, :, 1], y + o[None, :, 2], x + o[None, :, 3]]
        return np.concatenate([a, b1 - b2], axis=1)

    def _candidates(self, maps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self._pad
        prob = maps[0, p:-p, p:-p]
        st = self.config.stride
        ys, xs = np.nonzero(prob[::st, ::st] >= self.config.candidate_prob)
        return ys.astype(np.intp) * st, xs.astype(np.intp) * st

    # ------------------------------------------------------------------------- detect
    def detect(self, rgb: np.ndarray, crop: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Fingertip detections in one colour image.

        Args:
            rgb: (H, W, 3) uint8 image.
            crop: work only in the box around the skin-coloured pixels (same detections,
                less work; False: the whole image).

        Returns:
            (points, scores): (k, 2) pixel positions (u, v) [px, full resolution] and (k,)
            vote masses, strongest first (k <= ``max_detections``; 0 when nothing is found).

        Raises:
            InputError: not an (H, W, 3) uint8 image.
        """
        import cv2

        cfg = self.config
        s = cfg.downsample
        img = _check_rgb(rgb)
        x0 = y0 = 0
        if crop and s == 1:  # the box around the skin-coloured pixels + the feature reach
            q = (img[::cfg.stride, ::cfg.stride] >> 4).astype(np.intp)
            sk = self.lut[q[..., 0], q[..., 1], q[..., 2]] >= cfg.candidate_prob
            if not sk.any():
                return np.zeros((0, 2)), np.zeros(0)
            r, c = np.nonzero(sk)
            m = self._pad + 4 + cfg.stride
            y0, x0 = max(0, r.min() * cfg.stride - m), max(0, c.min() * cfg.stride - m)
            y1 = min(img.shape[0], r.max() * cfg.stride + m + 1)
            x1 = min(img.shape[1], c.max() * cfg.stride + m + 1)
            y0 -= y0 % cfg.stride  # keep the candidate grid of the whole image
            x0 -= x0 % cfg.stride
            img = img[y0:y1, x0:x1]
        maps = self._channel_maps(img)
        ys, xs = self._candidates(maps)
        h, w = maps.shape[1] - 2 * self._pad, maps.shape[2] - 2 * self._pad
        if len(ys) == 0:
            return np.zeros((0, 2)), np.zeros(0)
        X = self._features(maps, ys, xs)
        prob = self.classifier.predict(X)[:, 0]
        keep = prob > 0.15
        if not keep.any():
            return np.zeros((0, 2)), np.zeros(0)
        off = self.regressor.predict(X[keep])
        # Hough voting: each candidate votes at its predicted fingertip with its probability
        vx = np.clip(np.round(xs[keep] + off[:, 0]).astype(np.intp), 0, w - 1)
        vy = np.clip(np.round(ys[keep] + off[:, 1]).astype(np.intp), 0, h - 1)
        votes = np.bincount(vy * w + vx, weights=prob[keep], minlength=h * w)
        votes *= self.config.stride ** 2  # a vote mass independent of the stride
        votes = votes.reshape(h, w).astype(np.float32)
        sig = cfg.vote_sigma_px / s
        k = int(2 * np.ceil(3 * sig) + 1)
        # a Gaussian of unit peak: a blob's score is about its vote mass / (2 pi sig^2) * ...
        sm = cv2.GaussianBlur(votes, (k, k), sig) * float(2 * np.pi * sig * sig)
        r = max(1, int(round(cfg.nms_radius_px / s)))
        mx = cv2.dilate(sm, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,
                                                                          2 * r + 1)))
        py, px = np.nonzero((sm >= mx) & (sm >= cfg.min_score) & (sm > 0))
        sc = sm[py, px]
        order = np.argsort(-sc, kind="stable")[: cfg.max_detections]
        pts = np.column_stack([px[order], py[order]]).astype(float) * s + (s - 1) / 2.0
        return pts + np.array([x0, y0], float), sc[order].astype(float)

    # ---------------------------------------------------------------------------- I/O
    def save(self, path: str | Path) -> Path:
        """Write the detector to ``path`` (.npz)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        cfg = {k: getattr(self.config, k) for k in DetectorConfig.__dataclass_fields__}
        np.savez_compressed(path, lut=self.lut, offsets=self.offsets, channels=self.channels,
                            config=json.dumps(cfg), meta=json.dumps(self.meta),
                            **self.classifier.to_arrays("cls_"),
                            **self.regressor.to_arrays("off_"))
        return path

    @classmethod
    def load(cls, path: str | Path) -> SalientDetector:
        """Read a detector written by :meth:`save`.

        Raises:
            InputError: a missing or malformed file.
        """
        path = Path(path)
        if not path.is_file():
            raise InputError(f"no salient detector at {path}; run `hand-suite train salient`")
        try:
            with np.load(path, allow_pickle=False) as z:
                a = {k: z[k] for k in z.files}
            cfg = DetectorConfig(**json.loads(str(a["config"])))
            return cls(cfg, a["lut"].astype(np.float32), a["offsets"].astype(np.intp),
                       a["channels"].astype(np.intp),
                       RegressionForest.from_arrays(a, "cls_"),
                       RegressionForest.from_arrays(a, "off_"),
                       json.loads(str(a["meta"])))
        except (KeyError, ValueError, ConfigError) as e:
            raise InputError(f"{path}: not a salient detector file ({e})") from e


def _check_rgb(rgb: np.ndarray) -> np.ndarray:
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8 or a.shape[0] < 8 or \
            a.shape[1] < 8:
        raise InputError(f"expected an (H, W, 3) uint8 image, got {a.shape} {a.dtype}")
    return a


def tip_vertices(hand: object) -> np.ndarray:
    """(5,) index of the mesh vertex nearest each fingertip keypoint (thumb .. little) of a
    :class:`~hand_capture.model.HandModel` in its rest pose: the salient vertices whose
    projections the detector's points are (its training targets are the tip keypoints)."""
    from hand_capture.model.joints import N_DOF
    from hand_capture.model.skeleton import FINGERTIP_KEYPOINTS, KEYPOINT_BONE

    fk = hand.forward(np.zeros(N_DOF))
    out = np.empty(5, dtype=np.int64)
    for f, k in enumerate(FINGERTIP_KEYPOINTS):
        cand = np.flatnonzero(hand.vertex_labels == KEYPOINT_BONE[k])
        out[f] = cand[np.argmin(np.linalg.norm(fk.vertices[cand] - fk.joint_positions[k],
                                               axis=1))]
    return out


def default_detector_path() -> Path:
    """``data/salient/salient.npz`` (source tree or installed share folder)."""
    return data_dir() / "salient" / "salient.npz"


def load_salient_detector(path: str | Path | None = None) -> SalientDetector:
    """The shipped detector (or the one at ``path``)."""
    return SalientDetector.load(default_detector_path() if path is None else path)


# ------------------------------------------------------------------------ training data
@dataclass(frozen=True)
class LabelledView:
    """One rendered camera image and the fingertips visible in it.

    Attributes:
        rgb: (H, W, 3) uint8 image (studio noise applied).
        hand_mask: (H, W) bool, pixels of either hand (labels of the render).
        tips: (k, 2) pixel positions (u, v) of the visible fingertips [px].
    """

    rgb: np.ndarray
    hand_mask: np.ndarray
    tips: np.ndarray


def random_hand_pose(rng: np.random.Generator, centre: Sequence[float] = (0.0, 0.0, 0.13)
                     ) -> np.ndarray:
    """A random 27-DoF world pose over the studio table: every joint uniform within its
    limits (abduction halved), the palm turned about z by up to 180 deg and tilted up to
    40 deg, the wrist within +-6 cm of ``centre`` [m] (+-3 cm in height)."""
    from hand_capture.model.joints import JOINT_LIMITS, JOINT_NAMES

    lo, hi = JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1]
    q = np.zeros(27)
    fingers = rng.uniform(lo, hi)
    abd = np.array(["abd" in n for n in JOINT_NAMES[6:]])
    fingers[abd] *= 0.5
    q[6:] = fingers
    q[:3] = np.asarray(centre) + rng.uniform(-1, 1, 3) * np.array([0.06, 0.06, 0.03])
    q[3:5] = rng.uniform(-0.7, 0.7, 2)
    q[5] = rng.uniform(-np.pi, np.pi)
    return q


def _visible_tips(view: object, cam: object, tips_w: np.ndarray, labels: Sequence[int]
                  ) -> np.ndarray:
    """Pixels of the fingertips that the render shows: in the image, the hand's label near
    the projection and the rendered surface within 2 cm of the tip's depth."""
    uv, front = cam.project(tips_w)
    z = cam.to_camera(tips_w)[:, 2]
    h, w = view.labels.shape
    out = []
    for (u, v), f, zz in zip(uv, front, z, strict=True):
        ui, vi = int(round(u)), int(round(v))
        if not f or ui < 3 or vi < 3 or ui >= w - 3 or vi >= h - 3:
            continue
        lab = view.labels[vi - 2: vi + 3, ui - 2: ui + 3]
        dep = view.depth_m[vi - 2: vi + 3, ui - 2: ui + 3]
        hit = np.isin(lab, labels) & (dep > 0)
        if hit.any() and np.min(np.abs(dep[hit] - zz)) < 0.02:
            out.append((u, v))
    return np.array(out, dtype=float).reshape(-1, 2)


def render_views(n_scenes: int, seed: int, *, heldout: bool = False, rig: str = "studio6",
                 cameras: int | None = None) -> Iterator[LabelledView]:
    """Studio renders with visible-fingertip labels, ``n_scenes`` random scenes x every rig
    camera (or the first ``cameras``).

    ``heldout=False`` (training): the suite's own MJCF hand (the template), one hand and two
    hands in alternate scenes. ``heldout=True`` (evaluation): the
    right hand drawn as a subject of the held-out surface family (with a forearm), the left
    MJCF hand beside it in every other scene. Poses: :func:`random_hand_pose`; objects on the
    table; studio colour noise with a per-scene seed.
    """
    from hand_capture.evaldata.scene import sample_subject
    from hand_capture.evaldata.surface import sample_surface
    from hand_capture.model import HandModel
    from hand_capture.multiview.rig import load_rig
    from hand_capture.multiview.studio import Studio, StudioNoise, studio_scene

    rng = np.random.default_rng(seed)
    the_rig = load_rig(rig)
    if cameras is not None:
        from hand_capture.multiview.rig import Rig

        the_rig = Rig(the_rig.name, the_rig.cameras[:cameras], the_rig.world_frame)
    for i in range(n_scenes):
        two = i % 2 == 1
        noise = StudioNoise(seed=int(rng.integers(0, 2**31)),
                            exposure_sigma=float(rng.uniform(0.0, 0.12)),
                            sensor_sigma=float(rng.uniform(0.5, 4.0)))
        objects = [["box"], ["ball"], ["box", "ball"]][int(rng.integers(0, 3))]
        scene = studio_scene(objects, two_hands=two)
        right_model = HandModel()
        left_model = HandModel(side="left") if two else None
        with Studio(the_rig, scene, noise) as st:
            q = random_hand_pose(rng)
            left = None
            if left_model is not None:
                left = random_hand_pose(rng, centre=(0.0, 0.22, 0.13))
                if q[1] > 0.0:  # keep the two wrists apart
                    q[1] -= 0.1
            if heldout:
                right_model = sample_subject(rng)
                st.set_surface(right_model, sample_surface(rng, forearm=True))
            st.set_state(q, left_pose=left)
            tips = right_model.fingertips(q)
            hand_labels = [1]
            if left_model is not None:
                tips = np.vstack([tips, left_model.fingertips(left)])
                hand_labels = [1, 2]
            for ci, cam in enumerate(the_rig.cameras):
                view = st.render(ci)
                yield LabelledView(view.rgb, np.isin(view.labels, hand_labels),
                                   _visible_tips(view, cam, tips, hand_labels))


# ------------------------------------------------------------------------------ training
def _fit_lut(views: Sequence[LabelledView]) -> np.ndarray:
    """P(hand | colour) on 16 levels per channel, with a prior of one pixel per bin."""
    n = _LUT_LEVELS
    hand = np.zeros(n ** 3)
    tot = np.zeros(n ** 3)
    for v in views:
        q = (v.rgb >> 4).astype(np.intp)
        idx = (q[..., 0] * n + q[..., 1]) * n + q[..., 2]
        tot += np.bincount(idx.ravel(), minlength=n ** 3)
        hand += np.bincount(idx[v.hand_mask], minlength=n ** 3)
    return ((hand + 0.01) / (tot + 1.0)).reshape(n, n, n).astype(np.float32)


def train_detector(views: Sequence[LabelledView], config: DetectorConfig | None = None,
                   *, seed: int = 0, n_trees: int = 8, max_depth: int = 14,
                   max_negatives: int = 120_000) -> SalientDetector:
    """Fit the detector on labelled views (seeded: same views and seed, same detector)."""
    cfg = config or DetectorConfig()
    if not views:
        raise InputError("train_detector needs at least one labelled view")
    rng = np.random.default_rng(seed)
    s = cfg.downsample
    r = cfg.patch_radius_px / s
    # offsets uniform in the disc of radius r (reduced px), plus the centre pixel
    ang = rng.uniform(0, 2 * np.pi, (cfg.n_offsets, 2))
    rad = r * np.sqrt(rng.uniform(0, 1, (cfg.n_offsets, 2)))
    off = np.round(np.stack([rad[:, 0] * np.sin(ang[:, 0]), rad[:, 0] * np.cos(ang[:, 0]),
                             rad[:, 1] * np.sin(ang[:, 1]), rad[:, 1] * np.cos(ang[:, 1])],
                            axis=1)).astype(np.intp)
    off[0] = 0
    # half of the features read the hand probability (shape), the rest grey and chroma
    chans = np.where(rng.random((cfg.n_offsets, 2)) < 0.5, 0,
                     rng.integers(1, _N_CHANNELS, (cfg.n_offsets, 2))).astype(np.intp)
    det = SalientDetector(cfg, _fit_lut(views), off, chans,
                          RegressionForest.fit(np.zeros((2, 1)), np.zeros((2, 1)), n_trees=1),
                          RegressionForest.fit(np.zeros((2, 1)), np.zeros((2, 2)), n_trees=1))
    Xs, ys, offs = [], [], []
    pos_r = cfg.pos_radius_px / s
    for v in views:
        maps = det._channel_maps(v.rgb)
        cy, cx = det._candidates(maps)
        if len(cy) == 0:
            continue
        tips = (v.tips - (s - 1) / 2.0) / s
        if len(tips):
            d = np.hypot(cx[:, None] - tips[None, :, 0], cy[:, None] - tips[None, :, 1])
            near = np.argmin(d, axis=1)
            dmin = d[np.arange(len(cx)), near]
            pos = dmin <= pos_r
            o = tips[near] - np.column_stack([cx, cy])
        else:
            pos = np.zeros(len(cx), bool)
            o = np.zeros((len(cx), 2))
        Xs.append(det._features(maps, cy, cx))
        ys.append(pos)
        offs.append(o)
    X = np.concatenate(Xs)
    y = np.concatenate(ys)
    o = np.concatenate(offs)
    pos_idx = np.nonzero(y)[0]
    neg_idx = np.nonzero(~y)[0]
    if len(pos_idx) < 20:
        raise InputError(f"only {len(pos_idx)} positive pixels in the training views")
    if len(neg_idx) > max_negatives:
        neg_idx = rng.choice(neg_idx, max_negatives, replace=False)
    # balance: positives repeated up to a quarter of the negatives' count
    reps = max(1, int(0.25 * len(neg_idx) / len(pos_idx)))
    idx = np.concatenate([np.repeat(pos_idx, reps), neg_idx])
    det.classifier = RegressionForest.fit(X[idx], y[idx, None].astype(float), n_trees=n_trees,
                                          max_depth=max_depth, min_leaf=10, n_try=40,
                                          n_thresholds=8, rng=rng)
    det.regressor = RegressionForest.fit(X[pos_idx], o[pos_idx], n_trees=n_trees,
                                         max_depth=max(6, max_depth - 4), min_leaf=8,
                                         n_try=40, n_thresholds=8, rng=rng)
    det.meta = {"views": str(len(views)), "positives": str(len(pos_idx)),
                "negatives": str(len(neg_idx)), "seed": str(seed),
                "balance_repeats": str(reps)}
    return det


# ---------------------------------------------------------------------------- evaluation
def match_detections(points: np.ndarray, tips: np.ndarray, radius_px: float
                     ) -> tuple[int, int, int]:
    """(true positives, detections, visible tips): each tip matched to at most one detection
    within ``radius_px`` (optimal one-to-one assignment)."""
    from scipy.optimize import linear_sum_assignment

    p = np.asarray(points, float).reshape(-1, 2)
    t = np.asarray(tips, float).reshape(-1, 2)
    if len(p) == 0 or len(t) == 0:
        return 0, len(p), len(t)
    d = np.hypot(p[:, None, 0] - t[None, :, 0], p[:, None, 1] - t[None, :, 1])
    cost = np.where(d <= radius_px, d, 1e6)
    r, c = linear_sum_assignment(cost)
    return int(np.sum(cost[r, c] <= radius_px)), len(p), len(t)


def choose_min_score(det: SalientDetector, views: Sequence[LabelledView],
                     radius_px: float = 6.0) -> float:
    """The ``min_score`` with the best F1 score on ``views`` (training-family views not used
    for the fit), from the detections at threshold 0."""
    from dataclasses import replace

    low = replace(det.config, min_score=0.0, max_detections=100)
    keep = det.config
    det.config = low
    scores, hits, n_tip = [], [], 0
    try:
        for v in views:
            pts, sc = det.detect(v.rgb)
            n_tip += len(v.tips)
            hit = np.zeros(len(pts), bool)
            if len(pts) and len(v.tips):
                d = np.hypot(pts[:, None, 0] - v.tips[None, :, 0],
                             pts[:, None, 1] - v.tips[None, :, 1])
                hit = d.min(axis=1) <= radius_px
            scores.append(sc)
            hits.append(hit)
    finally:
        det.config = keep
    s = np.concatenate(scores)
    h = np.concatenate(hits)
    best, best_f1 = keep.min_score, -1.0
    for t in np.unique(np.round(s, 1)):
        sel = s >= t
        tp = float(np.sum(h & sel))
        prec, rec = tp / max(sel.sum(), 1), min(tp / max(n_tip, 1), 1.0)
        f1 = 2 * prec * rec / max(prec + rec, 1e-9)
        if f1 > best_f1:
            best, best_f1 = float(t), f1
    return best


def evaluate(det: SalientDetector, views: Sequence[LabelledView], radius_px: float = 6.0
             ) -> dict[str, float]:
    """Precision and recall of the detections within ``radius_px`` of a visible fingertip,
    and the detector's mean time per image [s]."""
    tp = n_det = n_tip = 0
    t = 0.0
    for v in views:
        t0 = time.perf_counter()
        pts, _ = det.detect(v.rgb)
        t += time.perf_counter() - t0
        a, b, c = match_detections(pts, v.tips, radius_px)
        tp, n_det, n_tip = tp + a, n_det + b, n_tip + c
    return {"precision": tp / max(n_det, 1), "recall": tp / max(n_tip, 1),
            "detections_per_image": n_det / max(len(views), 1),
            "tips_per_image": n_tip / max(len(views), 1),
            "s_per_image": t / max(len(views), 1), "images": float(len(views))}


# --------------------------------------------------------------------------- the trainer
#: training scenes (x 6 cameras) of the shipped model and of ``--quick``; evaluation scenes
TRAIN_SCENES, QUICK_SCENES, EVAL_SCENES, QUICK_EVAL_SCENES = 70, 12, 20, 4
TRAIN_SEED, EVAL_SEED = 0, 1000
#: a detection within this of a visible fingertip is a true positive [px] (about half a
#: finger's width at the studio's 0.75 m)
EVAL_RADIUS_PX = 6.0


def main(argv: list[str] | None = None) -> int:
    """``hand-suite train salient [--quick] [--out PATH]``: render, fit, evaluate, save."""
    ap = argparse.ArgumentParser(prog="hand-suite train salient",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help=f"{QUICK_SCENES} training scenes instead of {TRAIN_SCENES} (a smoke "
                         "run; the default output is then not the shipped file)")
    ap.add_argument("--out", type=Path, default=None,
                    help="detector file (default: data/salient/salient.npz; with --quick a "
                         "file in the temporary folder)")
    ap.add_argument("--seed", type=int, default=TRAIN_SEED)
    ap.add_argument("--trees", type=int, default=None,
                    help="trees per forest (default: 8; 4 with --quick)")
    a = ap.parse_args(argv)
    import os
    import tempfile

    os.environ.setdefault("MUJOCO_GL", "osmesa")
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    n_train = QUICK_SCENES if a.quick else TRAIN_SCENES
    n_eval = QUICK_EVAL_SCENES if a.quick else EVAL_SCENES
    out = a.out or (Path(tempfile.gettempdir()) / "salient_quick.npz" if a.quick
                    else default_detector_path())
    t0 = time.perf_counter()
    views = list(render_views(n_train, a.seed))
    t1 = time.perf_counter()
    trees = a.trees if a.trees is not None else 4 if a.quick else 8
    if not 1 <= trees <= 64:
        raise InputError(f"--trees must be in [1, 64], got {trees}")
    det = train_detector(views, seed=a.seed, n_trees=trees)
    from dataclasses import replace

    val = list(render_views(max(2, n_train // 6), a.seed + 500))
    det.config = replace(det.config, min_score=choose_min_score(det, val))
    det.meta["min_score_from"] = f"best F1 on {len(val)} own-hand validation views"
    t2 = time.perf_counter()
    det.save(out)
    held = list(render_views(n_eval, EVAL_SEED, heldout=True))
    own = list(render_views(max(2, n_eval // 2), EVAL_SEED + 1))
    r_held = evaluate(det, held, EVAL_RADIUS_PX)
    r_own = evaluate(det, own, EVAL_RADIUS_PX)
    print(f"rendered {len(views)} training views in {t1 - t0:.1f} s, fitted in "
          f"{t2 - t1:.1f} s -> {out} ({out.stat().st_size / 1e6:.2f} MB)")
    for name, r in (("held-out surfaces", r_held), ("own MJCF hand (new poses)", r_own)):
        print(f"{name}: precision {r['precision']:.3f}, recall {r['recall']:.3f} at 6 px "
              f"({r['images']:.0f} images, {r['s_per_image'] * 1e3:.1f} ms per image)")
    print(json.dumps({"heldout_precision": r_held["precision"],
                      "heldout_recall": r_held["recall"], "own_precision": r_own["precision"],
                      "own_recall": r_own["recall"], "ms_per_image": 1e3 * r_held["s_per_image"],
                      "min_score": det.config.min_score, "radius_px": EVAL_RADIUS_PX,
                      "file": str(out)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
