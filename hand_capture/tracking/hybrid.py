"""Hybrid tracking (ch. II.5.1): regression candidates + previous pose, ICP, selection.

Per frame (steps 1-6 of the dissertation):

1. segment the hand; the palm regressor (initialised by PCA) gives several palm modes; each
   is refined by one palm-only Gauss-Newton iteration;
2. the finger regressor runs on each refined palm -> full candidates;
3. the previous pose, after one palm-only iteration, joins the pool;
4. the candidates are refined by Gauss-Newton ICP (``icp_iterations``; to stay real time on a
   CPU the pool is first screened by its cost and the ``refine_top`` best are refined);
5. the candidate with the lowest cost ``E_c = l1 E_d + l2 delta ||q - q_prev||^2``
   (eq. II.20) wins;
6. the success flag ``delta = E_d < tau`` (eq. II.19) is stored for the next frame.

Speed: the poses of one step go through the model together (``ModelTracker.refine_batch``
and ``depth_costs``: one FK pass and one skinning product per iteration for all of them), so
step 4's three Gauss-Newton iterations per candidate fit a 30 frames/s budget on two cores.

After a loss (blank or occluded frames, delta = 0) the temporal term is off and the
regressor's candidates re-initialise the tracker by themselves: no manual reset.

Cheaper settings (the teleop graph's, ``config/teleop.yaml``): with ``regress_every`` n > 1
steps 1-2 run only every n-th frame while the previous frame passed eq. II.19 (and, with
``regress_above_mm``, whenever its E_d was above that doubtful level); the frames in
between refine the previous pose alone (steps 3-6), so the ICP from the previous pose tracks
and the regression re-anchors it. After a failure the regression runs on every frame, so
recovery is automatic as above. ``refine_top`` 1, fewer ``icp_iterations`` and no
``palm_iterations`` cut the rest; ``hand-suite bench tracking`` measures the trade-off (row
``teleop``). A pool no larger than ``refine_top`` is not screened (all of it is refined).
With ``defer_regression`` a regression due while tracking is taken off the frame's latency:
the frame is tracked from the previous pose and published first, then
:meth:`HybridTracker.run_deferred` runs steps 1-2 on the same frame and keeps its best
candidate for the next frame's pool when it fits that frame better than the tracked pose.

Departures for real hands (issue 13): while a hand is tracked, step 1's segment is the
depth band's component holding most pixels near the previous pose's bones, the band started
at the hand when something nearer the camera elsewhere would leave it behind
(``track_roi_m``, :func:`~hand_capture.tracking.preprocess.segment_hand`'s ``roi``; the
dissertation takes the nearest object for the hand, so another hand or an object coming
nearer the camera took over the tracking); the pixels a per-pixel classifier calls arm are
dropped first (``armseg.remove_arm``, trained on the suite's renders with forearms), then
the forearm is cut off the segment (``preprocess.cut_forearm``: at the previous pose's wrist
while tracking, else from the cloud's shape; after a cloud-only cut the selected pose's
wrist cuts again and the pose is refined on those points); the ICP data term is
Huber-weighted (``robust_mm``); tau of eq. II.19 follows the calibration fit
(:attr:`HybridTracker.tau_mm`, :meth:`set_calibration`); the template's wrist stub is
optional in the model-to-data pairs (``wrist_optional``, ``icp.optional_vertices``); step 5
selects finger by finger among the refined candidates (``finger_swap``,
:meth:`HybridTracker._swap_fingers`: on another surface the regression often gets one finger
wrong in the best candidate and right in another), each finger also tried straight and
curled (``finger_postures``: a finger that no candidate has right); step 2 also regresses
the fingers on the previous pose's palm (``regress_previous``: a finger tracked wrong while
the palm is right gets a regressed alternative on the palm the tracker holds); a frame
without a tracked previous pose (the first, any after a loss) searches wider, with
``acquire_modes`` palm modes in step 1 and ``acquire_refine_top`` candidates refined in
step 4, each for ``acquire_icp_iterations`` Gauss-Newton iterations (no previous pose
carries the fit there, the regressed candidates start far off, and a wrong start is kept
for many frames), and so does a tracked frame whose previous E_d was above
``acquire_above_tau`` of tau (a wrong acquisition that still passes eq. II.19; its
candidates are refined without the smoothness term, which would hold them at the pose in
doubt, and that pose stays among them);
step 4 keeps a screened candidate as it was when its refinement raised its cost
(``keep_unrefined``: while tracking, the smoothness term of eq. II.24 holds every candidate
near the previous pose, so a regressed candidate that rightly leaves a wrong previous pose
comes out of the refinement worse than it went in); E_d of eq. II.19 / II.20 past the
wrist counts the model's wrist stub only where data lies on a frame without a forearm cut
off, and the arm past each pose's wrist only where the model is on a frame with one
(``cost_stub_optional``, ``cost_arm_optional``; ``ModelTracker.depth_costs``); with
``ensemble`` a second regressor trained on another seed and surfaces (a
:class:`~hand_capture.tracking.regressor.RegressorSet`, :func:`load_regressor`) adds its palm
modes in step 1 and its finger regression on every palm in step 2 (on every frame, or with
``ensemble_frames`` "acquire" on the frames that search wide only; the held-out misses are
the search's: the true pose, offered as a candidate, wins most failing frames).

Modes ``icp`` (model-based only, from an initial pose) and ``regressor`` (per-frame
regression only, best mode by E_d) are the ablations of Figure II.18.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.model import (
    FINGER_DOFS,
    JOINT_LIMITS,
    JOINT_NAMES,
    N_DOF,
    HandModel,
    HandShape,
)
from hand_capture.model.joints import root_rotation_matrix
from hand_capture.tracking.armseg import ArmClassifier, load_arm_classifier, remove_arm
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.icp import ModelTracker, cost_grid, downsampled_depth, wrap_angles
from hand_capture.tracking.preprocess import (
    HandObservation,
    cut_forearm,
    segment_hand,
    split_surfaces,
    union_observation,
)
from hand_capture.tracking.regressor import (
    DepthLookup,
    HandRegressor,
    ModelFrames,
    RegressorSet,
    palm_init_pca,
)

__all__ = ["HybridTracker", "TrackResult", "default_model_path", "load_regressor", "model_path",
           "regressor_files", "second_model_path", "SECOND_MODEL_NAME", "STAGES"]

STAGES = ("preprocess", "regression", "icp", "selection")
#: the second regressor's file name in ``data/tracker`` (``ensemble``; ``hand-suite train
#: tracker --second`` writes it)
SECOND_MODEL_NAME = "regressor_tubes.npz"


#: the hand's bones as keypoint pairs (KEYPOINT_NAMES order: wrist, then per finger its root
#: to its tip), with the knuckle line across the palm, for ``track_roi_m``: (23, 2)
_SKELETON = np.array([(0, 1), (1, 2), (2, 3), (3, 4)]
                     + [(a, b) for f in range(5, 21, 4)
                        for a, b in ((0, f), (f, f + 1), (f + 1, f + 2), (f + 2, f + 3))]
                     + [(5, 9), (9, 13), (13, 17)])


#: flexion angles of the straight and the curled posture of ``finger_postures`` [rad], by
#: the short joint name (abduction joints keep the selected pose's angle)
_POSTURES: tuple[dict[str, float], ...] = (
    {"mcp_flex": 0.0, "pip_flex": 0.0, "dip_flex": 0.0, "tm_flex": 0.0, "ip_flex": 0.0},
    {"mcp_flex": 1.2, "pip_flex": 1.4, "dip_flex": 0.9, "tm_flex": 0.6, "ip_flex": 0.9},
)


#: the MCP abduction DoFs of the four fingers (not the thumb), for ``abduction_trial``
_FINGER_ABD = np.array([i for i, n in enumerate(JOINT_NAMES)
                        if n.endswith("_mcp_abd") and not n.startswith("thumb")])


#: the MCP, PIP and DIP flexion DoFs of each of the four fingers (not the thumb), for
#: ``exchange_trial``: (4, 3)
_FINGER_FLEX = np.array([[JOINT_NAMES.index(f"{f}_{j}_flex") for j in ("mcp", "pip", "dip")]
                         for f in ("index", "middle", "ring", "little")])


def _exchanged_flexions(q: np.ndarray) -> list[np.ndarray]:
    """``q`` with the flexion angles of two of the four fingers exchanged, for each of the
    six pairs, within the joint limits (``exchange_trial``)."""
    out = []
    for i in range(4):
        for j in range(i + 1, 4):
            t = q.copy()
            a, b = _FINGER_FLEX[i], _FINGER_FLEX[j]
            t[a], t[b] = q[b], q[a]
            out.append(np.clip(t, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1]))
    return out


def _finger_postures(q: np.ndarray, dofs: np.ndarray) -> list[np.ndarray]:
    """The straight and curled alternatives of one finger (``dofs`` of the pose ``q``):
    its flexion joints set to :data:`_POSTURES`, clipped to the joint limits."""
    out = []
    for posture in _POSTURES:
        a = q[dofs].copy()
        for k, i in enumerate(dofs):
            short = JOINT_NAMES[i].split("_", 1)[1]
            if short in posture:
                a[k] = posture[short]
        out.append(np.clip(a, JOINT_LIMITS[dofs, 0], JOINT_LIMITS[dofs, 1]))
    return out


def default_model_path() -> Path:
    """``data/tracker/regressor.npz`` in the source tree or the installed share folder."""
    from hand_capture.paths import data_dir

    return data_dir() / "tracker" / "regressor.npz"


def model_path(cfg: TrackerConfig) -> Path:
    """The regressor file ``cfg`` names (``model_file``, ``~`` expanded), else
    :func:`default_model_path`."""
    return Path(cfg.model_file).expanduser() if cfg.model_file else default_model_path()


def second_model_path(cfg: TrackerConfig) -> Path | None:
    """The second regressor's file of ``ensemble`` (``second_model_file``, ``~`` expanded,
    else ``data/tracker/regressor_tubes.npz``); None with ``ensemble`` off."""
    if not cfg.ensemble:
        return None
    if cfg.second_model_file:
        return Path(cfg.second_model_file).expanduser()
    return default_model_path().with_name(SECOND_MODEL_NAME)


def regressor_files(cfg: TrackerConfig) -> list[Path]:
    """The regressor files ``cfg`` asks for that exist: :func:`model_path`'s, then with
    ``ensemble`` :func:`second_model_path`'s (none without the first).

    Raises:
        InputError: ``second_model_file`` names a file that does not exist.
    """
    first, second = model_path(cfg), second_model_path(cfg)
    if second is not None and cfg.second_model_file and not second.exists():
        raise InputError(f"second_model_file {second} does not exist (empty: the shipped "
                         "data/tracker/regressor_tubes.npz; ensemble false: none)")
    if not first.exists():
        return []
    return [first] + ([second] if second is not None and second.exists() else [])


def load_regressor(cfg: TrackerConfig) -> HandRegressor | RegressorSet | None:
    """The regressor(s) of :func:`regressor_files`: None without any, one
    :class:`HandRegressor`, or a :class:`RegressorSet` of both (``ensemble``).

    Raises:
        InputError: a file cannot be read, or ``second_model_file`` does not exist.
    """
    regs = [HandRegressor.load(p) for p in regressor_files(cfg)]
    if not regs:
        return None
    return regs[0] if len(regs) == 1 else RegressorSet(regs)


@dataclass
class TrackResult:
    """Outcome of one frame.

    Attributes:
        pose: (27,) the selected estimate (JOINT_NAMES order, camera frame).
        success: delta of eq. II.19 for this frame.
        status: ``tracking`` | ``recovering`` (success right after a loss) | ``lost`` |
            ``no_hand`` (nothing segmented).
        cost: E_d of the selected pose [mm] (eq. II.19).
        confidence: 0..1 derived from E_d.
        last_good: the last pose that passed the success test (None before the first).
        n_candidates: size of the pose pool.
        timing: seconds per stage (``STAGES``).
        observation: the segmented hand.
        regressed: whether the regression (steps 1-2) ran on this frame (see
            ``TrackerConfig.regress_every``).
        forearm_cut: whether a forearm was cut off the segmented hand
            (:func:`~hand_capture.tracking.preprocess.cut_forearm`).
        tau_mm: the success threshold of eq. II.19 used [mm] (:attr:`HybridTracker.tau_mm`).
        background_plane: whether a background plane (a table, a wall) was dropped from
            the frame's segment (``TrackerConfig.plane_removal``).
    """

    pose: np.ndarray
    success: bool
    status: str
    cost: float
    confidence: float
    last_good: np.ndarray | None
    n_candidates: int
    timing: dict[str, float] = field(default_factory=dict)
    observation: HandObservation | None = None
    regressed: bool = False
    forearm_cut: bool = False
    tau_mm: float = 0.0
    background_plane: bool = False


def pose_distance_sq(q: np.ndarray, p: np.ndarray) -> float:
    """``||q - p||^2`` of eq. II.20 with the root rotation compared as a rotation (the
    squared geodesic angle, so equivalent hinge-angle triples are not far apart); root
    translation in metres, finger angles in radians."""
    Rq = root_rotation_matrix(q[3:6])
    Rp = root_rotation_matrix(p[3:6])
    c = np.clip((np.trace(Rq @ Rp.T) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.sum((q[0:3] - p[0:3]) ** 2) + np.arccos(c) ** 2
                 + np.sum((q[6:] - p[6:]) ** 2))


class HybridTracker:
    """Tracks one hand through a depth stream (module docstring).

    Args:
        model: hand model (the subject's calibrated shape, or the default).
        config: all weights and thresholds.
        regressor: trained regressor, or a :class:`RegressorSet` (``ensemble``,
            :func:`load_regressor`); required for ``hybrid`` and ``regressor`` modes.
        arm: per-pixel hand/arm classifier; None = ``config.arm_model_file`` or
            ``data/tracker/arm.npz`` when present (with ``arm_classifier`` and
            ``forearm_cut`` on).
    """

    def __init__(self, model: HandModel, config: TrackerConfig | None = None,
                 regressor: HandRegressor | RegressorSet | None = None,
                 arm: ArmClassifier | None = None) -> None:
        self.cfg = config or TrackerConfig()
        self.regressor = regressor
        if arm is None and self.cfg.arm_classifier and self.cfg.forearm_cut:
            arm = load_arm_classifier(self.cfg.arm_model_file or None)
        #: the per-pixel hand/arm classifier (None: the geometric forearm cut only)
        self.arm = arm if self.cfg.arm_classifier and self.cfg.forearm_cut else None
        self.icp = ModelTracker(model, self.cfg)
        self.frames = ModelFrames(model)
        self.fit_residual_mm: float | None = None
        #: this frame's E_d leaves the wrist stub out where no data lies (no forearm cut),
        #: or the data past each pose's wrist where the model is not (a forearm cut)
        self._stub_free = False
        self._arm_free = False
        self.reset()

    @property
    def model(self) -> HandModel:
        return self.icp.model

    @property
    def tau_mm(self) -> float:
        """tau of eq. II.19 [mm]. A departure from the dissertation's fixed threshold: on a
        hand whose surface differs from the model's (every real hand), E_d stays high even
        at the true pose (silhouette rims, thicker or thinner fingers), so a fixed tau flags
        good poses as failures. After :meth:`set_calibration` tau follows the calibrated
        fit: ``max(success_tau_mm, tau_fit_ratio * E_d of the calibration fit)``, at most
        ``tau_max_mm``."""
        cfg = self.cfg
        if self.fit_residual_mm is None:
            return cfg.success_tau_mm
        return float(min(max(cfg.success_tau_mm, cfg.tau_fit_ratio * self.fit_residual_mm),
                         max(cfg.tau_max_mm, cfg.success_tau_mm)))

    def set_calibration(self, result: object) -> None:
        """Track with a calibration's shape and let tau follow its fit (:attr:`tau_mm`).

        ``result`` is a :class:`~hand_capture.tracking.calibration.CalibrationResult`; a
        refused one (``ok`` False) changes nothing."""
        if not getattr(result, "ok", True):
            return
        self.set_shape(result.shape)
        e_d = getattr(result, "depth_residual_mm", float("nan"))
        self.fit_residual_mm = float(e_d) if np.isfinite(e_d) else None

    def _segment_roi(self) -> tuple[np.ndarray, float] | None:
        """Where the hand is looked for while the previous frame tracked (``track_roi_m``):
        ``(the previous pose's bones (B, 2, 3) [m], track_roi_m)``; else None."""
        if self.cfg.track_roi_m <= 0 or not (self.delta and self.prev is not None):
            return None
        kp = self.model.joint_positions(self.prev)
        return kp[_SKELETON], self.cfg.track_roi_m

    def _wrist_plane(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The previous pose's wrist [m] and its forearm direction (unit, middle MCP to
        wrist), while the previous frame tracked (eq. II.19); else None."""
        if not (self.delta and self.prev is not None):
            return None
        return self._wrist_of(self.prev)

    def _plane_at_hand_end(self, plane: tuple[np.ndarray, np.ndarray], obs: HandObservation,
                           limit_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The forearm cut's ``plane`` (wrist [m], unit forearm direction) moved along the
        forearm by as far as the segment's hand end (its 99.5th percentile towards the
        fingers) lies beyond the previous pose's mesh's, when that is at most ``limit_m``
        [m] either way (``cut_hand_end_mm``; an addition to the cut). At the previous wrist
        the cut keeps a frame's motion more forearm beside a hand moving towards its
        fingers; those points hold the fit back, the next cut keeps more, and the lag builds
        up (docs/experiments/depth_tracking.md, the fifty-third session). The hand end is
        where the data, not a past estimate, puts the hand."""
        w, d = plane
        mesh = np.asarray(self.model.vertices(self.prev))                # (V, 3) [m]
        model_end = float(np.percentile((mesh - w) @ -d, 99.5))
        data_end = float(np.percentile((obs.points - w) @ -d, 99.5))
        shift = data_end - model_end                  # [m], positive towards the fingers
        return plane if abs(shift) > limit_m else (w - shift * d, d)

    def _wrist_of(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Pose ``q``'s wrist keypoint [m] and forearm direction (unit, middle MCP to
        wrist); None for a degenerate pose."""
        kp = self.model.joint_positions(q)
        d = kp[0] - kp[9]
        n = float(np.linalg.norm(d))
        return None if n < 1e-6 else (kp[0], d / n)

    def set_shape(self, shape: HandShape) -> None:
        """Track with another subject shape (e.g. from calibration)."""
        m = self.model.with_shape(shape)
        self.icp.set_model(m)
        self.frames = ModelFrames(m)

    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        """Forget the past; ``initial_pose`` seeds the previous pose (ICP-only mode)."""
        self.prev: np.ndarray | None = None if initial_pose is None else \
            np.asarray(initial_pose, float).copy()
        self.delta = initial_pose is not None
        self._prev2: np.ndarray | None = None  # the pose before prev, both tracked
        self.last_good: np.ndarray | None = self.prev
        self.frame_count = 0
        self._since_regression = 0
        self._prev_cost = 0.0   # E_d of the previous frame [mm]
        # run_deferred's inputs: (the frame's regressor, obs, intr, pts, obs_ds, tracked pose,
        # its E_c)
        self._deferred: tuple | None = None
        self._carry: np.ndarray | None = None  # a deferred regression's candidate (27,)
        self._centroid: np.ndarray | None = None  # the last frame's segment centroid (3,) [m]

    # ------------------------------------------------------------------------------ frame
    _STATE = ("prev", "delta", "last_good", "frame_count", "_since_regression", "_prev_cost",
              "_deferred", "_carry", "_stub_free", "_arm_free", "_centroid")

    def process(self, depth: np.ndarray, intr: Intrinsics) -> TrackResult:
        """Track one depth frame (uint16 mm or float m).

        With ``arm_fallback``: a frame that fails eq. (II.19) after the arm classifier
        dropped pixels, or any such frame without a tracked wrist (the first frame, after a
        loss), is tracked again from the same state on the forearm cut alone, and the
        result of lower E_d is kept (both steps' time counted). The classifier's segment
        can lose the hand where its training never looked (clutter touching the hand
        reads half arm, half hand: with the arm gone, the clutter dominates the cloud the
        cut and the PCA start go by); the cut alone is then one more candidate, as the
        pool of step 5 (eq. II.20 selects by cost). With ``flip_retry`` a failed frame whose
        forearm was cut from the cloud's shape (no previous wrist) is tried once more with
        the cloud's other end taken for the arm (clutter touching the hand can be the
        widest place the cut takes for the palm); again the lower E_d is kept. With
        ``split_retry`` a failed frame whose segment splits along depth steps into large
        pieces is tried once more without the pieces but the one nearest the camera (an
        object touching the hand joins the depth band's segment;
        :func:`~hand_capture.tracking.preprocess.split_surfaces`); its result is kept when
        it passes eq. II.19 at a lower E_d."""
        cfg = self.cfg
        before = {k: getattr(self, k) for k in self._STATE}
        t0 = time.perf_counter()
        # the same segment for every attempt; while tracking, near the previous hand
        roi = self._segment_roi()
        seg = segment_hand(depth, intr, cfg, roi)
        if roi is not None and not seg.found:   # nothing near it: the whole image
            seg = segment_hand(depth, intr, cfg)
        t_seg = time.perf_counter() - t0
        r, dropped, cloud = self._process(seg, intr, self.arm)
        r.timing["preprocess"] += t_seg
        retries = []
        if dropped and cfg.arm_fallback:
            retries.append((None, False, False))
        if cfg.flip_retry:
            retries.append((None if dropped else self.arm, True, False))
        if cfg.split_retry:
            retries.append((self.arm, False, True))
        best = r
        # without a tracked wrist the classifier's segment is also checked against the cut
        # alone on a frame that passes eq. II.19: a hand fitted to the arm alone can pass it
        # (E_d 22-26 mm against tau 25 on the suite's generator)
        untracked = not (before["delta"] and before["prev"] is not None)
        for arm, flip, split in retries:
            if best.success and (flip or split or not untracked):
                break
            if flip and not cloud:
                continue
            obs = seg
            if split:
                t0 = time.perf_counter()
                obs = split_surfaces(seg, cfg.jump_m, cfg.split_share, cfg.min_hand_pixels)
                best.timing["preprocess"] += time.perf_counter() - t0
                if obs is None:   # the segment does not split: nothing to try
                    continue
            kept = {k: getattr(self, k) for k in self._STATE}
            for k, v in before.items():
                setattr(self, k, v)
            r2, _, cloud2 = self._process(obs, intr, arm, flip)
            for k in STAGES:
                r2.timing[k] += best.timing[k]
            cloud = cloud or cloud2
            # a split retry counts only when it passes eq. II.19: a fit to what is left
            # of a segment that still fails is no better evidence than the whole one
            better = r2.cost < best.cost
            if (better and cfg.fallback_union and untracked and arm is None and not flip
                    and not split and best.observation is not None
                    and best.observation.found and r2.observation is not None
                    and r2.observation.found):
                # without a tracked pose the two fits saw different segments: the retry
                # must also win on the pixels of both (fallback_union)
                c_best, c_retry = self._union_costs(best, r2)
                better = c_retry < c_best
            if better and (r2.success or not split):
                best = r2
            else:
                best.timing = r2.timing
                for k, v in kept.items():
                    setattr(self, k, v)
        best.background_plane = seg.background_plane
        return best

    def _process(self, obs: HandObservation, intr: Intrinsics, arm: ArmClassifier | None,
                 flip: bool = False) -> tuple[TrackResult, bool, bool]:
        """One frame (:meth:`process`) from its segment ``obs`` (:func:`segment_hand`, or
        what :func:`~hand_capture.tracking.preprocess.split_surfaces` left of it) with the
        classifier ``arm`` (None: the cut alone), ``flip`` passed to the cloud cut; also
        whether the classifier dropped pixels and whether the forearm was cut from the
        cloud's shape."""
        cfg = self.cfg
        timing = dict.fromkeys(STAGES, 0.0)
        t0 = time.perf_counter()
        cut = dropped = cloud = False
        whole = None   # the uncut segment, when the cut had no tracked wrist to go by
        if cfg.forearm_cut and obs.found:
            scale = self.model.shape.global_scale
            if arm is not None:   # the pixels the classifier calls arm (armseg)
                obs, _, dropped = remove_arm(obs, arm, cfg.arm_threshold, cfg.arm_grid_mm,
                                             cfg.min_hand_pixels,
                                             margin_m=cfg.arm_margin_m * scale,
                                             reach_m=cfg.forearm_reach_m * scale)
                cut = dropped
            plane = self._wrist_plane()
            if plane is None:
                whole = obs
            elif cfg.cut_hand_end_mm > 0.0:
                plane = self._plane_at_hand_end(plane, obs, cfg.cut_hand_end_mm * 1e-3)
            obs, cut_g = cut_forearm(obs, cfg, scale, plane, flip)
            cut = cut or cut_g
            cloud = cut_g and plane is None
        # E_d past the wrist: the hand may end there where no forearm was cut off
        # (cost_stub_optional); where one was, the arm the cut left is not the model's
        # (cost_arm_optional)
        self._stub_free = cfg.cost_stub_optional and not cut
        self._arm_free = cfg.cost_arm_optional and cut
        timing["preprocess"] = time.perf_counter() - t0
        self.frame_count += 1
        last_centroid = self._centroid
        self._centroid = obs.points.mean(axis=0) if obs.found else None
        if not obs.found:
            self.delta = False
            pose = self.prev if self.prev is not None else np.zeros(N_DOF)
            return TrackResult(pose.copy(), False, "no_hand", cfg.depth_cap_mm, 0.0,
                               self.last_good, 0, timing, obs, tau_mm=self.tau_mm), dropped, cloud
        pts = obs.subsample(cfg.max_points)
        obs_ds = downsampled_depth(obs, cost_grid(obs, cfg))

        pool: list[tuple[np.ndarray, np.ndarray]] = []  # (pose, regression reference)
        mode = cfg.mode
        regress = mode in ("hybrid", "regressor") and self.regressor is not None
        tracking = mode == "hybrid" and self.delta and self.prev is not None
        if regress and tracking:
            # tracking well: the regression every regress_every-th frame only, or when the
            # last fit was doubtful
            regress = (self._since_regression + 1 >= cfg.regress_every
                       or 0.0 < cfg.regress_above_mm < self._prev_cost)
        self._since_regression = 0 if regress else self._since_regression + 1
        self._deferred = None
        defer = regress and tracking and cfg.defer_regression
        if defer:  # tracking: after this frame's pose is out (run_deferred)
            regress = False
        palms: list[np.ndarray] = []
        # no tracked previous pose (the first frame, after a loss), or a tracked one in
        # doubt (its E_d above acquire_above_tau of tau): the wider search of acquire_modes
        # / acquire_refine_top, each candidate refined acquire_icp_iterations (they start
        # far off)
        doubtful = tracking and 0.0 < cfg.acquire_above_tau \
            and self._prev_cost > cfg.acquire_above_tau * self.tau_mm
        acquire = mode == "hybrid" and (not tracking or doubtful)
        n_modes = (cfg.acquire_modes or cfg.n_modes) if acquire else cfg.n_modes
        top = (cfg.acquire_refine_top or cfg.refine_top) if acquire else cfg.refine_top
        its = ((cfg.acquire_icp_iterations or cfg.icp_iterations) if acquire
               else cfg.icp_iterations)
        # ensemble_frames "acquire": a tracked frame asks the first regressor alone (the
        # cheaper setting: on every frame the second costs about 1.2x the CPU a frame)
        reg = self.regressor
        if (cfg.ensemble_frames == "acquire" and mode == "hybrid" and not acquire
                and isinstance(reg, RegressorSet)):
            reg = reg.members[0]
        if regress:  # step 1: palm modes
            t = time.perf_counter()
            lookup, palms = self._palm_modes(reg, obs, intr, n_modes)
            timing["regression"] += time.perf_counter() - t
        prev = None
        if mode in ("hybrid", "icp"):  # step 3: the previous pose
            prev = self.prev if self.prev is not None else palm_init_pca(obs.points,
                                                                         self.frames)
        # an addition to step 3 (shift_previous): the previous pose moved by the shift of
        # the segment's centroid since the last frame, one more start for a moving wrist.
        # The previous pose lags a frame behind such a hand, and so does the smoothness
        # reference of eq. II.24 (constant velocity at best): the shifted start is refined
        # towards itself instead (a departure from II.24 for this candidate). Only for a
        # shift of shift_min_mm or more: a finger closing moves the centroid a few mm.
        shifted: list[np.ndarray] = []
        if cfg.shift_previous and tracking and last_centroid is not None:
            shift = self._centroid - last_centroid                       # (3,) [m]
            if float(np.linalg.norm(shift)) * 1e3 >= cfg.shift_min_mm:
                qs = self.prev.copy()
                qs[0:3] += shift
                shifted.append(qs)
        if mode == "hybrid" and cfg.palm_iterations:
            # steps 1 and 3: palm-only iterations of the palm modes and the previous pose
            # (and its shifted copy), all in one batch
            t = time.perf_counter()
            out = self.icp.refine_batch(palms + shifted + [prev], obs, cfg.palm_iterations,
                                        palm_only=True, points=pts)
            n_p = len(palms)
            palms, shifted, prev = list(out[:n_p]), list(out[n_p:-1]), out[-1]
            timing["icp"] += time.perf_counter() - t
        if regress:  # step 2: finger regression on every palm
            t = time.perf_counter()
            # an addition to step 2 (regress_previous): the fingers regressed on the
            # previous pose's palm too
            own = cfg.regress_previous and self.prev is not None and prev is not None
            roots = [*palms, prev] if own else palms
            cands = reg.regress_fingers(self.frames, lookup, np.array(roots),
                                        cfg.ik_iterations)
            pool += [(qc, qc.copy()) for qc in cands]
            timing["regression"] += time.perf_counter() - t
        if self._carry is not None:  # the last frame's deferred regression
            pool.append((self._carry, self._carry.copy()))
            self._carry = None
        if prev is not None:
            pool.append((prev, prev.copy()))
        # the shifted starts' rows of the pool: each is its own smoothness reference
        own_ref = range(len(pool), len(pool) + len(shifted))
        pool += [(qs, qs.copy()) for qs in shifted]
        if not pool:  # regressor mode without a regressor
            q = palm_init_pca(obs.points, self.frames)
            pool.append((q, q.copy()))

        # step 4: screen by cost, refine the best, select by eq. II.20
        refine = mode != "regressor" and cfg.icp_iterations > 0
        costs = None
        if not refine or len(pool) > top:  # screening needed
            t = time.perf_counter()
            costs = self._costs([q for q, _ in pool], obs, obs_ds)
            timing["selection"] += time.perf_counter() - t
        if refine:
            order = np.arange(len(pool)) if costs is None else \
                np.argsort([c[0] for c in costs])[:top]
            t = time.perf_counter()
            track = self.delta and self.prev is not None and not acquire
            ref = self._smooth_ref() if track else None
            refs = [ref if track and i not in own_ref else pool[i][1] for i in order]
            refined = list(self.icp.refine_batch([pool[i][0] for i in order], obs, its,
                                                 q_refs=refs, points=pts))
            timing["icp"] += time.perf_counter() - t
            t = time.perf_counter()
            # (pose, cost) of each refined candidate as screened, for keep_unrefined
            screened = ([(pool[i][0], costs[i]) for i in order]
                        if cfg.keep_unrefined and costs is not None else None)
            pool = [(q, q) for q in refined]
            costs = self._costs(refined, obs, obs_ds)
            if screened is not None:  # as screened, when cheaper
                for k, (q0, c0) in enumerate(screened):
                    if c0[0] < costs[k][0]:
                        pool[k], costs[k] = (q0, q0), c0
            timing["selection"] += time.perf_counter() - t
        best = int(np.argmin([c[0] for c in costs]))
        if cfg.finger_swap and refine and (len(pool) > 1 or cfg.finger_postures):
            t = time.perf_counter()
            q, c = self._swap_fingers([p[0] for p in pool], costs, best, obs, obs_ds, pts)
            pool[best], costs[best] = (q, q), c
            timing["selection"] += time.perf_counter() - t
        if cfg.abduction_trial and refine:
            t = time.perf_counter()
            q, c = self._abduction_trial(pool[best][0], costs[best], obs, obs_ds, pts)
            pool[best], costs[best] = (q, q), c
            timing["selection"] += time.perf_counter() - t
        if cfg.exchange_trial and refine:
            t = time.perf_counter()
            q, c = self._exchange_trial(pool[best][0], costs[best], obs, obs_ds, pts)
            pool[best], costs[best] = (q, q), c
            timing["selection"] += time.perf_counter() - t
        q = pool[best][0]
        e_d = costs[best][1]
        if whole is not None and refine:
            # the cut came from the cloud's shape alone: cut again at the selected pose's
            # wrist and refine it on those points (the regressor's and the fit's wrist
            # estimate; an addition to step 4)
            t = time.perf_counter()
            obs2, cut2 = cut_forearm(whole, cfg, self.model.shape.global_scale,
                                     self._wrist_of(q))
            if cut2 and obs2.n_points != obs.n_points:
                obs, cut = obs2, True
                pts = obs.subsample(cfg.max_points)
                obs_ds = downsampled_depth(obs, cost_grid(obs, cfg))
                q = self.icp.refine_batch([q], obs, cfg.icp_iterations,
                                          q_refs=[pool[best][1]], points=pts)[0]
                c2 = self._costs([q], obs, obs_ds)[0]
                costs[best] = c2
                e_d = c2[1]
            timing["icp"] += time.perf_counter() - t
        success = e_d < self.tau_mm   # eq. (II.19), tau following the calibration
        if success:
            status = "tracking" if self.delta else "recovering"
            self.last_good = q.copy()
        else:
            status = "lost"
        self._prev2 = self.prev if (self.delta and success) else None
        self.prev = q.copy()
        self.delta = success
        self._prev_cost = e_d
        if defer:
            self._deferred = (reg, obs, intr, pts, obs_ds, q.copy(), costs[best][0])
        conf = float(np.clip(1.0 - e_d / cfg.depth_cap_mm, 0.0, 1.0))
        return TrackResult(q.copy(), success, status, e_d, conf, self.last_good, len(costs),
                           timing, obs, regress, cut, self.tau_mm), dropped, cloud

    def _swap_fingers(self, qs: list[np.ndarray], costs: list[tuple[float, float]],
                      best: int, obs: HandObservation, obs_ds: np.ndarray,
                      pts: tuple[np.ndarray, np.ndarray]
                      ) -> tuple[np.ndarray, tuple[float, float]]:
        """Finger-wise selection (``finger_swap``, an extension of step 5): starting from
        the candidate ``best``, each finger in turn takes the angles another refined
        candidate has for it (or, with ``finger_postures``, a straight or curled posture)
        when the cost (E_c of eq. II.20) goes down; a changed pose is
        refined by one Gauss-Newton iteration and kept if its cost stays lower. Returns
        the pose and its ``(E_c, E_d)``."""
        q, c = qs[best].copy(), costs[best]
        changed = False
        for dofs in FINGER_DOFS:
            trials = self._finger_trials(q, dofs, qs, best)
            if not trials:
                continue
            tc = self._costs(trials, obs, obs_ds)
            k = int(np.argmin([x[0] for x in tc]))
            if tc[k][0] < c[0]:
                q, c, changed = trials[k], tc[k], True
        if changed:
            q, c = self._refined_if_cheaper(q, 1, q, c, obs, obs_ds, pts)
        return q, c

    def _refined_if_cheaper(self, start: np.ndarray, iterations: int, q: np.ndarray,
                            c: tuple[float, float], obs: HandObservation, obs_ds: np.ndarray,
                            pts: tuple[np.ndarray, np.ndarray]
                            ) -> tuple[np.ndarray, tuple[float, float]]:
        """``start`` refined by ``iterations`` GN steps (smoothness reference: the predicted
        pose while tracking, else ``start`` itself) when its ``(E_c, E_d)`` has a lower E_c
        of eq. II.20 than ``c``, the cost of ``q``; else ``q`` and ``c``."""
        ref = self._smooth_ref() if (self.delta and self.prev is not None) else start
        r = self.icp.refine_batch([start], obs, iterations, q_refs=[ref], points=pts)[0]
        cr = self._costs([r], obs, obs_ds)[0]
        return (r, cr) if cr[0] < c[0] else (q, c)

    def _abduction_trial(self, q: np.ndarray, c: tuple[float, float], obs: HandObservation,
                         obs_ds: np.ndarray, pts: tuple[np.ndarray, np.ndarray]
                         ) -> tuple[np.ndarray, tuple[float, float]]:
        """``abduction_trial`` (an extension of step 5): the selected pose ``q`` (cost
        ``c``, its ``(E_c, E_d)``) with the MCP abduction of the four fingers set to zero,
        refined as a candidate of step 4 (``icp_iterations``, the same smoothness
        reference) and taken when its E_c of eq. II.20 is lower. Diagnosed on the validation
        families: two neighbouring fingers each fitted to the other's points, crossed at
        20-38 deg of abduction, with a cost E_d below tau; the finger-wise selection keeps
        each finger's abduction and changes one finger at a time, so it cannot undo that.
        Skipped (``q`` and ``c`` returned) when no finger is abducted by
        ``abduction_min_deg`` or more: the trial would start next to ``q``. Returns the pose
        and its ``(E_c, E_d)``."""
        if np.degrees(np.abs(q[_FINGER_ABD]).max()) < self.cfg.abduction_min_deg:
            return q, c
        trial = q.copy()
        trial[_FINGER_ABD] = 0.0
        return self._refined_if_cheaper(trial, self.cfg.icp_iterations, q, c, obs, obs_ds,
                                        pts)

    def _exchange_trial(self, q: np.ndarray, c: tuple[float, float], obs: HandObservation,
                        obs_ds: np.ndarray, pts: tuple[np.ndarray, np.ndarray]
                        ) -> tuple[np.ndarray, tuple[float, float]]:
        """``exchange_trial`` (an extension of step 5): the selected pose ``q`` (cost ``c``,
        its ``(E_c, E_d)``) with two fingers' flexions exchanged, each of the six pairs;
        the cheapest, when its E_c of eq. II.20 is lower than ``c``'s, taken, and refined as
        a candidate of step 4 (``icp_iterations``) when that lowers it further. Diagnosed
        on a far hand: the index fitted straight onto the ring's points and the ring curled
        where the curled index is; the finger-wise selection changes one finger at a time,
        and either change alone puts two fingers on the same points. Returns the pose and
        its ``(E_c, E_d)``."""
        trials = _exchanged_flexions(q)
        tc = self._costs(trials, obs, obs_ds)
        k = int(np.argmin([x[0] for x in tc]))
        if tc[k][0] >= c[0]:
            return q, c
        return self._refined_if_cheaper(trials[k], self.cfg.icp_iterations, trials[k], tc[k],
                                        obs, obs_ds, pts)

    def _smooth_ref(self) -> np.ndarray:
        """Reference of the smoothness term (eq. II.24) while tracking: the previous pose,
        or with ``smooth_predict`` that pose moved on at the last frame's velocity (a
        departure from II.24, which damps steady motion as much as jitter)."""
        assert self.prev is not None
        how = self.cfg.smooth_predict
        if how == "off" or self._prev2 is None:
            return self.prev
        d = self.prev - self._prev2
        d[3:] = 0.0 if how == "translation" else wrap_angles(d[3:])
        return self.prev + d

    def _finger_trials(self, q: np.ndarray, dofs: np.ndarray, qs: list[np.ndarray],
                       best: int) -> list[np.ndarray]:
        """:meth:`_swap_fingers`' trials for one finger: ``q`` with the finger's angles
        ``dofs`` taken from each other candidate of ``qs`` (and, with ``finger_postures``,
        set straight or curled), those that change them."""
        donors = [qj[dofs] for j, qj in enumerate(qs) if j != best]
        if self.cfg.finger_postures:
            donors += _finger_postures(q, dofs)
        cur = q[dofs]
        tol = 1e-8 + 1e-5 * np.abs(cur)   # np.allclose's test (finite angles)
        trials = []
        for d in donors:
            if not np.all(np.abs(d - cur) <= tol):
                t = q.copy()
                t[dofs] = d
                trials.append(t)
        return trials

    def _palm_modes(self, reg: HandRegressor | RegressorSet, obs: HandObservation,
                    intr: Intrinsics, n_modes: int
                    ) -> tuple[DepthLookup | tuple[DepthLookup, ...], list[np.ndarray]]:
        """Step 1: ``n_modes`` palm modes of ``reg`` (each member's, for a set) for a frame,
        and its depth lookup."""
        # the features read depth in the hand's bounding box (off it: background, as off the
        # hand anywhere)
        r0, r1, c0, c1 = obs.box if obs.box is not None else (0, intr.height, 0, intr.width)
        lookup = reg.lookup(obs.depth_m[r0:r1, c0:c1], c0, r0, intr)
        q0 = palm_init_pca(obs.points, self.frames)
        return lookup, reg.palm_modes(self.frames, lookup, q0, n_modes)

    def run_deferred(self) -> dict[str, float] | None:
        """Steps 1-2 for the last frame, when it deferred them (``defer_regression``).

        The candidates are scored on that frame with the cost of eq. (II.20); the best one
        joins the next frame's pool if it scored lower than the pose tracked there.

        Returns:
            seconds per stage spent (``STAGES`` keys), or None when nothing was deferred.
        """
        d, self._deferred = self._deferred, None
        if d is None:
            return None
        reg, obs, intr, pts, obs_ds, q_tracked, c_tracked = d
        cfg = self.cfg
        timing = dict.fromkeys(STAGES, 0.0)
        t = time.perf_counter()
        lookup, palms = self._palm_modes(reg, obs, intr, cfg.n_modes)
        timing["regression"] += time.perf_counter() - t
        if cfg.palm_iterations:
            t = time.perf_counter()
            palms = list(self.icp.refine_batch(palms, obs, cfg.palm_iterations,
                                               palm_only=True, points=pts))
            timing["icp"] += time.perf_counter() - t
        if cfg.regress_previous:   # as in _process: the tracked palm too
            palms = [*palms, q_tracked]
        t = time.perf_counter()
        cands = list(reg.regress_fingers(self.frames, lookup, np.array(palms),
                                         cfg.ik_iterations))
        timing["regression"] += time.perf_counter() - t
        t = time.perf_counter()
        costs = self._costs(cands, obs, obs_ds)
        best = int(np.argmin([c[0] for c in costs]))
        if costs[best][0] < c_tracked:
            self._carry = cands[best]
        timing["selection"] += time.perf_counter() - t
        return timing

    def _union_costs(self, a: TrackResult, b: TrackResult) -> tuple[float, float]:
        """E_d (eq. II.19) of both results' poses [mm] on the union of their segments
        (``fallback_union``), the arm past each pose's wrist left out only up to
        ``fallback_arm_free_m`` beyond its wrist plane when either segment had a forearm
        cut off."""
        obs = union_observation(a.observation, b.observation)
        free_m = self.cfg.fallback_arm_free_m * self.model.shape.global_scale
        c = self.icp.depth_costs(np.array([a.pose, b.pose]), obs,
                                 arm_optional=self.cfg.cost_arm_optional
                                 and (a.forearm_cut or b.forearm_cut), arm_free_m=free_m)
        return float(c[0]), float(c[1])

    def _costs(self, qs: list[np.ndarray], obs: HandObservation, obs_ds: np.ndarray
               ) -> list[tuple[float, float]]:
        """(E_c of eq. II.20, E_d of eq. II.19) of every pose."""
        e_ds = self.icp.depth_costs(np.array(qs), obs, obs_ds, stub_optional=self._stub_free,
                                    arm_optional=self._arm_free)
        out = []
        for q, e_d in zip(qs, e_ds, strict=True):
            e_s = 0.0
            if self.delta and self.prev is not None and self.cfg.cost_temporal_weight > 0:
                e_s = pose_distance_sq(q, self.prev)
            out.append((self.cfg.cost_data_weight * float(e_d)
                        + self.cfg.cost_temporal_weight * e_s, float(e_d)))
        return out
