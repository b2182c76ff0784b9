"""Archives of captures for the physics capture: listing, validation, loading.

An archive is a directory; every entry at its top level is one capture:

* ``NAME.npz``: a :class:`~hand_control.physcap.capture.Capture` saved with
  ``save_capture_npz`` (object properties inside). In an archive a capture is called by its
  file's (or bag's) name, whatever name it was saved with.
* ``NAME/`` (a rosbag2 directory with ``metadata.yaml``) or ``NAME.mcap`` (one MCAP file): a
  recorded capture. Topics read (leading slash optional):

  - hand: ``hand/pose`` (hand_msgs/HandPose, world frame), else ``hand/pose_truth``; the
    messages of one hand (``ArchiveConfig.hand``, by ``handedness``: right by default),
    without those of status LOST (a stale pose);
  - object: ``object/pose``, else ``object/pose_truth`` (geometry_msgs/PoseStamped, world;
    the object's body frame); with several objects ``object/NAME/pose[_truth]`` where NAME is
    the ``name`` of the object properties;
  - optional ``hand/keypoints`` (hand_msgs/HandKeypoints, 21 points) matched by stamp.

  The frames are the hand poses' header stamps; object poses are interpolated at them (linear
  position, normalised-linear quaternion) and hand frames outside the object's time range
  are dropped. The depth tracker's bags carry ``hand/pose`` only (camera frame): give the
  object (with its ``pose`` on the table) and ``camera_pose`` (the camera in the world) in
  the object properties; its poses are then a kinematic guess the optimiser corrects: at
  rest until the hand root arrives at its grasp distance (closest approach within
  :attr:`ArchiveConfig.touch_distance`), then moving rigidly with the hand root.

Object properties of a bag, first found wins:

1. a sidecar YAML next to the bag: ``NAME.object.yaml`` for ``NAME/`` or ``NAME.mcap``;
2. the bag's own ``metadata.yaml``: ``rosbag2_bagfile_information.custom_data.physcap_object``
   holding the same YAML as a string (rosbag2 custom data);
3. the default object given to :func:`list_archive` (``--object FILE`` on the command line).

The YAML keys are those of :class:`ObjectProperties`::

    kind: box            # box | sphere (or ball) | cylinder | mesh
    size: [0.0285, 0.0285, 0.0285]   # half extents | radius | radius, half length [m]
    mass: 0.2            # [kg]
    friction: 0.75       # sliding friction coefficient
    mesh: ""             # mesh file (kind mesh), relative to the YAML file
    name: ""             # which object/NAME/pose topic (bags with several objects)
    pose: []             # x y z qw qx qy qz: the object at rest [m] (bags without its poses)
    camera_pose: []      # x y z qw qx qy qz: camera in the world (hand poses in camera frame)

Validation (:func:`list_archive`, :func:`load_entry`): a corrupt capture (CRC mismatch,
truncated storage, unreadable file) raises :class:`CorruptCaptureError`; an incomplete one
(no hand or object poses, fewer than ``min_frames`` frames, NaN / Inf values, no object
properties, stamps that do not increase) raises :class:`IncompleteCaptureError`. Both name
the capture and the reason, and :func:`list_archive` reports them as entry statuses instead.
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.config import from_mapping, load_yaml, param, validate
from hand_capture.errors import BagError, ConfigError, InputError
from hand_capture.model.joints import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from hand_capture.posemsg import HAND_LEFT, HAND_RIGHT, STATUS
from hand_control.physcap.capture import (
    Capture,
    CapturedObject,
    CaptureError,
    load_capture_npz,
)

__all__ = [
    "ArchiveConfig",
    "ArchiveEntry",
    "ArchiveCaptureError",
    "CorruptCaptureError",
    "IncompleteCaptureError",
    "ObjectProperties",
    "list_archive",
    "load_entry",
    "load_object_yaml",
    "read_capture_bag",
]

#: the file next to a bag NAME/ or NAME.mcap that holds its object properties
SIDECAR_SUFFIX = ".object.yaml"
#: key of the object properties in a bag's rosbag2 custom data
METADATA_KEY = "physcap_object"
HAND_TOPICS = ("hand/pose", "hand/pose_truth")
OBJECT_TOPICS = ("object/pose", "object/pose_truth")
KEYPOINT_TOPIC = "hand/keypoints"


class ArchiveCaptureError(CaptureError):
    """A capture of an archive cannot be used; ``name`` and ``reason`` say which and why."""

    status = "invalid"

    def __init__(self, name: str, reason: str) -> None:
        super().__init__(f"capture {name!r} is {self.status}: {reason}")
        self.name = name
        self.reason = reason


class CorruptCaptureError(ArchiveCaptureError):
    """The capture's file is damaged: CRC mismatch, truncated storage, not readable."""

    status = "corrupt"


class IncompleteCaptureError(ArchiveCaptureError):
    """The capture lacks data: no hand / object poses, too few frames, NaN, no object."""

    status = "incomplete"


@dataclass(frozen=True)
class ArchiveConfig:
    """How an archive is read and what a usable capture needs."""

    min_frames: int = param(5, "fewest frames a capture may have", lo=2, hi=1_000_000)
    hand: str = param("right", "which hand of a bag (HandPose.handedness) is captured",
                      choices=("right", "left"))
    touch_distance: float = param(
        0.12, "bags without object poses: the object moves with the hand root once the root "
        "has come this close to it (else it stays at rest) [m]", lo=0.0, hi=1.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class ObjectProperties:
    """The object of a recorded capture (sidecar / metadata / ``--object`` YAML)."""

    kind: str = param("box", "object shape (ball = sphere)",
                      choices=("box", "sphere", "ball", "cylinder", "mesh"))
    size: tuple[float, ...] = param(
        (), "box half extents (3) | sphere radius (1) | cylinder radius, half length along "
        "the object's x axis (2) [m]", lo=0.002, hi=0.5)
    mass: float = param(0.2, "object mass [kg]", lo=0.001, hi=20.0)
    friction: float = param(0.75, "sliding friction coefficient", lo=0.001, hi=5.0)
    mesh: str = param("", "mesh file for kind mesh (absolute, or relative to the YAML)")
    name: str = param("", "object name: selects object/NAME/pose in a bag with several")
    pose: tuple[float, ...] = param(
        (), "x y z qw qx qy qz: the object at rest, for bags without object poses [m]")
    camera_pose: tuple[float, ...] = param(
        (), "x y z qw qx qy qz: the camera in the world, for hand poses in a camera frame")

    def __post_init__(self) -> None:
        validate(self)
        if self.kind == "ball":
            object.__setattr__(self, "kind", "sphere")
        need = {"box": 3, "sphere": 1, "cylinder": 2}.get(self.kind)
        if need is not None and len(self.size) != need:
            raise ConfigError(f"ObjectProperties.size: a {self.kind} needs {need} values "
                              f"[m], got {list(self.size)}")
        if self.kind == "mesh" and not self.mesh:
            raise ConfigError("ObjectProperties.mesh: kind mesh needs a mesh file")
        for key in ("pose", "camera_pose"):
            v = getattr(self, key)
            if v and (len(v) != 7 or not np.isfinite(v).all()
                      or np.linalg.norm(v[3:]) < 1e-9):
                raise ConfigError(f"ObjectProperties.{key} needs 7 finite values "
                                  f"x y z qw qx qy qz with a non-zero quaternion, got {list(v)}")


def load_object_yaml(path: str | Path) -> ObjectProperties:
    """Object properties from a YAML file (keys of :class:`ObjectProperties`); a relative
    ``mesh`` is resolved against the file's folder.

    Raises:
        ConfigError: missing file, bad YAML, unknown key or value out of range.
    """
    path = Path(path)
    data = load_yaml(path)
    return _object_from_mapping(data, path.parent, str(path))


def _object_from_mapping(data: Any, base: Path, where: str) -> ObjectProperties:
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping of object properties, got "
                          f"{type(data).__name__}")
    obj = from_mapping(ObjectProperties, data)
    if obj.mesh and not Path(obj.mesh).is_absolute():
        obj = replace(obj, mesh=str((base / obj.mesh).resolve()))
    return obj


@dataclass(frozen=True)
class ArchiveEntry:
    """One capture of an archive and whether it can be processed.

    Attributes:
        name: the capture's name (file or bag name without suffix); seeds derive from it.
        path: the ``.npz`` file, bag directory or ``.mcap`` file.
        kind: ``"npz"`` or ``"bag"``.
        status: ``"ok"``, ``"corrupt"`` or ``"incomplete"``.
        reason: why it is not ok (empty when ok).
        frames: number of frames (0 when not ok).
        duration_s: time from first to last frame [s].
        object_kind: the object's shape (empty when unknown).
        object_source: where a bag's object properties came from (sidecar, metadata, default).
    """

    name: str
    path: Path
    kind: str
    status: str
    reason: str = ""
    frames: int = 0
    duration_s: float = 0.0
    object_kind: str = ""
    object_source: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def _entry_kind(path: Path) -> str | None:
    if path.is_file() and path.suffix == ".npz":
        return "npz"
    if path.is_file() and path.suffix == ".mcap":
        return "bag"
    if path.is_dir() and ((path / "metadata.yaml").exists() or any(path.glob("*.mcap"))
                          or any(path.glob("*.db3"))):
        return "bag"
    return None


def _entry_name(path: Path) -> str:
    return path.stem if path.is_file() else path.name


def list_archive(directory: str | Path, default_object: ObjectProperties | None = None,
                 config: ArchiveConfig | None = None) -> list[ArchiveEntry]:
    """Every capture at the top level of ``directory``, validated, sorted by name (or the one
    capture ``directory`` is: an ``.npz``, a bag folder or an ``.mcap`` file).

    Each capture is read completely (bags: CRCs and every message); one that cannot be used
    gets status ``corrupt`` or ``incomplete`` with its reason instead of an exception.

    Raises:
        InputError: ``directory`` is neither a directory nor a capture, or two captures share
            a name.
    """
    root = Path(directory)
    config = config or ArchiveConfig()
    if root.is_file() or (root / "metadata.yaml").is_file():  # one capture
        kind = _entry_kind(root)
        if kind is None:
            raise InputError(f"{root} is not a capture (.npz, .mcap or a bag folder)")
        return [inspect_entry(root, kind, default_object, config)]
    if not root.is_dir():
        raise InputError(f"archive {root} is neither a directory nor a capture file")
    entries: list[ArchiveEntry] = []
    seen: dict[str, Path] = {}
    for path in sorted(root.iterdir()):
        kind = _entry_kind(path)
        if kind is None:
            continue
        name = _entry_name(path)
        if name in seen:
            raise InputError(f"archive {root}: two captures named {name!r} ({seen[name].name} "
                             f"and {path.name}); results and seeds go by name, rename one")
        seen[name] = path
        entries.append(inspect_entry(path, kind, default_object, config))
    return entries


def inspect_entry(path: Path, kind: str, default_object: ObjectProperties | None,
                  config: ArchiveConfig) -> ArchiveEntry:
    """Validate one capture; returns its entry (never raises for a bad capture)."""
    name = _entry_name(path)
    try:
        cap, source = _load(path, kind, name, default_object, config)
    except ArchiveCaptureError as e:
        return ArchiveEntry(name, path, kind, e.status, e.reason)
    t = np.asarray(cap.times, dtype=float)
    return ArchiveEntry(name, path, kind, "ok", "", len(t), float(t[-1] - t[0]),
                        str(cap.obj.kind), source)


def load_entry(entry: ArchiveEntry, default_object: ObjectProperties | None = None,
               config: ArchiveConfig | None = None) -> Any:
    """The :class:`~hand_control.physcap.capture.Capture` of an archive entry (read from its
    file again: a worker of a cluster calls this with the path, not with arrays).

    Raises:
        CorruptCaptureError, IncompleteCaptureError: naming the capture and the reason.
    """
    cap, _ = _load(Path(entry.path), entry.kind, entry.name, default_object,
                   config or ArchiveConfig())
    return cap


def _load(path: Path, kind: str, name: str, default_object: ObjectProperties | None,
          config: ArchiveConfig) -> tuple[Any, str]:
    if kind == "npz":
        return _load_npz(path, name, config), "npz"
    return read_capture_bag(path, default_object, config, name=name)


def _load_npz(path: Path, name: str, config: ArchiveConfig) -> Capture:
    try:  # every member's CRC first: a damaged file is corrupt, a valid one incomplete
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        raise CorruptCaptureError(name, f"{path.name} is not a readable npz (zip) file: "
                                  f"{type(e).__name__}: {e}") from e
    if bad is not None:
        raise CorruptCaptureError(name, f"{path.name}: CRC mismatch in member {bad}")
    try:
        cap = load_capture_npz(path)
    except CaptureError as e:
        raise IncompleteCaptureError(name, str(e)) from e
    if cap.name != name:  # the file's name is the capture's name in an archive
        cap = replace(cap, name=name)
    _check_capture(cap, name, config)
    return cap


def _check_capture(cap: Capture, name: str, config: ArchiveConfig) -> None:
    """What an archive asks beyond a valid :class:`Capture` (shapes, finite values and
    increasing times are checked on its construction): enough frames."""
    if cap.n_frames < config.min_frames:
        raise IncompleteCaptureError(name, f"{cap.n_frames} frames, fewer than the "
                                     f"{config.min_frames} a capture needs")


def _bag_object(path: Path, name: str, default_object: ObjectProperties | None
                ) -> tuple[ObjectProperties, str]:
    sidecar = path.with_name(_entry_name(path) + SIDECAR_SUFFIX)
    try:
        if sidecar.exists():
            return load_object_yaml(sidecar), "sidecar"
        meta = path / "metadata.yaml" if path.is_dir() else None
        if meta is not None and meta.exists():
            info = (load_yaml(meta) or {}).get("rosbag2_bagfile_information", {}) or {}
            text = (info.get("custom_data") or {}).get(METADATA_KEY)
            if text:
                import yaml

                return _object_from_mapping(yaml.safe_load(text), path,
                                            f"{meta} custom_data.{METADATA_KEY}"), "metadata"
    except (ConfigError, AttributeError, ValueError) as e:
        raise IncompleteCaptureError(name, f"bad object properties: {e}") from e
    if default_object is not None:
        return default_object, "default"
    raise IncompleteCaptureError(
        name, f"no object properties: put them in {sidecar.name} next to the bag, in its "
        f"metadata (custom_data.{METADATA_KEY}), or give a default object (--object FILE)")


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _pose7(msg: Any) -> np.ndarray:
    p, o = msg.pose.position, msg.pose.orientation
    return np.array([p.x, p.y, p.z, o.w, o.x, o.y, o.z], dtype=float)


def _interp_poses(t_src: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(T, 7) poses (pos, quat wxyz) at times ``t`` inside [t_src[0], t_src[-1]]: linear
    position, normalised-linear quaternion on the shorter arc."""
    k = np.clip(np.searchsorted(t_src, t, side="right") - 1, 0, len(t_src) - 1)
    k1 = np.minimum(k + 1, len(t_src) - 1)
    span = np.where(k1 > k, t_src[k1] - t_src[k], 1.0)
    a = np.clip((t - t_src[k]) / span, 0.0, 1.0)[:, None]
    pos = (1 - a) * poses[k, :3] + a * poses[k1, :3]
    q0, q1 = poses[k, 3:], poses[k1, 3:]
    q1 = np.where((q0 * q1).sum(axis=1, keepdims=True) < 0, -q1, q1)
    quat = (1 - a) * q0 + a * q1
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return np.hstack([pos, quat])


def _to_world(q: np.ndarray, camera_pose: Sequence[float]) -> np.ndarray:
    from hand_capture.cameras.transforms import pose_in_world

    c = np.asarray(camera_pose, dtype=float)
    R = quat_wxyz_to_matrix(c[3:7])
    return np.array([pose_in_world(x, R, c[:3]) for x in q])


def read_capture_bag(path: str | Path, default_object: ObjectProperties | None = None,
                     config: ArchiveConfig | None = None, *, name: str | None = None
                     ) -> tuple[Any, str]:
    """A :class:`~hand_control.physcap.capture.Capture` from a recorded bag (module doc for
    the topics and the object properties); returns it and where its object came from.

    Raises:
        CorruptCaptureError: CRC mismatch, truncated storage, undecodable message.
        IncompleteCaptureError: missing topics or object properties, too few frames, NaN.
    """
    from hand_capture.bag import BagReader
    from hand_capture.posemsg import pose_from_msg

    path = Path(path)
    config = config or ArchiveConfig()
    name = name or _entry_name(path)
    obj, source = _bag_object(path, name, default_object)
    wanted_obj = ((f"object/{obj.name}/pose", f"object/{obj.name}/pose_truth")
                  if obj.name else OBJECT_TOPICS)
    hand_msgs: dict[str, list[Any]] = {}
    obj_msgs: dict[str, list[Any]] = {}
    kp_msgs: list[Any] = []
    side = HAND_RIGHT if config.hand == "right" else HAND_LEFT
    try:
        with BagReader(path) as r:
            topics = {t.lstrip("/"): t for t in r.topics}
            several = sorted(t for t in topics if t.startswith("object/")
                             and t.endswith(("/pose", "/pose_truth")) and t.count("/") == 2)
            if not obj.name and not any(t in topics for t in OBJECT_TOPICS) and several:
                raise IncompleteCaptureError(name, f"several objects ({several}): name one "
                                             f"with 'name' in the object properties")
            for m in r.messages():
                topic = m.topic.lstrip("/")
                if topic in HAND_TOPICS:
                    msg = r.check(m)  # a lost tracker repeats a stale pose: not a frame
                    if int(msg.handedness) == side and int(msg.status) != STATUS["lost"]:
                        hand_msgs.setdefault(topic, []).append(msg)
                elif topic in wanted_obj:
                    obj_msgs.setdefault(topic, []).append(r.check(m))
                elif topic == KEYPOINT_TOPIC:
                    msg = r.check(m)
                    if int(msg.handedness) == side:
                        kp_msgs.append(msg)
    except BagError as e:
        raise CorruptCaptureError(name, str(e)) from e
    hand_topic = next((t for t in HAND_TOPICS if hand_msgs.get(t)), None)
    if hand_topic is None:
        raise IncompleteCaptureError(name, f"no {config.hand} hand poses (none on "
                                     f"{list(HAND_TOPICS)})")
    hands = hand_msgs[hand_topic]
    t_hand = np.array([_stamp_ns(m.header) for m in hands], dtype=np.int64)
    order = np.argsort(t_hand, kind="stable")
    hands, t_hand = [hands[i] for i in order], t_hand[order]
    if np.any(np.diff(t_hand) <= 0):
        raise IncompleteCaptureError(name, f"{hand_topic}: repeated header stamps")
    try:
        q = np.array([pose_from_msg(m) for m in hands])
    except InputError as e:
        raise IncompleteCaptureError(name, f"{hand_topic}: {e}") from e
    if not np.isfinite(q).all():
        bad = int(np.argmax(~np.isfinite(q).all(axis=1)))
        raise IncompleteCaptureError(name, f"NaN or Inf in {hand_topic} at frame {bad}")
    if obj.camera_pose:
        q = _to_world(q, obj.camera_pose)
    obj_topic = next((t for t in wanted_obj if obj_msgs.get(t)), None)
    if obj_topic is not None:
        om = sorted(obj_msgs[obj_topic], key=lambda m: _stamp_ns(m.header))
        t_obj = np.array([_stamp_ns(m.header) for m in om], dtype=np.int64)
        poses = np.array([_pose7(m) for m in om])
        if not np.isfinite(poses).all():
            bad = int(np.argmax(~np.isfinite(poses).all(axis=1)))
            raise IncompleteCaptureError(name, f"NaN or Inf in {obj_topic} at message {bad}")
        if np.any(np.linalg.norm(poses[:, 3:], axis=1) < 1e-9):
            raise IncompleteCaptureError(name, f"{obj_topic}: zero quaternion")
        keep = (t_hand >= t_obj[0]) & (t_hand <= t_obj[-1])
        t_hand, q = t_hand[keep], q[keep]
        object_pose = (_interp_poses((t_obj - t_obj[0]) * 1e-9, poses,
                                     (t_hand - t_obj[0]) * 1e-9)
                       if len(t_hand) else np.zeros((0, 7)))
    elif obj.pose:
        object_pose = _object_from_hand(q, np.asarray(obj.pose, dtype=float), config)
    else:
        raise IncompleteCaptureError(
            name, f"no object poses (none of {list(wanted_obj)}) and no object 'pose' in "
            f"its properties ({source if source != 'default' else '--object'})")
    keypoints = _keypoints(kp_msgs, t_hand)
    if keypoints is not None and obj.camera_pose:
        c = np.asarray(obj.camera_pose, dtype=float)
        keypoints = keypoints @ quat_wxyz_to_matrix(c[3:7]).T + c[:3]
    if len(t_hand) < config.min_frames:
        raise IncompleteCaptureError(name, f"{len(t_hand)} frames with object poses, fewer "
                                     f"than the {config.min_frames} a capture needs")
    cap = _make_capture(name, (t_hand - t_hand[0]) * 1e-9, q, object_pose, obj, keypoints)
    _check_capture(cap, name, config)
    return cap, source


def _object_from_hand(q: np.ndarray, pose: np.ndarray, config: ArchiveConfig
                      ) -> np.ndarray:
    """Object poses (T, 7) for a bag that never saw the object (the depth tracker's): at rest
    at ``pose`` until the hand root arrives at its grasp distance (the first frame within
    5 mm of its closest approach, if that is within ``touch_distance``), then moving rigidly
    with the hand root (a kinematic guess the optimiser corrects)."""
    from hand_capture.model.joints import root_rotation_matrix

    pose = pose.copy()
    pose[3:] /= np.linalg.norm(pose[3:])
    out = np.tile(pose, (len(q), 1))
    d = np.linalg.norm(q[:, :3] - pose[:3], axis=1)
    if not len(q) or d.min() > config.touch_distance:
        return out
    k = int(np.argmax(d <= d.min() + 0.005))
    R_obj = quat_wxyz_to_matrix(pose[3:7])
    R_k = root_rotation_matrix(q[k, 3:6])
    rel_R, rel_p = R_k.T @ R_obj, R_k.T @ (pose[:3] - q[k, :3])
    for i in range(k, len(q)):
        R_i = root_rotation_matrix(q[i, 3:6])
        out[i] = np.r_[q[i, :3] + R_i @ rel_p, matrix_to_quat_wxyz(R_i @ rel_R)]
    return out


def _keypoints(msgs: list[Any], t: np.ndarray) -> np.ndarray | None:
    """(T, 21, 3) keypoints matched by stamp to ``t``; None unless every frame has them."""
    if not msgs or not len(t):
        return None
    by_stamp = {_stamp_ns(m.header): m for m in msgs if len(m.points) == 21}
    out = []
    for s in t:
        m = by_stamp.get(int(s))
        if m is None:
            return None
        out.append([[p.x, p.y, p.z] for p in m.points])
    kp = np.asarray(out, dtype=float)
    return kp if np.isfinite(kp).all() else None


def _make_capture(name: str, times: np.ndarray, q: np.ndarray, object_pose: np.ndarray,
                  obj: ObjectProperties, keypoints: np.ndarray | None) -> Capture:
    try:
        co = CapturedObject(kind=obj.kind, size=tuple(obj.size), mass=obj.mass,
                            friction=obj.friction, mesh=obj.mesh)
        return Capture(name=name, times=times, hand_q=q, object_pose=object_pose, obj=co,
                       keypoints=keypoints)
    except CaptureError as e:
        raise IncompleteCaptureError(name, str(e)) from e
