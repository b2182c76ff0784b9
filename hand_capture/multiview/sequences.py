"""Multi-view evaluation sequences with ground truth for the tracker (seed 002 sec. 5.1).

Scripted performances, posed kinematically (no physics) in the studio
(:mod:`hand_capture.multiview.studio`):

* ``fingers`` -- two hands, the right one above the left with their fingers crossing (the
  left hand turned 30 degrees under the right one), fingers folding in a wave (a 1 s period
  at 30 fps);
* ``ball`` -- two palm-up hands holding and passing a ball from the right palm to the left;
* ``box`` -- one hand grasps a box from above, lifts it by 4 cm and turns it by 30 degrees;
* ``leave`` -- one hand leaves every camera's view for 20 frames and comes back.

:func:`render_sequence` renders them from every rig camera:

* ``surface='heldout'``: the right hand as a subject of the held-out surface family
  (:mod:`hand_capture.evaldata.surface`, with a forearm), the left hand as the MJCF capsule
  hand: not the mesh the tracker fits;
* ``surface='own'``: the tracker's own skinned mesh (z-buffered into the studio's render of
  the objects and the room, Lambert shaded),

with the studio's colour noise and seed 002's structural noise (``circles`` random discs of
radius 10-30 px per image, half filled with random colours -- added structure -- and half with
the colour under their centre -- removed structure) and synthetic salient detections: the
visible nail centres projected with 1.5 px noise, each deleted with probability
``salient_miss``, plus ``salient_fp`` false positives per true one near the hands. Each
frame also carries, per camera, the mask of the pixels its circles changed
(``SequenceFrame.noise_masks``): seed 002 sec. 5.1 left the optical flow features of those
circles out, and a benchmark passes the masks to the tracker to do the same.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model import HandModel
from hand_capture.model.joints import JOINT_INDEX, JOINT_LIMITS, N_DOF, matrix_to_quat_wxyz
from hand_capture.multiview.rig import Rig
from hand_capture.multiview.scene_model import SceneModel, object_mesh

__all__ = ["LENGTHS", "SEQUENCES", "Sequence", "SequenceFrame", "make_sequence",
           "render_sequence"]

SEQUENCES = ("fingers", "ball", "box", "leave")
_FINGERS = ("index", "middle", "ring", "little")


@dataclass(frozen=True)
class Sequence:
    """A performance: hand poses (T, n_hands, 27) in scene-model hand order (right first),
    object poses (T, n_objects, 4, 4), object kinds (or ``ObjectSpec`` objects, for other
    sizes than a kind's default), and the scene model that tracks it."""

    name: str
    sides: tuple[str, ...]
    objects: tuple[Any, ...]
    hand_poses: np.ndarray
    object_poses: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.hand_poses.shape[0])

    def model(self) -> SceneModel:
        """The combined model of this scene (template hands, the objects' meshes)."""
        return SceneModel([HandModel(side=s) for s in self.sides],
                          [object_mesh(k) for k in self.objects])

    def truth(self, model: SceneModel, t: int) -> np.ndarray:
        """Scene parameters of frame ``t``."""
        return model.pack(list(self.hand_poses[t]), list(self.object_poses[t]))


@dataclass
class SequenceFrame:
    """One rendered group: camera -> RGB image, camera -> salient detections (k, 2) [px],
    and camera -> (H, W) bool mask of the pixels the structural-noise circles changed (every
    pixel a circle's anti-aliased disc touches, not grown; empty when ``circles`` = 0): the
    protocol's knowledge of where the noise is, which seed 002 sec. 5.1 uses to leave the
    optical flow features of those circles out (``MultiviewTracker.step(flow_ignore=...)``)."""

    images: dict[str, np.ndarray]
    detections: dict[str, np.ndarray]
    noise_masks: dict[str, np.ndarray] = field(default_factory=dict)


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    R = np.eye(3)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _hand(root: np.ndarray, R: np.ndarray, flex: float, spread: float = 0.0,
          thumb: float = 0.3, wave: np.ndarray | None = None) -> np.ndarray:
    """A 27-DoF pose: wrist at ``root``, orientation ``R``, fingers flexed by ``flex`` of
    their range (per finger offsets ``wave``), abduction ``spread`` [rad]."""
    from hand_capture.model.joints import root_angles_from_matrix

    q = np.zeros(N_DOF)
    q[:3] = root
    q[3:6] = root_angles_from_matrix(R)
    w = np.zeros(4) if wave is None else wave
    for i, f in enumerate(_FINGERS):
        a = float(np.clip(flex + w[i], 0.0, 1.0))
        for j in ("mcp_flex", "pip_flex", "dip_flex"):
            k = JOINT_INDEX[f"{f}_{j}"]
            q[k] = a * 0.85 * JOINT_LIMITS[k, 1]
        q[JOINT_INDEX[f"{f}_mcp_abd"]] = spread * (1.5 - i) / 1.5
    q[JOINT_INDEX["thumb_tm_abd"]] = 0.2
    for j in ("thumb_tm_flex", "thumb_mcp_flex", "thumb_ip_flex"):
        k = JOINT_INDEX[j]
        q[k] = thumb * 0.8 * JOINT_LIMITS[k, 1]
    return np.clip(q, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])


def _T(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def _smooth(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


#: frames each performance spans by default, at a real camera's 30 fps: the finger wave's
#: period is 1 s (30 frames; it was 16 frames, 0.53 s, up to 39 mm of fingertip motion a
#: frame); the ball pass and the box's grasp-lift-turn take 16 frames (0.53 s)
LENGTHS = {"fingers": 30, "ball": 16, "box": 16, "leave": 16}


def make_sequence(name: str, n_frames: int, length: int | None = None) -> Sequence:
    """The first ``n_frames`` frames of the scripted performance ``name`` (one of
    :data:`SEQUENCES`), which spans ``length`` frames (default :data:`LENGTHS`; a shorter run
    sees the same motion per frame, only less of it); ``leave`` has 3 + 3 + 20 + 3 +
    ``n_frames`` frames."""
    if name not in SEQUENCES:
        raise InputError(f"unknown sequence {name!r}; choose from {SEQUENCES}")
    length = LENGTHS[name] if length is None else length
    if n_frames < 2 or length < 2:
        raise InputError(f"a sequence needs at least 2 frames, got {n_frames} of {length}")
    s = np.arange(n_frames) / (length - 1.0)
    hands, objs = [], []
    if name == "fingers":
        for t in s:
            ph = 2 * math.pi * t
            wave = 0.25 * np.sin(ph + np.arange(4) * 0.9)
            right = _hand(np.array([-0.03, -0.04, 0.19]), _rot(2, 0.15), 0.25 + 0.15 *
                          math.sin(ph), spread=0.15, thumb=0.2, wave=wave)
            left = _hand(np.array([-0.02, 0.07, 0.10]), _rot(2, -0.5), 0.2 + 0.15 *
                         math.sin(ph + 1.0), spread=0.1, thumb=0.2, wave=wave[::-1])
            hands.append([right, left])
        return Sequence(name, ("right", "left"), (), np.array(hands), np.zeros((n_frames, 0,
                                                                                4, 4)))
    if name == "ball":
        r = 0.035
        up = _rot(0, math.pi)       # palm up
        for t in s:
            gap = 0.065 - 0.015 * math.sin(math.pi * t)
            rr = np.array([-0.04, -gap - 0.04, 0.08])
            ll = np.array([-0.04, gap + 0.04, 0.08])
            Rr = up @ _rot(2, 0.5) @ _rot(0, 0.25 * _smooth(np.array(t / 0.5)))
            Rl = up @ _rot(2, -0.5) @ _rot(0, -0.25 * _smooth(np.array((1 - t) / 0.5)))
            right = _hand(rr, Rr, 0.3, thumb=0.3)
            left = _hand(ll, Rl, 0.3, thumb=0.3)
            m = HandModel()
            pr = _palm_centre(m, right, r)
            pl = _palm_centre(HandModel(side="left"), left, r)
            k = float(_smooth(np.array((t - 0.3) / 0.4)))
            pos = (1 - k) * pr + k * pl + np.array([0, 0, 0.05 * math.sin(math.pi * k)])
            hands.append([right, left])
            objs.append([_T(_rot(0, 2.0 * k), pos)])
        return Sequence(name, ("right", "left"), ("ball",), np.array(hands), np.array(objs))
    if name == "box":
        h = 0.0285
        box0 = np.array([0.10, 0.0, h])
        palm_down = np.eye(3)
        grasp_rel = _T(palm_down, np.array([-0.05, 0.0, h + 0.031]))  # wrist w.r.t. box
        for t in s:
            a = float(_smooth(np.array(t / 0.25)))
            lift = float(_smooth(np.array((t - 0.25) / 0.4)))
            turn = float(_smooth(np.array((t - 0.55) / 0.45)))
            Tb = _T(_rot(2, math.radians(30) * turn), box0 + np.array([0, 0, 0.04 * lift]))
            Th = Tb @ grasp_rel
            Th[2, 3] += 0.02 * (1 - a)
            q = _hand(Th[:3, 3], Th[:3, :3], 0.1 + 0.2 * a, thumb=0.2 + 0.2 * a)
            hands.append([q])
            objs.append([Tb])
        return Sequence(name, ("right",), ("box",), np.array(hands), np.array(objs))
    # leave: 3 frames in view, 3 out, 20 away, 3 back, then n_frames in view
    base = np.array([0.0, 0.0, 0.12])
    away = np.array([0.0, 0.0, 1.05])
    path = [base] * 3 + [base + (away - base) * k / 3 for k in (1, 2, 3)] + [away] * 20 + \
        [away + (base - away) * k / 3 for k in (1, 2, 3)] + [base] * n_frames
    for i, p in enumerate(path):
        hands.append([_hand(p, _rot(2, 0.2), 0.2 + 0.15 * math.sin(0.3 * i), thumb=0.3)])
    return Sequence(name, ("right",), (), np.array(hands), np.zeros((len(path), 0, 4, 4)))


def _palm_centre(m: HandModel, q: np.ndarray, r: float) -> np.ndarray:
    """Where a ball of radius ``r`` rests on the palm of pose ``q`` (palm side normal)."""
    fk = m.forward(q)
    kp = fk.joint_positions
    c = kp[[0, 5, 9, 13, 17]].mean(axis=0)
    n = -fk.joint_frames[0, :3, 2]        # palm side: -z of the hand frame
    return c + n * (r + 0.016)


def _studio_objects(seq: Sequence) -> list:
    from hand_capture.model.mjcf import ObjectSpec

    return [k if isinstance(k, ObjectSpec) else ObjectSpec(k, pos=(0.6, 0.6, 0.5))
            for k in seq.objects]


def _object_qpos(poses: np.ndarray) -> np.ndarray:
    out = []
    for T in poses:
        out.extend([*T[:3, 3], *matrix_to_quat_wxyz(T[:3, :3])])
    return np.array(out)


def _structural_noise(img: np.ndarray, rng: np.random.Generator, n: int,
                      radius_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Seed 002's structural noise: ``n`` discs of radius 10-30 px (times ``radius_scale``,
    same draws) at random centres of the (H, W, 3) uint8 image, even ones filled with a
    random colour (added structure), odd ones with the colour under their centre (removed
    structure).

    Returns:
        (the noisy image (H, W, 3) uint8, (H, W) bool mask of every pixel a disc's
        anti-aliased fill touches). The mask costs no random draws: the image is the same
        as without it for the same ``rng`` state.
    """
    import cv2

    out = img.copy()
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    for i in range(n):
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        rad = max(1, int(round(int(rng.integers(10, 31)) * radius_scale)))
        if i % 2 == 0:
            col = tuple(int(v) for v in rng.integers(0, 256, 3))
        else:
            col = tuple(int(v) for v in img[c[1], c[0]])
        cv2.circle(out, c, rad, col, -1, lineType=cv2.LINE_AA)
        cv2.circle(mask, c, rad, 255, -1, lineType=cv2.LINE_AA)
    return out, mask > 0


def render_sequence(seq: Sequence, rig: Rig, *, surface: str = "heldout",
                    noise: bool = True, circles: int = 100, salient_miss: float = 0.3,
                    salient_fp: float = 0.1, seed: int = 0,
                    frames: list[int] | None = None, circle_scale: float = 1.0
                    ) -> Iterator[SequenceFrame]:
    """Render ``seq`` from every camera of ``rig``; see the module docstring. Each frame
    carries the circles' pixel masks (``SequenceFrame.noise_masks``) beside its images.
    ``circle_scale`` scales the circles' radii (same draws; 1 = the issue's 10-30 px, 1/3 =
    the share of a 640x480 image that seed 002's 10-30 px covered of its 1920x1080 ones)."""
    from hand_capture.cameras.render import Mesh, ZBufferRenderer
    from hand_capture.evaldata.surface import sample_surface
    from hand_capture.multiview.studio import Studio, StudioNoise, studio_scene

    if surface not in ("heldout", "own"):
        raise InputError(f"surface must be 'heldout' or 'own', got {surface!r}")
    rng = np.random.default_rng(seed)
    model = seq.model()
    two = len(seq.sides) == 2
    spec = studio_scene(_studio_objects(seq), two_hands=two, left_root=(0.0, 0.3, 0.12))
    studio = Studio(rig, spec, StudioNoise(seed=seed) if noise else None)
    zbuf = ZBufferRenderer(near=0.02)
    skin = np.array([222.0, 173.0, 148.0])
    try:
        if surface == "heldout":
            studio.set_surface(HandModel(), sample_surface(rng, forearm=True, sleeve=False))
        for t in range(seq.n_frames) if frames is None else frames:
            hp = seq.hand_poses[t]
            hidden = hp.copy()
            hidden[:, :3] = (0.0, 0.0, -3.0)
            show = hp if surface == "heldout" else hidden
            studio.set_state(show[0], _object_qpos(seq.object_poses[t]) if seq.objects
                             else None, show[1] if two else None)
            state = model.pose(seq.truth(model, t))
            images, dets, masks = {}, {}, {}
            for ci, cam in enumerate(rig.cameras):
                view = studio.render(ci, labels=False)
                rgb = view.rgb.copy()
                depth = view.depth_m
                if surface == "own":
                    meshes = [Mesh(cam.to_camera(state.vertices[i]), model.faces[i], closed=True)
                              for i in range(model.n_hands)]
                    res = zbuf.render(meshes, cam.intrinsics)
                    over = res.hit & ((depth == 0) | (res.depth < depth))
                    shade = (0.35 + 0.65 * res.cos_incidence[over])[:, None]
                    col = skin * shade + rng.normal(0.0, 2.0, (int(over.sum()), 3))
                    rgb[over] = np.clip(col, 0, 255).astype(np.uint8)
                    depth = np.where(over, res.depth, depth)
                dets[cam.name] = _detections(model, state, cam, depth, rng, salient_miss,
                                             salient_fp)
                if circles:
                    images[cam.name], masks[cam.name] = _structural_noise(rgb, rng, circles,
                                                                         circle_scale)
                else:
                    images[cam.name] = rgb
            yield SequenceFrame(images, dets, masks)
    finally:
        studio.close()


def _detections(model: SceneModel, state: object, cam: object, depth: np.ndarray,
                rng: np.random.Generator, miss: float, fp: float) -> np.ndarray:
    """Synthetic salient detections: visible nail centres + noise, deletions, false ones."""
    h, w = depth.shape
    pts, anchor = [], []
    for p in range(model.n_hands):
        v = state.vertices[p][model.salient[p]]
        uv, front = model.project(cam, v)
        z = cam.to_camera(v)[:, 2]
        anchor.append(model.project(cam, state.keypoints[p])[0])
        for k in range(len(v)):
            c, r = int(round(uv[k, 0])), int(round(uv[k, 1]))
            if not front[k] or not (0 <= c < w and 0 <= r < h):
                continue
            if depth[r, c] > 0 and abs(depth[r, c] - z[k]) > 0.015:
                continue  # hidden behind something
            if rng.random() < miss:
                continue
            pts.append(uv[k] + rng.normal(0.0, 1.5, 2))
    n_fp = int(rng.binomial(max(len(pts), 1), fp)) if fp > 0 else 0
    a = np.concatenate(anchor)
    lo, hi = a.min(0) - 40, a.max(0) + 40
    for _ in range(n_fp):
        pts.append(rng.uniform(lo, hi))
    return np.array(pts, dtype=float).reshape(-1, 2)
