"""Local optimisation of one frame: seed 002's Algorithm 1 with Levenberg-Marquardt.

Each outer iteration renders the combined model at the current estimate in every camera,
builds the edge and salient-point correspondences (optical flow ones are built once per frame
from the previous frame's estimate), adds the collisions detected at this estimate to the
frame's set C, rejects outliers, and takes a few Levenberg-Marquardt steps on eq. (2):

    F(theta) = sum_{(k, c, p) in E u O u S} w_type ||Pi_c(v_k(theta)) - p||^2 + Gamma(theta)

with analytic Jacobians (the part's vertex Jacobian chained with the projection's, see
:mod:`hand_capture.multiview.scene_model`) and the collision term of eq. (4)
(:mod:`hand_capture.multiview.collision`) weighted by ``collision_px_per_m``^2. Box
constraints (joint limits) are kept by projection with an active set: parameters at a bound
whose gradient pushes outwards are held for the step. Outliers (sec. 4.3): per bone and
camera, the image displacements ``p - Pi_c(v_k)`` of its correspondences get a mean and a
standard deviation; those farther than ``outlier_sigma`` standard deviations from the mean
are left out of the iteration.

Seed 000 sec. 4.3's smoothness term, added to eq. (2) (seed 002 names motion priors as the
extension its failure cases call for): every parameter optimised gets the residual
``smooth_px_per_mm * L * (q_t - 2 q_{t-1} + q_{t-2})``, with ``L`` 1000 mm per metre for a
wrist's or an object's position and 50 mm per radian (the arc of a finger-long lever) for the
angles, so that an acceleration moving a part by 1 mm costs about ``smooth_px_per_mm``
pixels of residual. The objects take it too: with the hands alone held by it, the collision
term (eq. 4) pushed a grasped box out of the still hand instead of both yielding
(docs/experiments/multiview.md).
The tracker passes ``2 q_{t-1} - q_{t-2}`` (its last estimate moved on by its last motion) as
the ``prior`` of :meth:`LocalOptimizer.solve`. Structural noise and detector errors differ
from frame to frame, so a frame's optimum wanders around the true motion (the own-mesh error
with seed 002's circles correlates 0.4-0.56 between consecutive frames); the term keeps the
part of that wander that the motion does not explain out of the estimate.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.joints import N_DOF
from hand_capture.multiview.collision import (
    CollisionPairs,
    detect_collisions,
)
from hand_capture.multiview.correspondences import (
    FLOW_IGNORE_MARGIN_PX,
    ImageFeatures,
    edge_correspondences,
    flow_correspondences,
    image_features,
    match_salient,
    model_edges,
)
from hand_capture.multiview.rig import Rig
from hand_capture.multiview.scene_model import OBJECT_DOF, SceneModel, SceneState

__all__ = ["Correspondences", "FrameData", "LOConfig", "LOResult", "LocalOptimizer"]

EDGE, FLOW, SALIENT = 0, 1, 2
#: the smoothness term's lever for angles [mm per rad] (module docstring)
SMOOTH_LEVER_MM = 50.0
KIND_NAMES = ("edge", "flow", "salient")


@dataclass(frozen=True)
class LOConfig:
    """Local optimiser settings (seed 002 sec. 4.3; weights on squared pixel residuals)."""

    iterations: int = param(15, "outer iterations per frame (render + correspondences)",
                            lo=1, hi=200)
    inner_steps: int = param(4, "Levenberg-Marquardt steps per outer iteration", lo=1, hi=20)
    render_scale: float = param(0.5, "resolution of the model renders (share of the image)",
                                lo=0.1, hi=1.0)
    use_edges: bool = param(True, "edge correspondences E")
    use_flow: bool = param(True, "optical flow correspondences O")
    use_salient: bool = param(True, "salient point correspondences S")
    use_collisions: bool = param(True, "collision term C (eq. 4)")
    # 30 px: 20 or 15 px (narrowing to a third) lowered the own-mesh validation error with
    # the circles but failed the physcap studio lifts
    # (docs/experiments/multiview.md: the own-mesh floor)
    edge_max_px: float = param(30.0, "farthest image edge matched to a model edge in the "
                               "first outer iteration [px]; the gate narrows to a third of "
                               "it (gate_narrow_share)", lo=1.0, hi=200.0)
    # 1 (over the whole solve): 0.5 (10 px from the 8th of 15 iterations) lowered the
    # own-mesh validation error with the circles 5.91 -> 5.30 mm, but the full bench then gave
    # held-out fingers 10.98 mm (docs/experiments/multiview.md: the own-mesh floor),
    # so it is not default
    gate_narrow_share: float = param(1.0, "share of the outer iterations over which the edge "
                                     "gate narrows from edge_max_px to a third of it (held "
                                     "there after; 1: over the whole solve)", lo=0.05, hi=1.0)
    edges_per_view: int = param(120, "edge correspondences kept per part and camera",
                                lo=5, hi=5000)
    flow_per_view: int = param(60, "flow correspondences tried per part and camera", lo=0,
                               hi=5000)
    salient_lambda_px: float = param(20.0, "outlier cost lambda of eq. (3) [px]: seed 002's 60 "
                                     "px at 1920 px wide images is 20 px at 640", lo=1.0,
                                     hi=1000.0)
    w_edge: float = param(1.0, "weight of edge residuals", lo=0.0, hi=1e3)
    w_flow: float = param(1.0, "weight of flow residuals", lo=0.0, hi=1e3)
    w_salient: float = param(20.0, "weight of salient point residuals (the circles of seed "
                             "002's structural noise corrupt edges, not salient points)",
                             lo=0.0, hi=1e3)
    collision_px_per_m: float = param(1500.0, "collision residual scale [px per m of depth]",
                                      lo=0.0, hi=1e6)
    collision_depth_m: float = param(0.02, "depth of the local distance fields [m]", lo=1e-3,
                                     hi=0.1)
    outlier_sigma: float = param(2.0, "outlier gate in standard deviations (sec. 4.3)",
                                 lo=0.5, hi=10.0)
    robust_px: float = param(2.0, "scale of the Cauchy weights of correspondences [px]; "
                             "0 = plain least squares", lo=0.0, hi=100.0)
    support_px: float = param(4.0, "a model edge is supported by an image edge this near [px]",
                              lo=0.5, hi=50.0)
    colour_check_px: float = param(3.0, "a hand's edge correspondence is kept only when the "
                                   "hand colour model (learned on the first frame) sees "
                                   "hand within this distance on either side of the image "
                                   "edge [px]; 0 = off", lo=0.0, hi=20.0)
    salient_seen: bool = param(False, "match the salient vertices whose fingertip the "
                               "camera sees (SceneModel.salient_seen: the nearest surface "
                               "within 15 mm of the vertex, or none); False: the vertices "
                               "visible themselves (SceneModel.visible)")
    edge_blur_px: float = param(1.0, "Gaussian smoothing of the images before Canny [px] "
                                "(0: none)", lo=0.0, hi=5.0)
    edge_saturation: float = param(0.0, "the hands' edges: per pixel the larger of the grey "
                                   "level's gradient and this times the HSV saturation's "
                                   "(correspondences.image_features; 0: grey level only); "
                                   "the objects' edges stay the grey level's", lo=0.0, hi=8.0)
    smooth_px_per_mm: float = param(0.0, "weight of seed 000 sec. 4.3's smoothness term on "
                                    "every part: residual [px] per mm of acceleration "
                                    "(angles at a 50 mm lever); 0 = none (seed 002's eq. 2 "
                                    "alone)",
                                    lo=0.0, hi=1000.0)
    smooth_ref_hz: float = param(20.0, "frame rate at and above which smooth_px_per_mm "
                                 "applies as it is [Hz]; at a lower rate r it is scaled by "
                                 "(r / this)^2, so an acceleration [m/s^2] costs what it "
                                 "does at this rate (seed 000 sec. 4.1 films at 20 fps)",
                                 lo=1.0, hi=1000.0)
    seed: int = param(0, "subsampling seed", lo=0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class Correspondences:
    """Triplets (k, c, p) of eq. (2) with their part, kind and weight (parallel arrays)."""

    part: np.ndarray
    vert: np.ndarray
    cam: np.ndarray
    target: np.ndarray
    kind: np.ndarray
    normal: np.ndarray | None = None   # (n, 2) edge normals; zero rows: full 2-D residual
    robust: np.ndarray | None = None   # (n,) robust weight of this iteration (1 = full)

    def __post_init__(self) -> None:
        if self.normal is None:
            self.normal = np.zeros((len(self.part), 2))
        if self.robust is None:
            self.robust = np.ones(len(self.part))

    @staticmethod
    def concat(items: Sequence[Correspondences]) -> Correspondences:
        items = [c for c in items if len(c.part)]
        if not items:
            z = np.zeros(0, np.int64)
            return Correspondences(z, z, z, np.zeros((0, 2)), z)
        return Correspondences(*(np.concatenate([getattr(c, f) for c in items])
                                 for f in ("part", "vert", "cam", "target", "kind", "normal",
                                           "robust")))

    def subset(self, keep: np.ndarray) -> Correspondences:
        return Correspondences(self.part[keep], self.vert[keep], self.cam[keep],
                               self.target[keep], self.kind[keep], self.normal[keep],
                               self.robust[keep])

    def __len__(self) -> int:
        return int(len(self.part))


@dataclass
class FrameData:
    """One frame's image evidence: features per present camera, salient detections, flow."""

    features: dict[int, ImageFeatures]
    detections: dict[int, np.ndarray]
    flow: Correspondences
    hand_mask: dict[int, np.ndarray] = field(default_factory=dict)  # camera -> (H, W) bool
    #: camera -> the hands' edge features when they differ from ``features``
    #: (``LOConfig.edge_saturation``); the objects' are always ``features``
    hand_features: dict[int, ImageFeatures] = field(default_factory=dict)


@dataclass
class LOResult:
    """Outcome of :meth:`LocalOptimizer.solve`."""

    params: np.ndarray
    cost: float
    support: np.ndarray          # per part: share of its model edges near an image edge
    model_edges: np.ndarray      # per part: model edge vertices seen over all cameras
    counts: dict[str, int] = field(default_factory=dict)
    collisions: int = 0
    seconds: float = 0.0
    #: (iterations, n_params): the estimate after each outer iteration (diagnostics: does the
    #: solve still move at its last iteration?)
    trace: np.ndarray | None = None
    #: (iterations,): eq. (2)'s cost after each outer iteration's LM steps (each over that
    #: iteration's own correspondences, so not comparable across iterations in general)
    costs: np.ndarray | None = None


class LocalOptimizer:
    """Seed 002's iterative local optimisation over a rig; see the module docstring."""

    def __init__(self, model: SceneModel, rig: Rig, config: LOConfig | None = None) -> None:
        self.model = model
        self.rig = rig
        self.cfg = config or LOConfig()
        self._rng = np.random.default_rng(self.cfg.seed)
        hands = range(model.n_hands)
        parts = range(len(model.part_names))
        self.collision_parts = [(a, b) for a in hands for b in parts if b > a]
        #: hand / background colours (seed 000 eq. 4), see :meth:`learn_colours`
        self.colour: object | None = None

    def learn_colours(self, images: Mapping[str, np.ndarray | None], params: np.ndarray
                      ) -> bool:
        """Learn the hand / background colour model (seed 000 eq. 4) from a frame whose
        configuration ``params`` is known (the hands' rendered silhouettes, 4 px of each
        outline left out). Edge correspondences of the hands are then screened by it (an
        image edge with no hand colour on either side is clutter, not a hand's outline).
        False when no camera sees a hand."""
        import cv2

        from hand_capture.multiview.imageterms import ColourModel

        if not self.model.n_hands or self.cfg.colour_check_px <= 0:
            return False
        state = self.model.pose(params)
        imgs, masks = [], []
        for cam in self.rig.cameras:
            img = images.get(cam.name)
            if img is None:
                continue
            ren = self.model.render(cam, state, 0.5, parts=list(range(self.model.n_hands)))
            h, w = np.asarray(img).shape[:2]
            mask = cv2.resize((ren.labels > 0).astype(np.uint8), (w, h),
                              interpolation=cv2.INTER_NEAREST) > 0
            if mask.sum() > 50:
                imgs.append(np.asarray(img))
                masks.append(mask)
        if not imgs:
            return False
        self.colour = ColourModel.fit(imgs, masks, margin_px=4)
        return True

    def _hand_mask(self, rgb: np.ndarray) -> np.ndarray:
        """(H, W) bool: pixels of hand colour, grown by ``colour_check_px``."""
        import cv2

        # opened: the thin mixed-colour rims along other edges (anti-aliasing) drop out
        m = self.colour.silhouette(rgb).astype(np.uint8)
        r = int(np.ceil(self.cfg.colour_check_px))
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
        return cv2.dilate(m, k) > 0

    # -------------------------------------------------------------------------- per frame
    def prepare(self, images: Mapping[str, np.ndarray | None],
                detections: Mapping[str, np.ndarray] | None = None,
                prev: tuple[Mapping[str, np.ndarray | None], SceneState] | None = None,
                parts: Sequence[int] | None = None,
                flow_ignore: Mapping[str, np.ndarray] | None = None,
                prev_flow_ignore: Mapping[str, np.ndarray] | None = None) -> FrameData:
        """Image features of the present cameras, their salient detections, and the optical
        flow correspondences from the previous frame (its images and final state).

        ``flow_ignore`` / ``prev_flow_ignore``: camera -> (H, W) bool mask of this / the
        previous frame's pixels whose optical flow is not considered (None: every pixel
        counts, as for a real camera). Seed 002 sec. 5.1's protocol: the structural-noise
        circles added to the synthetic images, and "the optical flow features
        corresponding to those circles" left out; a benchmark that knows where it drew
        them passes them here. A visible vertex is not a flow start when a previous-frame
        mask pixel lies within ``FLOW_IGNORE_MARGIN_PX`` (the LK half-window) of its
        projection, and its flow is dropped when one of this frame's does of its tracked end
        (:func:`~hand_capture.multiview.correspondences.flow_correspondences`)."""
        feats: dict[int, ImageFeatures] = {}
        hand_feats: dict[int, ImageFeatures] = {}
        for c, cam in enumerate(self.rig.cameras):
            img = images.get(cam.name)
            if img is not None:
                feats[c] = image_features(img, blur_px=self.cfg.edge_blur_px)
                if self.cfg.edge_saturation > 0 and np.ndim(img) == 3:
                    hand_feats[c] = image_features(img, blur_px=self.cfg.edge_blur_px,
                                                   saturation=self.cfg.edge_saturation)
        dets = {}
        for c, cam in enumerate(self.rig.cameras):
            d = None if detections is None else detections.get(cam.name)
            if d is not None and c in feats:
                dets[c] = np.asarray(d, dtype=float).reshape(-1, 2)
        masks = {}
        if self.colour is not None and self.cfg.colour_check_px > 0:
            masks = {c: self._hand_mask(images[self.rig.cameras[c].name]) for c in feats
                     if np.ndim(images[self.rig.cameras[c].name]) == 3}
        flow = Correspondences.concat([])
        if prev is not None and self.cfg.use_flow and self.cfg.flow_per_view > 0:
            flow = self._flow(feats, prev[0], prev[1],
                              list(range(len(self.model.part_names))) if parts is None
                              else list(parts), flow_ignore or {}, prev_flow_ignore or {})
        return FrameData(feats, dets, flow, masks, hand_feats)

    def _flow(self, feats: dict[int, ImageFeatures], prev_images: Mapping[str, object],
              prev_state: SceneState, parts: list[int], ignore: Mapping[str, np.ndarray],
              prev_ignore: Mapping[str, np.ndarray]) -> Correspondences:
        from hand_capture.multiview.correspondences import to_grey, window_clear

        out = []
        s = self.cfg.render_scale
        for c, f in feats.items():
            cam = self.rig.cameras[c]
            pimg = prev_images.get(cam.name)
            if pimg is None:
                continue
            pg = to_grey(pimg)
            pmask, cmask = prev_ignore.get(cam.name), ignore.get(cam.name)
            ren = self.model.render(cam, prev_state, s, parts=parts)
            for p in parts:
                idx, uv = self.model.visible(cam, prev_state, ren, p)
                if pmask is not None:
                    # screened before the draw: the budget goes to starts that may be used
                    ok = window_clear(pmask, uv, FLOW_IGNORE_MARGIN_PX)
                    idx, uv = idx[ok], uv[ok]
                if len(idx) > self.cfg.flow_per_view:
                    pick = self._rng.choice(len(idx), self.cfg.flow_per_view, replace=False)
                    idx, uv = idx[pick], uv[pick]
                sel, tgt = flow_correspondences(pg, f.grey, uv, ignore=cmask)
                n = len(sel)
                out.append(Correspondences(np.full(n, p), idx[sel], np.full(n, c), tgt,
                                           np.full(n, FLOW)))
        return Correspondences.concat(out)

    # ----------------------------------------------------------------------- per iteration
    def correspondences(self, state: SceneState, frame: FrameData, parts: Sequence[int],
                        gate_px: float | None = None, support: bool = True
                        ) -> tuple[Correspondences, np.ndarray, np.ndarray]:
        """Edge and salient correspondences at ``state`` (Algorithm 1's loop body), edges
        matched within ``gate_px`` (default ``edge_max_px``), and per part the model edge
        vertices seen and how many an image edge supports."""
        cfg, m = self.cfg, self.model
        gate_px = cfg.edge_max_px if gate_px is None else gate_px
        out = []
        n_edge = np.zeros(len(m.part_names))
        n_sup = np.zeros(len(m.part_names))
        for c, feats in frame.features.items():
            cam = self.rig.cameras[c]
            ren = m.render(cam, state, cfg.render_scale, parts=parts)
            edge, bins = model_edges(ren.depth, ren.labels)
            h, w = ren.depth.shape
            sal_uv, sal_ref = [], []
            for p in parts:
                idx, uv = m.visible(cam, state, ren, p)
                if not len(idx):
                    continue
                pf = frame.hand_features.get(c, feats) if p < m.n_hands else feats
                pix = np.stack([np.floor((uv[:, 0] + 0.5) * cfg.render_scale),
                                np.floor((uv[:, 1] + 0.5) * cfg.render_scale)],
                               axis=1).astype(np.int64)
                pix[:, 0] = np.clip(pix[:, 0], 0, w - 1)
                pix[:, 1] = np.clip(pix[:, 1], 0, h - 1)
                # outline vertices: on the contour generator (between faces turned to and
                # away from the camera); others in the rendered edge band lie inside it
                usable = m.edge_usable[p][idx] & m.contour(cam, state, p)[idx]
                on = (bins[pix[:, 1], pix[:, 0]] >= 0) & usable
                n_on = int(on.sum())
                if n_on and support:
                    _, dist, _ = feats.nearest_edge(uv[on], bins[pix[on, 1], pix[on, 0]])
                    n_edge[p] += n_on
                    n_sup[p] += float(np.sum(dist <= cfg.support_px))
                if cfg.use_edges:
                    eb = np.where(usable[:, None], pix, -1)
                    sel, tgt, nrm = edge_correspondences(uv, eb, bins, pf, gate_px)
                    hm = frame.hand_mask.get(c) if p < m.n_hands else None
                    if hm is not None and len(sel):
                        # clutter screen: a hand's outline has hand colour beside it (the
                        # mask is grown by colour_check_px, so the edge pixel itself counts)
                        col = np.clip(np.round(tgt[:, 0]).astype(np.int64), 0,
                                      hm.shape[1] - 1)
                        row = np.clip(np.round(tgt[:, 1]).astype(np.int64), 0,
                                      hm.shape[0] - 1)
                        ok = hm[row, col]
                        sel, tgt, nrm = sel[ok], tgt[ok], nrm[ok]
                    if len(sel) > cfg.edges_per_view:
                        pick = self._rng.choice(len(sel), cfg.edges_per_view, replace=False)
                        sel, tgt, nrm = sel[pick], tgt[pick], nrm[pick]
                    n = len(sel)
                    out.append(Correspondences(np.full(n, p), idx[sel], np.full(n, c), tgt,
                                               np.full(n, EDGE), nrm))
                if cfg.use_salient and p < m.n_hands and c in frame.detections:
                    vis = m.salient_seen(cam, state, ren, p) if cfg.salient_seen else \
                        np.isin(m.salient[p], idx)
                    sv = m.salient[p][vis]
                    if len(sv):
                        sal_uv.append(m.project(cam, state.vertices[p][sv])[0])
                        sal_ref.append(np.stack([np.full(len(sv), p), sv], axis=1))
            if sal_uv:
                P = np.concatenate(sal_uv)
                ref = np.concatenate(sal_ref)
                s, t = match_salient(P, frame.detections[c], cfg.salient_lambda_px)
                n = len(s)
                out.append(Correspondences(ref[s, 0], ref[s, 1], np.full(n, c),
                                           frame.detections[c][t], np.full(n, SALIENT)))
            del edge
        return Correspondences.concat(out), n_edge, n_sup

    def _reject_outliers(self, corr: Correspondences, state: SceneState) -> Correspondences:
        """Seed 002 sec. 4.3: per (part, bone, camera), drop correspondences whose image
        displacement is farther than ``outlier_sigma`` standard deviations from the mean."""
        if not len(corr):
            return corr
        uv = np.zeros((len(corr), 2))
        for (p, c) in {(int(a), int(b)) for a, b in zip(corr.part, corr.cam, strict=True)}:
            sel = np.flatnonzero((corr.part == p) & (corr.cam == c))
            uv[sel] = self.model.project(self.rig.cameras[c],
                                         state.vertices[p][corr.vert[sel]])[0]
        disp = corr.target - uv
        bone = np.array([self.model.vertex_bones[p][v] for p, v in zip(corr.part, corr.vert,
                                                                      strict=True)])
        key = (corr.part * 64 + bone) * 64 + corr.cam
        keep = np.ones(len(corr), bool)
        for k in np.unique(key):
            sel = np.flatnonzero(key == k)
            if len(sel) < 4:
                continue
            d = disp[sel]
            dev = np.linalg.norm(d - d.mean(axis=0), axis=1)
            sd = float(np.sqrt(np.mean(dev ** 2)))
            keep[sel] = dev <= self.cfg.outlier_sigma * sd + 1.0
        return corr.subset(keep)

    def _robust_weights(self, x: np.ndarray, corr: Correspondences) -> Correspondences:
        """Cauchy weights ``1 / (1 + (e / c)^2)`` of each correspondence's pixel error ``e``
        at ``x`` (iteratively reweighted least squares): structure that is not the model's
        (clutter, occluders) pulls less than the correspondences that agree."""
        c = self.cfg.robust_px
        if not len(corr) or c <= 0:
            return corr
        corr.robust = np.ones(len(corr))
        res, _ = self._residuals(x, corr, CollisionPairs.empty(), None)
        sw = self._weights(corr)
        e = np.hypot(res[0::2], res[1::2]) / np.maximum(sw, 1e-12)
        corr.robust = 1.0 / (1.0 + (e / c) ** 2)
        return corr

    # ------------------------------------------------------------------- least squares
    def _weights(self, corr: Correspondences) -> np.ndarray:
        w = np.array([self.cfg.w_edge, self.cfg.w_flow, self.cfg.w_salient])
        return np.sqrt(w[corr.kind] * corr.robust)

    def _plan(self, corr: Correspondences, coll: CollisionPairs) -> dict:
        """Index bookkeeping of a correspondence set, shared by every residual evaluation of
        an outer iteration: the vertices each part needs and the (part, camera) groups."""
        key = (id(corr), len(corr), id(coll), len(coll))
        if getattr(self, "_plan_key", None) == key:
            return self._plan_cache
        m = self.model
        needed: dict[int, list[np.ndarray]] = {}
        for p in np.unique(corr.part):
            needed.setdefault(int(p), []).append(corr.vert[corr.part == p])
        if len(coll):
            for p in np.unique(coll.vert_part):
                needed.setdefault(int(p), []).append(coll.vert[coll.vert_part == p])
            for p in np.unique(coll.face_part):
                needed.setdefault(int(p), []).append(
                    m.faces[p][coll.face[coll.face_part == p]].reshape(-1))
        idx = {p: np.unique(np.concatenate(v)) for p, v in needed.items()}
        groups = []
        for p in np.unique(corr.part):
            for c in np.unique(corr.cam[corr.part == p]):
                sel = np.flatnonzero((corr.part == p) & (corr.cam == c))
                pos = np.searchsorted(idx[int(p)], corr.vert[sel])
                groups.append((int(p), int(c), sel, pos))
        plan = {"idx": idx, "groups": groups}
        self._plan_key, self._plan_cache = key, plan
        return plan

    def _residuals(self, params: np.ndarray, corr: Correspondences, coll: CollisionPairs,
                   cols: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Stacked weighted residuals of eq. (2) and, when ``cols`` is given, their Jacobian
        with respect to the parameters ``cols``."""
        m = self.model
        n = len(corr)
        sw = self._weights(corr)
        res = np.zeros(2 * n + len(coll))
        jac = None if cols is None else np.zeros((len(res), len(cols)))
        colpos = None if cols is None else {int(c): i for i, c in enumerate(cols)}
        plan = self._plan(corr, coll)
        verts: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for p, idx in plan["idx"].items():
            pts, J = m.linearize(params, p, idx)
            verts[p] = (idx, pts, J)

        def lookup(p: int, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            idx, pts, J = verts[p]
            pos = np.searchsorted(idx, v)
            return pts[pos], J[pos]

        def part_cols(p: int) -> tuple[np.ndarray, np.ndarray]:
            sl = m.slices[m.part_names[p]]
            src = np.arange(sl.stop - sl.start)
            dst = np.array([colpos.get(sl.start + k, -1) for k in src])
            ok = dst >= 0
            return src[ok], dst[ok]

        pcols = {p: part_cols(p) for p in verts} if jac is not None else {}
        for p, c, sel, pos in plan["groups"]:
            _, allpts, allJ = verts[p]
            pts = allpts[pos]
            cam = self.rig.cameras[c]
            uv = m.project(cam, pts)[0]
            r = (uv - corr.target[sel]) * sw[sel, None]
            nrm = corr.normal[sel]
            line = np.any(nrm != 0, axis=1)
            # edges: the residual along the image edge's normal (point-to-line)
            res[2 * sel] = np.where(line, np.sum(r * nrm, axis=1), r[:, 0])
            res[2 * sel + 1] = np.where(line, 0.0, r[:, 1])
            if jac is not None and len(pcols[p][0]):
                src, dst = pcols[p]
                Jp = np.einsum("nij,njk->nik", m.project_jacobian(cam, pts),
                               allJ[pos][:, :, src]) * sw[sel, None, None]
                j0 = np.where(line[:, None], np.einsum("ij,ijk->ik", nrm, Jp), Jp[:, 0])
                j1 = np.where(line[:, None], 0.0, Jp[:, 1])
                jac[2 * sel[:, None], dst[None, :]] = j0
                jac[2 * sel[:, None] + 1, dst[None, :]] = j1
        if len(coll):
            k = self.cfg.collision_px_per_m
            base = 2 * n
            for sp in np.unique(coll.face_part):
                sp = int(sp)
                sel = np.flatnonzero(coll.face_part == sp)
                f = coll.face[sel]
                tri = m.faces[sp][f]
                pts_t, J_t = lookup(sp, tri.reshape(-1))
                pts_t = pts_t.reshape(len(sel), 3, 3)
                c_ = pts_t.mean(axis=1)
                nrm = np.cross(pts_t[:, 1] - pts_t[:, 0], pts_t[:, 2] - pts_t[:, 0])
                nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-15)
                rho = np.linalg.norm(pts_t - c_[:, None], axis=2).max(axis=1)
                for tp in np.unique(coll.vert_part[sel]):
                    tp = int(tp)
                    ss = sel[coll.vert_part[sel] == tp]
                    loc = np.searchsorted(sel, ss)
                    x, Jx = lookup(tp, coll.vert[ss])
                    d = np.einsum("ij,ij->i", c_[loc] - x, nrm[loc])
                    lat = np.linalg.norm((x - c_[loc]) + d[:, None] * nrm[loc], axis=1)
                    inside = (d > 0) & (d <= self.cfg.collision_depth_m) & \
                        (lat <= rho[loc] + d)
                    res[base + ss] = k * np.where(inside, d, 0.0)
                    if jac is None:
                        continue
                    g = np.where(inside, k, 0.0)[:, None]
                    src, dst = part_cols(tp)
                    if len(src):   # d d / d theta_vertex = -n . J_x
                        jac[np.ix_(base + ss, dst)] -= g * np.einsum(
                            "ij,ijk->ik", nrm[loc], Jx[:, :, src])
                    src, dst = part_cols(sp)
                    if len(src):   # d d / d theta_face = n . mean(J_face vertices)
                        Jc = J_t.reshape(len(sel), 3, 3, -1).mean(axis=1)[loc]
                        jac[np.ix_(base + ss, dst)] += g * np.einsum(
                            "ij,ijk->ik", nrm[loc], Jc[:, :, src])
        return res, jac

    def smoothness_weights(self, prior: np.ndarray | None, cols: np.ndarray,
                           dt: float | None = None) -> np.ndarray | None:
        """The smoothness term's weight (module docstring) of each optimised parameter
        ``cols`` [px per m or per rad], one row each; None when the term is off. ``dt``: the
        time since the previous frame [s] (None: ``smooth_ref_hz``'s); at intervals longer
        than ``1 / smooth_ref_hz`` the weight falls with their square (the same motion
        accelerates by (dt / dt_ref)^2 more per frame)."""
        k = self.cfg.smooth_px_per_mm
        if k <= 0 or prior is None or not len(cols):
            return None
        if dt is not None and math.isfinite(dt) and dt > 0.0:
            k *= min(1.0, 1.0 / (dt * self.cfg.smooth_ref_hz) ** 2)
        nh = self.model.n_hands * N_DOF
        # positions [m]: a hand's wrist (its first 3), an object's origin (its first 3 of 6)
        metres = np.where(cols < nh, cols % N_DOF < 3, (cols - nh) % OBJECT_DOF < 3)
        return np.where(metres, k * 1000.0, k * SMOOTH_LEVER_MM)

    @staticmethod
    def _with_smoothness(res: tuple[np.ndarray, np.ndarray | None], x: np.ndarray,
                         cols: np.ndarray, smooth: tuple | None
                         ) -> tuple[np.ndarray, np.ndarray | None]:
        """``res`` (residuals, Jacobian over ``cols`` or None) with the smoothness rows
        ``smooth`` = ``(prior, w)`` appended: ``w (x - prior)`` over ``cols`` and
        ``diag(w)``."""
        r, J = res
        if smooth is None:
            return r, J
        prior, w = smooth
        r = np.concatenate([r, w * (x[cols] - prior[cols])])
        return r, None if J is None else np.vstack([J, np.diag(w)])

    def _lm_steps(self, params: np.ndarray, corr: Correspondences, coll: CollisionPairs,
                  cols: np.ndarray, steps: int, mu: float, smooth: tuple | None = None
                  ) -> tuple[np.ndarray, float, float]:
        lo, hi = self.model.lo, self.model.hi
        x = params.copy()
        r, J = self._with_smoothness(self._residuals(x, corr, coll, cols), x, cols, smooth)
        cost = float(r @ r)
        for _ in range(steps):
            g = J.T @ r
            xc = x[cols]
            free = ~(((xc <= lo[cols] + 1e-9) & (g > 0)) | ((xc >= hi[cols] - 1e-9) & (g < 0)))
            if not free.any():
                break
            Jf = J[:, free]
            A = Jf.T @ Jf
            d = np.diag(A).copy()
            for _try in range(4):
                H = A + mu * np.diag(d + 1e-9 * (d.max() + 1.0))
                try:
                    delta = -np.linalg.solve(H, g[free])
                except np.linalg.LinAlgError:
                    mu *= 10.0
                    continue
                xn = x.copy()
                xn[cols[free]] += delta
                xn = np.clip(xn, lo, hi)
                rn, _ = self._with_smoothness(self._residuals(xn, corr, coll, None), xn,
                                              cols, smooth)
                cn = float(rn @ rn)
                if cn < cost:
                    x, cost = xn, cn
                    mu = max(mu / 3.0, 1e-7)
                    r, J = self._with_smoothness(self._residuals(x, corr, coll, cols), x,
                                                 cols, smooth)
                    break
                mu *= 4.0
            else:
                break
        return x, cost, mu

    def solve(self, params0: np.ndarray, frame: FrameData, parts: Sequence[int] | None = None,
              iterations: int | None = None, prior: np.ndarray | None = None,
              dt: float | None = None) -> LOResult:
        """Algorithm 1 from ``params0``, optimising the parameters of ``parts`` (default:
        every part; the others are held and not rendered). ``prior`` (n_params,): the
        smoothness term's reference ``2 q_{t-1} - q_{t-2}`` (module docstring; None: no
        term); ``dt``: the time since the previous frame [s] (:meth:`smoothness_weights`)."""
        from threadpoolctl import threadpool_limits

        # small dense products: BLAS threads only spin against each other on a busy machine
        with threadpool_limits(1):
            return self._solve(params0, frame, parts, iterations, prior, dt)

    def _solve(self, params0: np.ndarray, frame: FrameData, parts: Sequence[int] | None,
               iterations: int | None, prior: np.ndarray | None,
               dt: float | None = None) -> LOResult:
        t0 = time.perf_counter()
        m, cfg = self.model, self.cfg
        parts = list(range(len(m.part_names))) if parts is None else list(parts)
        cols = np.concatenate([np.arange(m.slices[m.part_names[p]].start,
                                         m.slices[m.part_names[p]].stop) for p in parts]) \
            if parts else np.zeros(0, np.int64)
        x = m.clip(m.check(params0))
        w = self.smoothness_weights(prior, cols, dt)
        smooth = None if w is None else (m.check(prior), w)
        coll = CollisionPairs.empty()
        coll_parts = [(a, b) for a, b in self.collision_parts if a in parts and b in parts]
        counts = {k: 0 for k in KIND_NAMES}
        mu = 1e-3
        cost = 0.0
        n_iter = cfg.iterations if iterations is None else iterations
        trace, costs = [], []
        for it in range(n_iter):
            state = m.pose(x)
            # the edge gate narrows over the iterations, from edge_max_px to a third of it,
            # reached after gate_narrow_share of them (this project's schedule; seed 002
            # gives none)
            span = max(cfg.gate_narrow_share * (n_iter - 1), 1e-9)
            gate = cfg.edge_max_px * (1.0 - (2.0 / 3.0) * min(it / span, 1.0))
            corr, _, _ = self.correspondences(state, frame, parts, gate, support=False)
            flow = frame.flow.subset(np.isin(frame.flow.part, parts))
            corr = Correspondences.concat([corr, flow])
            corr = self._reject_outliers(corr, state)
            corr = self._robust_weights(x, corr)
            if cfg.use_collisions and coll_parts:
                coll = coll.union(detect_collisions(m, state, coll_parts,
                                                    cfg.collision_depth_m))
            if not len(corr) and not len(coll) or not len(cols):
                break
            x, cost, mu = self._lm_steps(x, corr, coll, cols, cfg.inner_steps, mu, smooth)
            trace.append(x.copy())
            costs.append(cost)
        for k, name in enumerate(KIND_NAMES):
            counts[name] = int(np.sum(corr.kind == k)) if n_iter and len(cols) else 0
        state = m.pose(x)
        _, n_edge, n_sup = self.correspondences(state, frame, parts)
        support = np.where(n_edge > 0, n_sup / np.maximum(n_edge, 1), 0.0)
        return LOResult(x, cost, support, n_edge, counts, len(coll),
                        time.perf_counter() - t0,
                        np.array(trace) if trace else np.zeros((0, len(x))), np.array(costs))

    def support(self, params: np.ndarray, frame: FrameData, parts: Sequence[int]
                ) -> tuple[np.ndarray, np.ndarray]:
        """Per part: the share of its model edge vertices with an image edge within
        ``support_px``, and how many model edge vertices were seen (all cameras)."""
        state = self.model.pose(params)
        _, n_edge, n_sup = self.correspondences(state, frame, parts)
        return np.where(n_edge > 0, n_sup / np.maximum(n_edge, 1), 0.0), n_edge
