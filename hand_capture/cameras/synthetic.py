"""Synthetic depth/colour camera: renders the hand model (and objects) with sensor noise.

The dissertation trains on depth images rendered from randomly shaped hand models in many
poses and viewpoints, with noise added because rendered data is cleaner than a sensor's
(ch. II.4.4). :class:`SyntheticCamera` does the same for one moving hand:

1. the motion clip gives the 27-DoF pose at time t (world frame) and the object positions;
2. the pose is expressed in the camera's optical frame (the ground truth that is published);
3. the hand mesh of that pose (shape from ``shape_seed``, eq. II.9) and the object meshes
   are rendered by a CPU renderer (:mod:`hand_capture.cameras.render`) into clean depth,
   labels and incidence angles;
4. the noise model (:mod:`hand_capture.cameras.noise`) turns clean depth into a ``16UC1``
   image; colour is Lambert-shaded with a light at the camera, plus Gaussian noise.

Colour and depth share one pinhole (an ideal aligned RGB-D sensor). The source implements
:class:`~hand_capture.cameras.base.FrameSource`, so the node and tests use it like a real
camera; :meth:`SyntheticCamera.render` renders any time directly.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from hand_capture.cameras.base import Frame, FrameSource, Intrinsics, depth_m_to_mm
from hand_capture.cameras.motion import CLIPS, MotionClip, load_motion
from hand_capture.cameras.noise import ColorNoise, DepthNoiseConfig, DepthNoiseModel
from hand_capture.cameras.primitives import SceneObject, scene_objects_from_mapping
from hand_capture.cameras.render import Mesh, RenderResult, make_renderer
from hand_capture.cameras.transforms import matrix_to_rotvec, pose_in_camera, rotvec_to_matrix
from hand_capture.config import load_yaml, param, validate
from hand_capture.errors import ConfigError, DeviceError, InputError
from hand_capture.model.joints import (
    N_DOF,
)

__all__ = ["HAND_LABEL", "HandMeshModel", "SyntheticCamera", "SyntheticCameraConfig",
           "SyntheticFrame", "pose_in_camera", "render_benchmark"]

#: label of the hand in :attr:`SyntheticFrame.labels`; objects get 2, 3, ...
HAND_LABEL = 1


class HandMeshModel(Protocol):
    """What the synthetic camera needs from a hand model (``hand_capture.model.HandModel``)."""

    @property
    def faces(self) -> np.ndarray: ...

    def vertices(self, pose: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class SyntheticCameraConfig:
    """Parameters of :class:`SyntheticCamera` (noise parameters: :class:`DepthNoiseConfig`)."""

    width: int = param(320, "image width [px]", lo=8, hi=4096)
    height: int = param(240, "image height [px]", lo=8, hi=4096)
    hfov_deg: float = param(70.0, "horizontal field of view when fx is 0 [deg]", lo=1.0,
                            hi=179.0)
    fx: float = param(0.0, "focal length [px]; 0 = from hfov_deg", lo=0.0)
    fy: float = param(0.0, "focal length [px]; 0 = same as fx", lo=0.0)
    cx: float = param(-1.0, "principal point x [px]; negative = image centre")
    cy: float = param(-1.0, "principal point y [px]; negative = image centre")
    fps: float = param(30.0, "frame rate [Hz]", lo=0.1, hi=1000.0)
    camera_position: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), "camera optical centre in the world frame [m]")
    camera_rotation: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), "camera orientation in the world frame, rotation vector [rad]")
    clip: str = param("finger_counting", "built-in motion clip", choices=tuple(sorted(CLIPS)))
    pose_file: str = param("", "CSV/NPZ pose sequence to play instead of the clip")
    pose_file_rate: float = param(30.0, "pose rate of a file without times [Hz]", lo=0.1,
                                  hi=10000.0)
    speed: float = param(1.0, "playback speed of the motion", lo=0.0, hi=100.0)
    loop: bool = param(True, "loop the motion")
    side: str = param("right", "hand side", choices=("right", "left"))
    shape_seed: int = param(-1, "seed of the sampled hand shape; -1 = the default shape",
                            lo=-1)
    noise_seed: int = param(0, "seed of the sensor noise", lo=0)
    renderer: str = param("zbuffer", "renderer", choices=("zbuffer", "raycast", "naive"))
    render_color: bool = param(True, "also render the colour image")
    scene_file: str = param("", "YAML file with extra scene objects")
    frame_id: str = param("camera_depth_optical_frame", "optical frame of both images")
    skin_color: tuple[float, ...] = param((0.87, 0.68, 0.58), "hand albedo, RGB in [0, 1]",
                                          lo=0.0, hi=1.0)
    background_color: tuple[float, ...] = param((0.22, 0.23, 0.26),
                                                "background colour, RGB in [0, 1]",
                                                lo=0.0, hi=1.0)
    ambient: float = param(0.35, "ambient share of the shading", lo=0.0, hi=1.0)

    def __post_init__(self) -> None:
        validate(self)
        for name in ("camera_position", "camera_rotation", "skin_color", "background_color"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"SyntheticCameraConfig.{name} needs 3 values, got "
                                  f"{list(getattr(self, name))}")

    def intrinsics(self) -> Intrinsics:
        """The pinhole of both images."""
        if self.fx > 0:
            fx = self.fx
            fy = self.fy if self.fy > 0 else fx
            intr = Intrinsics(self.width, self.height, fx, fy, 0.0, 0.0)
        else:
            intr = Intrinsics.from_fov(self.width, self.height, self.hfov_deg)
        cx = self.cx if self.cx >= 0 else (self.width - 1) / 2.0
        cy = self.cy if self.cy >= 0 else (self.height - 1) / 2.0
        return Intrinsics(self.width, self.height, intr.fx, intr.fy, cx, cy,
                          frame_id=self.frame_id)


@dataclass
class SyntheticFrame(Frame):
    """A rendered frame with its ground truth.

    Attributes (besides :class:`Frame`'s):
        pose: (27,) true pose in the camera optical frame (JOINT_NAMES order).
        labels: (H, W) uint8, 0 background, 1 hand, 2.. objects (in clip/scene order).
        depth_clean_m: (H, W) float32 noise-free depth [m] (0 = nothing).
        cos_incidence: (H, W) float32 |cos| of the incidence angle of the seen surface.
        clip_time_s: the motion time that was rendered [s].
        object_poses: object name -> (position (3,), rotation vector (3,)) in the camera frame.
    """

    pose: np.ndarray = field(default_factory=lambda: np.zeros(N_DOF))
    labels: np.ndarray | None = None
    depth_clean_m: np.ndarray | None = None
    cos_incidence: np.ndarray | None = None
    clip_time_s: float = 0.0
    object_poses: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def silhouette(self) -> np.ndarray:
        """(H, W) bool mask of the hand (before noise)."""
        if self.labels is None:
            raise InputError("this frame has no labels")
        return self.labels == HAND_LABEL


def _default_model(side: str, shape_seed: int) -> HandMeshModel:
    try:
        from hand_capture.model import HandModel, default_shape, sample_shape
    except ImportError as e:  # the model package is a sibling part of the suite
        raise ConfigError(f"the hand model is not available: {e}") from e
    shape = default_shape() if shape_seed < 0 else sample_shape(np.random.default_rng(shape_seed))
    return HandModel(shape=shape, side=side)


class SyntheticCamera(FrameSource):
    """Renders a moving hand model as an RGB-D camera would see it (module docstring).

    Args:
        config: camera, motion and rendering parameters.
        noise: the depth-sensor noise model parameters.
        model: a hand model (default: ``HandModel`` with the configured side and shape).
        motion: a motion clip (default: from ``config.clip`` / ``config.pose_file``).
        objects: extra scene objects (added to the clip's and the scene file's).
    """

    driver = "synthetic"

    def __init__(self, config: SyntheticCameraConfig | None = None,
                 noise: DepthNoiseConfig | None = None, *, model: HandMeshModel | None = None,
                 motion: MotionClip | None = None,
                 objects: Sequence[SceneObject] = ()) -> None:
        self.config = config or SyntheticCameraConfig()
        self.noise = DepthNoiseModel(noise or DepthNoiseConfig())
        self.intrinsics = self.config.intrinsics()
        self._model = model
        self._motion = motion
        self._extra_objects = list(objects)
        self._objects: list[SceneObject] = []
        self._renderer = None
        self._rng = np.random.default_rng(self.config.noise_seed)
        self._seq = 0
        self._open = False
        self.dropped_frames = 0
        c = self.config
        self._R_wc = rotvec_to_matrix(np.array(c.camera_rotation, float))
        self._t_wc = np.array(c.camera_position, float)
        self._identity_camera = bool(np.allclose(self._R_wc, np.eye(3))
                                     and np.allclose(self._t_wc, 0))
        self._palette = np.zeros((256, 3), np.float32)
        self._background: np.ndarray | None = None
        self._color_noise: ColorNoise | None = None

    # -- FrameSource -----------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._open

    @property
    def nominal_fps(self) -> float:
        return float(self.config.fps)

    @property
    def model(self) -> HandMeshModel:
        if self._model is None:
            self._model = _default_model(self.config.side, self.config.shape_seed)
        return self._model

    @property
    def motion(self) -> MotionClip:
        if self._motion is None:
            c = self.config
            self._motion = load_motion(c.clip, c.pose_file, rate=c.pose_file_rate, loop=c.loop)
        return self._motion

    @property
    def objects(self) -> list[SceneObject]:
        """Every scene object: the clip's, the scene file's and the extra ones."""
        return self._objects

    def open(self) -> None:
        if self._open:
            return
        c = self.config
        try:
            _ = self.model
            motion = self.motion
        except (ConfigError, InputError) as e:
            raise DeviceError(f"synthetic camera cannot start: {e}") from e
        objs = list(motion.objects)
        if c.scene_file:
            objs += scene_objects_from_mapping(load_yaml(c.scene_file))
        objs += self._extra_objects
        names = [o.name for o in objs]
        if len(set(names)) != len(names):
            raise ConfigError(f"scene object names must be unique, got {names}")
        if len(objs) > 250:
            raise ConfigError(f"too many scene objects ({len(objs)} > 250)")
        self._objects = objs
        self._renderer = make_renderer(c.renderer)
        pal = self._palette
        pal[0] = c.background_color
        pal[HAND_LABEL] = c.skin_color
        for i, o in enumerate(objs):
            pal[HAND_LABEL + 1 + i] = o.color
        self._seq = 0
        self._open = True

    def close(self) -> None:
        self._open = False

    def read(self, timeout_s: float = 1.0) -> SyntheticFrame | None:
        """The next frame of the sequence (motion time = sequence / fps * speed).

        Returns None for a frame the noise model drops (``frame_drop_prob``).
        """
        t = self._seq / self.config.fps
        return self.frame_at(t, stamp_s=time.time())

    def frame_at(self, t: float, stamp_s: float | None = None) -> SyntheticFrame | None:
        """The frame at wall/sim time ``t`` since the start [s]; None if it is dropped."""
        if not self._open:
            raise DeviceError("synthetic camera is not open")
        seq = self._seq
        self._seq += 1
        if self.noise.drop_frame(self._rng):
            self.dropped_frames += 1
            return None
        frame = self.render(t * self.config.speed, stamp_s=stamp_s)
        frame.sequence = seq
        return frame

    def describe(self) -> dict[str, str]:
        c = self.config
        i = self.intrinsics
        return {"driver": self.driver, "resolution": f"{c.width}x{c.height}",
                "fps": f"{c.fps:g}", "fx": f"{i.fx:.2f}", "fy": f"{i.fy:.2f}",
                "motion": c.pose_file or c.clip, "side": c.side,
                "shape_seed": str(c.shape_seed), "noise_seed": str(c.noise_seed),
                "renderer": c.renderer, "noise": str(self.noise.config.enabled)}

    # -- rendering -------------------------------------------------------------------------
    def truth_pose(self, clip_time: float) -> np.ndarray:
        """The true pose (27,) in the camera frame at motion time ``clip_time``."""
        q = self.motion.sample(clip_time)
        if self._identity_camera:
            return q
        return pose_in_camera(q, self._R_wc, self._t_wc)

    def scene_meshes(self, clip_time: float, pose_cam: np.ndarray
                     ) -> tuple[list[Mesh], dict[str, tuple[np.ndarray, np.ndarray]]]:
        """Meshes in the camera frame (hand first) and the object poses in that frame."""
        V = np.asarray(self.model.vertices(pose_cam), dtype=np.float64)
        meshes = [Mesh(V, self.model.faces, HAND_LABEL, tuple(self.config.skin_color),
                       closed=True)]
        R_cw = self._R_wc.T
        poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        positions = self.motion.object_positions(clip_time) if self._objects else {}
        for i, o in enumerate(self._objects):
            p = positions.get(o.name, o.position)
            Vw = o.world_vertices(p)
            Vc = (Vw - self._t_wc) @ R_cw.T if not self._identity_camera else Vw
            meshes.append(Mesh(Vc, o.faces, HAND_LABEL + 1 + i, o.color, closed=o.closed))
            R_obj = R_cw @ rotvec_to_matrix(o.rotvec)
            poses[o.name] = (R_cw @ (np.asarray(p) - self._t_wc), matrix_to_rotvec(R_obj))
        return meshes, poses

    def render(self, clip_time: float, stamp_s: float | None = None,
               noise: bool = True) -> SyntheticFrame:
        """Render motion time ``clip_time`` [s] (no frame dropping)."""
        if not self._open:
            self.open()
        pose = self.truth_pose(clip_time)
        meshes, obj_poses = self.scene_meshes(clip_time, pose)
        res = self._renderer.render(meshes, self.intrinsics)
        if noise:
            depth_mm = self.noise.apply_mm(res.depth, res.cos_incidence, self.intrinsics,
                                           self._rng)
        else:
            depth_mm = depth_m_to_mm(res.depth)
        color = self.shade(res, noise) if self.config.render_color else None
        return SyntheticFrame(
            stamp_s=time.time() if stamp_s is None else float(stamp_s), sequence=self._seq,
            depth=depth_mm, color=color, depth_intrinsics=self.intrinsics,
            color_intrinsics=self.intrinsics if color is not None else None,
            pose=pose, labels=res.label, depth_clean_m=res.depth,
            cos_incidence=res.cos_incidence, clip_time_s=float(clip_time),
            object_poses=obj_poses)

    def shade(self, res: RenderResult, noise: bool = True) -> np.ndarray:
        """Lambert-shaded RGB image (light at the camera) of a render result."""
        if self._background is None or self._background.shape[:2] != res.label.shape:
            self._background = np.broadcast_to(
                np.clip(np.rint(self._palette[0] * 255), 0, 255).astype(np.uint8),
                res.label.shape + (3,)).copy()
        rgb = self._background.copy()
        hit = np.flatnonzero(res.face.ravel() >= 0)
        if hit.size:
            a = np.float32(self.config.ambient)
            shade = a + (1 - a) * res.cos_incidence.ravel()[hit]
            col = self._palette[res.label.ravel()[hit]] * (shade[:, None] * np.float32(255.0))
            rgb.reshape(-1, 3)[hit] = np.clip(col + np.float32(0.5), 0, 255).astype(np.uint8)
        std = self.noise.config.color_noise_std
        if noise and self.noise.config.enabled and std > 0:
            if self._color_noise is None or self._color_noise.shape != rgb.shape:
                self._color_noise = ColorNoise(rgb.shape, std, self._rng)
            rgb = self._color_noise.apply(rgb, self._rng)
        return rgb


def render_benchmark(model: HandMeshModel | None = None, quick: bool = False,
                     **kwargs: object) -> dict:
    """Renderer figures for ``hand-suite bench model`` (which calls ``(model, quick)``).

    See :func:`hand_capture.cameras.bench.render_benchmark`.
    """
    from hand_capture.cameras.bench import render_benchmark as _bench

    return _bench(quick, model=model, **kwargs)
