"""Automatic construction of the subject's hand model from a few depth frames (ch. II.3.6).

The subject holds a few predefined poses (:data:`CALIBRATION_POSES`: finger angles; the wrist
is wherever the hand is). Eq. II.11 is solved by alternation, as in the dissertation:

1. every frame's pose starts at its predefined finger angles, the palm placed by PCA and
   palm-only ICP, then a few full ICP iterations (default shape);
2. the shape parameters ``(s_g, alpha, beta)`` take one Gauss-Newton step on all frames'
   correspondences together (the model's analytic shape Jacobian), with a Gaussian prior
   on the parameters to keep the fit well posed (the shape model's own spread for
   ``beta``, three times it for the bone scales ``alpha``, 0.3 for ``s_g``);
3. every frame's pose is refined with the new shape; repeat 2-3 ``rounds`` times.

Departures, for hands whose surface is not the model's and that come with a forearm: the
forearm is cut off every frame first (``preprocess.cut_forearm``), the residuals are
Huber-weighted as in the tracker (``robust_mm``), the data-to-model pairs of eq. II.23
count mostly along the model's normal (their tangential part weighted by
``tangent_weight``: pairs with the nearest *vertex* drew the fit to a smaller hand, whose
vertices lie closer together), the global scale starts from the best of a grid (0.85 to
1.15; each tried with its own cut at its fitted wrists), the cut is
redone half-way through the rounds, and a fit that cannot be trusted (few
hand points, a high residual, much of the model off the observed hand) is refused: ``ok``
False, a ``status`` naming why, and the starting shape returned unchanged.

Shapes are saved per subject as YAML (``<folder>/<subject_id>.yaml``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.config import load_yaml
from hand_capture.errors import ConfigError, InputError
from hand_capture.model import N_ALPHA, N_BETA, N_DOF, HandModel, HandShape
from hand_capture.model.joints import pose_from_dict
from hand_capture.model.shape import BETA_SD
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.icp import ModelTracker, huber_sqrt_weights
from hand_capture.tracking.preprocess import cut_forearm, segment_hand
from hand_capture.tracking.regressor import ModelFrames, palm_init_pca

__all__ = ["CALIBRATION_POSES", "CalibrationResult", "calibrate", "load_shape", "save_shape",
           "shape_path", "tangent_projector"]

_D = math.radians
#: Predefined calibration poses (finger angles only): flat spread hand, open hand with the
#: thumb out, fingers slightly bent.
CALIBRATION_POSES: dict[str, np.ndarray] = {
    "flat": np.zeros(N_DOF),
    "spread": pose_from_dict({**{f"{f}_mcp_abd": _D(a) for f, a in
                                 (("index", 8), ("ring", -6), ("little", -12))},
                              "thumb_tm_abd": _D(20)}),
    "bent": pose_from_dict({**{f"{f}_mcp_flex": _D(25) for f in
                               ("index", "middle", "ring", "little")},
                            **{f"{f}_pip_flex": _D(20) for f in
                               ("index", "middle", "ring", "little")}}),
}


@dataclass
class CalibrationResult:
    """The fitted shape, the fitted pose of every frame and the mean residual [mm].

    Attributes:
        shape: the fitted shape; when refused (``ok`` False), the starting model's shape.
        poses: fitted pose (27,) of every frame.
        residual_mm: mean point-to-model distance of the fit [mm].
        rounds: shape/pose alternations run.
        ok: whether the fit can be trusted (else the shape must not be used).
        status: ``ok`` or ``refused: <reasons>``.
        depth_residual_mm: mean E_d (eq. II.19) of the fitted poses [mm]: what E_d is on
            this subject at a good pose (:attr:`HybridTracker.tau_mm` follows it).
        n_points: hand points per frame (after the forearm cut).
    """

    shape: HandShape
    poses: list[np.ndarray]
    residual_mm: float
    rounds: int
    ok: bool = True
    status: str = "ok"
    depth_residual_mm: float = float("nan")
    n_points: tuple[int, ...] = ()


def calibrate(frames: Sequence[tuple[np.ndarray, Intrinsics]],
              finger_poses: Sequence[np.ndarray] | None = None,
              model: HandModel | None = None, config: TrackerConfig | None = None, *,
              rounds: int = 30, pose_iterations: int = 5, prior_weight: float = 300.0,
              scale_grid: Sequence[float] = (0.85, 0.9, 1.0, 1.1, 1.15),
              subject_id: str = "", min_points: int = 400,
              max_residual_mm: float = 6.0, max_off_share: float = 0.1,
              alpha_sd: float = 3.0, tangent_weight: float = 0.2,
              scale_sd: float = 0.3, recut_margin_m: float = -0.025
              ) -> CalibrationResult:
    """Fit the subject's shape (eq. II.11) from depth frames of predefined poses.

    Args:
        frames: (depth image, intrinsics) pairs, one per predefined pose.
        finger_poses: the predefined poses (27,) (only the finger angles are used); default:
            the :data:`CALIBRATION_POSES` in order, cycled.
        model: starting model (default: the template shape, right hand).
        config: tracker thresholds for segmentation and ICP.
        rounds: shape/pose alternations.
        pose_iterations: ICP iterations per frame and round. Both were 10 / 3; 30 / 5
            were chosen on validation subjects (an earlier, uncommitted form of
            ``scripts/calibration_validation.py``; the suite's mesh, rasteriser and noise,
            two thirds with ``SurfaceVariant`` surfaces, scales 0.85-1.15, 36 subjects):
            mean bone-length error 2.61 -> 2.31 %, worst 8.1 -> 4.8 % (20 / 5: 2.46 / 5.3;
            40 / 8: 2.26 / 4.7 at 1.3 x the time); the fit was still moving after 10 rounds.
            About 1 s a calibration instead of 0.5 s.
        prior_weight: weight of the shape prior (in squared prior SDs vs squared mm).
        scale_grid: factors of the starting global scale tried before the joint fit (the
            best one starts it; a single 1.0 = start from the given model). It spans the
            subjects' range 0.85-1.15: the joint fit hardly moves the scale, so a 0.85 hand
            started at 0.9 stayed near 0.89 (bone error 4-6 %, 2-2.5 % from 0.85).
        alpha_sd: prior SD of the bone-scale coefficients ``alpha`` in units of their
            population SD (the shape model's; 1 = the population prior). With 1 the
            prior held long-fingered hands half-way to the template's fingers (a hand
            with 9 % longer fingers came out 6 % short on clean depth).
        tangent_weight: weight of the tangential part of each data-to-model residual
            (:func:`tangent_projector`; 1 = point-to-vertex as in eq. II.23, 0 =
            point-to-plane). The observed points pair with model *vertices* (about 4 mm
            apart), so the point-to-vertex cost falls as the model shrinks and its vertices
            close up: on clean depth of a hand with 9 % longer fingers, without the alpha
            prior, the fit converged to fingers 3 % short and ``s_g`` 0.977 (mean residual
            2.30 mm, lower than the 2.39 mm of a fit started at the truth).
        scale_sd: prior SD of the global scale ``s_g`` (the population's is
            ``GLOBAL_SCALE_SD`` 0.06; the subjects to serve span 0.85-1.15, and the scale
            grid already starts the fit near the data's scale). With 0.06 and the weaker
            ``alpha`` prior, ``s_g`` stayed near 1 and the bone scales took up the size:
            the palm, whose length only ``s_g`` sets, came out 4.5 % off on average.
            ``alpha_sd`` 3, ``tangent_weight`` 0.2 and ``scale_sd`` 0.3 were chosen on the
            validation subjects (``scripts/calibration_validation.py``: the suite's mesh,
            rasteriser and noise, two thirds with ``SurfaceVariant`` surfaces, scales
            0.85-1.15, shapes ``sample_shape``, 36 subjects, seeds 900-935): mean / worst
            bone-length error 3.46 / 8.06 % -> 2.17 / 4.28 %, palm 3.2 -> 2.0 %, rest-pose
            keypoints 3.8 -> 2.2 mm, 0.99 -> 1.16 s a calibration (see
            docs/experiments/depth_tracking.md). The bench's calibration section, measured
            after the choice (same run, same machine): worst 5.20 -> 4.45 %, held-out mean 3.56 ->
            2.71 %, suite's hands 1.67 -> 1.06 %; 1.06 -> 1.13 s a calibration.
        recut_margin_m: where the data is cut at the fitted wrists (after the scale grid's first
            fits and half-way through the rounds), beyond the wrist keypoint along the forearm [m,
            at template size; negative: towards the fingers]; the model's surface beyond that plane
            pairs with no data either (``wrist_optional_m`` of the fit lowered to it, at least
            -0.04). The tracker's cut (``forearm_margin_m`` 36 mm, where the template's mesh ends)
            let the fit slide down a forearm in view: the cut follows the fitted wrist, the palm's
            base takes up the forearm's first centimetres, the hand grows to reach them, and the
            next cut keeps them. On the validation subjects with the training renders' forearm
            (``scripts/calibration_validation.py --forearm``, 36 subjects) the tracker's cut gave
            bone errors of 7.92 % mean (worst 27.8 %, every bone long, the fitted wrist up to 20 mm
            down the arm); cut at the wrist (0) 3.7 / 13.8 % (12 subjects, 10.7 / 27.8 % with the
            36 mm cut); -0.025 (chosen, with the model's surface beyond the cut optional; without
            that the model's base pulled the hand small: -0.02 gave 9.0 % on 12 subjects) 2.70 /
            7.20 % with a forearm and 2.24 / 4.33 % without (before: 2.17 / 4.28 %). -0.01 / -0.015
            / -0.02 / -0.03: 3.02 / 12.9, 2.69 / 7.22, 2.68 / 8.61 (one refused), 2.71 / 5.72 %
            with a forearm; 2.25 / 4.79, 2.29 / 5.13, 2.33 / 4.76, 2.32 / 5.25 % without (those
            five before the off-hand test below judged the uncut segment; with it -0.025 gives the
            same figures and no subject is refused). Applied only when a forearm is seen (the
            cloud cut shortened a frame's segment): on a hand alone the short cut left the
            palm's length to the scale alone (held-out 0.85 hand of the bench: 4.33 -> 5.75 %),
            so it keeps the tracker's cut and its figures are main's to the digit. With a
            sleeve on every second subject (``--sleeves``, checked after the choice): 6.86 /
            20.38 % -> 3.25 / 15.84 % (the worst refused either way; accepted: 5.42 %).
        subject_id: stored in the result's shape.
        min_points: fewer hand points than this in a frame (after the forearm cut) =
            refused.
        max_residual_mm: a mean fit residual above this = refused.
        max_off_share: a frame whose fitted model has more than this share of its facing
            vertices off the observed hand (occluded or cut hand) = refused (the wrist stub,
            ``icp.optional_vertices``, left out; good fits stay under 2 %).

    Returns:
        The fit; ``ok`` False (with ``status`` naming the reasons and the starting shape)
        when it cannot be trusted: few points, a high residual, or an occluded hand.

    Raises:
        InputError: no frame, or a frame without a hand.
    """
    if not frames:
        raise InputError("calibration needs at least one depth frame")
    cfg = config or TrackerConfig()
    # the pose fits' smoothness term holds a pose near its start, not the previous frame
    cfg = replace(cfg, smooth_weight=cfg.calibration_smooth_weight)
    model = model or HandModel()
    presets = list(CALIBRATION_POSES.values())
    if finger_poses is None:
        finger_poses = [presets[i % len(presets)] for i in range(len(frames))]
    if len(finger_poses) != len(frames):
        raise InputError(f"{len(frames)} frames but {len(finger_poses)} predefined poses")
    obs_list, whole = [], []
    arm_seen = False   # a frame whose segment the cloud cut shortened (a forearm in view)
    for depth, intr in frames:
        obs = segment_hand(depth, intr, cfg)
        if len(obs.points) < 100:
            raise InputError("a calibration frame shows no hand")
        whole.append(obs)
        # the forearm is not the hand: a surface fitted to it inflates the hand (40-60 %)
        if cfg.forearm_cut:
            obs, did = cut_forearm(obs, cfg, model.shape.global_scale)
            arm_seen |= did
        obs_list.append(obs)
    reasons = []
    n_points = tuple(int(o.n_points) for o in obs_list)
    if min(n_points) < min_points:
        reasons.append(f"{min(n_points)} hand points in a frame (< {min_points})")
    # with a forearm in view the data is cut short of the fitted wrists, and the model's
    # surface beyond that cut pairs with nothing (icp.optional_vertices); a hand alone keeps
    # the tracker's cut
    if not arm_seen:
        recut_margin_m = cfg.forearm_margin_m
    cfg_fit = (replace(cfg, wrist_optional_m=max(-0.04, recut_margin_m))
               if cfg.wrist_optional and recut_margin_m < cfg.wrist_optional_m else cfg)
    # coarse search of the global scale first: the joint Gauss-Newton below converges slowly
    # along the scale (sliding correspondences), so it starts from the best scale of a grid
    best = None
    for sg in scale_grid:
        gs = float(np.clip(sg * model.shape.global_scale, 0.6, 1.6))
        shape_try = model.shape.with_params(global_scale=gs)
        tracker = ModelTracker(model.with_shape(shape_try), cfg_fit)
        obs_try = list(obs_list)
        poses_try, score = _fit_poses(tracker, obs_try, finger_poses, pose_iterations)
        if cfg.forearm_cut:
            # cut again at the fitted wrists (the cloud-only cut may leave some forearm,
            # and where the wrist ends depends on the scale tried), refit and score
            _recut(tracker, whole, obs_try, poses_try, cfg, recut_margin_m)
            poses_try, score = _fit_poses(tracker, obs_try, finger_poses, pose_iterations,
                                          poses_try)
        if best is None or score < best[0]:
            best = (score, shape_try, tracker, poses_try, obs_try)
    _, shape, tracker, poses, obs_list = best
    p0 = HandShape().params
    sd = np.r_[scale_sd, np.full(N_ALPHA, alpha_sd), np.full(N_BETA, BETA_SD)]
    lo = np.r_[0.6, np.full(N_ALPHA, -3.0), np.full(N_BETA, -0.004)]
    hi = np.r_[1.6, np.full(N_ALPHA, 3.0), np.full(N_BETA, 0.004)]
    residual = float("nan")
    T = len(poses)
    n = len(p0)
    q_pre = [q.copy() for q in poses]
    for k in range(rounds):
        if k == rounds // 2:   # and again with the half-fitted shape's wrists
            _recut(tracker, whole, obs_list, poses, cfg, recut_margin_m)
        p = shape.params
        m = tracker.model
        N = T * N_DOF + n
        A = np.zeros((N, N))
        g = np.zeros(N)
        res = []
        for t, (obs, q) in enumerate(zip(obs_list, poses, strict=True)):
            pts, pix = obs.subsample(cfg.max_points * 2)
            V, facing = tracker.posed(q)
            corr = tracker.correspond(pts, pix, V, facing, obs.intrinsics)
            if len(corr.vertex) == 0:
                continue
            rev = tracker.reverse_correspond(pts, V, facing, obs, stride=2)
            vidx = np.r_[corr.vertex, rev.vertex]
            J = np.concatenate([m.jacobian(q, vidx), m.shape_jacobian(q, vidx)], axis=2)
            J = J * 1000.0
            r3 = np.concatenate([corr.residual_mm, rev.residual_mm])
            if tangent_weight != 1.0:
                # eq. II.23's data-to-model pairs mostly along the vertex normal (module doc)
                nc = len(corr.vertex)
                P = tangent_projector(m.normals(V)[corr.vertex], tangent_weight)
                J[:nc] = np.einsum("nab,nbk->nak", P, J[:nc])
                r3[:nc] = np.einsum("nab,nb->na", P, r3[:nc])
            J = J.reshape(-1, N_DOF + n)
            r = r3.reshape(-1)
            wr = np.r_[np.ones(3 * len(corr.vertex)),
                       np.full(3 * len(rev.vertex), max(cfg.reverse_weight, 0.5))]
            if cfg.robust_mm > 0:  # Huber IRLS, as the tracker's data term (icp.py), on
                # the data-to-model pairs only: the model-to-data pairs carry the size
                nd = 3 * len(corr.vertex)
                wr[:nd] *= huber_sqrt_weights(r[:nd], cfg.robust_mm) ** 2
            J = J * np.sqrt(wr)[:, None]
            r = r * np.sqrt(wr)
            H = J.T @ J
            gg = J.T @ r
            sl = slice(t * N_DOF, (t + 1) * N_DOF)
            ss = slice(T * N_DOF, N)
            A[sl, sl] += H[:N_DOF, :N_DOF]
            A[sl, ss] += H[:N_DOF, N_DOF:]
            A[ss, sl] += H[N_DOF:, :N_DOF]
            A[ss, ss] += H[N_DOF:, N_DOF:]
            g[sl] += gg[:N_DOF]
            g[ss] += gg[N_DOF:]
            # pose terms: smoothness towards the starting pose, joint limits
            Ap, gp, _ = tracker.normal_equations(q, type(corr)(corr.points[:0], corr.vertex[:0],
                                                               corr.model[:0]),
                                                 q_pre[t], np.arange(N_DOF))
            A[sl, sl] += Ap
            g[sl] += gp
            res.append(np.linalg.norm(corr.residual_mm, axis=1))
        w = prior_weight / sd ** 2
        ss = slice(T * N_DOF, N)
        A[ss, ss][np.diag_indices(n)] += w
        g[ss] += w * (p - p0)
        A[np.diag_indices(N)] += cfg.damping * (1.0 + A.diagonal())
        try:
            dx = -np.linalg.solve(A, g)
        except np.linalg.LinAlgError:
            break
        poses = [q + dx[t * N_DOF:(t + 1) * N_DOF] for t, q in enumerate(poses)]
        shape = HandShape.from_params(np.clip(p + dx[ss], lo, hi), subject_id)
        tracker.set_model(tracker.model.with_shape(shape))
        residual = float(np.mean(np.concatenate(res))) if res else float("nan")
    for _ in range(1):
        poses = [tracker.refine(q, obs, pose_iterations, q_ref=q)
                 for q, obs in zip(poses, obs_list, strict=True)]
    e_d, off = [], []
    # the off-hand test with the tracker's optional stub only, against the uncut segment
    # (the fit's wider optional base would let a hand slid off an occluded frame pass)
    judge = tracker if cfg_fit is cfg else ModelTracker(tracker.model, cfg)
    for q, obs, seg in zip(poses, obs_list, whole, strict=True):
        e_d.append(tracker.depth_cost(q, obs))
        off.append(_off_share(judge, q, seg))
    if not np.isfinite(residual) or residual > max_residual_mm:
        reasons.append(f"residual {residual:.1f} mm (> {max_residual_mm})")
    if max(off) > max_off_share:
        reasons.append(f"{max(off):.0%} of the model off the observed hand in a frame "
                       f"(> {max_off_share:.0%}): occluded or not the predefined pose")
    ok = not reasons
    status = "ok" if ok else "refused: " + "; ".join(reasons)
    return CalibrationResult(shape if ok else model.shape, poses, residual, rounds, ok,
                             status, float(np.mean(e_d)), n_points)


def tangent_projector(normals: np.ndarray, tangent_weight: float) -> np.ndarray:
    """``P = n n^T + w (I - n n^T)`` (N, 3, 3) for unit normals (N, 3): applied to a
    point-to-vertex residual and its Jacobian rows, it keeps the component along the normal
    and scales the tangential one by ``w`` (0 = point-to-plane, 1 = point-to-point)."""
    n = np.asarray(normals, float)
    P = (1.0 - tangent_weight) * n[:, :, None] * n[:, None, :]
    P[:, np.arange(3), np.arange(3)] += tangent_weight
    return P


def _recut(tracker: ModelTracker, whole: list, obs_list: list, poses: list,
           cfg: TrackerConfig, margin_m: float) -> None:
    """Replace ``obs_list[t]`` by ``whole[t]`` cut ``margin_m`` [m, at template size] beyond
    the wrist of ``poses[t]`` (:func:`~hand_capture.tracking.preprocess.cut_forearm`)."""
    if not cfg.forearm_cut:
        return
    cfg = replace(cfg, forearm_margin_m=0.0)
    sg = tracker.model.shape.global_scale
    for t, (obs, q) in enumerate(zip(whole, poses, strict=True)):
        kp = tracker.model.joint_positions(q)
        d = kp[0] - kp[9]
        d = d / max(float(np.linalg.norm(d)), 1e-9)
        obs_list[t], _ = cut_forearm(obs, cfg, sg, (kp[0] + d * margin_m * sg, d))


def _off_share(tracker: ModelTracker, q: np.ndarray, obs: object) -> float:
    """Share of the facing model vertices at pose ``q`` that project more than 3 px off the
    observed hand (or off the image)."""
    V, facing = tracker.posed(q)
    facing = facing[~tracker.optional[facing]]   # the wrist stub may lack data (icp.py)
    if not len(facing):
        return 1.0
    intr = obs.intrinsics
    Vf = V[facing]
    z = np.maximum(Vf[:, 2], 1e-3)
    u = np.rint(intr.fx * Vf[:, 0] / z + intr.cx).astype(np.int64)
    v = np.rint(intr.fy * Vf[:, 1] / z + intr.cy).astype(np.int64)
    inside = (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
    off = np.ones(len(Vf), bool)
    off[inside] = obs.off_hand(v[inside], u[inside], 3.0)
    return float(np.mean(off))


def _fit_poses(tracker: ModelTracker, obs_list: list, finger_poses: Sequence[np.ndarray],
               iterations: int, start: list[np.ndarray] | None = None
               ) -> tuple[list[np.ndarray], float]:
    """Poses of the calibration frames for the tracker's shape, and the symmetric mean
    distance [mm] between model and points (data-to-model and model-to-data pairs).
    ``start``: poses to refine (default: PCA palm, predefined fingers, palm-only ICP)."""
    poses, dists = [], []
    for t, (obs, qd) in enumerate(zip(obs_list, finger_poses, strict=True)):
        if start is None:
            q = palm_init_pca(obs.points, ModelFrames(tracker.model))
            q[6:] = np.asarray(qd, float)[6:]
            q = tracker.refine(q, obs, 6, palm_only=True)
        else:
            q = start[t]
        q = tracker.refine(q, obs, iterations, q_ref=q)
        pts, pix = obs.subsample(tracker.cfg.max_points)
        V, facing = tracker.posed(q)
        c = tracker.correspond(pts, pix, V, facing, obs.intrinsics)
        r = tracker.reverse_correspond(pts, V, facing, obs, stride=2)
        d = np.r_[np.linalg.norm(c.residual_mm, axis=1), np.linalg.norm(r.residual_mm, axis=1)]
        dists.append(float(d.mean()) if d.size else tracker.cfg.outlier_mm)
        poses.append(q)
    return poses, float(np.mean(dists))


# ------------------------------------------------------------------------------ storage
_SAFE = re.compile(r"^[A-Za-z0-9_.-]+$")


def shape_path(folder: str | Path, subject_id: str) -> Path:
    """``<folder>/<subject_id>.yaml``; the id must be a plain file name."""
    if not subject_id or not _SAFE.match(subject_id) or subject_id.startswith("."):
        raise ConfigError(f"subject_id {subject_id!r} must be letters, digits, '_', '-', '.'")
    return Path(folder).expanduser() / f"{subject_id}.yaml"


def save_shape(shape: HandShape, folder: str | Path, subject_id: str, side: str = "right",
               residual_mm: float = float("nan")) -> Path:
    """Write a subject's calibrated shape as YAML; returns the path."""
    import yaml

    p = shape_path(folder, subject_id)
    p.parent.mkdir(parents=True, exist_ok=True)
    data = {"subject_id": subject_id, "side": side, "global_scale": float(shape.global_scale),
            "alpha": [float(a) for a in shape.alpha], "beta": [float(b) for b in shape.beta],
            "residual_mm": None if not math.isfinite(residual_mm) else float(residual_mm)}
    tmp = p.with_suffix(".yaml.tmp")
    tmp.write_text(yaml.safe_dump(data, sort_keys=False))
    tmp.replace(p)
    return p


def load_shape(folder: str | Path, subject_id: str) -> HandShape:
    """Read a subject's shape saved by :func:`save_shape`.

    Raises:
        ConfigError: missing or malformed file.
    """
    p = shape_path(folder, subject_id)
    data = load_yaml(p)
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: not a shape file")
    try:
        return HandShape(float(data["global_scale"]), tuple(data["alpha"]),
                         tuple(data["beta"]), str(data.get("subject_id", subject_id)))
    except (KeyError, TypeError, InputError) as e:
        raise ConfigError(f"{p}: bad shape file: {e}") from e


def render_calibration_frames(model: object, intr: Intrinsics,
                              rng: np.random.Generator | None = None,
                              mesh_fn: Callable[[np.ndarray], object] | None = None
                              ) -> list[tuple[np.ndarray, Intrinsics]]:
    """Depth frames (uint16 mm) of a hand model holding the predefined calibration poses.

    The palm faces the camera 0.42 m away, turned slightly differently in each frame, as a
    subject would hold them. With ``rng`` the sensor noise model is applied (benchmarks),
    without it the depth is exact (tests).

    Args:
        model: the (true) hand model to render, e.g. ``HandModel(shape)``.
        intr: camera intrinsics.
        rng: noise generator, or None for clean depth.
        mesh_fn: the rendered :class:`~hand_capture.cameras.render.Mesh` of a pose (27,)
            (another surface on the model's skeleton), or a list of meshes (e.g. with a
            forearm); default the model's own mesh.
    """
    from hand_capture.cameras.motion import R_PALM_TO_CAMERA
    from hand_capture.cameras.noise import DepthNoiseConfig, DepthNoiseModel
    from hand_capture.cameras.render import Mesh, make_renderer
    from hand_capture.cameras.transforms import rotvec_to_matrix
    from hand_capture.model.joints import root_angles_from_matrix

    ren = make_renderer("zbuffer")
    noise = DepthNoiseModel(DepthNoiseConfig()) if rng is not None else None
    frames = []
    for i, qd in enumerate(CALIBRATION_POSES.values()):
        q = qd.copy()
        R = R_PALM_TO_CAMERA @ rotvec_to_matrix(np.array([0.25 * (i - 1), 0.2 * (i - 1), 0]))
        q[3:6] = root_angles_from_matrix(R)
        q[0:3] = (0.0, 0.07, 0.42)
        mesh = mesh_fn(q) if mesh_fn is not None else Mesh(model.vertices(q), model.faces, 1,
                                                            closed=True)
        res = ren.render(mesh if isinstance(mesh, list) else [mesh], intr)
        depth = (noise.apply_mm(res.depth, res.cos_incidence, intr, rng) if noise is not None
                 else np.rint(res.depth * 1000).astype(np.uint16))
        frames.append((depth, intr))
    return frames
