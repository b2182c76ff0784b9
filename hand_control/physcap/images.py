"""The image cost of eq. (3) for captures that carry multi-view colour images (seed 000 sec. 6:
the energy of a simulated frame compares it with the observed images).

:class:`CaptureImages` holds, per frame of a capture on the optimiser's step grid, the
observed views of every camera (:func:`hand_capture.multiview.imageterms.observe`: silhouette
from the colour model of eq. 4, distance transforms of the observed edges, the colour window)
and an :class:`~hand_capture.multiview.imageterms.ImageCost` of a scene with one hand and the
capture's object: the silhouette (eq. 5), colour (eq. 6) and edge (eq. 7) terms of the
simulated hand and object poses, weighted 1.0 / 0.6 / 1.0 (eq. 3). The optimiser adds
``weight`` times this to the 3-D terms of each simulated frame
(:func:`hand_control.physcap.capture.optimise_capture` with ``images=``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hand_capture.model.hand import HandModel
from hand_capture.model.joints import quat_wxyz_to_matrix
from hand_control.physcap.capture import CapturedObject, CaptureError

__all__ = ["CaptureImages", "capture_images", "pose_matrices"]


def pose_matrices(object_pose: np.ndarray) -> np.ndarray:
    """(N, 4, 4) world <- object of (N, 7) poses (position, quaternion w x y z)."""
    p = np.atleast_2d(np.asarray(object_pose, float))
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, :3] = quat_wxyz_to_matrix(p[:, 3:7])
    T[:, :3, 3] = p[:, 0:3]
    return T


@dataclass(frozen=True, eq=False)
class CaptureImages:
    """Observed multi-view images of a capture and their cost (module docstring).

    Attributes:
        views: per capture frame (on the ``PhysCapConfig.step`` grid) the observed views
            (``ObservedView``, one per camera).
        cost: the ``ImageCost`` of a scene with one hand and the capture's object (hand
            colours learned).
        weight: the image term's weight in a frame's energy (the 3-D terms are in the units
            of ``PhysCapConfig``'s weights; eq. 3's sum over views is of order 0.1-1 per
            view). 0.3: on a 4-frame studio-filmed lift with every grasping finger 10-20 mm
            off in the reference, 0.3 lowered the hand error against the truth from 6.1 to
            5.8 mm (32 samples; 1.0: 5.9, 3.0: 6.0), a small trial, not a validated choice.
    """

    views: tuple[tuple[object, ...], ...]
    cost: object
    weight: float = 0.3

    def __post_init__(self) -> None:
        if len(self.views) < 2 or any(len(v) == 0 for v in self.views):
            raise CaptureError("CaptureImages.views needs >= 2 frames, each with >= 1 view")
        if not (np.isfinite(self.weight) and self.weight >= 0.0):
            raise CaptureError(f"CaptureImages.weight must be >= 0, got {self.weight}")

    @property
    def n_frames(self) -> int:
        return len(self.views)

    def params(self, hand_q: np.ndarray, object_pose: np.ndarray) -> np.ndarray:
        """(N, n_params) scene parameters of (N, 27) hand poses and (N, 7) object poses."""
        scene = self.cost.scene
        hq = np.atleast_2d(np.asarray(hand_q, float))
        T = pose_matrices(object_pose)
        return np.stack([scene.pack([h], [t]) for h, t in zip(hq, T, strict=True)])

    def energies(self, frame: int, hand_q: np.ndarray, object_pose: np.ndarray
                 ) -> np.ndarray:
        """(N,) ``weight`` x eq. (3) of N simulated frames against frame ``frame``'s views."""
        return self.weight * np.asarray(
            self.cost(self.params(hand_q, object_pose), self.views[frame]), float)


def capture_images(obj: CapturedObject, rig: object, groups: Sequence[Mapping[str, np.ndarray]],
                   hand_masks: Mapping[str, np.ndarray], hand_q0: np.ndarray,
                   object_pose0: np.ndarray, config: object | None = None,
                   weight: float = 0.3) -> CaptureImages:
    """The :class:`CaptureImages` of a capture filmed by ``rig``.

    Args:
        obj: the captured object (its primitive's mesh is the scene's object).
        rig: the ``Rig`` of the cameras; groups: per frame, camera name -> (H, W, 3) uint8
            colour image.
        hand_masks: camera name -> (H, W) bool hand pixels of the FIRST frame (seed 000
            learns the colour model of eq. 4 and the hand's colours there).
        hand_q0 (27,), object_pose0 (7,): the first frame's hand and object poses.
        config: ``ImageTermsConfig`` (default: seed 000's weights, 1/4 resolution).

    Raises:
        CaptureError: a mesh object (not supported here), no frames, or a camera without
            a first-frame mask.
    """
    from hand_capture.multiview.imageterms import (
        ColourModel,
        ImageCost,
        ImageTermsConfig,
        observe_group,
    )
    from hand_capture.multiview.scene_model import SceneModel, object_mesh
    from hand_control.physcap.world import object_spec

    if obj.kind == "mesh":
        raise CaptureError("capture_images: mesh objects are not supported (primitives only)")
    if not groups:
        raise CaptureError("capture_images: no image groups")
    names = [c.name for c in rig.cameras if c.name in groups[0]]
    missing = [n for n in names if n not in hand_masks]
    if missing:
        raise CaptureError(f"capture_images: no first-frame hand mask for cameras {missing}")
    cfg = config or ImageTermsConfig()
    colour = ColourModel.fit([groups[0][n] for n in names], [hand_masks[n] for n in names])
    views = tuple(tuple(observe_group(g, rig, colour, cfg)) for g in groups)
    cost = ImageCost(SceneModel([HandModel()], [object_mesh(object_spec(obj))]), cfg)
    out = CaptureImages(views, cost, weight)
    cost.learn_colours(out.params(hand_q0, object_pose0)[0], views[0])
    return out
