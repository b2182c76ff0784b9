"""Studio captures: a simulated lift filmed by the multi-view studio and tracked by the suite's
own multi-view tracker, so that the physics capture gets a real tracker's errors (and the
images of eq. 3) instead of synthetic corruption (:mod:`hand_control.physcap.synth`).

:func:`studio_capture` takes a ground-truth capture (``synth.scenario_capture``: the hand's
27-DoF pose and the object's pose per frame), renders it from every camera of a rig with
``hand_capture.multiview.sequences.render_sequence`` as the multi-view bench does (the hand
drawn as a HELD-OUT surface with its forearm, not the mesh the tracker fits; the studio's
colour noise, seed 002's structural noise circles, synthetic salient detections), tracks it
with :class:`~hand_capture.multiview.tracker.MultiviewTracker` (LO with edges, collisions,
optical flow and salient points) from the first frame's true pose, and returns the tracked
capture beside its truth, with the rendered images turned into the eq. 3 cost
(:func:`hand_control.physcap.images.capture_images`) when asked. The tracked poses can be
cached in a folder (the images are rendered again: rendering is deterministic and cheap
against tracking).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.model.joints import matrix_to_quat_wxyz
from hand_control.physcap.capture import Capture, CaptureError
from hand_control.physcap.images import pose_matrices
from hand_control.physcap.synth import SyntheticCapture

__all__ = ["STUDIO_RIG", "StudioCapture", "capture_sequence", "hand_penetration_mm",
           "studio_capture"]

#: the multi-view bench's rig: six 640x480 cameras (config/rigs/studio6.yaml)
STUDIO_RIG = "studio6"


def capture_sequence(capture: Capture) -> Any:
    """The multi-view ``Sequence`` of a capture: one right hand and the capture's object (its
    own size; the MJCF primitive of ``physcap.world.object_spec``), posed per frame.

    Raises:
        CaptureError: a mesh object (the studio draws primitives only).
    """
    from hand_capture.multiview.sequences import Sequence
    from hand_control.physcap.world import object_spec

    if capture.obj.kind == "mesh":
        raise CaptureError("studio captures: mesh objects are not supported (primitives only)")
    return Sequence(capture.name, ("right",), (object_spec(capture.obj),),
                    np.asarray(capture.hand_q, float)[:, None, :],
                    pose_matrices(capture.object_pose)[:, None])


def hand_penetration_mm(capture: Capture, hand_q: np.ndarray | None = None,
                        object_pose: np.ndarray | None = None) -> np.ndarray:
    """(T,) per frame the depth [mm] of the hand mesh's deepest vertex inside the object's
    primitive (0 without penetration): the tracker's collision term (seed 002 eq. 4) keeps it
    small. ``hand_q`` (T, 27) / ``object_pose`` (T, 7) default to the capture's."""
    from hand_capture.model.hand import HandModel
    from hand_control.physcap.world import object_spec

    q = capture.hand_q if hand_q is None else np.asarray(hand_q, float)
    T = pose_matrices(capture.object_pose if object_pose is None else object_pose)
    spec = object_spec(capture.obj)
    s = np.asarray(spec.size, float)
    model = HandModel()
    out = np.zeros(len(q))
    for t in range(len(q)):
        v = (model.forward(q[t]).vertices - T[t, :3, 3]) @ T[t, :3, :3]  # object frame
        if spec.kind == "ball":
            depth = s[0] - np.linalg.norm(v, axis=1)
        elif spec.kind == "stick":  # cylinder along the body x: radius, half length
            depth = np.minimum(s[1] - np.abs(v[:, 0]), s[0] - np.linalg.norm(v[:, 1:], axis=1))
        else:
            depth = np.min(s - np.abs(v), axis=1)
        out[t] = max(0.0, float(depth.max())) * 1e3
    return out


@dataclass(frozen=True, eq=False)
class StudioCapture:
    """A studio-filmed, tracked capture.

    Attributes:
        synthetic: the tracked capture (``.capture``, corruption ``"studio"``) and its truth.
        images: the eq. 3 cost of the rendered images (``CaptureImages``), or None.
        track_s_per_frame: the tracker's wall time per frame [s] (nan when loaded from the
            cache).
        cached: whether the tracked poses came from the cache.
    """

    synthetic: SyntheticCapture
    images: Any
    track_s_per_frame: float
    cached: bool


def _design_key(truth: Capture, rig: Any, seed: int, lo_config: Any,
                tracker_config: Any) -> str:
    """What the tracked poses depend on: the truth, the cameras, the render seed, the local
    optimiser's settings and the tracker's lost / prediction settings."""
    h = hashlib.sha256()
    for a in (truth.times, truth.hand_q, truth.object_pose):
        h.update(np.ascontiguousarray(a, float).tobytes())
    cams = [(c.name, c.intrinsics.width, c.intrinsics.height) for c in rig.cameras]
    return json.dumps({"truth": h.hexdigest(), "obj": [truth.obj.kind, list(truth.obj.size)],
                       "rig": rig.name, "cameras": cams, "seed": seed,
                       "lo": asdict(lo_config), "tracker": asdict(tracker_config)},
                      sort_keys=True, default=str)


def studio_capture(truth: Capture, *, rig: Any = None, seed: int = 0, lo_config: Any = None,
                   tracker_config: Any = None, images: bool = True, image_config: Any = None,
                   cache_dir: str | Path | None = None, verbose: bool = False
                   ) -> StudioCapture:
    """``truth`` filmed in the studio and tracked (module docstring).

    Args:
        truth: the ground-truth capture (frames at the optimiser's step, e.g. 20 fps).
        rig: the cameras (default :data:`STUDIO_RIG`); seed: the render's seed (the held-out
            surface's subject, colour and structural noise, detections).
        lo_config: the tracker's ``LOConfig`` (default: its defaults, 15 iterations, E+C+O+S).
        tracker_config: the tracker's ``MultiviewTrackerConfig`` (default: its defaults).
        images: also build the eq. 3 cost (``CaptureImages``) of the rendered images; its
            first-frame hand masks are the tracker's model rendered at the first frame's true
            pose (the pose the tracker starts from).
        image_config: the ``ImageTermsConfig`` of the eq. 3 cost (default: its defaults).
        cache_dir: folder of tracked poses (``NAME_studioSEED.npz``, reused when the truth,
            rig, seed and tracker settings match).

    Raises:
        CaptureError: a mesh object.
    """
    from hand_capture.multiview.lo import LOConfig
    from hand_capture.multiview.rig import load_rig
    from hand_capture.multiview.sequences import render_sequence
    from hand_capture.multiview.tracker import MultiviewTracker, MultiviewTrackerConfig

    rig = load_rig(STUDIO_RIG) if rig is None else rig
    lo_config = LOConfig() if lo_config is None else lo_config
    tracker_config = MultiviewTrackerConfig() if tracker_config is None else tracker_config
    seq = capture_sequence(truth)
    model = seq.model()
    key = _design_key(truth, rig, seed, lo_config, tracker_config)
    path = None if cache_dir is None else Path(cache_dir) / f"{truth.name}_studio{seed}.npz"
    hand_q = obj_pose = None
    if path is not None and path.is_file():
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) == key:
                hand_q, obj_pose = z["hand_q"].copy(), z["object_pose"].copy()
    cached = hand_q is not None
    tracker = None
    if not cached:
        tracker = MultiviewTracker(model, rig, lo_config, tracker_config)
        tracker.reset(seq.truth(model, 0))
        hand_q = np.zeros_like(truth.hand_q)
        obj_pose = np.zeros_like(truth.object_pose)
    groups: list[dict[str, np.ndarray]] = []
    secs: list[float] = []
    frames = render_sequence(seq, rig, surface="heldout", seed=seed) \
        if images or not cached else ()  # cached poses without images: nothing to render
    for t, fr in enumerate(frames):
        if images:
            groups.append(fr.images)
        if tracker is None:
            continue
        t0 = time.perf_counter()
        p = tracker.step(fr.images, fr.detections).params
        secs.append(time.perf_counter() - t0)
        hand_q[t] = model.part_params(p, 0)
        T = model.object_transform(model.part_params(p, 1))
        obj_pose[t] = [*T[:3, 3], *matrix_to_quat_wxyz(T[:3, :3])]
        if verbose:
            print(f"  {truth.name} frame {t}: tracked in {secs[-1]:.1f} s", flush=True)
    if not cached:
        # the first frame is the initial state: the object at rest where it truly is (as
        # ``synth.corrupt``); the tracker started from that frame's truth anyway
        obj_pose[0] = truth.object_pose[0]
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.savez(path, hand_q=hand_q, object_pose=obj_pose, key=np.array(key))
    tracked = Capture(f"{truth.name}_studio{seed}", truth.times, hand_q, obj_pose, truth.obj)
    cost = None
    if images:
        from hand_control.physcap.images import capture_images

        st = model.pose(seq.truth(model, 0))
        # part 0 (the hand) is label 1 of the model's render
        masks = {c.name: model.render(c, st, 1.0).labels == 1 for c in rig.cameras}
        cost = capture_images(truth.obj, rig, groups, masks, tracked.hand_q[0],
                              tracked.object_pose[0], image_config)
    return StudioCapture(SyntheticCapture(tracked, truth, truth.name, "studio", {}), cost,
                         float(np.mean(secs[1:])) if len(secs) > 1 else float("nan"), cached)
