"""First-frame initialisation of the scene (seed 000 sec. 4.3): visual hull + ICP, then ISA.

Seed 000 starts its tracking from the subject's "flat hand": the hand's global position and
orientation come from ICP between the visual hull of the hand's silhouettes and the skinned
mesh in the flat pose, the joint angles are the flat pose's, and the registration is refined
by ISA on the silhouette and edge terms (eq. 5, 7); objects get the same ICP treatment.

* :func:`visual_hull`: voxels of a workspace box whose projection falls inside the
  silhouette of every camera that sees them (one miss allowed per voxel, for mask noise);
  the hull's surface voxels are the point cloud.
* :func:`icp_rigid`: trimmed point-to-point ICP (model -> hull nearest neighbours with a
  k-d tree, Kabsch / SVD step), from several starting orientations around the hull's
  principal axes; the start with the lowest trimmed RMS wins.
* :func:`initialise`: both for a first frame and for the tracker re-finding a lost hand
  (``parts``: which hands to initialise; the others stay at ``prior``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.joints import N_DOF, root_angles_from_matrix

__all__ = ["HullInitializer", "InitResult", "icp_rigid", "initialise", "place_object",
           "register", "visual_hull"]


def visual_hull(masks: Mapping[str, np.ndarray], rig: object,
                lo: Sequence[float] = (-0.35, -0.35, 0.005),
                hi: Sequence[float] = (0.35, 0.35, 0.4), voxel_m: float = 0.006,
                min_views: int = 3, max_misses: int = 1, keep_components: int = 0
                ) -> np.ndarray:
    """Surface points (N, 3) [m, world] of the visual hull of silhouettes.

    Args:
        masks: camera name -> (H, W) bool silhouette (cameras of ``rig``).
        rig: the cameras.
        lo, hi: the workspace box [m, world] (default: the studio's table, above its top).
        voxel_m: voxel size [m].
        min_views: a voxel needs at least this many cameras that see it in their image.
        max_misses: cameras that may see a voxel outside their silhouette.
        keep_components: > 0: keep only the largest this many connected pieces of the hull
            (and none under a tenth of the largest).
    """
    lo_a, hi_a = np.asarray(lo, float), np.asarray(hi, float)
    if not (voxel_m > 0 and np.all(hi_a > lo_a)):
        raise InputError("visual_hull: need voxel_m > 0 and hi > lo")
    axes = [np.arange(a + voxel_m / 2, b, voxel_m) for a, b in zip(lo_a, hi_a, strict=True)]
    shape = tuple(len(a) for a in axes)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    seen = np.zeros(len(grid), np.int16)
    miss = np.zeros(len(grid), np.int16)
    for name, m in masks.items():
        cam = rig.camera(name)
        mask = np.asarray(m, bool)
        k = cam.intrinsics
        if mask.shape != (k.height, k.width):
            raise InputError(f"mask of {name!r} is {mask.shape}, the camera is "
                             f"{(k.height, k.width)}")
        uv, front = cam.project(grid)
        u = np.round(uv[:, 0]).astype(np.int64)
        v = np.round(uv[:, 1]).astype(np.int64)
        inside = front & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
        idx = np.flatnonzero(inside)
        seen[idx] += 1
        miss[idx] += ~mask[v[idx], u[idx]]
    occ = ((seen >= min_views) & (miss <= max_misses)).reshape(shape)
    if keep_components > 0 and occ.any():  # drop stray voxels of silhouette noise
        from scipy import ndimage

        lab, n = ndimage.label(occ)
        sizes = np.bincount(lab.ravel())[1:]
        big = np.argsort(-sizes)[:keep_components]
        big = big[sizes[big] >= 0.1 * sizes.max()]
        occ = np.isin(lab, big + 1)
    inner = occ.copy()
    for ax in range(3):  # a surface voxel has an empty 6-neighbour
        for sh in (1, -1):
            inner &= np.roll(occ, sh, axis=ax)
    surf = occ & ~inner
    return grid[surf.ravel()]


def _kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R a + t - b| over matched points (N, 3)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cb - R @ ca


def icp_rigid(model: np.ndarray, target: np.ndarray, R0: np.ndarray, t0: np.ndarray,
              iters: int = 30, trim: float = 0.8) -> tuple[np.ndarray, np.ndarray, float]:
    """Trimmed point-to-point ICP of ``model`` (N, 3) onto ``target`` (M, 3) from (R0, t0).

    Returns:
        (R, t, rms): the pose (world <- model) and the RMS distance [m] of the kept
        ``trim`` share of model points to their nearest target points.
    """
    from scipy.spatial import cKDTree

    if len(model) < 3 or len(target) < 3:
        raise InputError("icp_rigid needs at least 3 model and 3 target points")
    tree = cKDTree(target)
    R, t = np.asarray(R0, float), np.asarray(t0, float)
    rms = np.inf
    for _ in range(iters):
        p = model @ R.T + t
        d, j = tree.query(p)
        keep = d <= np.quantile(d, trim)
        R_new, t_new = _kabsch(model[keep], target[j[keep]])
        rms_new = float(np.sqrt(np.mean(d[keep] ** 2)))
        R, t = R_new, t_new
        if abs(rms - rms_new) < 1e-6:
            rms = rms_new
            break
        rms = rms_new
    d, _ = tree.query(model @ R.T + t)
    d = np.sort(d)[: max(1, int(trim * len(d)))]
    return R, t, float(np.sqrt(np.mean(d ** 2)))


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def _starts(model: np.ndarray, target: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Starting poses: the model's principal axes onto the target's, in the 4 proper sign
    combinations, each also turned about the long axis by 90 / 180 / 270 deg."""
    def frame(x: np.ndarray) -> np.ndarray:
        _, _, Vt = np.linalg.svd(x - x.mean(axis=0), full_matrices=False)
        F = Vt.T
        if np.linalg.det(F) < 0:
            F[:, 2] *= -1
        return F

    Fm, Ft = frame(model), frame(target)
    out = []
    for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        S = np.diag([sx, sy, sx * sy])
        for a in (0.0, np.pi / 2, np.pi, 1.5 * np.pi):
            R = Ft @ S @ _rot(0, a) @ Fm.T
            out.append((R, target.mean(axis=0) - R @ model.mean(axis=0)))
    return out


def register(model: np.ndarray, target: np.ndarray, iters: int = 30
             ) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`icp_rigid` from every start of :func:`_starts`; the best (R, t, rms)."""
    best = None
    for R0, t0 in _starts(model, target):
        R, t, rms = icp_rigid(model, target, R0, t0, iters=iters)
        if best is None or rms < best[2]:
            best = (R, t, rms)
    assert best is not None
    return best


def place_object(masks: Mapping[str, np.ndarray], rig: object, vertices: np.ndarray, *,
                 voxel_m: float = 0.006, lo: Sequence[float] = (-0.35, -0.35, 0.005),
                 hi: Sequence[float] = (0.35, 0.35, 0.4), min_views: int = 3,
                 name: str = "object") -> tuple[np.ndarray, float]:
    """A rigid object's 6 parameters (position [m], XYZ angles [rad]) from its silhouettes:
    the largest piece of their visual hull (:func:`visual_hull` in the box ``lo``..``hi``)
    and the mesh ``vertices`` (V, 3) [m, object frame] registered onto it (:func:`register`).

    Returns:
        (params (6,), the ICP's trimmed RMS [m]).

    Raises:
        InputError: a hull of fewer than 10 points.
    """
    oh = visual_hull({k: v for k, v in masks.items() if k in rig.names}, rig, lo=lo, hi=hi,
                     voxel_m=voxel_m, min_views=min_views, keep_components=1)
    if len(oh) < 10:
        raise InputError(f"the visual hull of {name!r} has {len(oh)} points")
    verts = np.asarray(vertices, float)
    R, t, r = register(verts[:: max(1, len(verts) // 600)], oh)
    return np.concatenate([t, root_angles_from_matrix(R)]), r


@dataclass
class InitResult:
    """What :func:`initialise` found.

    Attributes:
        params: (n_params,) the initial configuration.
        hull: (N, 3) the hull's surface points [m, world].
        rms_m: per initialised part (hand index, or n_hands + object index), the ICP's
            trimmed RMS distance [m].
        refined: whether ISA refined the ICP result.
    """

    params: np.ndarray
    hull: np.ndarray
    rms_m: dict[int, float]
    refined: bool


def initialise(group: Mapping[str, object], scene: object, rig: object, *,
               hand_masks: Mapping[str, np.ndarray] | None = None, colour: object = None,
               prior: np.ndarray | None = None, parts: Sequence[int] | None = None,
               refine_particles: int = 0, refine_iters: int = 10, seed: int = 0,
               voxel_m: float = 0.006,
               object_masks: Mapping[str, Mapping[str, np.ndarray]] | None = None
               ) -> InitResult:
    """Initial configuration of hands from one synchronised group (seed 000 sec. 4.3).

    Args:
        group: camera name -> (H, W, 3) uint8 image (or a view with ``rgb``).
        scene: the :class:`~hand_capture.multiview.scene_model.SceneModel`.
        rig: the cameras.
        hand_masks: camera name -> (H, W) bool hand silhouettes; else from ``colour``
            (a :class:`~hand_capture.multiview.imageterms.ColourModel`, eq. 4).
        prior: (n_params,) configuration the parts not initialised keep (objects, a hand
            still tracked); default: the flat hands at the origin, objects at the origin.
        parts: indices of the hands to initialise (default: every hand).
        refine_particles: > 0: refine the ICP result with ISA (this many particles,
            ``refine_iters`` iterations) on the silhouette and edge terms (eq. 5, 7); the
            colour term is left out (its model is learned on this very frame).
        seed: random seed of the refinement.
        voxel_m: voxel size of the hull [m].
        object_masks: object name -> (camera name -> (H, W) bool silhouette): those objects
            are placed by the same hull + ICP (their mesh onto their hull); the others keep
            ``prior``.

    Returns:
        the configuration, the hull and the ICP residuals.

    Raises:
        InputError: no silhouettes, or a hull too small for a hand.
    """
    from hand_capture.tracking.forest import weighted_kmeans

    p = np.zeros(scene.n_params) if prior is None else scene.check(prior).copy()
    todo = list(range(scene.n_hands)) if parts is None else [int(i) for i in parts]
    if any(not 0 <= i < scene.n_hands for i in todo):
        raise InputError(f"parts must index the scene's {scene.n_hands} hands, got {todo}")
    if hand_masks is None:
        if colour is None:
            raise InputError("initialise needs hand_masks or a colour model")
        hand_masks = {k: colour.silhouette(np.asarray(getattr(v, "rgb", v)))
                      for k, v in group.items() if k in rig.names}
    masks = {k: np.asarray(v, bool) for k, v in hand_masks.items() if k in rig.names}
    if len(masks) < 3:
        raise InputError(f"initialise needs silhouettes from >= 3 cameras, got {len(masks)}")
    hull = visual_hull(masks, rig, voxel_m=voxel_m, keep_components=scene.n_hands)
    # a hand kept at the prior is taken out of the hull (its points within 2 cm)
    from scipy.spatial import cKDTree

    for i in range(scene.n_hands):
        if i in todo or prior is None:
            continue
        v = scene.hands[i].vertices(scene.part_params(p, i))
        if len(hull):
            d, _ = cKDTree(v).query(hull)
            hull = hull[d > 0.02]
    if len(hull) < 30 * len(todo):
        raise InputError(f"the visual hull has {len(hull)} points: no hand in the silhouettes")
    # the hull holds every hand not taken out above: one cluster per such hand
    n_clusters = len(todo) if prior is not None else scene.n_hands
    if n_clusters > 1:
        centres, _ = weighted_kmeans(hull, np.ones(len(hull)), n_clusters)
        lab = np.argmin(((hull[:, None] - centres[None]) ** 2).sum(-1), axis=1)
        clusters = [hull[lab == c] for c in range(len(centres))]
    else:
        clusters = [hull]
    flat = [scene.hands[i].vertices(np.zeros(N_DOF))[::3] for i in todo]
    # assign clusters to hands: every permutation, the lowest total RMS
    from itertools import permutations

    best = None
    for perm in permutations(range(len(clusters)), len(todo)):
        fits = [register(flat[k], clusters[c]) for k, c in enumerate(perm)]
        tot = sum(f[2] for f in fits)
        if best is None or tot < best[0]:
            best = (tot, fits)
    assert best is not None
    rms = {}
    for k, i in enumerate(todo):
        R, t, r = best[1][k]
        q = np.zeros(N_DOF)
        q[:3] = t
        q[3:6] = root_angles_from_matrix(R)
        p[scene.slices[scene.part_names[i]]] = q
        rms[i] = r
    for name, om in (object_masks or {}).items():
        j = scene.part_index(name) - scene.n_hands
        if j < 0:
            raise InputError(f"object_masks: {name!r} is a hand, not an object")
        p[scene.slices[name]], rms[scene.n_hands + j] = place_object(
            om, rig, scene.objects[j].vertices, voxel_m=voxel_m, name=name)
    p = scene.clip(p)
    refined = False
    if refine_particles > 0:
        from hand_capture.multiview.imageterms import ImageCost, ImageTermsConfig, observe
        from hand_capture.multiview.isa import ISAConfig, default_sigma, isa_minimise

        tcfg = ImageTermsConfig(w_color=0.0)
        views = [observe(np.asarray(getattr(group[n], "rgb", group[n])), rig.camera(n), None,
                         tcfg, silhouette=masks[n]) for n in masks if n in group]
        cost = ImageCost(scene, tcfg)
        sig = default_sigma(scene) * 2.0
        keep = np.zeros(scene.n_params, bool)
        for i in todo:
            keep[scene.slices[scene.part_names[i]]] = True
        sig[~keep] = 0.0
        res = isa_minimise(lambda X: cost(X, views), p, sig, scene.lo, scene.hi,
                           config=ISAConfig(n_particles=refine_particles,
                                            n_iters=refine_iters), seed=seed)
        p = res.best_x if res.best_cost < res.cost else res.x
        refined = True
    return InitResult(p, hull, rms, refined)


class HullInitializer:
    """:func:`initialise` as the multi-view tracker's initialiser: called with
    ``(images, model, part)`` it returns the hand's 27 parameters, or None (an object, no
    colour model yet, or no hand in the hull).

    The hand silhouettes come from a colour model (eq. 4) that :meth:`learn` fits on a
    frame whose configuration is known (the first frame, or any well-tracked one); the
    configuration given to :meth:`set_prior` keeps the other, still tracked hand out of
    the hull.

    Args:
        rig: the cameras.
        voxel_m: voxel size of the hull [m].
    """

    def __init__(self, rig: object, voxel_m: float = 0.008) -> None:
        self.rig = rig
        self.voxel_m = voxel_m
        self.colour: object | None = None
        self.prior: np.ndarray | None = None

    def learn(self, images: Mapping[str, np.ndarray | None], model: object,
              params: np.ndarray) -> None:
        """Fit the colour model on ``images`` seen at the configuration ``params``."""
        from hand_capture.multiview.imageterms import ColourModel
        from hand_capture.multiview.isa import first_frame_masks

        names = [n for n in self.rig.names if images.get(n) is not None]
        masks = first_frame_masks(model, self.rig, params, names)
        self.colour = ColourModel.fit([np.asarray(images[n]) for n in names], masks,
                                      margin_px=3)
        self.prior = np.asarray(params, float).copy()

    def set_prior(self, params: np.ndarray) -> None:
        """The current configuration (its tracked hands are kept out of the hull)."""
        self.prior = np.asarray(params, float).copy()

    def __call__(self, images: Mapping[str, np.ndarray | None], model: object,
                 part: int) -> np.ndarray | None:
        if part >= model.n_hands or self.colour is None:
            return None
        group = {k: v for k, v in images.items() if v is not None}
        try:
            res = initialise(group, model, self.rig, colour=self.colour, prior=self.prior,
                             parts=[part], voxel_m=self.voxel_m)
        except InputError:
            return None
        return res.params[model.slices[model.part_names[part]]].copy()
