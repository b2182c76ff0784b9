"""Saving an optimised capture: an npz of the whole :class:`PhysCapResult` and a bag with the
suite's usual topics, so ``hand-suite bag play``, ``hand-suite report`` and ``hand-suite
physcap replay`` work on it.

Layout of one result (``write_result(result, OUT/NAME)``)::

    OUT/NAME/result.npz          every array and figure of the result (read_result)
    OUT/NAME/bag/                rosbag2 (MCAP), topics below, stamps = capture time
    OUT/NAME/bag.object.yaml     the object's properties (the archive's sidecar format)

Topics of the bag (header frame ``world``; message k at ``t0 + times[k]``):

====================================  ==============================  =========================
topic                                 type                            content
====================================  ==============================  =========================
``/hand/pose``                        hand_msgs/HandPose              simulated hand (T)
``/sim/joint_states``                 sensor_msgs/JointState          same, all 27 DoF, with
                                                                      velocities [rad/s, m/s]
``/object/pose``, ``/sim/object_pose`` geometry_msgs/PoseStamped      simulated object (T)
``/control/joint_command``            hand_msgs/JointCommand          PD targets (T - 1)
``/control/object_target``            geometry_msgs/PoseStamped       object target (T - 1)
``/control/virtual_wrench``           geometry_msgs/WrenchStamped     virtual wrench (T - 1)
``/sim/contacts``                     hand_msgs/ContactArray          hand-object contacts and
                                                                      forces (T - 1, replayed)
``/physcap/reference/hand_pose``      hand_msgs/HandPose              the capture (T)
``/physcap/reference/object_pose``    geometry_msgs/PoseStamped       the capture (T)
====================================  ==============================  =========================

The bag with its sidecar is itself a capture an archive can hold (``hand/pose`` +
``object/pose`` + object properties), e.g. to retarget or re-optimise it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

import numpy as np

from hand_capture.config import from_mapping
from hand_capture.errors import BagError, ConfigError, InputError
from hand_capture.model.joints import ARTICULATED_JOINTS, JOINT_NAMES
from hand_control.physcap.capture import (
    Capture,
    CapturedObject,
    PhysCapConfig,
    PhysCapResult,
    read_npz,
)

__all__ = ["OUTPUT_TOPICS", "RESULT_FORMAT", "ResultFiles", "read_result", "replay_contacts",
           "replay_match", "result_files", "results_equal", "write_capture_bag", "write_result",
           "write_result_bag", "write_result_npz"]

RESULT_FORMAT = "hand_suite.physcap.result/1"
#: topic -> message type of a result bag
OUTPUT_TOPICS = {
    "/hand/pose": "hand_msgs/msg/HandPose",
    "/sim/joint_states": "sensor_msgs/msg/JointState",
    "/object/pose": "geometry_msgs/msg/PoseStamped",
    "/sim/object_pose": "geometry_msgs/msg/PoseStamped",
    "/control/joint_command": "hand_msgs/msg/JointCommand",
    "/control/object_target": "geometry_msgs/msg/PoseStamped",
    "/control/virtual_wrench": "geometry_msgs/msg/WrenchStamped",
    "/sim/contacts": "hand_msgs/msg/ContactArray",
    "/physcap/reference/hand_pose": "hand_msgs/msg/HandPose",
    "/physcap/reference/object_pose": "geometry_msgs/msg/PoseStamped",
}
#: receive time of a result bag's frame 0 [ns] (stamps are capture time from here)
T0_NS = 1_700_000_000_000_000_000
_ARRAYS = ("times", "hand_q", "object_pose", "reference_q", "reference_object", "targets",
           "object_targets", "virtual_forces", "costs", "frame_seconds")
_FLAGS = ("success", "reached_goal", "dropped")


class ResultFiles:
    """Paths of one saved result: ``root/result.npz``, ``root/bag``, ``root/bag.object.yaml``."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.npz = self.root / "result.npz"
        self.bag = self.root / "bag"
        self.sidecar = self.root / "bag.object.yaml"


def result_files(root: str | Path) -> ResultFiles:
    """The file layout of a result folder (see the module docstring)."""
    return ResultFiles(root)


def _jsonable(v: Any) -> bool:
    try:
        json.dumps(v)
    except (TypeError, ValueError):
        return False
    return True


def write_result_npz(result: PhysCapResult, path: str | Path) -> Path:
    """Every array, flag and figure of ``result`` into ``path`` (.npz, no pickles); array
    extras as ``extra_<key>``, JSON-able extras in ``extras_json``, others dropped."""
    path = Path(path)
    arrays: dict[str, Any] = {k: np.asarray(getattr(result, k)) for k in _ARRAYS}
    arrays.update({k: np.array(bool(getattr(result, k))) for k in _FLAGS})
    arrays["final_error_m"] = np.array(float(result.final_error_m))
    arrays["name"] = np.array(result.name)
    arrays["config_json"] = np.array(json.dumps(asdict(result.config)))
    arrays["obj_json"] = np.array(json.dumps(asdict(result.obj)))
    plain = {}
    for k, v in result.extras.items():
        if isinstance(v, np.ndarray) and v.dtype != object:
            arrays[f"extra_{k}"] = v
        elif _jsonable(v):
            plain[k] = v
    arrays["extras_json"] = np.array(json.dumps(plain))
    arrays["format"] = np.array(RESULT_FORMAT)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


def read_result(path: str | Path) -> PhysCapResult:
    """A :class:`PhysCapResult` from ``result.npz`` (or a result folder holding one).

    Raises:
        InputError: missing or unreadable file, another format, missing arrays.
    """
    path = Path(path)
    if path.is_dir():
        path = result_files(path).npz
    d = read_npz(path, "result", InputError)
    if str(d.get("format", "")) != RESULT_FORMAT:
        raise InputError(f"{path}: not a physcap result (format "
                         f"{str(d.get('format', 'missing'))!r}, expected {RESULT_FORMAT!r})")
    missing = [k for k in (*_ARRAYS, *_FLAGS, "final_error_m", "config_json", "obj_json")
               if k not in d]
    if missing:
        raise InputError(f"{path}: result is missing {missing}")
    try:
        cfg = json.loads(str(d["config_json"]))
        known = {f.name for f in fields(PhysCapConfig)}
        config = from_mapping(PhysCapConfig, {k: v for k, v in cfg.items() if k in known})
        obj = CapturedObject(**json.loads(str(d["obj_json"])))
    except (ConfigError, InputError, TypeError, ValueError) as e:
        raise InputError(f"{path}: bad config or object: {e}") from e
    extras: dict[str, Any] = json.loads(str(d.get("extras_json", "{}")))
    extras.update({k[len("extra_"):]: v for k, v in d.items() if k.startswith("extra_")})
    return PhysCapResult(
        name=str(d["name"]), **{k: d[k] for k in _ARRAYS},
        **{k: bool(d[k]) for k in _FLAGS}, final_error_m=float(d["final_error_m"]),
        config=config, obj=obj, extras=extras)


def results_equal(a: PhysCapResult, b: PhysCapResult) -> list[str]:
    """Fields in which two results differ (empty: identical), ignoring the computation
    times (``frame_seconds``) and extras. Arrays must be bit-identical."""
    diff = [k for k in _ARRAYS if k != "frame_seconds"
            and not np.array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k)))]
    diff += [k for k in (*_FLAGS, "name", "final_error_m", "obj", "config")
             if getattr(a, k) != getattr(b, k)]
    return diff


def _stamp(store: Any, t_ns: int) -> Any:
    return store.types["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _pose_stamped(store: Any, header: Any, p7: np.ndarray) -> Any:
    T = store.types
    pos = T["geometry_msgs/msg/Point"](x=float(p7[0]), y=float(p7[1]), z=float(p7[2]))
    rot = T["geometry_msgs/msg/Quaternion"](x=float(p7[4]), y=float(p7[5]), z=float(p7[6]),
                                            w=float(p7[3]))
    return T["geometry_msgs/msg/PoseStamped"](
        header=header, pose=T["geometry_msgs/msg/Pose"](position=pos, orientation=rot))


def _hand_pose(store: Any, header: Any, q: np.ndarray, status: str, source: str) -> Any:
    from hand_capture.posemsg import fill_pose_msg

    T = store.types
    msg = T["hand_msgs/msg/HandPose"](
        header=header, handedness=0, joint_names=[], positions=np.zeros(0),
        wrist_pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        confidence=1.0, status=0, source="")
    fill_pose_msg(msg, q, status=status, source=source)
    msg.positions = np.asarray(msg.positions, dtype=np.float64)
    return msg


def replay_contacts(result: PhysCapResult) -> list[Any]:
    """The hand-object contacts (:class:`~hand_control.sim.contacts.ContactFrame`, world
    frame, forces the hand applies) at the end of each control step, from simulating the
    result's control again from its first state (the optimiser's simulator: the same
    motion). Stops at a divergence. Length <= T - 1."""
    from hand_control.physcap.optimise import SegmentSimulator
    from hand_control.physcap.world import OBJECT_NAME

    cfg = result.config
    sim = SegmentSimulator(result.obj, result.hand_q[0], result.object_pose[0], cfg)
    n = int(round(cfg.step / cfg.timestep))
    state = sim.initial_state
    out = []
    for qt, ot in zip(np.asarray(result.targets, float),
                      np.asarray(result.object_targets, float), strict=True):
        seg = sim.run(state, qt, ot, n)
        if not seg.ok:
            break
        state = seg.state
        out.append(sim.world.contacts(OBJECT_NAME))
    return out


def _contact_array(store: Any, header: Any, cf: Any) -> Any:
    T = store.types
    vec, point = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Point"]
    contacts = [T["hand_msgs/msg/Contact"](
        body1=cf.body1[k], body2=cf.body2[k], point=point(*map(float, cf.points[k])),
        normal=vec(*map(float, cf.normals[k])), penetration=float(cf.penetration[k]),
        force=vec(*map(float, cf.forces[k])), torsional_torque=float(cf.torsional[k]),
        friction=float(cf.friction[k])) for k in range(len(cf))]
    return T["hand_msgs/msg/ContactArray"](header=header, contacts=contacts)


def write_result_bag(result: PhysCapResult, path: str | Path, *, storage: str = "mcap",
                     t0_ns: int = T0_NS, contacts: list[Any] | None = None) -> int:
    """The result as a bag (module docstring for the topics); returns the message count.

    Args:
        contacts: the contacts of each step (:func:`replay_contacts`, computed when None).

    Raises:
        BagError: ``path`` exists or cannot be written.
    """
    from hand_capture.bag import BagWriter, default_typestore, make_qos

    path = Path(path)
    if path.exists():
        raise BagError(f"{path} exists; a result bag is never overwritten")
    store = default_typestore()
    T = store.types
    times = np.asarray(result.times, dtype=float)
    hq = np.asarray(result.hand_q, dtype=float)
    dt = np.diff(times)
    vel = np.zeros_like(hq)
    if len(times) > 1:
        vel[1:] = np.diff(hq, axis=0) / dt[:, None]
        vel[0] = vel[1]
    names = list(JOINT_NAMES)
    art = [JOINT_NAMES.index(j) for j in ARTICULATED_JOINTS]
    if contacts is None:
        contacts = replay_contacts(result)
    w = BagWriter(path, storage=storage, flush_period=1.0)
    try:
        for topic, msgtype in OUTPUT_TOPICS.items():
            w.add_topic(topic, msgtype, qos=[make_qos(reliable=True)])

        def put(topic: str, t_ns: int, msg: Any) -> None:
            w.write(topic, t_ns, bytes(store.serialize_cdr(msg, OUTPUT_TOPICS[topic])))

        for k, t in enumerate(times):
            t_ns = t0_ns + int(round(t * 1e9))
            header = T["std_msgs/msg/Header"](stamp=_stamp(store, t_ns), frame_id="world")
            put("/hand/pose", t_ns, _hand_pose(store, header, hq[k], "tracking", "physcap"))
            put("/sim/joint_states", t_ns, T["sensor_msgs/msg/JointState"](
                header=header, name=names, position=hq[k].copy(), velocity=vel[k].copy(),
                effort=np.zeros(0)))
            obj = _pose_stamped(store, header, np.asarray(result.object_pose[k]))
            put("/object/pose", t_ns, obj)
            put("/sim/object_pose", t_ns, obj)
            put("/physcap/reference/hand_pose", t_ns,
                _hand_pose(store, header, np.asarray(result.reference_q[k]), "tracking",
                           "capture"))
            put("/physcap/reference/object_pose", t_ns,
                _pose_stamped(store, header, np.asarray(result.reference_object[k])))
            if 0 < k <= len(contacts):  # contacts at the end of step k - 1, i.e. at frame k
                put("/sim/contacts", t_ns, _contact_array(store, header, contacts[k - 1]))
            if k >= len(result.targets):
                continue
            # control of step k (frame k -> k + 1), stamped at its start
            tq = np.asarray(result.targets[k], dtype=float)
            put("/control/joint_command", t_ns, T["hand_msgs/msg/JointCommand"](
                header=header, joint_names=[names[i] for i in art],
                positions=tq[art].copy(), velocities=np.zeros(0), efforts=np.zeros(0)))
            put("/control/object_target", t_ns,
                _pose_stamped(store, header, np.asarray(result.object_targets[k])))
            f = np.asarray(result.virtual_forces[k], dtype=float)
            vec = T["geometry_msgs/msg/Vector3"]
            put("/control/virtual_wrench", t_ns, T["geometry_msgs/msg/WrenchStamped"](
                header=header, wrench=T["geometry_msgs/msg/Wrench"](
                    force=vec(x=f[0], y=f[1], z=f[2]), torque=vec(x=f[3], y=f[4], z=f[5]))))
    finally:
        w.close()
    return w.count


def _object_yaml(obj: CapturedObject) -> str:
    import yaml

    return yaml.safe_dump({"kind": obj.kind, "size": [float(v) for v in obj.size],
                           "mass": float(obj.mass), "friction": float(obj.friction),
                           "mesh": obj.mesh}, sort_keys=False)


def write_capture_bag(capture: Capture, path: str | Path, *, t0_ns: int = T0_NS) -> Path:
    """A capture as the archive reads a recorded one: ``/hand/pose`` (HandPose) and
    ``/object/pose`` (PoseStamped), world frame, plus its object in ``NAME.object.yaml``
    next to the bag (:mod:`hand_control.physcap.archive`); returns the bag's path.

    Raises:
        BagError: ``path`` exists.
    """
    from hand_capture.bag import BagWriter, default_typestore, make_qos

    path = Path(path)
    if path.exists():
        raise BagError(f"{path} exists; a capture bag is never overwritten")
    store = default_typestore()
    T = store.types
    topics = {"/hand/pose": "hand_msgs/msg/HandPose",
              "/object/pose": "geometry_msgs/msg/PoseStamped"}
    w = BagWriter(path, storage="mcap", flush_period=1.0)
    try:
        for topic, msgtype in topics.items():
            w.add_topic(topic, msgtype, qos=[make_qos(reliable=True)])
        for k, t in enumerate(np.asarray(capture.times, dtype=float)):
            t_ns = t0_ns + int(round(t * 1e9))
            header = T["std_msgs/msg/Header"](stamp=_stamp(store, t_ns), frame_id="world")
            w.write("/hand/pose", t_ns, bytes(store.serialize_cdr(
                _hand_pose(store, header, capture.hand_q[k], "tracking", "capture"),
                topics["/hand/pose"])))
            w.write("/object/pose", t_ns, bytes(store.serialize_cdr(
                _pose_stamped(store, header, capture.object_pose[k]), topics["/object/pose"])))
    finally:
        w.close()
    path.with_name(path.name + ".object.yaml").write_text(_object_yaml(capture.obj))
    return path


def write_result(result: PhysCapResult, root: str | Path) -> ResultFiles:
    """``root/result.npz``, ``root/bag`` and its object sidecar (module docstring).

    Raises:
        BagError: ``root/bag`` exists already.
    """
    files = result_files(root)
    files.root.mkdir(parents=True, exist_ok=True)
    write_result_npz(result, files.npz)
    write_result_bag(result, files.bag)
    files.sidecar.write_text(_object_yaml(result.obj))
    return files


def replay_match(result: PhysCapResult, tolerance_m: float = 1e-3, *,
                 mass: float | None = None, friction: float | None = None) -> dict[str, Any]:
    """Re-simulate a saved result's control (its PD and object targets, from its first
    state) and compare the motion with the saved one (``hand-suite physcap replay``).

    Args:
        result: a result (e.g. from :func:`read_result`).
        tolerance_m: the largest object position / hand root deviation of a match [m].
        mass, friction: replay with another object mass [kg] / friction (retargeting).

    Returns:
        ``object_max_dev_mm``, ``hand_root_max_dev_mm``, ``finger_max_dev_rad``,
        ``object_final_dev_mm``, ``diverged`` (bool), ``match`` (bool), ``steps``.
    """
    from hand_control.physcap.optimise import replay_control

    hand, obj, ok = replay_control(result.obj, result.hand_q[0], result.object_pose[0],
                                   result.targets, result.object_targets, result.config,
                                   mass=mass, friction=friction)
    fin = np.isfinite(obj).all(axis=1) & np.isfinite(hand).all(axis=1)
    n = int(fin.sum())
    d_obj = np.linalg.norm(obj[fin, :3] - result.object_pose[fin, :3], axis=1)
    d_root = np.linalg.norm(hand[fin, :3] - result.hand_q[fin, :3], axis=1)
    d_fing = np.abs(hand[fin, 6:] - result.hand_q[fin, 6:])
    diverged = not bool(np.all(ok)) or n < len(obj)
    out = {"steps": int(len(result.targets)),
           "object_max_dev_mm": float(d_obj.max() * 1e3) if n else float("nan"),
           "object_final_dev_mm": float(d_obj[-1] * 1e3) if n else float("nan"),
           "hand_root_max_dev_mm": float(d_root.max() * 1e3) if n else float("nan"),
           "finger_max_dev_rad": float(d_fing.max()) if n else float("nan"),
           "diverged": diverged}
    out["match"] = bool(not diverged and out["object_max_dev_mm"] <= tolerance_m * 1e3
                        and out["hand_root_max_dev_mm"] <= tolerance_m * 1e3)
    return out
