"""The grasp database (dissertation III.3): grip modes, demonstrations, the object frame.

The dissertation's database is Vicon + Kinect captures of a human subject (ten objects, ten
grip modes, 120 fps). That data is not available to this project, so the shipped database is
*generated with the suite's own tools* (:mod:`hand_control.grasp.generate`): fingertip IK onto
grip-mode-specific contact layouts on primitive objects, human-like randomised timing, each
demonstration executed by the composite controller in the MuJoCo simulation and kept only when
the object was lifted, with the contacts the simulation reported. ``hand-suite train grasps``
rebuilds it (seeded, reproducible).

Every motion is stored in the object's local frame of III.3: origin at the object's centre of
mass (at rest, before the grasp), ``z`` up (normal of the table), ``x`` the horizontal
direction from the centre of the hand (the palm centre) to the object's centre at the grasping
pose (the last frame of the closing phase). :func:`to_object_frame` / :func:`from_object_frame`
convert 27-DoF pose vectors between the world and that frame.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.model.joints import N_DOF, root_angles_from_matrix, root_rotation_matrix
from hand_capture.paths import data_dir
from hand_control.errors import InputError
from hand_control.grasp.closing import ClosingModel

__all__ = ["DATABASE_FILE", "GRIP_CONTACT_FINGERS", "GRIP_MODES", "GraspRecord",
           "default_grasp_dir", "from_object_frame", "load_grasp_database", "load_grasp_models",
           "model_file", "object_frame_yaw", "save_grasp_database", "to_object_frame"]

#: The ten grip modes of Fig. III.3. The figure's own labels are not in the text we have; the
#: names spell the finger sets the dissertation names (Fig. III.7: "thumb and index finger",
#: "thumb and middle finger", "all fingers except index fingers", "all fingers"; the "pinch"
#: and the "power grip" of III.4.1.2, where the thumb opposes all four fingers).
GRIP_MODES: tuple[str, ...] = (
    "thumb_index",              # pinch of thumb and index (SP = 1)
    "thumb_middle",             # pinch of thumb and middle finger
    "thumb_ring",               # pinch of thumb and ring finger
    "thumb_index_middle",       # tripod
    "thumb_middle_ring",
    "thumb_index_middle_ring",
    "all_except_index",         # thumb, middle, ring, little
    "all_fingers",              # five-finger precision grip (SP = 4)
    "spherical",                # all fingers spread around a round object
    "power",                    # power grip: palm on the object, all fingers wrapped (SP = 4)
)

#: The fingers whose pads touch the object in each grip mode (the thumb opposes the others).
GRIP_CONTACT_FINGERS: dict[str, tuple[str, ...]] = {
    "thumb_index": ("thumb", "index"),
    "thumb_middle": ("thumb", "middle"),
    "thumb_ring": ("thumb", "ring"),
    "thumb_index_middle": ("thumb", "index", "middle"),
    "thumb_middle_ring": ("thumb", "middle", "ring"),
    "thumb_index_middle_ring": ("thumb", "index", "middle", "ring"),
    "all_except_index": ("thumb", "middle", "ring", "little"),
    "all_fingers": ("thumb", "index", "middle", "ring", "little"),
    "spherical": ("thumb", "index", "middle", "ring", "little"),
    "power": ("thumb", "index", "middle", "ring", "little"),
}
assert set(GRIP_CONTACT_FINGERS) == set(GRIP_MODES)

OBJECT_KINDS: tuple[str, ...] = ("box", "ball", "cylinder")


@dataclass(frozen=True, eq=False)
class GraspRecord:
    """One demonstration: reaching, closing and manipulation of one object.

    Attributes:
        grip_mode: one of :data:`GRIP_MODES`.
        object_kind: ``box`` (size = half extents, 3) | ``ball`` (radius) | ``cylinder``
            (radius, half height; standing upright).
        object_size: [m]; object_mass [kg].
        motion: (T, 27) hand pose vectors (``JOINT_NAMES`` order) in the object frame of III.3
            (module docstring), sampled at ``fps``.
        phases: ``(closing_start, manipulation_start)`` frame indices; the closing segment is
            ``motion[closing_start:manipulation_start]``.
        contacts: ``(bone, point in the object frame [m])`` reported by the simulation at the
            grasping pose (bones are the MuJoCo body names of the hand).
        contacts_local: the same contacts as ``(bone, point in that bone's frame [m])``.
        object_friction: sliding friction of the object in the check.
        placement: ``(x, y, yaw)`` of the object frame in the simulation's world [m, rad].
        lift_mm: how far the simulated object rose [mm] (the check passed).
        fps: frame rate [Hz].
    """

    grip_mode: str
    object_kind: str
    object_size: tuple[float, ...]
    object_mass: float
    motion: np.ndarray
    phases: tuple[int, int]
    contacts: tuple[tuple[str, tuple[float, float, float]], ...]
    contacts_local: tuple[tuple[str, tuple[float, float, float]], ...] = ()
    object_friction: float = 0.75
    placement: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lift_mm: float = float("nan")
    fps: float = 100.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.grip_mode not in GRIP_MODES:
            raise InputError(f"GraspRecord: unknown grip mode {self.grip_mode!r}; valid: "
                             f"{', '.join(GRIP_MODES)}")
        if self.object_kind not in OBJECT_KINDS:
            raise InputError(f"GraspRecord: object_kind must be one of {OBJECT_KINDS}, "
                             f"got {self.object_kind!r}")
        m = np.asarray(self.motion, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != N_DOF or not np.isfinite(m).all():
            raise InputError(f"GraspRecord: motion must be finite (T, {N_DOF}), got "
                             f"{np.shape(self.motion)}")
        a, b = self.phases
        if not 0 <= a < b <= m.shape[0]:
            raise InputError(f"GraspRecord: phases {self.phases} outside 0..{m.shape[0]}")
        object.__setattr__(self, "motion", m)

    @property
    def reaching(self) -> np.ndarray:
        """The reaching segment (n, 27): from the start to the first closing frame."""
        return self.motion[:self.phases[0] + 1]

    @property
    def manipulation(self) -> np.ndarray:
        """The manipulation segment (n, 27): from the grasping pose on (lift and hold)."""
        return self.motion[self.phases[1] - 1:]

    @property
    def closing(self) -> np.ndarray:
        """The closing segment (n, 27)."""
        return self.motion[self.phases[0]:self.phases[1]]

    @property
    def grasp_pose(self) -> np.ndarray:
        """The grasping pose (27,): the closing segment's last frame."""
        return self.motion[self.phases[1] - 1]


# ---- the object frame ------------------------------------------------------------------
def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def object_frame_yaw(hand_center: Sequence[float], object_center: Sequence[float]) -> float:
    """Heading [rad] of the object frame's ``x`` axis: the horizontal direction from the
    hand's centre to the object's centre (world frame, z up)."""
    d = np.asarray(object_center, dtype=np.float64) - np.asarray(hand_center, dtype=np.float64)
    if np.hypot(d[0], d[1]) < 1e-9:
        raise InputError("object_frame_yaw: the hand centre is straight above/below the object")
    return float(np.arctan2(d[1], d[0]))


def to_object_frame(motion: np.ndarray, origin: Sequence[float], yaw: float) -> np.ndarray:
    """World-frame pose vectors (T, 27) or (27,) -> the object frame at ``origin`` (the centre
    of mass) turned by ``yaw`` about z. Finger angles are unchanged; the root position and
    orientation are re-expressed; root angles stay continuous over time."""
    return _transform(motion, np.asarray(origin, dtype=np.float64), _rz(yaw).T, inverse=True)


def from_object_frame(motion: np.ndarray, origin: Sequence[float], yaw: float) -> np.ndarray:
    """The inverse of :func:`to_object_frame`: object-frame poses -> world poses."""
    return _transform(motion, np.asarray(origin, dtype=np.float64), _rz(yaw), inverse=False)


def _transform(motion: np.ndarray, origin: np.ndarray, rot: np.ndarray, inverse: bool
               ) -> np.ndarray:
    m = np.array(motion, dtype=np.float64)
    one = m.ndim == 1
    m = np.atleast_2d(m)
    if m.shape[1] != N_DOF:
        raise InputError(f"pose vectors must have {N_DOF} values, got {m.shape[1]}")
    out = m.copy()
    if inverse:
        out[:, 0:3] = (m[:, 0:3] - origin) @ rot.T
    else:
        out[:, 0:3] = m[:, 0:3] @ rot.T + origin
    prev = None
    for i in range(m.shape[0]):
        a = root_angles_from_matrix(rot @ root_rotation_matrix(m[i, 3:6]))
        if prev is not None:  # keep each angle continuous (no 2 pi jumps)
            a = prev + (a - prev + np.pi) % (2 * np.pi) - np.pi
        out[i, 3:6] = a
        prev = a
    return out[0] if one else out


# ---- files -----------------------------------------------------------------------------
def default_grasp_dir() -> Path:
    """``data/grasp``: the shipped database and closing models."""
    return data_dir() / "grasp"


DATABASE_FILE = "database.npz"


def _contacts_json(c: tuple) -> list:
    return [[b, [float(v) for v in p]] for b, p in c]


def save_grasp_database(records: Sequence[GraspRecord], path: str | Path) -> None:
    """Write the records to one compressed ``.npz`` (motions as float32, metadata as JSON)."""
    meta, arrays = [], {}
    for i, r in enumerate(records):
        arrays[f"motion_{i:04d}"] = r.motion.astype(np.float32)
        meta.append({
            "grip_mode": r.grip_mode, "object_kind": r.object_kind,
            "object_size": list(r.object_size), "object_mass": r.object_mass,
            "phases": list(r.phases), "contacts": _contacts_json(r.contacts),
            "contacts_local": _contacts_json(r.contacts_local),
            "object_friction": r.object_friction, "placement": list(r.placement),
            "lift_mm": r.lift_mm, "fps": r.fps, "extra": r.extra})
    np.savez_compressed(Path(path), meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)


def _contacts_tuple(c: list) -> tuple:
    return tuple((str(b), tuple(float(v) for v in p)) for b, p in c)


def load_grasp_database(path: str | Path | None = None) -> list[GraspRecord]:
    """The demonstrations of the database (default: the shipped ``data/grasp/database.npz``).

    Raises:
        InputError: the file is missing or malformed (run ``hand-suite train grasps``).
    """
    p = Path(path) if path is not None else default_grasp_dir() / DATABASE_FILE
    if p.is_dir():
        p = p / DATABASE_FILE
    try:
        with np.load(p, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            motions = [z[f"motion_{i:04d}"].astype(np.float64) for i in range(len(meta))]
    except (OSError, KeyError, ValueError) as e:
        raise InputError(f"cannot read the grasp database {p}: {e} "
                         "(rebuild it with `hand-suite train grasps`)") from e
    return [GraspRecord(m["grip_mode"], m["object_kind"], tuple(m["object_size"]),
                        float(m["object_mass"]), mo, tuple(m["phases"]),
                        _contacts_tuple(m["contacts"]), _contacts_tuple(m["contacts_local"]),
                        float(m["object_friction"]), tuple(m["placement"]),
                        float(m["lift_mm"]), float(m["fps"]), dict(m.get("extra", {})))
            for m, mo in zip(meta, motions, strict=True)]


def model_file(grip_mode: str) -> str:
    return f"closing_{grip_mode}.npz"


def load_grasp_models(path: str | Path | None = None) -> dict[str, ClosingModel]:
    """The closing-phase model of every grip mode found in ``path`` (a folder of
    ``closing_<mode>.npz``; default: the shipped ``data/grasp``), by grip mode, in
    :data:`GRIP_MODES` order.

    Raises:
        InputError: no model in the folder (run ``hand-suite train grasps``).
    """
    d = Path(path) if path is not None else default_grasp_dir()
    models = {g: ClosingModel.load(d / model_file(g)) for g in GRIP_MODES
              if (d / model_file(g)).is_file()}
    if not models:
        raise InputError(f"no closing models in {d} (run `hand-suite train grasps`)")
    return models
