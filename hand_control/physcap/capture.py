"""Physics-based manipulation capture (seed 000 sec. 6-7): the data types and the entry point.

A :class:`Capture` is a kinematic recording of a hand manipulating one rigid object (from a
tracker, the multi-view studio, or a simulation with added noise): per frame the hand's 27-DoF
pose vector (``hand_capture.model.joints.JOINT_NAMES`` order, world frame), the object's pose
and optionally observed 3-D hand keypoints. :func:`optimise_capture` searches the control of
the composite controller (seed 000 sec. 5: PD targets of the hand, eq. 8, and target poses of
the object, whose virtual wrench eq. 9 the contact QP and the Jacobian transpose realise,
eq. 10-13) that drives a MuJoCo simulation to match the capture (sec. 6), and returns a
:class:`PhysCapResult`: the physically valid hand and object motion, the control that produced
it, and the per-frame costs and timings.

Frames of a capture: ``times`` strictly increasing [s]; the optimiser works on a grid of
``PhysCapConfig.step`` (0.05 s = 20 fps in the paper) and interpolates a capture that is on
another one.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.joints import N_DOF
from hand_control.errors import ConfigError, InputError

__all__ = ["OBJECT_KINDS", "Capture", "CaptureError", "CapturedObject", "PhysCapConfig",
           "PhysCapResult", "load_capture_npz", "optimise_capture", "save_capture_npz"]

#: kinds of captured objects. size: box (hx, hy, hz) half extents; cylinder (radius, half
#: length) along the object frame's x axis; sphere (radius,); mesh: () (the mesh file's own
#: size; collision by its oriented bounding box, see physcap.world)
OBJECT_KINDS: tuple[str, ...] = ("box", "cylinder", "sphere", "mesh")
_SIZE_LEN = {"box": 3, "cylinder": 2, "sphere": 1}


class CaptureError(InputError):
    """A capture (arrays, object or file) is malformed: the message names what and why."""


@dataclass(frozen=True)
class CapturedObject:
    """The manipulated object: shape, mass [kg] and sliding friction (sec. 7.1 computes the
    inertia from the shape at uniform density; MuJoCo does the same from the geom).

    ``mesh`` is a path to a mesh file (``kind='mesh'``), else ``""``."""

    kind: str
    size: tuple[float, ...] = ()
    mass: float = 0.2
    friction: float = 0.75
    mesh: str = ""

    def __post_init__(self) -> None:
        if self.kind not in OBJECT_KINDS:
            raise CaptureError(f"CapturedObject.kind must be one of {OBJECT_KINDS}, "
                               f"got {self.kind!r}")
        try:
            size = tuple(float(s) for s in self.size)
        except (TypeError, ValueError) as e:
            raise CaptureError(f"CapturedObject.size must be numbers, got {self.size!r}") from e
        object.__setattr__(self, "size", size)
        if self.kind == "mesh":
            if not self.mesh:
                raise CaptureError("CapturedObject: kind 'mesh' needs a mesh path")
        else:
            n = _SIZE_LEN[self.kind]
            if len(size) != n or not all(math.isfinite(s) and 0.002 <= s <= 0.5 for s in size):
                raise CaptureError(f"CapturedObject.size of a {self.kind} must be {n} values "
                                   f"in [0.002, 0.5] m, got {size}")
        if not (math.isfinite(self.mass) and 0.001 <= self.mass <= 20.0):
            raise CaptureError(f"CapturedObject.mass must be in [0.001, 20] kg, got {self.mass}")
        if not (math.isfinite(self.friction) and 0.001 <= self.friction <= 5.0):
            raise CaptureError(f"CapturedObject.friction must be in [0.001, 5], got "
                               f"{self.friction}")


def _array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise CaptureError(f"Capture.{name} is not numeric: {e}") from e
    if a.ndim != len(shape) or any(s is not None and a.shape[i] != s
                                   for i, s in enumerate(shape)):
        want = "(" + ", ".join("T" if s is None else str(s) for s in shape) + ")"
        raise CaptureError(f"Capture.{name} must have shape {want}, got {a.shape}")
    if not np.isfinite(a).all():
        bad = np.flatnonzero(~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1))
        raise CaptureError(f"Capture.{name} has non-finite values (frames {bad[:5].tolist()})")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Capture:
    """A kinematic capture of one hand and one object (see the module docstring).

    Arrays (validated and copied read-only on construction):
        times: (T,) [s], strictly increasing, T >= 2.
        hand_q: (T, 27) hand pose vectors (JOINT_NAMES order), world frame [m, rad].
        object_pose: (T, 7) object position [m] + unit quaternion w, x, y, z, world frame.
        keypoints: optional (T, K, 3) observed 3-D hand keypoints [m] (K = 21: the model's
            KEYPOINT_NAMES); ``None``: the cost uses the keypoints of ``hand_q``.

    Raises:
        CaptureError: a wrong shape, a non-finite value, times not strictly increasing, a
            quaternion that is not unit length (|q| off by more than 1e-3), an empty name.
    """

    name: str
    times: np.ndarray
    hand_q: np.ndarray
    object_pose: np.ndarray
    obj: CapturedObject
    keypoints: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise CaptureError("Capture.name must be a non-empty string")
        if not isinstance(self.obj, CapturedObject):
            raise CaptureError(f"Capture.obj must be a CapturedObject, got {type(self.obj)}")
        times = _array("times", self.times, (None,))
        t = times.shape[0]
        if t < 2:
            raise CaptureError(f"Capture.times needs at least 2 frames, got {t}")
        if not (np.diff(times) > 0).all():
            i = int(np.flatnonzero(np.diff(times) <= 0)[0])
            raise CaptureError(f"Capture.times must be strictly increasing; frame {i + 1} "
                               f"({times[i + 1]}) follows {times[i]}")
        hand_q = _array("hand_q", self.hand_q, (t, N_DOF))
        pose = _array("object_pose", self.object_pose, (t, 7))
        norm = np.linalg.norm(pose[:, 3:7], axis=1)
        if np.abs(norm - 1.0).max() > 1e-3:
            i = int(np.argmax(np.abs(norm - 1.0)))
            raise CaptureError(f"Capture.object_pose quaternions must be unit length; frame "
                               f"{i} has |q| = {norm[i]:.4g}")
        kp = None if self.keypoints is None else _array("keypoints", self.keypoints,
                                                        (t, None, 3))
        for k, v in (("times", times), ("hand_q", hand_q), ("object_pose", pose),
                     ("keypoints", kp)):
            object.__setattr__(self, k, v)

    @property
    def n_frames(self) -> int:
        return int(self.times.shape[0])

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])


def save_capture_npz(c: Capture, path: str | os.PathLike[str]) -> Path:
    """Write a capture to ``path`` (.npz, no pickles); returns the path written."""
    p = Path(path)
    arrays: dict[str, Any] = {
        "name": np.array(c.name), "times": c.times, "hand_q": c.hand_q,
        "object_pose": c.object_pose, "obj_kind": np.array(c.obj.kind),
        "obj_size": np.array(c.obj.size, dtype=np.float64),
        "obj_mass": np.array(c.obj.mass), "obj_friction": np.array(c.obj.friction),
        "obj_mesh": np.array(c.obj.mesh), "format": np.array("hand_suite.physcap.capture/1")}
    if c.keypoints is not None:
        arrays["keypoints"] = c.keypoints
    with open(p, "wb") as f:
        np.savez_compressed(f, **arrays)
    return p


def read_npz(path: Path, what: str, error: type[Exception]) -> dict[str, np.ndarray]:
    """Every array of the npz file ``path`` (no pickles), or ``error`` naming the file: missing
    (``no such {what} file``) or unreadable (``not a readable {what} npz``)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except FileNotFoundError as e:
        raise error(f"{path}: no such {what} file") from e
    except (OSError, ValueError, EOFError) as e:
        raise error(f"{path}: not a readable {what} npz ({e})") from e


def load_capture_npz(path: str | os.PathLike[str]) -> Capture:
    """Read a capture written by :func:`save_capture_npz`.

    Raises:
        CaptureError: a missing or unreadable file, a missing array, or invalid content
            (the message names the file).
    """
    p = Path(path)
    d = read_npz(p, "capture", CaptureError)
    need = ("name", "times", "hand_q", "object_pose", "obj_kind", "obj_size", "obj_mass",
            "obj_friction")
    missing = [k for k in need if k not in d]
    if missing:
        raise CaptureError(f"{p}: capture is missing {missing}")
    try:
        obj = CapturedObject(str(d["obj_kind"]), tuple(d["obj_size"].tolist()),
                             float(d["obj_mass"]), float(d["obj_friction"]),
                             str(d.get("obj_mesh", np.array(""))))
        return Capture(str(d["name"]), d["times"], d["hand_q"], d["object_pose"], obj,
                       d.get("keypoints"))
    except CaptureError as e:
        raise CaptureError(f"{p}: {e}") from e


@dataclass(frozen=True)
class PhysCapConfig:
    """Sampling-based control optimisation (seed 000 sec. 6) and its cost (eq. 2 without
    images: 3-D keypoints and object pose)."""

    n_samples: int = param(1500, "samples per step (seed 000: 1500)", lo=2, hi=100000)
    n_keep: int = param(150, "samples saved per step after pruning and diversification "
                        "(seed 000: m = 150)", lo=1, hi=10000)
    step: float = param(0.05, "sampling time step [s] (seed 000: 0.05); a capture on "
                        "another frame grid is interpolated onto this one", lo=0.005, hi=0.5)
    timestep: float = param(0.001, "physics step [s] (the suite's sim: 1 ms)", lo=1e-4,
                            hi=0.005)
    control_every: int = param(4, "physics steps per composite-controller update", lo=1,
                               hi=50)
    sampling: str = param("contact", "'contact' (contact-based sampling) or 'random' "
                          "(hypercubes around the reference only)",
                          choices=("contact", "random"))
    control: str = param("composite", "'composite' (PD + virtual object wrench, eq. 8-13) or "
                         "'pd_only' (eq. 8)", choices=("composite", "pd_only"))
    # hypercube half-widths around the reference / the seed poses
    root_pos_width: float = param(0.004, "hand root translation half-width [m]", lo=0.0,
                                  hi=0.1)
    root_rot_width: float = param(0.03, "hand root rotation half-width [rad]", lo=0.0, hi=1.0)
    finger_width: float = param(0.08, "finger joint half-width [rad]", lo=0.0, hi=1.0)
    object_pos_width: float = param(0.004, "object target position half-width [m]", lo=0.0,
                                    hi=0.1)
    object_rot_width: float = param(0.03, "object target rotation half-width [rad]", lo=0.0,
                                    hi=1.0)
    # energy (eq. 2 without images), per frame
    w_keypoint: float = param(1.0e4, "weight of the mean squared keypoint error [1/m^2]",
                              lo=0.0)
    w_object_pos: float = param(4.0e4, "weight of the squared object position error "
                                "[1/m^2]", lo=0.0)
    w_object_rot: float = param(30.0, "weight of the squared object rotation error "
                                "[1/rad^2]", lo=0.0)
    w_penetration: float = param(1.0e4, "weight of the squared hand-object penetration "
                                 "beyond 2 mm [1/m^2]", lo=0.0)
    # contact-based sampling
    contact_threshold: float = param(0.02, "bone-object closest distance below which a "
                                     "contact is potential [m]", lo=0.0, hi=0.1)
    contact_depth: float = param(0.004, "the IK puts a contacting bone this far into the "
                                 "object (the PD servo's squeeze) [m]", lo=0.0, hi=0.02)
    contact_clearance: float = param(0.006, "the IK keeps a non-contacting bone this far "
                                     "from the object [m]", lo=0.0, hi=0.05)
    max_contacts: int = param(8, "at most this many potential contacts (the nearest): 2^k "
                              "configurations", lo=0, hi=12)
    seed_fraction: float = param(0.75, "share of the samples drawn around contact seeds "
                                 "(the rest around the reference)", lo=0.0, hi=1.0)
    smoothing: int = param(2, "the sampling centres come from the reference averaged over "
                           "+-this many frames (a tracker's per-frame jitter shakes a grasp "
                           "loose); the cost uses the capture as it is", lo=0, hi=20)
    lead: float = param(1.0, "the wrist position's sampling centres lead the (smoothed) "
                        "reference by this many frames of its velocity: the root servos lag "
                        "their targets (about 0.1 s)", lo=0.0, hi=5.0)
    object_lead: float = param(0.0, "the same lead for the object's target position (the "
                               "virtual wrench's servo lags too)", lo=0.0, hi=5.0)
    carry_fraction: float = param(0.5, "share of the samples centred on the reference plus "
                                  "their parent's correction of the previous step (at half "
                                  "width): a correction found once is kept", lo=0.0, hi=1.0)
    success_tolerance: float = param(0.03, "the object reaches its goal when its final "
                                     "position is this close to the capture's [m]", lo=0.001)
    drop_tolerance: float = param(0.03, "the object counts as dropped when it falls this "
                                  "far below the capture's height [m]", lo=0.001)
    seed: int = param(0, "random seed (a run is a function of the capture and the config)")
    n_threads: int = param(1, "threads that simulate samples (each its own MuJoCo data and "
                           "controller; MuJoCo releases the GIL while stepping)", lo=1, hi=64)

    def __post_init__(self) -> None:
        validate(self)
        if self.n_keep > self.n_samples:
            raise ConfigError(f"PhysCapConfig.n_keep ({self.n_keep}) must be <= n_samples "
                              f"({self.n_samples})")
        if self.timestep * self.control_every > self.step + 1e-12:
            raise ConfigError("PhysCapConfig: timestep * control_every must be <= step")
        if abs(self.step / self.timestep - round(self.step / self.timestep)) > 1e-6:
            raise ConfigError(f"PhysCapConfig.step ({self.step}) must be a multiple of "
                              f"timestep ({self.timestep})")


@dataclass(frozen=True, eq=False)
class PhysCapResult:
    """The optimised simulation of a capture (frames on the ``config.step`` grid).

    Arrays (T frames, T - 1 control steps):
        times: (T,) [s].
        hand_q: (T, 27) simulated hand pose; object_pose: (T, 7) simulated object pose.
        reference_q: (T, 27), reference_object: (T, 7): the (interpolated) capture.
        targets: (T - 1, 27) the hand's PD targets of each step (eq. 8).
        object_targets: (T - 1, 7) the object's target pose of each step (eq. 9).
        virtual_forces: (T - 1, 6) mean virtual wrench (force [N], torque [N m]) over each
            step (zero for PD only or without contact).
        costs: (T,) energy of each frame (eq. 2 without images; frame 0: the initial state).
        frame_seconds: (T - 1,) computation time of each step [s].
    """

    name: str
    times: np.ndarray
    hand_q: np.ndarray
    object_pose: np.ndarray
    reference_q: np.ndarray
    reference_object: np.ndarray
    targets: np.ndarray
    object_targets: np.ndarray
    virtual_forces: np.ndarray
    costs: np.ndarray
    frame_seconds: np.ndarray
    success: bool
    reached_goal: bool
    dropped: bool
    final_error_m: float
    config: PhysCapConfig
    obj: CapturedObject
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def s_per_frame(self) -> float:
        return float(self.frame_seconds.mean()) if self.frame_seconds.size else 0.0

    @property
    def energy(self) -> float:
        return float(self.costs.sum())

    def summary(self) -> dict[str, Any]:
        """Plain figures (JSON-ready)."""
        return {"name": self.name, "frames": int(self.times.shape[0]),
                "success": bool(self.success), "reached_goal": bool(self.reached_goal),
                "dropped": bool(self.dropped), "final_error_mm": self.final_error_m * 1e3,
                "energy": self.energy, "s_per_frame": self.s_per_frame,
                "config": asdict(self.config)}


def optimise_capture(capture: Capture, config: PhysCapConfig | None = None, *,
                     progress: Callable[[int, int], None] | None = None,
                     images: Any = None) -> PhysCapResult:
    """Find the composite control that makes the simulation match ``capture`` (seed 000
    sec. 6) and return the simulated motion, the control and its figures.

    Deterministic: the same capture and config (``config.seed``) give the same result, in
    any process and with any ``n_threads``.

    Args:
        capture: the kinematic capture (its first frame is the initial state, at rest).
        config: sampling, cost and simulation settings.
        progress: called as ``progress(done_steps, total_steps)`` after every step.
        images: a :class:`~hand_control.physcap.images.CaptureImages` (one group of views
            per frame, the capture on the ``config.step`` grid): each frame's energy adds
            the image term of eq. (3); ``None``: 3-D terms only.

    Raises:
        CaptureError: the capture cannot be simulated (e.g. an unreadable mesh), or its
            images do not match its frames.
    """
    from hand_control.physcap.optimise import optimise

    return optimise(capture, config or PhysCapConfig(), progress=progress, images=images)
