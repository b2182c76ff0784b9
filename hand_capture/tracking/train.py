"""Training of the shape-indexed cascaded regressor on rendered depth images (ch. II.4.4).

Subject variation: ``n_shapes`` random shapes (``sample_shape``, the dissertation uses 40).
Pose variation: a library of hand poses (open, fist, pinch, grasp, counting, the zero pose)
each perturbed at random, plus uniformly random poses inside the joint limits. Viewpoint
variation: random palm orientations around "palm towards the camera" and random positions
in front of the camera. Every sample is rendered by the project's CPU renderer and passed
through the sensor noise model (random and silhouette noise), then segmented like a live
frame. :func:`train_tracker` is reproducible from its seed on one machine (another CPU's
floating point can grow other forests from the same draws).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.motion import FIST, GRASP, OPEN, PINCH, R_PALM_TO_CAMERA
from hand_capture.cameras.noise import DepthNoiseConfig, DepthNoiseModel
from hand_capture.cameras.render import Mesh, make_renderer
from hand_capture.cameras.transforms import rotvec_to_matrix
from hand_capture.errors import InputError
from hand_capture.model import JOINT_LIMITS, N_DOF, HandModel, default_shape, sample_shape
from hand_capture.model.joints import pose_from_dict, root_angles_from_matrix
from hand_capture.tracking.augment import add_artifacts_mm
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.forest import RegressionForest
from hand_capture.tracking.preprocess import segment_hand
from hand_capture.tracking.regressor import (
    FINGER_KP,
    DepthLookup,
    FeatureSet,
    HandRegressor,
    ModelFrames,
    ik_fingers,
    palm_init_pca,
)
from hand_capture.tracking.tubes import TubeSurface, tube_mesh

__all__ = ["ARM_FRAMES", "ARM_LABEL", "HAND_LABEL", "POSE_FLOOR_RAD",
           "TOWARDS_PROB", "TRAIN_SAMPLES",
           "TrainingSample", "default_intrinsics", "draw_forearm",
           "finger_pitch_deg", "forearm_mesh", "random_pose", "render_samples",
           "train_tracker"]


#: renderer labels of the training renders: the hand mesh and the forearm
HAND_LABEL, ARM_LABEL = 1, 2
#: rendered frames of the shipped arm classifier (``hand-suite train tracker``)
ARM_FRAMES = 2000
#: rendered frames of the shipped regressor and its share of poses with the fingers pitched
#: towards the camera (:func:`random_pose`): chosen on the validation shapes 21-24
#: (``scripts/regressor_validation.py``; 3000 / 0 before, docs/experiments/depth_tracking.md)
TRAIN_SAMPLES, TOWARDS_PROB = 10000, 0.15
#: share of training renders with stereo artifacts (:mod:`~hand_capture.tracking.augment`)
ARTIFACT_PROB = 0.5
#: share of training hands drawn with the tube surface (:mod:`~hand_capture.tracking.tubes`)
#: in the first regressor (0.5 there was tried and not shipped,
#: docs/experiments/depth_tracking.md)
TUBE_PROB = 0.0
#: the ensemble's second regressor (``TrackerConfig.ensemble``,
#: ``data/tracker/regressor_tubes.npz``, ``--second``): half of its training hands drawn as
#: tubes, and another seed (chosen on the validation families,
#: docs/experiments/depth_tracking.md)
SECOND_TUBE_PROB, SECOND_SEED = 0.5, 2
#: the uniformly drawn training poses' finger joints start here or at their lower limit,
#: whichever is higher [rad] (:func:`random_pose`; None: at the limits). The shipped files'
#: draw: no MCP hyperextension beyond 11 deg (the limits allow 30), the ring and little
#: fingers' spread cut at 11 of 20-25 deg. None was tried in the forty-sixth session and
#: not shipped (docs/experiments/depth_tracking.md)
POSE_FLOOR_RAD: float | None = -0.2


def default_intrinsics() -> Intrinsics:
    """The synthetic camera's default 320x240 pinhole (70 deg horizontal FOV)."""
    return Intrinsics.from_fov(320, 240, 70.0)


def _library() -> list[np.ndarray]:
    def hand(ext: tuple[str, ...], thumb_out: bool) -> dict[str, float]:
        d = math.radians
        q: dict[str, float] = {}
        for f in ("index", "middle", "ring", "little"):
            flex = (0, 0, 0) if f in ext else (85, 100, 60)
            q.update({f"{f}_mcp_flex": d(flex[0]), f"{f}_pip_flex": d(flex[1]),
                      f"{f}_dip_flex": d(flex[2])})
        q.update({"thumb_tm_flex": 0.0, "thumb_mcp_flex": 0.0, "thumb_ip_flex": 0.0}
                 if thumb_out else {"thumb_tm_abd": d(15), "thumb_tm_flex": d(45),
                                    "thumb_mcp_flex": d(45), "thumb_ip_flex": d(50)})
        return q

    lib = [OPEN, FIST, PINCH, GRASP, hand(("index",), False), hand(("index", "middle"), False),
           hand(("index", "middle", "ring"), False), hand(("index", "middle", "ring", "little"),
                                                          False), hand(("index",), True), {}]
    return [pose_from_dict(p) for p in lib]


_LIB = _library()


def finger_pitch_deg(model: HandModel, q: np.ndarray) -> float:
    """How far the hand's fingers point towards the camera [deg]: the angle of the wrist ->
    middle-MCP direction of pose ``q`` (27,) above the image plane (positive: towards the
    camera, i.e. its camera-frame z decreasing; negative: away)."""
    kp = model.joint_positions(q)
    d = kp[9] - kp[0]
    return math.degrees(math.asin(float(np.clip(-d[2] / np.linalg.norm(d), -1.0, 1.0))))


def random_pose(rng: np.random.Generator, model: HandModel, *, max_tilt_deg: float = 60.0,
                max_roll_deg: float = 45.0, towards_prob: float = 0.0,
                towards_deg: tuple[float, float] = (20.0, 60.0),
                floor_rad: float | None = POSE_FLOOR_RAD) -> np.ndarray:
    """A random training pose in the camera frame (see the module docstring).

    Args:
        rng: the random source.
        model: the hand (its middle MCP is put at the sampled position).
        max_tilt_deg: the palm turned about a random axis by up to this from "palm towards
            the camera" [deg] (angle uniform in [0, max_tilt_deg]).
        max_roll_deg: roll about the optical axis, uniform in +-max_roll_deg [deg].
        towards_prob: share of poses then pitched with the fingers towards the camera
            (about the axis across the distal direction and the optical axis) by an angle
            uniform in ``towards_deg`` [deg] (the held-out diagnosis' failing views: fingers
            40-45 deg towards the camera). 0 draws nothing extra, so the poses of a seed
            are those of the plain generator.
        floor_rad: the uniformly drawn poses' finger joints start at ``max(lower limit,
            floor_rad)`` [rad]; None = at the joint limits (default :data:`POSE_FLOOR_RAD`).
    """
    if not 0.0 <= towards_prob <= 1.0:
        raise InputError(f"towards_prob must be in [0, 1], got {towards_prob}")
    if rng.random() < 0.75:
        q = _LIB[rng.integers(len(_LIB))].copy()
        q[6:] += rng.normal(0.0, 0.18, N_DOF - 6)
    else:
        hi = JOINT_LIMITS[6:, 1]
        lo = JOINT_LIMITS[6:, 0] if floor_rad is None else np.maximum(JOINT_LIMITS[6:, 0],
                                                                       floor_rad)
        q = np.zeros(N_DOF)
        q[6:] = lo + (hi - lo) * rng.random(N_DOF - 6)
    q[6:] = np.clip(q[6:], JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1])
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    tilt = rotvec_to_matrix(axis * math.radians(max_tilt_deg) * rng.random())
    roll = rotvec_to_matrix(np.array([0.0, 0.0, 1.0]) * math.radians(max_roll_deg)
                            * rng.uniform(-1, 1))
    R = roll @ R_PALM_TO_CAMERA @ tilt
    rest = model.joint_positions(np.zeros(N_DOF))   # (21, 3) keypoints of the zero pose
    if towards_prob > 0.0 and rng.random() < towards_prob:
        d = R @ (rest[9] - rest[0])
        axis = np.cross(d, np.array([0.0, 0.0, -1.0]))   # turns d towards -z (the camera)
        if np.linalg.norm(axis) > 1e-6:
            pitch = math.radians(rng.uniform(*towards_deg))
            R = rotvec_to_matrix(axis / np.linalg.norm(axis) * pitch) @ R
    centre = np.array([rng.uniform(-0.06, 0.06), rng.uniform(-0.05, 0.05),
                       rng.uniform(0.30, 0.55)])
    q[0:3] = centre - R @ rest[9]
    q[3:6] = root_angles_from_matrix(R)
    return q


def draw_forearm(rng: np.random.Generator) -> tuple[float, float, tuple[float, float]]:
    """The training renders' random forearm for :func:`forearm_mesh`: ``(radius, length,
    bend)``, radius uniform in 24-40 mm, length 0.25-0.5 m, bend +-0.4 rad about each axis
    (drawn in that order)."""
    radius, length = float(rng.uniform(0.024, 0.04)), float(rng.uniform(0.25, 0.5))
    return radius, length, tuple(float(b) for b in rng.uniform(-0.4, 0.4, 2))


def forearm_mesh(model: HandModel, q: np.ndarray, radius: float = 0.03,
                 length: float = 0.4, bend: tuple[float, float] = (0.0, 0.0),
                 label: int = HAND_LABEL, start: float = -0.015) -> Mesh:
    """A forearm for the training renders: a closed cylinder (from 15 mm inside the wrist)
    along the wrist-from-middle-MCP direction, turned by ``bend`` (flexion, deviation)
    [rad] at the wrist.

    Args:
        model: the rendered hand model.
        q: its pose (27,).
        radius, length: cylinder size [m].
        bend: rotation of the forearm axis about the palm's across axis and its normal.
        label: the renderer label of its pixels.
        start: where the cylinder begins along the forearm axis, from the wrist [m]
            (negative: inside the hand; a sleeve starts beyond the wrist).
    """
    from hand_capture.cameras.primitives import cylinder

    kp = model.joint_positions(q)
    d = kp[0] - kp[9]
    d /= np.linalg.norm(d)
    x = kp[5] - kp[17]
    x -= d * (x @ d)
    x /= np.linalg.norm(x)
    d = rotvec_to_matrix(x * bend[0] + np.cross(d, x) * bend[1]) @ d
    V, F = cylinder(radius, length, 20)
    # rotation taking the cylinder's z axis onto d (Rodrigues)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, d)
    sn, c = float(np.linalg.norm(v)), float(z @ d)
    if sn < 1e-9:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        R = np.eye(3) + K + K @ K * ((1 - c) / sn ** 2)
    return Mesh(V @ R.T + kp[0] + d * (0.5 * length + start), F, label, closed=True)


@dataclass
class TrainingSample:
    """One rendered, segmented training frame (hand crop only, to save memory)."""

    crop: np.ndarray      # (h, w) float32 hand depth [m]
    u0: int
    v0: int
    points: np.ndarray    # (N, 3) hand points (subsampled) for the PCA initialisation
    pose: np.ndarray      # (27,) true pose
    shape_index: int
    #: (h, w) uint8 renderer labels of the crop (HAND_LABEL, ARM_LABEL, 0 = none)
    label: np.ndarray | None = None


def render_samples(n: int, rng: np.random.Generator, models: list[HandModel],
                   intr: Intrinsics, noise: DepthNoiseConfig | None = None,
                   cfg: TrackerConfig | None = None, *, forearm_prob: float = 0.0,
                   surface_mm: tuple[float, float] = (0.0, 0.0), cut_arm: bool = True,
                   max_tilt_deg: float = 60.0, towards_prob: float = 0.0,
                   artifact_prob: float = 0.0, tube_prob: float = 0.0,
                   pose_floor_rad: float | None = POSE_FLOOR_RAD) -> list[TrainingSample]:
    """Render ``n`` noisy, segmented samples (shapes cycled through ``models``).

    Widened generator (issue 13): with probability ``forearm_prob`` a forearm
    (:func:`forearm_mesh`, :func:`draw_forearm`: radius 24-40 mm, length 0.25-0.5 m, bend
    +-0.4 rad) is
    rendered with the hand and cut as at run time (``cut_forearm``: at a wrist estimate
    perturbed by a few mm, or from the cloud's shape alone, half each); every sample's
    surface is moved along the normals by a uniform offset in ``surface_mm`` [mm] plus as
    much again on the palm, so the forests see hands thicker and thinner than the model's.
    Each sample keeps the renderer's labels of its crop (``label``: :data:`HAND_LABEL`,
    :data:`ARM_LABEL`); ``cut_arm`` False keeps the forearm in the segment (training data of
    the per-pixel arm classifier, :mod:`~hand_capture.tracking.armseg`). ``max_tilt_deg``
    and ``towards_prob`` set the viewpoints (:func:`random_pose`). A share
    ``artifact_prob`` of the images also gets a stereo camera's artifacts
    (:func:`~hand_capture.tracking.augment.add_artifacts_mm`) after the sensor model. A
    share ``tube_prob`` of the hands is drawn with another surface than the template mesh
    (:mod:`~hand_capture.tracking.tubes`, a new draw each; the surface offsets do not apply).
    ``pose_floor_rad``: where the uniformly drawn poses' finger joints start (:func:`random_pose`).
    """
    from hand_capture.tracking.preprocess import cut_forearm

    cfg = cfg or TrackerConfig()
    renderer = make_renderer("zbuffer")
    nm = DepthNoiseModel(noise or DepthNoiseConfig())
    out: list[TrainingSample] = []
    while len(out) < n:
        k = len(out) % len(models)
        m = models[k]
        q = random_pose(rng, m, max_tilt_deg=max_tilt_deg, towards_prob=towards_prob,
                        floor_rad=pose_floor_rad)
        if tube_prob > 0 and rng.random() < tube_prob:
            meshes = [tube_mesh(m, q, TubeSurface.sample(rng), HAND_LABEL)]
        else:
            V = m.vertices(q)
            if surface_mm != (0.0, 0.0):
                off = rng.uniform(*surface_mm) * 1e-3
                palm = rng.uniform(0.0, max(surface_mm[1], 0.0)) * 1e-3 \
                    * (m.vertex_labels == 0)
                V = V + m.normals(V) * (off + palm)[:, None]
            meshes = [Mesh(V, m.faces, HAND_LABEL, closed=True)]
        arm = rng.random() < forearm_prob
        if arm:
            meshes.append(forearm_mesh(m, q, *draw_forearm(rng), label=ARM_LABEL))
        res = renderer.render(meshes, intr)
        depth = nm.apply_mm(res.depth, res.cos_incidence, intr, rng)
        if artifact_prob > 0 and rng.random() < artifact_prob:
            depth = add_artifacts_mm(depth, rng)
        obs = segment_hand(depth, intr, cfg)
        if len(obs.points) < 200:
            continue
        if arm:
            kp = m.joint_positions(q)
            d = kp[0] - kp[9]
            d = d / np.linalg.norm(d) + rng.normal(0, 0.05, 3)
            wrist = (kp[0] + rng.normal(0, 0.005, 3), d / np.linalg.norm(d)) \
                if rng.random() < 0.5 else None
            if cut_arm:
                obs, _ = cut_forearm(obs, cfg, m.shape.global_scale, wrist)
            if obs.n_points < 200:
                continue
        v, u = np.nonzero(obs.mask)
        v0, v1, u0, u1 = v.min(), v.max() + 1, u.min(), u.max() + 1
        pts, _ = obs.subsample(400)
        out.append(TrainingSample(obs.depth_m[v0:v1, u0:u1].copy(), int(u0), int(v0),
                                  pts.copy(), q, k, res.label[v0:v1, u0:u1].copy()))
    return out


def _batched(models: list[HandModel], samples: list[TrainingSample], Q: np.ndarray,
             fn: Callable[[HandModel, np.ndarray], np.ndarray]) -> list[np.ndarray]:
    """``fn(model, Q_group)`` per shape group, results back in sample order."""
    out: list[np.ndarray | None] = [None] * len(samples)
    shape_idx = np.array([s.shape_index for s in samples])
    for k, m in enumerate(models):
        idx = np.flatnonzero(shape_idx == k)
        if idx.size == 0:
            continue
        res = fn(m, Q[idx])
        for j, i in enumerate(idx):
            out[i] = res[j]
    return out  # type: ignore[return-value]


def train_tracker(out_path: str | Path | None, seed: int = 0,
                  n_samples: int = TRAIN_SAMPLES, *,
                  n_shapes: int = 40, palm_stages: int = 3, finger_stages: int = 2,
                  n_trees: int = 6, max_depth: int = 12, min_leaf: int = 5,
                  n_features: int = 300, leaf_modes: int = 2, augment: int = 2,
                  intrinsics: Intrinsics | None = None, log: Callable[[str], None] | None = None,
                  forearm_prob: float = 0.5, surface_mm: tuple[float, float] = (-1.0, 2.5),
                  max_tilt_deg: float = 60.0, towards_prob: float = TOWARDS_PROB,
                  artifact_prob: float = ARTIFACT_PROB, tube_prob: float = TUBE_PROB,
                  relative_background: bool = True,
                  pose_floor_rad: float | None = POSE_FLOOR_RAD) -> HandRegressor:
    """Train the cascaded regressor from scratch, reproducibly from ``seed``.

    Args:
        out_path: where to save the model (``.npz``); None = do not save.
        seed: seeds shapes, poses, noise, feature sampling and the forests.
        n_samples: rendered training frames.
        n_shapes: random subject shapes (the first is the default shape).
        palm_stages, finger_stages: cascade lengths C of eq. II.17 / II.18.
        n_trees, max_depth, min_leaf: forest size per stage.
        n_features: candidate feature pairs per stage (and per finger).
        leaf_modes: modes stored per palm leaf (II.4.3).
        augment: initialisations per sample for palm training (PCA + perturbed copies).
        intrinsics: camera of the training images (default 320x240, 70 deg).
        log: progress callback (e.g. print).
        forearm_prob: share of samples rendered with a forearm (:func:`render_samples`).
        surface_mm: range of the per-sample surface offset [mm] (:func:`render_samples`).
        max_tilt_deg, towards_prob: the viewpoints of the training poses (:func:`random_pose`).
        artifact_prob: share of samples with a stereo camera's artifacts
            (:func:`render_samples`).
        tube_prob: share of samples whose hand is drawn as tubes on the skeleton
            (:mod:`~hand_capture.tracking.tubes`, :func:`render_samples`).
        relative_background: a feature's point off the hand reads its own depth + 1 m
            (:class:`~hand_capture.tracking.regressor.DepthLookup`; ``info["background"]``
            "relative"), not a constant 2 m ("constant": the distance of the hand a cue).
        pose_floor_rad: where the uniformly drawn poses' finger joints start
            (:func:`random_pose`, :data:`POSE_FLOOR_RAD`).

    Returns:
        The trained :class:`HandRegressor`.
    """
    t_start = time.perf_counter()
    say = log or (lambda s: None)
    rng = np.random.default_rng(seed)
    intr = intrinsics or default_intrinsics()
    base = HandModel(default_shape())
    shapes = [default_shape()] + [sample_shape(rng, f"train{k}") for k in range(1, n_shapes)]
    models = [base.with_shape(s) for s in shapes]
    frames = [ModelFrames(m) for m in models]
    samples = render_samples(n_samples, rng, models, intr, forearm_prob=forearm_prob,
                             surface_mm=surface_mm, max_tilt_deg=max_tilt_deg,
                             towards_prob=towards_prob, artifact_prob=artifact_prob,
                             tube_prob=tube_prob, pose_floor_rad=pose_floor_rad)
    say(f"rendered {len(samples)} samples in {time.perf_counter() - t_start:.1f} s")
    lookups = [DepthLookup(s.crop, s.u0, s.v0, intr, relative=relative_background)
               for s in samples]
    rest = ModelFrames(base).rest_vertices
    labels = base.vertex_labels
    q_true = np.array([s.pose for s in samples])

    # ---------------------------------------------------------------- palm (eq. II.17)
    inst = [(i, a) for i in range(len(samples)) for a in range(augment)]
    Q = np.empty((len(inst), N_DOF))
    for j, (i, a) in enumerate(inst):
        s = samples[i]
        q0 = palm_init_pca(s.points, frames[s.shape_index])
        if a > 0:
            R = rotvec_to_matrix(rng.normal(0, 0.25, 3)) @ \
                frames[0].palm_pose(q0)[0]
            q0 = frames[s.shape_index].set_palm(q0, R, q0[0:3] + rng.normal(0, 0.015, 3))
        Q[j] = q0
    inst_samples = [samples[i] for i, _ in inst]
    inst_true = q_true[[i for i, _ in inst]]
    palm_feats, palm_forests = [], []
    for s_idx in range(palm_stages):
        fs = FeatureSet.sample(rest, np.arange(len(rest)), np.eye(3), n_features, 0.035, rng)
        Vs = _batched(models, inst_samples, Q, lambda m, qq: m.vertices(qq))
        X = np.empty((len(inst), n_features), np.float32)
        Y = np.empty((len(inst), 18))
        for j, (i, _) in enumerate(inst):
            fr = frames[samples[i].shape_index]
            R, _ = fr.palm_pose(Q[j])
            X[j] = fs.evaluate(Vs[j], R, lookups[i])
            Y[j] = HandRegressor.palm_target(fr, Q[j], inst_true[j], models[samples[i]
                                                                            .shape_index])
        last = s_idx == palm_stages - 1
        forest = RegressionForest.fit(X, Y, n_trees=n_trees, max_depth=max_depth,
                                      min_leaf=min_leaf, leaf_modes=leaf_modes if last else 1,
                                      rng=rng)
        pred = forest.predict(X)
        for j, (i, _) in enumerate(inst):
            Q[j] = HandRegressor.palm_update(frames[samples[i].shape_index], Q[j], pred[j])
        palm_feats.append(fs)
        palm_forests.append(forest)
        err = np.linalg.norm((Y - pred).reshape(-1, 6, 3), axis=2).mean() * 1000
        say(f"palm stage {s_idx + 1}: {forest.value.shape[0]} leaves, residual before "
            f"{np.linalg.norm(Y.reshape(-1, 6, 3), axis=2).mean() * 1000:.1f} mm, after "
            f"{err:.1f} mm ({time.perf_counter() - t_start:.0f} s)")

    # ------------------------------------------------------------- fingers (eq. II.18)
    Qf = q_true.copy()
    Qf[:, 6:] = 0.0
    for j, s in enumerate(samples):  # palm as after refinement: true palm + small error
        fr = frames[s.shape_index]
        R = rotvec_to_matrix(rng.normal(0, 0.05, 3)) @ fr.palm_pose(Qf[j])[0]
        Qf[j] = fr.set_palm(Qf[j], R, Qf[j, 0:3] + rng.normal(0, 0.004, 3))
    kp_true = np.array(_batched(models, samples, q_true, lambda m, qq: m.joint_positions(qq)))
    finger_feats: list[list[FeatureSet]] = []
    finger_forests: list[list[RegressionForest]] = []
    for s_idx in range(finger_stages):
        Vs = _batched(models, samples, Qf, lambda m, qq: m.vertices(qq))
        kps = np.array(_batched(models, samples, Qf, lambda m, qq: m.joint_positions(qq)))
        targets = np.empty((len(samples), 5, 3, 3))
        feats_s, forests_s = [], []
        for f in range(5):
            bones = np.arange(1 + 3 * f, 4 + 3 * f)
            region = np.flatnonzero(np.isin(labels, bones))
            fs = FeatureSet.sample(rest, region, frames[0].finger_rot[f], n_features, 0.025,
                                   rng)
            X = np.empty((len(samples), n_features), np.float32)
            Y = np.empty((len(samples), 9))
            Rfs = []
            for j, s in enumerate(samples):
                Rf = HandRegressor.finger_frames(frames[s.shape_index], Qf[j])[f]
                Rfs.append(Rf)
                X[j] = fs.evaluate(Vs[j], Rf, lookups[j])
                Y[j] = ((kp_true[j, FINGER_KP[f]] - kps[j, FINGER_KP[f]]) @ Rf).reshape(-1)
            forest = RegressionForest.fit(X, Y, n_trees=n_trees, max_depth=max_depth,
                                          min_leaf=min_leaf, rng=rng)
            pred = forest.predict(X).reshape(-1, 3, 3)
            for j in range(len(samples)):
                targets[j, f] = kps[j, FINGER_KP[f]] + pred[j] @ Rfs[j].T
            feats_s.append(fs)
            forests_s.append(forest)
        T = targets
        shape_idx = np.array([s.shape_index for s in samples])
        for k, m in enumerate(models):
            idx = np.flatnonzero(shape_idx == k)
            if idx.size:
                Qf[idx] = ik_fingers(m, Qf[idx], T[idx], 2)
        kps = np.array(_batched(models, samples, Qf, lambda m, qq: m.joint_positions(qq)))
        err = np.linalg.norm(kps[:, FINGER_KP.reshape(-1)] - kp_true[:, FINGER_KP.reshape(-1)],
                             axis=2).mean() * 1000
        finger_feats.append(feats_s)
        finger_forests.append(forests_s)
        say(f"finger stage {s_idx + 1}: finger keypoint error {err:.1f} mm "
            f"({time.perf_counter() - t_start:.0f} s)")
    reg = HandRegressor(palm_feats, palm_forests, finger_feats, finger_forests, 2,
                        {"seed": str(seed), "n_samples": str(n_samples),
                         "n_shapes": str(n_shapes), "n_trees": str(n_trees),
                         "max_depth": str(max_depth), "forearm_prob": str(forearm_prob),
                         "surface_mm": f"{surface_mm[0]},{surface_mm[1]}",
                         "max_tilt_deg": str(max_tilt_deg), "towards_prob": str(towards_prob),
                         "tube_prob": str(tube_prob), "pose_floor_rad": str(pose_floor_rad),
                         "background": "relative" if relative_background else "constant",
                         "train_s": f"{time.perf_counter() - t_start:.0f}"})
    if out_path is not None:
        reg.save(out_path)
        say(f"saved {out_path}")
    return reg


def _floor_arg(text: str) -> float | None:
    """``--pose-floor``: a number [rad] or ``none`` (the joint limits)."""
    return None if text.strip().lower() == "none" else float(text)


def main(argv: list[str] | None = None) -> int:
    """``python -m hand_capture.tracking.train [--out PATH] [--seed N] [--samples N]
    [--towards P] [--tubes P] [--arm-out PATH] [--arm-frames N] [--arm-only | --second]``:
    the regressor, then the per-pixel arm classifier
    (:func:`~hand_capture.tracking.armseg.train_arm_classifier`); ``--second``: the
    ensemble's second regressor alone (its seed, tube share and file by default)."""
    import argparse

    from hand_capture.cameras.threads import limit_blas_threads
    from hand_capture.tracking.armseg import train_arm_classifier
    from hand_capture.tracking.hybrid import SECOND_MODEL_NAME

    tracker_dir = Path(__file__).resolve().parents[2] / "data" / "tracker"
    ap = argparse.ArgumentParser(description="train the depth tracker's regressor and its "
                                 "hand/arm pixel classifier")
    ap.add_argument("--out", default=None, help="default: data/tracker/regressor.npz "
                    "(--second: data/tracker/regressor_tubes.npz)")
    ap.add_argument("--seed", type=int, default=None, help=f"default: 0 (--second: "
                    f"{SECOND_SEED})")
    ap.add_argument("--samples", type=int, default=TRAIN_SAMPLES)
    ap.add_argument("--towards", type=float, default=TOWARDS_PROB,
                    help="share of training poses with the fingers towards the camera")
    ap.add_argument("--artifacts", type=float, default=ARTIFACT_PROB,
                    help="share of training renders with a stereo camera's artifacts")
    ap.add_argument("--tubes", type=float, default=None,
                    help=f"share of training hands drawn as tubes on the skeleton (default: "
                    f"{TUBE_PROB}; --second: {SECOND_TUBE_PROB})")
    ap.add_argument("--pose-floor", type=_floor_arg, default=POSE_FLOOR_RAD, metavar="RAD",
                    help="the uniformly drawn poses' finger joints start at max(lower limit, "
                    f"RAD) (default {POSE_FLOOR_RAD}; 'none': at the joint limits)")
    ap.add_argument("--arm-out", default=str(tracker_dir / "arm.npz"))
    ap.add_argument("--arm-frames", type=int, default=ARM_FRAMES)
    only = ap.add_mutually_exclusive_group()
    only.add_argument("--arm-only", action="store_true",
                      help="train the arm classifier only (the regressor is left as it is)")
    only.add_argument("--second", action="store_true",
                      help="train the ensemble's second regressor only (the arm classifier "
                      "is left as it is)")
    a = ap.parse_args(argv)
    limit_blas_threads(1)
    second = a.second
    out = a.out or str(tracker_dir / (SECOND_MODEL_NAME if second else "regressor.npz"))
    seed = a.seed if a.seed is not None else SECOND_SEED if second else 0
    tubes = a.tubes if a.tubes is not None else SECOND_TUBE_PROB if second else TUBE_PROB
    if not a.arm_only:
        train_tracker(out, seed=seed, n_samples=a.samples, towards_prob=a.towards,
                      artifact_prob=a.artifacts, tube_prob=tubes, log=print,
                      pose_floor_rad=a.pose_floor)
    if not second:
        train_arm_classifier(a.arm_out, seed=seed, n_frames=a.arm_frames, log=print)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
