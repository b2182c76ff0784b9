"""Frame-to-frame multi-view tracking of hands and objects (seed 002 Algorithm 1 per frame).

:class:`MultiviewTracker` holds the combined model's estimate and, per synchronised group of
images, runs the local optimiser (:mod:`hand_capture.multiview.lo`) from the previous frame's
estimate (theta_0 of Algorithm 1), with optical flow from the previous group's images.

Lost parts. After each frame every part gets a *support*: the share of its rendered model
edge vertices (over all cameras) that an image edge of similar orientation lies within
``support_px`` of. A part with too few model edges in view or too little support for
``lost_frames`` frames in a row is flagged LOST: its parameters go back to its last good
estimate, it is no longer optimised nor rendered, and its status and confidence say so (a lost
part is never reported as tracked). Every frame, each lost part is searched for: candidates
are its last good pose, that pose shifted by +-``search_m`` along each world axis, and the
first-frame initialiser's proposal when one is given; the best-supported candidate is refined
by a short local optimisation and the part is TRACKED again when the support passes
``recover_support``.

Objects' region score (:mod:`~hand_capture.multiview.region`, seed 000 eq. 4-5 per object):
each object's colour model is learned on its first frame with a supported outline (the first
frame's known pose); the share of its rendered silhouette in its colour then also flags it
LOST (below ``lost_region``), an object is searched for in the very frame it is lost, its
candidates include the placement of the visual hull of its colour blobs
(:func:`~hand_capture.multiview.hull.place_object`) and are ranked by support x region, and a
re-found object needs ``recover_region`` too. A tracked object whose score is below
``check_region`` (a pose half off the object's image region still fits its outline's edges,
e.g. a ball that flew off while the solve stopped beside the hand) is checked against its
colour hull's placement: refined, the better by support x region is kept (RECOVERED).
Edge support alone cannot tell a ball's pose on clutter circles or hand edges from its true
one (validation figures in docs/experiments/multiview.md).

Start of a frame: the previous estimate (seed 002), plus, for the objects no hand holds
(none within ``held_m``), their last frame-to-frame motion (``predict_objects``: a thrown
ball moves 4-6 cm a frame at 30 fps); an object re-found in the frame after a tracked one
keeps its motion since that frame.

Confidence of a tracked part: its support times the share of the rig's cameras present in
the group (a camera missing from a group lowers it; tracking continues on the others).

:func:`check_group` screens a group before tracking: a missing camera, an empty or malformed
image or non-finite calibration drop that camera's view, each counted with its reason; a group
with no usable view is rejected as a whole.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model.joints import root_angles_from_matrix
from hand_capture.multiview.lo import LocalOptimizer, LOConfig, LOResult
from hand_capture.multiview.region import ObjectRegions
from hand_capture.multiview.rig import Rig
from hand_capture.multiview.scene_model import SceneModel, SceneState

__all__ = ["GroupCheck", "GroupRunner", "LOST", "MultiviewTracker", "MultiviewTrackerConfig",
           "PartEstimate", "RECOVERED", "TRACKED", "TrackResult", "check_group"]

TRACKED, RECOVERED, LOST = "tracking", "recovering", "lost"

#: a detector of salient image points: ``detect(rgb) -> (points (k, 2) [px], scores (k,))``
Detector = object
#: a first-frame initialiser: ``(images, model, part) -> the part's parameters or None``
Initializer = Callable[[Mapping[str, np.ndarray | None], SceneModel, int], np.ndarray | None]


@dataclass(frozen=True)
class MultiviewTrackerConfig:
    """Lost-part flagging and recovery (see the module docstring)."""

    lost_support: float = param(0.3, "support below which a frame counts as bad", lo=0.0,
                                hi=1.0)
    min_edges: int = param(25, "model edge vertices in view below which a frame is bad",
                           lo=0, hi=100000)
    lost_frames: int = param(1, "bad frames in a row that flag a part LOST (1: a bad frame "
                             "is never reported as tracked)", lo=1, hi=100)
    recover_support: float = param(0.55, "support a re-found part must reach", lo=0.0,
                                   hi=1.0)
    search_m: float = param(0.08, "shift of the recovery candidates along each axis [m]",
                            lo=0.0, hi=1.0)
    recover_iterations: int = param(8, "local optimisation iterations of a recovery", lo=1,
                                    hi=100)
    predict: float = param(0.0, "share of the last frame-to-frame motion added to the start "
                           "of the next frame (0: start at the previous estimate, seed 002)",
                           lo=0.0, hi=1.0)
    predict_objects: float = param(1.0, "the same for the objects' 6 parameters (a thrown "
                                   "or passed object keeps its velocity; hands change "
                                   "theirs)", lo=0.0, hi=1.0)
    held_m: float = param(0.01, "an object with a vertex this near a hand's is held: not "
                          "predicted [m]", lo=0.0, hi=0.2)
    lost_region: float = param(0.35, "an object's region score (share of its rendered "
                               "silhouette in its own colour, seed 000 eq. 4-5) below which "
                               "a frame counts as bad (0: edge support alone)", lo=0.0, hi=1.0)
    recover_region: float = param(0.45, "region score a re-found object must reach", lo=0.0,
                                  hi=1.0)
    hull_box_m: float = param(0.2, "half size of the box around the estimate (or last good "
                              "pose) where an object's colour hull is carved [m]", lo=0.02,
                              hi=1.0)
    check_region: float = param(0.75, "a tracked object's region score below which the "
                                "placement of its colour hull is tried against the estimate "
                                "(the better by support x region, refined, is kept)",
                                lo=0.0, hi=1.0)
    carry_lost_m: float = param(0.0, "an object flagged LOST within this distance of a "
                                "hand (at its last good pose) is carried by that hand's palm "
                                "motion while lost: its reported pose and the search around "
                                "it follow the hand [m] (0: held where it was lost)", lo=0.0,
                                hi=0.2)
    check_margin: float = param(0.0, "a check replaces the estimate only when the colour "
                                "hull's refined placement scores above the estimate's "
                                "support x region times (1 + this) (0: any gain)", lo=0.0,
                                hi=10.0)
    check_agree_m: float = param(0.015, "a check keeps the estimate without evaluating the "
                                 "colour hull's placement when it lies this near [m]",
                                 lo=0.0, hi=1.0)
    object_colours: bool = param(True, "learn each object's colour model on its first "
                                 "well-supported frame: region score, the colour hull's "
                                 "recovery candidate and the candidates ranked by support x "
                                 "region (False: edge support alone)")

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class PartEstimate:
    """One part's estimate of a frame.

    Attributes:
        name: ``'right'``, ``'left'`` or the object's name.
        status: :data:`TRACKED`, :data:`RECOVERED` (re-found this frame) or :data:`LOST`.
        confidence: 0..1 (0 when lost).
        params: the part's parameters (hand: 27-DoF world pose; object: 6 values).
        support: share of its model edges supported by image edges.
        region: an object's region score (share of its rendered silhouette in its own
            colour, :mod:`~hand_capture.multiview.region`); NaN for hands and objects
            without a colour model or out of view.
    """

    name: str
    status: str
    confidence: float
    params: np.ndarray
    support: float
    region: float = float("nan")

    @property
    def tracked(self) -> bool:
        return self.status != LOST


@dataclass
class TrackResult:
    """One frame's output of :meth:`MultiviewTracker.step`."""

    params: np.ndarray
    parts: list[PartEstimate]
    cameras_present: int
    seconds: float
    lo: LOResult | None = None
    state: SceneState | None = None


@dataclass
class GroupCheck:
    """Outcome of :func:`check_group`: the usable images (None = dropped) and the reasons."""

    images: dict[str, np.ndarray | None]
    rejected: dict[str, str] = field(default_factory=dict)

    @property
    def usable(self) -> int:
        return sum(v is not None for v in self.images.values())


def check_group(rig: Rig, images: Mapping[str, object],
                infos: Mapping[str, object] | None = None) -> GroupCheck:
    """Screen one synchronised group: each rig camera's image must be present, an
    (H, W, 3) uint8 array of the rig's resolution, not empty; its calibration (``infos``:
    camera -> any of ``k``/``d``/``p`` arrays, e.g. a CameraInfo's fields) finite.
    Unusable views become None with a reason."""
    out: dict[str, np.ndarray | None] = {}
    why: dict[str, str] = {}
    for cam in rig.cameras:
        img = images.get(cam.name)
        reason = ""
        if img is None:
            reason = "missing from the group"
        else:
            a = np.asarray(img)
            k = cam.intrinsics
            if a.size == 0:
                reason = "empty image"
            elif a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
                reason = f"not an (H, W, 3) uint8 image: {a.shape} {a.dtype}"
            elif a.shape[:2] != (k.height, k.width):
                reason = f"size {a.shape[1]}x{a.shape[0]}, the rig says {k.width}x{k.height}"
        if not reason and infos is not None and cam.name in infos:
            info = infos[cam.name]
            vals = [np.asarray(v, dtype=float).ravel() for v in
                    (getattr(info, f, None) if not isinstance(info, Mapping) else info.get(f)
                     for f in ("k", "d", "p")) if v is not None]
            if any(not np.all(np.isfinite(v)) for v in vals):
                reason = "non-finite CameraInfo"
        if reason:
            out[cam.name] = None
            why[cam.name] = reason
        else:
            out[cam.name] = np.asarray(img)
    return GroupCheck(out, why)


class MultiviewTracker:
    """Tracks the scene frame to frame; see the module docstring.

    Args:
        model: the combined model.
        rig: the cameras (names as in the groups).
        lo_config: local optimiser settings.
        config: lost / recovery settings.
        detector: salient point detector (``detect(rgb) -> (points, scores)``), or None
            (then detections may be passed to :meth:`step`).
        initializer: first-frame initialiser (see :data:`Initializer`), or None; one with
            ``learn(images, model, params)`` is taught on the first tracked frame and one
            with ``set_prior(params)`` is told the configuration before each search.
    """

    def __init__(self, model: SceneModel, rig: Rig, lo_config: LOConfig | None = None,
                 config: MultiviewTrackerConfig | None = None, detector: Detector | None = None,
                 initializer: Initializer | None = None) -> None:
        self.model = model
        self.rig = rig
        self.lo = LocalOptimizer(model, rig, lo_config)
        self.cfg = config or MultiviewTrackerConfig()
        self.detector = detector
        self.initializer = initializer
        #: the objects' colour models and region scores (seed 000 eq. 4-5)
        self.regions = ObjectRegions(model, rig)
        n = len(model.part_names)
        self.params: np.ndarray | None = None
        self.status = [TRACKED] * n
        self._bad = np.zeros(n, dtype=np.int64)
        self._last_good: np.ndarray | None = None
        self._prev: tuple[Mapping[str, np.ndarray | None], SceneState] | None = None
        #: the previous group's flow-ignore masks (see :meth:`step`)
        self._prev_ignore: dict[str, np.ndarray] | None = None
        self._velocity: np.ndarray | None = None
        #: the hand carrying each lost object (``carry_lost_m``)
        self._holder: dict[int, int] = {}
        self.frames = 0

    def reset(self, params: np.ndarray) -> None:
        """Start from a known configuration (the first frame's pose, e.g. from ISA)."""
        p = self.model.clip(self.model.check(params))
        self.params = p.copy()
        self._last_good = p.copy()
        self.status = [TRACKED] * len(self.model.part_names)
        self._bad[:] = 0
        self._prev = None
        self._prev_ignore = None
        self._velocity = None
        self._holder = {}

    def _slice(self, p: int) -> slice:
        return self.model.slices[self.model.part_names[p]]

    def step(self, images: Mapping[str, np.ndarray | None],
             detections: Mapping[str, np.ndarray] | None = None,
             flow_ignore: Mapping[str, np.ndarray] | None = None,
             dt: float | None = None) -> TrackResult:
        """Track one synchronised group (camera name -> RGB image, None = missing).

        ``dt``: the time since the previous group [s] (the smoothness term's weight falls
        below its frame rate, :meth:`LocalOptimizer.smoothness_weights`; None: the
        reference rate's).

        ``flow_ignore``: camera -> (H, W) bool mask of this group's pixels whose optical
        flow is not to be considered, kept with the images for the next group's flow too
        (:meth:`LocalOptimizer.prepare`). Only a benchmark knows such pixels: seed 002 sec.
        5.1 left out the optical flow features of the structural-noise circles it drew.
        None (the node, ``track-multiview``, a real camera): every pixel counts."""
        t0 = time.perf_counter()
        m = self.model
        present = [c.name for c in self.rig.cameras if images.get(c.name) is not None]
        if not present:
            raise InputError("a group with no usable camera image")
        if self.params is None:
            self._initialise(images)
        assert self.params is not None and self._last_good is not None
        learn = getattr(self.initializer, "learn", None)
        if callable(learn) and self.frames == 0:
            learn(images, m, self.params)   # e.g. the hull's colour model, on a known frame
        if detections is None and self.detector is not None:
            detections = {c: np.asarray(self.detector.detect(images[c])[0]) for c in present}
        active = [p for p, s in enumerate(self.status) if s != LOST]
        before = self.params.copy()
        frame = self.lo.prepare(images, detections, self._prev, active, flow_ignore,
                                self._prev_ignore)
        if self.lo.colour is None and self._hands_in_place(frame, active):
            # the hands' colours, learned where the estimate matches the images
            if self.lo.learn_colours(images, self.params):
                frame = self.lo.prepare(images, detections, self._prev, active, flow_ignore,
                                        self._prev_ignore)
        maps = self.regions.maps(images) if self.cfg.object_colours else {}
        res = None
        if active:
            start = self.params
            gain = self._predict_gain(active)
            if self._velocity is not None and np.any(gain > 0):
                start = self.model.clip(self.params + gain * self._velocity)
            # seed 000 sec. 4.3's smoothness reference 2 q_{t-1} - q_{t-2} (zero motion
            # after a reset, and for a part lost or re-found in the last frame)
            prior = self.params if self._velocity is None else self.params + self._velocity
            res = self.lo.solve(start, frame, active, prior=prior, dt=dt)
            self._velocity = res.params - self.params
            self.params = res.params
        support = np.zeros(len(m.part_names))
        region = np.full(len(m.part_names), np.nan)
        recovered: set[int] = set()
        for p in active:
            sl = self._slice(p)
            s, n_edge = float(res.support[p]), float(res.model_edges[p])
            support[p] = s
            if p in maps:
                region[p] = self.regions.score(self.params, maps, p, active)[0]
            if n_edge < self.cfg.min_edges or s < self.cfg.lost_support or \
                    region[p] < self.cfg.lost_region:     # NaN (no score) compares False
                self._bad[p] += 1
                if self._bad[p] >= self.cfg.lost_frames:
                    self.status[p] = LOST
                    self.params[sl] = self._last_good[sl]
                    if p >= m.n_hands and self.cfg.carry_lost_m > 0:
                        self._holder.pop(p, None)
                        h = self._nearest_hand(m.pose(self.params), p, self.cfg.carry_lost_m)
                        if h is not None:
                            self._holder[p] = h
            else:
                self._bad[p] = 0
                self._last_good[sl] = self.params[sl]
        self._carry_lost(before)
        if self.cfg.object_colours:
            # each object's colours, learned on its first frame with a supported outline
            good = [p for p in active if p >= m.n_hands and self.status[p] != LOST
                    and p not in self.regions.colours]
            if good and self.regions.learn(images, self.params, good):
                maps = self.regions.maps(images)
        # a doubtful object (little of its silhouette in its colour): its colour hull's
        # placement against the estimate
        for p in [p for p in active if p in maps and self.status[p] != LOST
                  and region[p] < self.cfg.check_region]:
            with self._draws_kept():
                got = self._recover(p, images, frame, maps, current=(support[p], region[p]))
            if got is not None:
                recovered.add(p)
                support[p], region[p] = got
        prior = getattr(self.initializer, "set_prior", None)
        # lost parts are searched for from the next frame on; an object with a colour model
        # at once (its colour hull proposes where it went)
        for p in [p for p, s in enumerate(self.status) if s == LOST and
                  (p not in active or p in maps)]:
            if callable(prior):
                prior(self.params)
            with self._draws_kept(p in maps):
                got = self._recover(p, images, frame, maps)
            if got is not None:
                recovered.add(p)
                support[p], region[p] = got
        if self._velocity is not None:
            for p in range(len(m.part_names)):
                sl = self._slice(p)
                if p in recovered and p in active:
                    # re-found in the frame after a tracked one: its motion since then
                    self._velocity[sl] = self.params[sl] - before[sl]
                elif self.status[p] == LOST or p in recovered:
                    self._velocity[sl] = 0.0   # no motion carried by a lost or re-found part
        share = len(present) / len(self.rig.cameras)
        parts = []
        for p, name in enumerate(m.part_names):
            st = RECOVERED if p in recovered else self.status[p]
            conf = 0.0 if st == LOST else float(np.clip(support[p] * share, 0.0, 1.0))
            parts.append(PartEstimate(name, st, conf, self.params[self._slice(p)].copy(),
                                      float(support[p]), float(region[p])))
        state = m.pose(self.params)
        self._prev = (dict(images), state)
        self._prev_ignore = None if flow_ignore is None else dict(flow_ignore)
        self.frames += 1
        return TrackResult(self.params.copy(), parts, len(present), time.perf_counter() - t0,
                           res, state)

    @contextmanager
    def _draws_kept(self, keep: bool = True) -> Iterator[None]:
        """The local optimiser's random subsampling draws as they were before the block
        (``keep``): an object's colour checks and searches, which evaluate and refine
        candidates, do not shift the draws of the frames after them, so where they change
        nothing the tracking is the same as without them."""
        state = self.lo._rng.bit_generator.state if keep else None
        try:
            yield
        finally:
            if state is not None:
                self.lo._rng.bit_generator.state = state

    def _predict_gain(self, active: list[int]) -> np.ndarray:
        """(n_params,) share of the last frame-to-frame motion added to each parameter's
        start: ``predict`` for the hands, ``predict_objects`` for the free objects (none
        of their vertices within ``held_m`` of a hand's at the current estimate: a held
        object moves with the hand, which is not predicted, and starting it ahead would
        push it into the fingers), 0 for the parts not ``active`` (lost: held at their
        last good pose)."""
        m = self.model
        g = np.zeros(m.n_params)
        state = m.pose(self.params) if self.cfg.predict_objects > 0 else None
        for p in active:
            if p < m.n_hands:
                g[self._slice(p)] = self.cfg.predict
            elif state is not None and not self._held(state, p):
                g[self._slice(p)] = self.cfg.predict_objects
        return g

    def _nearest_hand(self, state: SceneState, part: int, within_m: float,
                      skip_lost: bool = True) -> int | None:
        """The hand with a vertex nearest to object ``part``'s at ``state``, if within
        ``within_m`` [m] (lost hands left out when ``skip_lost``); else None."""
        from scipy.spatial import cKDTree

        tree = cKDTree(state.vertices[part])
        best, best_d = None, math.inf
        for h in range(self.model.n_hands):
            if skip_lost and self.status[h] == LOST:
                continue
            d, _ = tree.query(state.vertices[h], distance_upper_bound=within_m)
            if np.isfinite(d).any() and float(d.min()) < best_d:
                best, best_d = h, float(d.min())
        return best

    def _carry_lost(self, before: np.ndarray) -> None:
        """Each lost object with a holder (``carry_lost_m``) moved by its hand's palm
        motion from ``before`` to the current estimate (its last good pose and the
        estimate, which a lost part keeps at the last good pose)."""
        m = self.model
        for p, h in list(self._holder.items()):
            if self.status[p] != LOST or self.status[h] == LOST:
                del self._holder[p]      # re-found, or the hand is gone too
                continue
            sl, hand = self._slice(p), m.hands[h]
            a = hand.forward(m.part_params(before, h)).joint_frames[0]
            b = hand.forward(m.part_params(self.params, h)).joint_frames[0]
            T = b @ np.linalg.inv(a) @ m.object_transform(self._last_good[sl])
            x = self.params.copy()
            x[sl] = [*T[:3, 3], *root_angles_from_matrix(T[:3, :3])]
            self.params[sl] = self._last_good[sl] = m.clip(x)[sl]

    def _held(self, state: SceneState, part: int) -> bool:
        """Whether object ``part`` is within ``held_m`` of a hand at ``state``."""
        return self._nearest_hand(state, part, self.cfg.held_m, skip_lost=False) is not None


    def _hands_in_place(self, frame: object, active: list[int]) -> bool:
        """Every tracked hand's outline at the current estimate is supported by the images
        (support and edge count as for a tracked part): its silhouettes may teach the colour
        model. A start far from the hands (a guessed first pose) teaches nothing."""
        hands = [p for p in active if p < self.model.n_hands]
        if not hands or self.lo.cfg.colour_check_px <= 0:
            return False
        s, n_edge = self.lo.support(self.params, frame, hands)
        return all(s[p] >= self.cfg.lost_support and n_edge[p] >= self.cfg.min_edges
                   for p in hands)

    def _initialise(self, images: Mapping[str, np.ndarray | None]) -> None:
        if self.initializer is None:
            raise InputError("no initial pose: call reset(params) with the first frame's "
                             "configuration or give the tracker an initializer")
        p = np.zeros(self.model.n_params)
        for k in range(len(self.model.part_names)):
            got = self.initializer(images, self.model, k)
            if got is None:
                raise InputError(f"the initializer found no {self.model.part_names[k]}")
            p[self._slice(k)] = got
        self.reset(p)

    def _recover(self, p: int, images: Mapping[str, np.ndarray | None], frame: object,
                 maps: Mapping[int, Mapping[int, np.ndarray]],
                 current: tuple[float, float] | None = None) -> tuple[float, float] | None:
        """Search for lost part ``p`` around its last good pose, at the initialiser's
        proposal and, for an object with a colour model, where the visual hull of its
        colour blobs places it; candidates are ranked by edge support times region score
        (support alone without a score). Returns its support and region score when it is
        found again (both high enough after a short local optimisation), else None.
        ``current``: the support and region score of a tracked part's estimate; only
        the colour hull's placement is tried, and it must beat them after refinement."""
        from hand_capture.multiview.hull import place_object

        cfg = self.cfg
        sl = self._slice(p)
        cands = []
        if current is None:
            base = self._last_good[sl].copy()
            cands.append(base)
            for ax in range(3):
                for sgn in (-1.0, 1.0):
                    c = base.copy()
                    c[ax] += sgn * cfg.search_m
                    cands.append(c)
            if self.initializer is not None:
                got = self.initializer(images, self.model, p)
                if got is not None:
                    cands.append(np.asarray(got, dtype=float))
        if p in maps:
            # the hull is carved in a box around the estimate (the last good pose when
            # lost): the whole table at 1 cm costs 0.7 s, this box 0.3 s
            near = (self.params if current is not None else self._last_good)[sl][:3]
            try:
                got, _ = place_object(self.regions.blob_masks(maps, p), self.rig,
                                      self.model.objects[p - self.model.n_hands].vertices,
                                      voxel_m=0.01, lo=near - cfg.hull_box_m,
                                      hi=near + cfg.hull_box_m)
            except InputError:
                got = None      # no consistent colour blob in enough views
            if current is not None and (got is None or
                                        np.linalg.norm(got[:3] - near) < cfg.check_agree_m):
                return None     # the colour blobs put it where it is (or nowhere)
            if got is not None:
                cands.append(got)
        tracked = [q for q, s in enumerate(self.status) if s != LOST and q != p]
        best, best_key = None, -1.0 if current is None else current[0] * current[1]
        for c in cands:
            x = self.params.copy()
            x[sl] = c
            s, n_edge = self.lo.support(x, frame, [*tracked, p])
            if n_edge[p] < cfg.min_edges or s[p] < 0.5 * cfg.recover_support:
                continue
            r = self.regions.score(x, maps, p, tracked)[0]   # NaN without a colour model
            key = float(s[p]) * (float(r) if np.isfinite(r) else 1.0)
            if key > best_key:
                best, best_key = x, key
        if best is None:
            return None
        res = self.lo.solve(best, frame, [p], iterations=cfg.recover_iterations)
        r = self.regions.score(res.params, maps, p, tracked)[0]
        if res.model_edges[p] < cfg.min_edges or res.support[p] < cfg.recover_support or \
                r < cfg.recover_region:
            return None
        if current is not None and \
                res.support[p] * r <= current[0] * current[1] * (1.0 + cfg.check_margin):
            return None
        self.params[sl] = res.params[sl]
        self._last_good[sl] = res.params[sl]
        self.status[p] = TRACKED
        self._bad[p] = 0
        return float(res.support[p]), float(r)


#: rejection reasons counted by :class:`GroupRunner` (a camera's view, or a whole group)
REJECT_KEYS = {"missing from the group": "missing_camera", "empty image": "empty_image",
               "non-finite CameraInfo": "bad_camera_info"}


class GroupRunner:
    """Screens each synchronised group (:func:`check_group`), counts and logs every dropped
    view by reason (``missing_camera``, ``empty_image``, ``bad_image``, ``bad_camera_info``)
    and every group with no usable view (``group``), and tracks the rest. The node and the
    offline tool share it.

    Args:
        tracker: the tracker.
        log: called with one line per rejection (default: this module's logger, WARNING).
    """

    def __init__(self, tracker: MultiviewTracker,
                 log: Callable[[str], None] | None = None) -> None:
        import logging
        from collections import Counter

        self.tracker = tracker
        self.rejected: Counter[str] = Counter()
        self.groups = 0
        self.tracked = 0
        self._log = log or logging.getLogger(__name__).warning
        self._last_stamp: float | None = None   # of the last group tracked [s]

    def process(self, images: Mapping[str, object], infos: Mapping[str, object] | None = None,
                stamp: float = 0.0) -> TrackResult | None:
        """Track one group (``stamp``: its time [s]; the interval since the last group
        tracked is the tracker's ``dt``); None when the whole group was rejected."""
        self.groups += 1
        chk = check_group(self.tracker.rig, images, infos)
        for cam, why in chk.rejected.items():
            key = REJECT_KEYS.get(why, "bad_image")
            self.rejected[key] += 1
            self._log(f"group at {stamp:.3f} s: camera {cam} dropped ({why}); "
                      f"{key} = {self.rejected[key]}")
        if chk.usable == 0:
            self.rejected["group"] += 1
            self._log(f"group at {stamp:.3f} s rejected: no usable view; "
                      f"group = {self.rejected['group']}")
            return None
        last, self._last_stamp = self._last_stamp, stamp
        dt = None if last is None or not stamp > last else stamp - last
        res = self.tracker.step(chk.images, dt=dt)
        self.tracked += 1
        return res
