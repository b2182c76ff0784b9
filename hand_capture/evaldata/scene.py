"""Held-out scenes: subject, surface, camera, clutter, motion and stereo-like noise together.

:func:`make_sequence` renders a sequence of the held-out family (uint16 depth [mm] plus the
true keypoints of the skeleton); :func:`calibration_frames` renders a held-out subject
holding given calibration poses. Cameras (:data:`CAMERAS`): D435-like at 640x480 and
848x480 and a D405-like at 640x480 (short baseline, close range), with principal points off
the image centre; ``d435_424`` (424x240) for resolution comparisons. Clutter: a table under
the hand, an object on it beside the hand (never nearer to the camera than the hand) and the
body behind.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import ConfigError
from hand_capture.evaldata.motion import palm_view, random_motion
from hand_capture.evaldata.raycast import BoundedPlane, Capsule, Ellipsoid, RayImage, raycast
from hand_capture.evaldata.stereo import StereoNoiseConfig, apply_stereo_noise
from hand_capture.evaldata.surface import SurfaceParams, hand_primitives, sample_surface
from hand_capture.model import N_ALPHA, HandModel, HandShape
from hand_capture.model.joints import root_angles_from_matrix

__all__ = ["CAMERAS", "CLUTTER", "HeldoutCamera", "HeldoutSequence", "calibration_frames",
           "clutter_primitives", "make_sequence", "sample_subject"]

CLUTTER = 4


@dataclass(frozen=True)
class HeldoutCamera:
    """A camera of the held-out family: pinhole, stereo noise, usable hand distances."""

    name: str
    intrinsics: Intrinsics
    noise: StereoNoiseConfig
    hand_depth_m: tuple[float, float]


CAMERAS: dict[str, HeldoutCamera] = {
    "d435_640": HeldoutCamera(
        "d435_640", Intrinsics(width=640, height=480, fx=386.2, fy=386.2, cx=318.4, cy=243.1),
        StereoNoiseConfig(baseline_m=0.050, min_z_m=0.17), (0.34, 0.58)),
    "d435_848": HeldoutCamera(
        "d435_848", Intrinsics(width=848, height=480, fx=425.9, fy=425.9, cx=421.7, cy=236.2),
        StereoNoiseConfig(baseline_m=0.050, min_z_m=0.19), (0.36, 0.60)),
    "d435_424": HeldoutCamera(
        "d435_424", Intrinsics(width=424, height=240, fx=213.4, fy=213.4, cx=210.9, cy=121.6),
        StereoNoiseConfig(baseline_m=0.050, min_z_m=0.11), (0.34, 0.58)),
    "d405_640": HeldoutCamera(
        "d405_640", Intrinsics(width=640, height=480, fx=433.5, fy=433.1, cx=322.6, cy=238.0),
        StereoNoiseConfig(baseline_m=0.018, disparity_sd_px=0.06, min_z_m=0.07,
                          fatten_px=1), (0.22, 0.38)),
}


@dataclass
class HeldoutSequence:
    """Rendered frames of one held-out sequence.

    Attributes:
        frames: (depth uint16 (H, W) [mm], intrinsics) per frame.
        poses: (N, 27) true poses.
        keypoints: (N, 21, 3) true keypoints [m].
        model: the subject's true hand model (its skeleton gives the keypoints).
        surface: the subject's surface.
        camera: the camera name.
        labels: (N, H, W) int16 primitive labels (1 hand, 2 forearm, 3 sleeve, 4 clutter).
    """

    frames: list[tuple[np.ndarray, Intrinsics]]
    poses: np.ndarray
    keypoints: np.ndarray
    model: HandModel
    surface: SurfaceParams
    camera: str
    labels: np.ndarray = field(repr=False)


def sample_subject(rng: np.random.Generator, scale: float | None = None) -> HandModel:
    """A subject's skeleton: global scale ``scale`` (None: uniform 0.88-1.12) and bone
    proportions drawn from a truncated normal (sd 0.7) on the shape model's coefficients."""
    s = float(rng.uniform(0.88, 1.12)) if scale is None else float(scale)
    alpha = np.clip(rng.normal(0.0, 0.7, N_ALPHA), -1.5, 1.5)
    return HandModel(HandShape(s, tuple(alpha), subject_id="heldout"))


def clutter_primitives(rng: np.random.Generator, kp: np.ndarray) -> list:
    """Table under the hand, an object on it beside the hand, the body behind (camera
    frame; ``kp`` (21, 3) are the hand's keypoints of the first frame)."""
    lo, hi = kp.min(axis=0), kp.max(axis=0)
    zc = float(kp[:, 2].mean())
    y_table = float(hi[1]) + rng.uniform(0.06, 0.18)     # +y is down in the image
    tilt = math.radians(rng.uniform(-10, 10))
    n = np.array([0.0, -math.cos(tilt), math.sin(tilt)])
    e2 = np.array([0.0, math.sin(tilt), math.cos(tilt)])
    # the table runs from just behind the hand's mean depth away from the camera
    prims: list = [BoundedPlane(np.array([0.0, y_table, zc + 0.5]), n,
                                np.array([1.0, 0.0, 0.0]), e2, (0.8, 0.5), CLUTTER)]
    # an object standing on the table, left or right of the hand, not nearer than the hand
    side = 1.0 if rng.random() < 0.5 else -1.0
    x = (hi[0] + rng.uniform(0.05, 0.15)) if side > 0 else (lo[0] - rng.uniform(0.05, 0.15))
    z = float(hi[2]) + rng.uniform(0.02, 0.25)
    r = rng.uniform(0.03, 0.05)
    h = rng.uniform(0.06, 0.16)
    if rng.random() < 0.5:   # a mug / bottle
        prims.append(Capsule(np.array([x, y_table - r, z]), np.array([x, y_table - h, z]), r,
                             CLUTTER))
    else:                    # a ball / fruit
        prims.append(Ellipsoid(np.array([x, y_table - r, z]), np.eye(3), np.array([r, r, r]),
                               CLUTTER))
    # the body (torso), behind the hand
    zb = zc + rng.uniform(0.3, 0.6)
    prims.append(Ellipsoid(np.array([rng.uniform(-0.1, 0.1), 0.25, zb]), np.eye(3),
                           np.array([0.2, 0.32, 0.12]), CLUTTER))
    return prims


def _render(model: HandModel, q: np.ndarray, surface: SurfaceParams, cam: HeldoutCamera,
            extra: RayImage | None, rng: np.random.Generator, noise: bool
            ) -> tuple[np.ndarray, np.ndarray]:
    img = raycast(hand_primitives(model, q, surface), cam.intrinsics, base=extra)
    if noise:
        depth = apply_stereo_noise(img.depth, cam.intrinsics, rng, cam.noise)
    else:
        depth = np.clip(np.rint(img.depth * 1e3), 0, 65535).astype(np.uint16)
    return depth, img.label


def make_sequence(seed: int, n_frames: int, camera: str = "d435_640", *,
                  forearm: bool = False, sleeve: bool | None = None, clutter: bool = False,
                  noise: bool = True, scale: float | None = None, step: int = 1
                  ) -> HeldoutSequence:
    """Render a held-out sequence, reproducible from ``seed``.

    Args:
        seed: seeds the subject, surface, motion, clutter and noise.
        n_frames: rendered frames (every ``step``-th frame of a 30 fps motion).
        camera: a key of :data:`CAMERAS`.
        forearm: a forearm continues from the wrist out of the frame.
        sleeve: a sleeve over the forearm (None: drawn at random; only with ``forearm``).
        clutter: table, an object and the body in view.
        noise: stereo-like noise (False: exact depth, rounded to mm).
        scale: the subject's global scale (None: drawn).
        step: frame step of the 30 fps motion.
    """
    if camera not in CAMERAS:
        raise ConfigError(f"unknown held-out camera {camera!r}; valid: {sorted(CAMERAS)}")
    if n_frames < 1 or step < 1:
        raise ConfigError("make_sequence: n_frames and step must be >= 1")
    cam = CAMERAS[camera]
    rng = np.random.default_rng(seed)
    model = sample_subject(rng, scale)
    surface = sample_surface(rng, forearm=forearm, sleeve=sleeve)
    poses = random_motion(rng, n_frames * step, depth_m=cam.hand_depth_m)[::step]
    kps = model.joint_positions(poses)
    extra = raycast(clutter_primitives(rng, kps[0]), cam.intrinsics) if clutter else None
    frames, labels = [], []
    for q in poses:
        d, lab = _render(model, q, surface, cam, extra, rng, noise)
        frames.append((d, cam.intrinsics))
        labels.append(lab)
    return HeldoutSequence(frames, poses, kps, model, surface, camera, np.stack(labels))


def calibration_frames(model: HandModel, surface: SurfaceParams, finger_poses:
                       Sequence[np.ndarray], camera: str = "d435_640",
                       rng: np.random.Generator | None = None, *, distance_m: float = 0.42
                       ) -> list[tuple[np.ndarray, Intrinsics]]:
    """Depth frames of a held-out subject holding ``finger_poses`` (27,) each (only the
    finger angles are used), palm towards the camera at ``distance_m``, turned a little
    differently each time; stereo-like noise when ``rng`` is given."""
    cam = CAMERAS[camera]
    frames = []
    for i, fp in enumerate(finger_poses):
        q = np.array(fp, dtype=float).copy()
        R = palm_view(np.array([0.12 * (i - 1), -0.15 * (i - 1), 0.05 * i]))
        q[3:6] = root_angles_from_matrix(R)
        q[0:3] = np.array([0.01, 0.0, distance_m]) - R @ np.array([0.05 * model.shape
                                                                   .global_scale, 0, 0])
        d, _ = _render(model, q, surface, cam, None, rng or np.random.default_rng(0),
                       rng is not None)
        frames.append((d, cam.intrinsics))
    return frames
