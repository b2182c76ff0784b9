"""Hand motions for the synthetic camera: keyframed clips and pose-sequence files.

A :class:`MotionClip` maps a time [s] to a 27-DoF pose (``JOINT_NAMES`` order, see
:mod:`hand_capture.model.joints`) and to the positions of the scene objects it moves. It is
built either from keyframes that name only the joints they change
(:meth:`MotionClip.from_keyframes`; the built-in clips of :data:`CLIPS`), or from a recorded
pose sequence in CSV or NPZ (:meth:`MotionClip.from_file`).

Interpolation between keyframes is per DoF: ``smooth`` (default) eases in and out with the
smoothstep ``s(u) = 3u^2 - 2u^3`` so the motion starts and stops without jumps in velocity;
``linear`` suits dense recorded sequences. Both interpolate each value as a convex
combination of two keyframes, so a clip whose keyframes respect the joint limits stays inside
them; :meth:`MotionClip.sample` also clamps to :data:`JOINT_LIMITS`. The root orientation
is interpolated on its three hinge angles, like every other DoF.

Built-in clips place the hand in front of a camera at the world origin looking along ``+z``
(the optical frame): the wrist is 0.40 m away and, unless the clip turns it, the palm faces
the camera with the fingers up.

File formats (unknown joint names are an error; missing joints keep :data:`BASE_POSE`):

* CSV: a header row of joint names, optionally a ``time`` column [s]; one pose per row.
* NPZ: ``joint_names`` (J,) strings, ``poses`` (T, J), optionally ``times`` (T,) [s].
Without times, rows are ``1 / rate`` seconds apart.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.cameras.primitives import SceneObject
from hand_capture.errors import ConfigError, InputError
from hand_capture.model.joints import (
    JOINT_INDEX,
    JOINT_LIMITS,
    JOINT_NAMES,
    N_DOF,
    pose_from_dict,
    root_angles_from_matrix,
)
from hand_capture.paths import resolve_path

__all__ = ["BASE_POSE", "CLIPS", "R_PALM_TO_CAMERA", "Keyframe", "MotionClip", "builtin_clip",
           "load_motion", "save_pose_sequence"]

_TIME_COLUMNS = ("time", "t", "stamp", "time_s")


@dataclass(frozen=True)
class Keyframe:
    """A key pose at time ``t`` [s].

    Attributes:
        t: time [s] from the start of the clip.
        joints: joint name -> value [rad or m]; joints not named keep the previous
            keyframe's value (the first keyframe starts from the clip's base pose).
        objects: object name -> world position [m]; objects not named keep theirs.
    """

    t: float
    joints: Mapping[str, float] = field(default_factory=dict)
    objects: Mapping[str, Sequence[float]] = field(default_factory=dict)


def _smoothstep(u: np.ndarray) -> np.ndarray:
    return u * u * (3.0 - 2.0 * u)


class MotionClip:
    """Poses (and object positions) as a function of time (see the module docstring).

    Args:
        name: clip name.
        times: (K,) strictly increasing key times [s], starting anywhere.
        poses: (K, 27) key poses in JOINT_NAMES order.
        interpolation: ``"smooth"`` or ``"linear"``.
        loop: wrap time around the clip's duration; otherwise hold the last pose.
        objects: scene objects shown with the hand (world frame, at their own positions).
        object_tracks: object name -> (K, 3) positions at the key times.
    """

    def __init__(self, name: str, times: Sequence[float], poses: np.ndarray, *,
                 interpolation: str = "smooth", loop: bool = True,
                 objects: Sequence[SceneObject] = (),
                 object_tracks: Mapping[str, np.ndarray] | None = None) -> None:
        t = np.asarray(times, dtype=float).reshape(-1)
        q = np.asarray(poses, dtype=float)
        if q.ndim != 2 or q.shape != (t.size, N_DOF):
            raise InputError(f"clip {name!r}: poses must be ({t.size}, {N_DOF}), got {q.shape}")
        if t.size == 0:
            raise InputError(f"clip {name!r} has no poses")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
            raise InputError(f"clip {name!r} has NaN/Inf times or poses")
        if t.size > 1 and np.any(np.diff(t) <= 0):
            raise InputError(f"clip {name!r}: key times must be strictly increasing")
        if interpolation not in ("smooth", "linear"):
            raise ConfigError(f"interpolation must be 'smooth' or 'linear', got "
                              f"{interpolation!r}")
        self.name = name
        self.times = t - t[0]
        self.poses = q
        self.interpolation = interpolation
        self.loop = bool(loop)
        self.objects = list(objects)
        names = {o.name for o in self.objects}
        self.object_tracks: dict[str, np.ndarray] = {}
        for k, track in (object_tracks or {}).items():
            if k not in names:
                raise InputError(f"clip {name!r}: track for unknown object {k!r}")
            tr = np.asarray(track, float)
            if tr.shape != (t.size, 3):
                raise InputError(f"clip {name!r}: track {k!r} must be ({t.size}, 3)")
            self.object_tracks[k] = tr

    @property
    def duration(self) -> float:
        """Time from the first to the last key [s]."""
        return float(self.times[-1])

    def _locate(self, t: float) -> tuple[int, float]:
        """Key index k and blend weight in [0, 1] between keys k and k+1 at time t."""
        d = self.duration
        if d <= 0:
            return 0, 0.0
        if self.loop:
            t = float(t) % d
        t = min(max(float(t), 0.0), d)
        k = int(np.searchsorted(self.times, t, side="right") - 1)
        k = min(max(k, 0), self.times.size - 2)
        u = (t - self.times[k]) / (self.times[k + 1] - self.times[k])
        u = min(max(u, 0.0), 1.0)
        if self.interpolation == "smooth":
            u = float(_smoothstep(np.float64(u)))
        return k, u

    def sample(self, t: float) -> np.ndarray:
        """The pose (27,) at time ``t`` [s], clamped to the joint limits."""
        if not math.isfinite(t):
            raise InputError(f"clip time must be finite, got {t}")
        if self.times.size == 1:
            q = self.poses[0].copy()
        else:
            k, u = self._locate(t)
            q = (1.0 - u) * self.poses[k] + u * self.poses[k + 1]
        return np.clip(q, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])

    def sample_many(self, ts: Sequence[float]) -> np.ndarray:
        """Poses (N, 27) at several times."""
        return np.stack([self.sample(float(t)) for t in ts]) if len(ts) else \
            np.zeros((0, N_DOF))

    def object_positions(self, t: float) -> dict[str, np.ndarray]:
        """World position of every object at time ``t`` (tracked or fixed)."""
        out = {o.name: o.position for o in self.objects}
        if self.object_tracks and self.times.size > 1:
            k, u = self._locate(t)
            for name, tr in self.object_tracks.items():
                out[name] = (1.0 - u) * tr[k] + u * tr[k + 1]
        return out

    # -- construction --------------------------------------------------------------------
    @classmethod
    def from_keyframes(cls, name: str, keyframes: Sequence[Keyframe], *,
                       base: np.ndarray | None = None, interpolation: str = "smooth",
                       loop: bool = True, objects: Sequence[SceneObject] = ()) -> MotionClip:
        """A clip from sparse keyframes (joints not named keep their previous value)."""
        if not keyframes:
            raise InputError(f"clip {name!r} needs at least one keyframe")
        q = BASE_POSE.copy() if base is None else np.asarray(base, float).copy()
        pos = {o.name: np.asarray(o.position, float) for o in objects}
        poses, tracks = [], {k: [] for k in pos}
        for kf in keyframes:
            q = pose_from_dict(kf.joints, default=q)
            poses.append(q)
            for k, p in kf.objects.items():
                if k not in pos:
                    raise InputError(f"clip {name!r}: keyframe at {kf.t} s moves unknown "
                                     f"object {k!r}")
                pos[k] = np.asarray(p, float).reshape(3)
            for k in tracks:
                tracks[k].append(pos[k])
        moved = {k: np.array(v) for k, v in tracks.items()
                 if np.ptp(np.array(v), axis=0).max() > 0}
        return cls(name, [kf.t for kf in keyframes], np.array(poses),
                   interpolation=interpolation, loop=loop, objects=objects,
                   object_tracks=moved)

    @classmethod
    def from_file(cls, path: str | Path, *, rate: float = 30.0, loop: bool = True,
                  interpolation: str = "linear") -> MotionClip:
        """A clip from a CSV or NPZ pose sequence (see the module docstring)."""
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"pose sequence file not found: {p}")
        if not rate > 0:
            raise ConfigError(f"rate must be > 0 Hz, got {rate}")
        if p.suffix.lower() == ".npz":
            names, values, times = _read_npz(p)
        elif p.suffix.lower() == ".csv":
            names, values, times = _read_csv(p)
        else:
            raise ConfigError(f"pose sequence {p}: unknown format {p.suffix!r} (use .csv or "
                              f".npz)")
        unknown = sorted(set(names) - set(JOINT_NAMES))
        if unknown:
            raise InputError(f"{p}: unknown joint name(s) {unknown}; valid names: "
                             f"{list(JOINT_NAMES)}")
        if len(set(names)) != len(names):
            raise InputError(f"{p}: duplicate joint columns")
        if values.ndim != 2 or values.shape[1] != len(names) or values.shape[0] == 0:
            raise InputError(f"{p}: expected (T, {len(names)}) values, got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise InputError(f"{p}: NaN/Inf in the pose values")
        poses = np.tile(BASE_POSE, (values.shape[0], 1))
        cols = [JOINT_INDEX[n] for n in names]
        poses[:, cols] = values
        if times is None:
            times = np.arange(values.shape[0]) / rate
        return cls(p.stem, times, poses, interpolation=interpolation, loop=loop)


def _read_csv(p: Path) -> tuple[list[str], np.ndarray, np.ndarray | None]:
    with p.open(newline="") as fh:
        rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    if len(rows) < 2:
        raise InputError(f"{p}: needs a header row and at least one pose row")
    header = [h.strip() for h in rows[0]]
    try:
        data = np.array([[float(c) for c in r] for r in rows[1:]])
    except ValueError as e:
        raise InputError(f"{p}: non-numeric value: {e}") from e
    if data.ndim != 2 or data.shape[1] != len(header):
        raise InputError(f"{p}: every row must have {len(header)} values")
    tcol = [i for i, h in enumerate(header) if h in _TIME_COLUMNS]
    times = data[:, tcol[0]] if tcol else None
    keep = [i for i in range(len(header)) if i not in tcol]
    return [header[i] for i in keep], data[:, keep], times


def _read_npz(p: Path) -> tuple[list[str], np.ndarray, np.ndarray | None]:
    try:
        with np.load(p, allow_pickle=False) as z:
            if "joint_names" not in z or "poses" not in z:
                raise InputError(f"{p}: needs arrays 'joint_names' and 'poses', has "
                                 f"{sorted(z.files)}")
            names = [str(n) for n in z["joint_names"]]
            values = np.asarray(z["poses"], float)
            times = np.asarray(z["times"], float) if "times" in z else None
    except (OSError, ValueError) as e:
        raise InputError(f"{p}: not a readable .npz file: {e}") from e
    return names, values, times


def save_pose_sequence(path: str | Path, times: Sequence[float], poses: np.ndarray) -> None:
    """Write (T, 27) poses with their times as CSV or NPZ (by suffix), readable by from_file."""
    p = Path(path)
    q = np.asarray(poses, float)
    t = np.asarray(times, float)
    if q.ndim != 2 or q.shape != (t.size, N_DOF):
        raise InputError(f"poses must be ({t.size}, {N_DOF}), got {q.shape}")
    if p.suffix.lower() == ".npz":
        np.savez(p, joint_names=np.array(JOINT_NAMES), poses=q, times=t)
    elif p.suffix.lower() == ".csv":
        with p.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(("time",) + JOINT_NAMES)
            for ti, qi in zip(t, q, strict=True):
                w.writerow([repr(float(ti))] + [repr(float(v)) for v in qi])
    else:
        raise ConfigError(f"unknown pose sequence format {p.suffix!r} (use .csv or .npz)")


# ------------------------------------------------------------------------------------------
# Built-in clips
# ------------------------------------------------------------------------------------------
def _root(R: np.ndarray, position: Sequence[float]) -> dict[str, float]:
    rx, ry, rz = root_angles_from_matrix(np.asarray(R, float))
    tx, ty, tz = position
    return {"root_tx": tx, "root_ty": ty, "root_tz": tz, "root_rx": float(rx),
            "root_ry": float(ry), "root_rz": float(rz)}


#: Root rotation of a hand seen palm-on: palm towards the camera, fingers up (-y of the optical
#: frame), thumb on the image's right for a right hand: hand +x -> camera -y, hand +z (dorsal)
#: -> camera +z. The clips, the tracker's training views and the teleop camera start from it.
R_PALM_TO_CAMERA = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
R_PALM_TO_CAMERA.setflags(write=False)
_WRIST = (0.0, 0.09, 0.40)

#: The pose the built-in clips start from and the default of joints a file leaves out.
BASE_POSE: np.ndarray = pose_from_dict(_root(R_PALM_TO_CAMERA, _WRIST))
BASE_POSE.setflags(write=False)

_D = math.radians
_LONG = ("index", "middle", "ring", "little")


def _finger(f: str, mcp: float, pip: float, dip: float, abd: float = 0.0) -> dict[str, float]:
    return {f"{f}_mcp_abd": _D(abd), f"{f}_mcp_flex": _D(mcp), f"{f}_pip_flex": _D(pip),
            f"{f}_dip_flex": _D(dip)}


def _thumb(tm_abd: float, tm_flex: float, mcp: float, ip: float,
           mcp_abd: float = 0.0) -> dict[str, float]:
    return {"thumb_tm_abd": _D(tm_abd), "thumb_tm_flex": _D(tm_flex),
            "thumb_mcp_abd": _D(mcp_abd), "thumb_mcp_flex": _D(mcp), "thumb_ip_flex": _D(ip)}


def _hand(extended: Sequence[str] = (), thumb_out: bool = False) -> dict[str, float]:
    """Fingers in ``extended`` straight, the others curled into a fist."""
    q: dict[str, float] = {}
    for f in _LONG:
        q.update(_finger(f, 0, 0, 0) if f in extended else _finger(f, 85, 100, 60))
    q.update(_thumb(0, 0, 0, 0) if thumb_out else _thumb(15, 45, 45, 50))
    return q


OPEN = _hand(_LONG, thumb_out=True)
FIST = _hand()


def _finger_counting() -> MotionClip:
    seq = [FIST, _hand(["index"]), _hand(["index", "middle"]),
           _hand(["index", "middle", "ring"]), _hand(_LONG), _hand(_LONG, thumb_out=True),
           FIST]
    kfs = []
    for i, q in enumerate(seq):
        kfs += [Keyframe(1.0 * i, q), Keyframe(1.0 * i + 0.5, {})]  # move 0.5 s, hold 0.5 s
    return MotionClip.from_keyframes("finger_counting", kfs[:-1])


def _fist() -> MotionClip:
    return MotionClip.from_keyframes("fist", [
        Keyframe(0.0, OPEN), Keyframe(0.4, {}), Keyframe(1.4, FIST), Keyframe(1.8, {}),
        Keyframe(2.8, OPEN)])


def _wrist_rotation() -> MotionClip:
    b = {k: BASE_POSE[JOINT_INDEX[k]] for k in ("root_rx", "root_ry", "root_rz")}
    rot = lambda drx=0.0, dry=0.0, drz=0.0: {
        "root_rx": b["root_rx"] + _D(drx), "root_ry": b["root_ry"] + _D(dry),
        "root_rz": b["root_rz"] + _D(drz)}
    return MotionClip.from_keyframes("wrist_rotation", [
        Keyframe(0.0, {**OPEN, **rot()}),
        Keyframe(1.2, rot(dry=70)), Keyframe(2.4, rot(dry=-70)),  # pronation / supination
        Keyframe(3.4, rot()), Keyframe(4.4, rot(drx=45)), Keyframe(5.4, rot(drx=-40)),
        Keyframe(6.4, rot()), Keyframe(7.2, rot(drz=35)), Keyframe(8.0, rot(drz=-35)),
        Keyframe(8.8, rot())])


def _translation() -> MotionClip:
    x, y, z = _WRIST
    at = lambda dx=0.0, dy=0.0, dz=0.0: {
        "root_tx": x + dx, "root_ty": y + dy, "root_tz": z + dz}
    return MotionClip.from_keyframes("translation", [
        Keyframe(0.0, {**OPEN, **at()}), Keyframe(1.0, at(dx=0.08)), Keyframe(2.0, at(dx=-0.08)),
        Keyframe(3.0, at()), Keyframe(4.0, at(dy=-0.06)), Keyframe(5.0, at(dy=0.05)),
        Keyframe(6.0, at()), Keyframe(7.0, at(dz=-0.10)), Keyframe(8.0, at(dz=0.20)),
        Keyframe(9.0, at())])


PINCH = {**_finger("index", 45, 60, 15), **_finger("middle", 20, 25, 10),
         **_finger("ring", 15, 20, 10), **_finger("little", 10, 15, 10),
         **_thumb(20, 20, 25, 10)}


def _pinch() -> MotionClip:
    return MotionClip.from_keyframes("pinch", [
        Keyframe(0.0, OPEN), Keyframe(0.5, {}), Keyframe(1.5, PINCH), Keyframe(2.1, {}),
        Keyframe(3.1, OPEN)])


# Grasp: seen from the thumb side, back of the hand up, fingers pointing to the image's left;
# hand +x -> camera -x, hand +z (dorsal) -> camera -y (up).
_R_GRASP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])
GRASP_BALL_RADIUS = 0.035
_GRASP_WRIST = np.array([0.085, -0.015, 0.42])
# ball under the palm centre (about 60 mm distal of the wrist), touching the palm skin
_BALL_AT = _GRASP_WRIST + np.array([-0.060, 0.0135 + GRASP_BALL_RADIUS, 0.0])
# wrap grasp: per finger, the flexion (DIP ~ 2/3 PIP) touching the most ball surface with
# at most 1.5 mm penetration, found by a grid search against the default hand shape
GRASP = {**_finger("index", 80, 30, 20), **_finger("middle", 65, 50, 34),
         **_finger("ring", 60, 50, 34), **_finger("little", 70, 30, 20),
         **_thumb(25, 15, 40, 40)}


def _grasp() -> MotionClip:
    ball = SceneObject.primitive("sphere", [GRASP_BALL_RADIUS], name="ball",
                                 position=_BALL_AT, color=(0.85, 0.35, 0.25))
    lift = np.array([0.0, -0.06, 0.0])
    up = {"root_ty": _GRASP_WRIST[1] - 0.07}
    at = {"root_ty": _GRASP_WRIST[1]}
    lifted = {"root_ty": _GRASP_WRIST[1] + lift[1]}
    start = {**OPEN, **_root(_R_GRASP, _GRASP_WRIST), **up}
    return MotionClip.from_keyframes("grasp", [
        Keyframe(0.0, start),
        Keyframe(1.2, at),                                   # reach down to the ball
        Keyframe(2.2, GRASP),                                # close
        Keyframe(3.2, lifted, {"ball": _BALL_AT + lift}),    # lift together
        Keyframe(4.0, {}),                                   # hold
        Keyframe(5.0, at, {"ball": _BALL_AT}),               # put down
        Keyframe(6.0, OPEN),                                 # release
        Keyframe(7.0, up),                                   # withdraw
    ], objects=[ball])


def _static() -> MotionClip:
    return MotionClip.from_keyframes("static", [Keyframe(0.0, OPEN)])


#: Built-in clip name -> builder.
CLIPS: dict[str, Callable[[], MotionClip]] = {
    "finger_counting": _finger_counting,
    "fist": _fist,
    "wrist_rotation": _wrist_rotation,
    "translation": _translation,
    "pinch": _pinch,
    "grasp": _grasp,
    "static": _static,
}


def builtin_clip(name: str) -> MotionClip:
    """A built-in clip by name (see :data:`CLIPS`)."""
    if name not in CLIPS:
        raise ConfigError(f"unknown motion clip {name!r}; valid: {sorted(CLIPS)}")
    return CLIPS[name]()


def load_motion(clip: str, pose_file: str = "", *, rate: float = 30.0,
                loop: bool = True) -> MotionClip:
    """The built-in ``clip``, or the pose sequence in ``pose_file`` when one is given.

    A relative ``pose_file`` that does not exist from the working directory is looked up in
    the suite's share folder (``data/teleop/lift_box.npz`` names the shipped performance).
    """
    if pose_file:
        return MotionClip.from_file(resolve_path(pose_file), rate=rate, loop=loop)
    c = builtin_clip(clip)
    c.loop = loop
    return c
