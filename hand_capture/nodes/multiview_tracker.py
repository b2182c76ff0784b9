"""multiview_tracker: hands and objects from the synchronised groups of a camera rig.

Thin wrapper around :class:`hand_capture.multiview.tracker.MultiviewTracker` (seed 002's
local optimisation) and :class:`~hand_capture.multiview.tracker.GroupRunner` (screening of
bad groups). It consumes the groups that ``rig_sync`` publishes: every member of a group
carries the group's common stamp.

Topics (``CAM`` = each camera of the rig, ``STREAM`` = the ``stream`` parameter):
    in   sync/CAM/STREAM/image_raw (sensor_msgs/Image, rgb8 / bgr8)
    in   sync/CAM/STREAM/camera_info (sensor_msgs/CameraInfo): checked for NaN
    in   hand/pose_truth, object/pose_truth: only while ``init_from_truth`` waits for the
         first frame's configuration (a studio capture); without them the tracker starts
         from ``init_root`` with the relaxed hand
    out  hand/pose (hand_msgs/HandPose): one per hand and group, world frame, the group's
         stamp, status tracking / recovering / lost, confidence (lower with cameras missing)
    out  object/pose (geometry_msgs/PoseStamped; object/NAME/pose with several objects)
    out  diagnostics (1 Hz): groups, tracked, rejected views and groups by reason, seconds
         per group, parts lost

A group waits at most ``group_timeout_s`` for its last members; then it is tracked with the
cameras it has (missing ones counted and logged). While a group is being tracked newer
complete groups replace older waiting ones (``dropped_busy``).

The offline tool (``hand-suite track-multiview BAG -o OUT``, :func:`track_bag`) runs the same
core on the images of a multi-view bag and writes the estimates to a new bag.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import HandPose
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import CameraInfo, Image

from hand_capture.config import param, validate
from hand_capture.errors import HandSuiteError, InputError
from hand_capture.model import HandModel
from hand_capture.model.joints import N_DOF, matrix_to_quat, quat_to_matrix
from hand_capture.multiview.lo import LOConfig
from hand_capture.multiview.rig import Rig, load_rig
from hand_capture.multiview.scene_model import SceneModel, object_mesh
from hand_capture.multiview.tracker import (
    LOST,
    GroupRunner,
    MultiviewTracker,
    MultiviewTrackerConfig,
    TrackResult,
)
from hand_capture.nodes.images import image_to_array
from hand_capture.nodes.params import declare_config
from hand_capture.nodes.shell import run_node
from hand_capture.posemsg import HAND_LEFT, fill_pose_msg, pose_from_msg

__all__ = ["MultiviewTrackerNode", "MultiviewTrackerNodeConfig", "build_model", "main",
           "make_tracker", "track_bag"]


@dataclass(frozen=True)
class MultiviewTrackerNodeConfig:
    """Node parameters besides the optimiser's (:class:`LOConfig`) and the lost-part ones
    (:class:`MultiviewTrackerConfig`)."""

    rig: str = param("studio6", "rig name (config/rigs/NAME.yaml) or rig file path",
                     read_only=True)
    stream: str = param("color", "image stream of every camera", read_only=True)
    hands: str = param("right", "tracked hands: right, left or right,left", read_only=True)
    objects: str = param("box", "tracked objects (comma list of box, ball, stick, cup; "
                         "empty: none)", read_only=True)
    group_timeout_s: float = param(0.5, "longest wait for a group's last cameras [s]",
                                   lo=0.01, hi=10.0)
    init_from_truth: bool = param(True, "start from the first hand/pose_truth and "
                                  "object/pose_truth (studio captures)", read_only=True)
    detector: str = param("learned", "salient points: 'learned' (data/salient, the "
                          "fingertip detector; about 0.2-0.5 s a view) or 'none'",
                          choices=("learned", "none"), read_only=True)
    hull_recovery: bool = param(True, "search for a lost hand also where the visual hull "
                                "puts it (colour model learned on the first frame)",
                                read_only=True)

    def __post_init__(self) -> None:
        validate(self)


def build_model(hands: str, objects: str, detector: str = "none") -> SceneModel:
    """The combined model of comma lists of hand sides and object kinds; with the learned
    detector its salient vertices are the fingertips the detector was trained on."""
    from hand_capture.multiview.salient import tip_vertices

    sides = [s.strip() for s in hands.split(",") if s.strip()]
    bad = [s for s in sides if s not in ("right", "left")]
    if not sides or bad:
        raise InputError(f"hands must list right and/or left, got {hands!r}")
    kinds = [k.strip() for k in objects.split(",") if k.strip()]
    hm = [HandModel(side=s) for s in sides]
    return SceneModel(hm, [object_mesh(k) for k in kinds],
                      salient=[tip_vertices(h) for h in hm] if detector == "learned" else None)


def make_tracker(model: SceneModel, rig: Rig, lo_cfg: LOConfig | None = None,
                 tr_cfg: MultiviewTrackerConfig | None = None, detector: str = "none",
                 hull_recovery: bool = False) -> MultiviewTracker:
    """The tracker with the partner components the options ask for."""
    det = init = None
    if detector == "learned":
        from hand_capture.multiview.salient import load_salient_detector

        det = load_salient_detector()
    if hull_recovery:
        from hand_capture.multiview.hull import HullInitializer

        init = HullInitializer(rig)
    return MultiviewTracker(model, rig, lo_cfg, tr_cfg, detector=det, initializer=init)


def default_params(model: SceneModel, root: Sequence[float] = (0.0, 0.0, 0.12)) -> np.ndarray:
    """A start configuration: relaxed hands at ``root`` (a left hand 0.3 m to its left),
    objects 0.25 m in front on the table."""
    from hand_capture.model.mjcf import home_pose

    hands = [home_pose((root[0], root[1] + (0.3 if h.side == "left" else 0.0), root[2]))
             for h in model.hands]
    objs = []
    for i, _ in enumerate(model.objects):
        T = np.eye(4)
        T[:3, 3] = (0.25, -0.1 + 0.1 * i, 0.03)
        objs.append(T)
    return model.pack(hands, objs)


def _pose_T(msg: Any) -> np.ndarray:
    p, o = msg.pose.position, msg.pose.orientation
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(np.array([o.x, o.y, o.z, o.w]))
    T[:3, 3] = (p.x, p.y, p.z)
    return T


def _rgb(msg: Any) -> np.ndarray | None:
    """An Image message as (H, W, 3) RGB uint8, or an array the group check rejects."""
    try:
        a = np.asarray(image_to_array(msg))
    except HandSuiteError:
        return np.zeros((0, 0, 3), np.uint8)
    if msg.encoding == "bgr8":
        a = a[..., ::-1]
    elif msg.encoding == "mono8":
        a = np.repeat(a[..., None], 3, axis=2)
    return np.ascontiguousarray(a)


def _object_topics(model: SceneModel, suffix: str) -> dict[str, str]:
    names = [o.name for o in model.objects]
    return {n: f"object/{suffix}" if len(names) == 1 else f"object/{n}/{suffix}"
            for n in names}


def _messages(model: SceneModel, res: TrackResult, stamp: Any, frame: str
              ) -> tuple[list[HandPose], dict[str, PoseStamped]]:
    hands, objs = [], {}
    for i, part in enumerate(res.parts):
        if i < model.n_hands:
            msg = fill_pose_msg(HandPose(), part.params, side=part.name,
                                status=part.status, confidence=part.confidence,
                                source="multiview_tracker")
            msg.header.stamp, msg.header.frame_id = stamp, frame
            hands.append(msg)
        else:
            T = model.object_transform(part.params)
            msg = PoseStamped()
            msg.header.stamp, msg.header.frame_id = stamp, frame
            p, q = msg.pose.position, msg.pose.orientation
            p.x, p.y, p.z = (float(v) for v in T[:3, 3])
            q.x, q.y, q.z, q.w = (float(v) for v in matrix_to_quat(T[:3, :3]))
            objs[part.name] = msg
    return hands, objs


class MultiviewTrackerNode(Node):
    """Tracks the rig's synchronised groups; see the module docstring."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("multiview_tracker", **kwargs)
        self.cfg = declare_config(self, MultiviewTrackerNodeConfig)
        lo_cfg = declare_config(self, LOConfig)
        tr_cfg = declare_config(self, MultiviewTrackerConfig)
        self.rig: Rig = load_rig(self.cfg.rig)
        self.model = build_model(self.cfg.hands, self.cfg.objects, self.cfg.detector)
        self.tracker = make_tracker(self.model, self.rig, lo_cfg, tr_cfg, self.cfg.detector,
                                    self.cfg.hull_recovery)
        self.runner = GroupRunner(self.tracker, lambda s: self.get_logger().warning(
            s, throttle_duration_sec=1.0))
        self._pending: dict[int, dict[str, Any]] = {}
        self._first_seen: dict[int, float] = {}
        # the newest group that came before the truth it starts from (tracked once it arrives)
        self._unready: tuple[int, dict[str, Any]] | None = None
        self._infos: dict[str, Any] = {}
        self.dropped_busy = 0
        self._seconds: list[float] = []
        self._truth_hands: dict[int, np.ndarray] = {}
        self._truth_objects: dict[str, np.ndarray] = {}
        if not self.cfg.init_from_truth:
            self.tracker.reset(default_params(self.model))
        s = self.cfg.stream
        for cam in self.rig.names:
            self.create_subscription(Image, f"sync/{cam}/{s}/image_raw",
                                     lambda m, c=cam: self._on_image(c, m),
                                     qos_profile_sensor_data)
            self.create_subscription(CameraInfo, f"sync/{cam}/{s}/camera_info",
                                     lambda m, c=cam: self._infos.__setitem__(c, m),
                                     qos_profile_sensor_data)
        if self.cfg.init_from_truth:
            self.create_subscription(HandPose, "hand/pose_truth", self._on_hand_truth, 10)
            for name, topic in _object_topics(self.model, "pose_truth").items():
                self.create_subscription(PoseStamped, topic,
                                         lambda m, n=name: self._truth_objects.__setitem__(
                                             n, _pose_T(m)), 10)
        self.pub_pose = self.create_publisher(HandPose, "hand/pose", 10)
        self.pub_obj = {n: self.create_publisher(PoseStamped, t, 10)
                        for n, t in _object_topics(self.model, "pose").items()}
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self.create_timer(0.05, self._poll)
        self.create_timer(1.0, self._diagnostics)
        self.get_logger().info(f"tracking {list(self.model.part_names)} with the "
                               f"{len(self.rig)} cameras of rig {self.rig.name!r}")

    def _on_hand_truth(self, msg: HandPose) -> None:
        try:
            self._truth_hands[int(msg.handedness)] = pose_from_msg(msg)
        except HandSuiteError as e:
            self.get_logger().warning(f"ignored hand/pose_truth: {e}")

    def _ready(self) -> bool:
        if self.tracker.params is not None:
            return True
        sides = [HAND_LEFT if h.side == "left" else 0 for h in self.model.hands]
        if not all(s in self._truth_hands for s in sides) or \
                len(self._truth_objects) < len(self.model.objects):
            return False
        self.tracker.reset(self.model.pack(
            [self._truth_hands[s] for s in sides],
            [self._truth_objects[o.name] for o in self.model.objects]))
        self.get_logger().info("initialised from the first ground-truth configuration")
        return True

    def _on_image(self, camera: str, msg: Image) -> None:
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._pending.setdefault(key, {})[camera] = msg
        self._first_seen.setdefault(key, time.monotonic())
        if len(self._pending[key]) == len(self.rig):
            self._run(key)

    def _poll(self) -> None:
        if self._unready is not None and self._ready():
            key, group = self._unready
            self._unready = None
            self._track(key, group)
        now = time.monotonic()
        for key in sorted(self._pending):
            if now - self._first_seen[key] > self.cfg.group_timeout_s:
                self._run(key)

    def _run(self, key: int) -> None:
        group = self._pending.pop(key, {})
        self._first_seen.pop(key, None)
        older = [k for k in self._pending if k < key]
        for k in older:   # never track backwards in time
            self._pending.pop(k)
            self._first_seen.pop(k, None)
            self.dropped_busy += 1
        if not self._ready():
            self._unready = (key, group)
            return
        self._unready = None
        self._track(key, group)

    def _track(self, key: int, group: dict[str, Any]) -> None:
        images = {c: _rgb(m) for c, m in group.items()}
        infos = {c: self._infos[c] for c in group if c in self._infos}
        t0 = time.perf_counter()
        try:
            res = self.runner.process(images, infos, key * 1e-9)
        except HandSuiteError as e:
            self.runner.rejected["error"] += 1
            self.get_logger().warning(f"group at {key * 1e-9:.3f} s not tracked: {e}")
            return
        self._seconds.append(time.perf_counter() - t0)
        if res is None:
            return
        stamp = Time(nanoseconds=key).to_msg()
        hands, objs = _messages(self.model, res, stamp, self.rig.world_frame)
        for m in hands:
            self.pub_pose.publish(m)
        for n, m in objs.items():
            self.pub_obj[n].publish(m)

    def _diagnostics(self) -> None:
        r = self.runner
        lost = [n for n, s in zip(self.model.part_names, self.tracker.status, strict=True)
                if s == LOST]
        level = DiagnosticStatus.WARN if lost or r.rejected else DiagnosticStatus.OK
        text = f"lost: {', '.join(lost)}" if lost else "tracking"
        if self.tracker.params is None:   # init_from_truth, and the truth has not come
            level = DiagnosticStatus.WARN
            text = ("waiting for the first hand/pose_truth and object/pose_truth"
                    + (" (a group is held)" if self._unready is not None else ""))
        st = DiagnosticStatus(level=level, name="multiview_tracker", message=text)
        vals = {"groups": r.groups, "tracked": r.tracked, "dropped_busy": self.dropped_busy,
                "s_per_group": round(float(np.mean(self._seconds[-20:])), 3)
                if self._seconds else 0.0,
                **{f"rejected_{k}": v for k, v in r.rejected.items()}}
        st.values = [KeyValue(key=k, value=str(v)) for k, v in vals.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(arr)


# ------------------------------------------------------------------------------ offline tool
@dataclass
class TrackBagSummary:
    """What :func:`track_bag` did."""

    output: Path
    groups: int
    tracked: int
    rejected: dict[str, int]
    seconds_per_group: float
    joint_err_mm: float | None     # against /hand/pose_truth when the bag has it
    lost_frames: int


def track_bag(bag: str | Path, output: str | Path, *, rig: str = "studio6",
              hands: str = "right", objects: str = "box", lo_config: LOConfig | None = None,
              max_groups: int | None = None, overwrite: bool = False,
              progress: bool = True, detector: str = "learned",
              hull_recovery: bool = True) -> TrackBagSummary:
    """Track the ``<camera>/color/image_raw`` groups of a multi-view bag offline and write
    ``/hand/pose`` and ``/object/pose`` (plus the input's truth topics, when present) to a
    new bag at ``output``. The first group starts from the bag's ground truth when it has
    one, else from :func:`default_params`. ``detector`` / ``hull_recovery``: as the node's
    parameters."""
    from rclpy.serialization import serialize_message

    from hand_capture.bag import BagWriter, prepare_output
    from hand_capture.bag.bagfile import BagReader
    from hand_capture.multiview.sync import FrameSynchronizer, SyncConfig

    out = prepare_output(output, overwrite)
    r = load_rig(rig)
    if detector not in ("learned", "none"):
        raise InputError(f"detector must be 'learned' or 'none', got {detector!r}")
    model = build_model(hands, objects, detector)
    tracker = make_tracker(model, r, lo_config, None, detector, hull_recovery)
    runner = GroupRunner(tracker)
    suffix = "/color/image_raw"
    truth_h: dict[int, list[tuple[float, np.ndarray]]] = {}
    truth_o: dict[str, list[tuple[float, np.ndarray]]] = {}
    groups = []
    obj_truth_topics = {f"/{t}": n for n, t in _object_topics(model, "pose_truth").items()}
    with BagReader(bag) as reader:
        cams = [c for c in r.names if f"/{c}{suffix}" in reader.topics]
        if not cams:
            raise InputError(f"{bag}: none of the rig's '<camera>{suffix}' topics; the bag "
                             f"has {sorted(reader.topics)}")
        sync = FrameSynchronizer(cams, SyncConfig(tolerance_s=0.010, camera_timeout_s=60.0))
        for m in reader.messages():
            if m.topic == "/hand/pose_truth":
                msg = reader.check(m)
                t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                truth_h.setdefault(int(msg.handedness), []).append((t, pose_from_msg(msg)))
                continue
            if m.topic in obj_truth_topics:
                msg = reader.check(m)
                t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                truth_o.setdefault(obj_truth_topics[m.topic], []).append((t, _pose_T(msg)))
                continue
            if not m.topic.endswith(suffix) or m.topic.strip("/").split("/")[0] not in cams:
                continue
            msg = reader.check(m)
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            groups += sync.push(m.topic.strip("/").split("/")[0], stamp, msg,
                                m.timestamp_ns * 1e-9)
        groups += sync.poll(np.inf)
    if max_groups is not None:
        groups = groups[:max_groups]
    if not groups:
        raise InputError(f"{bag}: no synchronised group of images")
    sides = [HAND_LEFT if h.side == "left" else 0 for h in model.hands]

    def nearest(seq: list[tuple[float, np.ndarray]], t: float) -> np.ndarray:
        return min(seq, key=lambda x: abs(x[0] - t))[1]

    t0s = groups[0].stamp
    have_truth = all(s in truth_h for s in sides) and all(o.name in truth_o
                                                          for o in model.objects)
    if have_truth:
        tracker.reset(model.pack([nearest(truth_h[s], t0s) for s in sides],
                                 [nearest(truth_o[o.name], t0s) for o in model.objects]))
    else:
        tracker.reset(default_params(model))
    writer = BagWriter(out, storage="mcap", compress=True)
    writer.add_topic("/hand/pose", "hand_msgs/msg/HandPose")
    obj_topics = {n: f"/{t}" for n, t in _object_topics(model, "pose").items()}
    for t in obj_topics.values():
        writer.add_topic(t, "geometry_msgs/msg/PoseStamped")
    errs, secs, lost = [], [], 0
    try:
        for i, g in enumerate(groups):
            images = {c: _rgb(f[1]) for c, f in g.frames.items()}
            t_start = time.perf_counter()
            res = runner.process(images, None, g.stamp)
            secs.append(time.perf_counter() - t_start)
            if res is None:
                continue
            ns = int(round(g.stamp * 1e9))
            stamp = Time(nanoseconds=ns).to_msg()
            hmsgs, omsgs = _messages(model, res, stamp, r.world_frame)
            for m in hmsgs:
                writer.write("/hand/pose", ns, serialize_message(m))
            for n, m in omsgs.items():
                writer.write(obj_topics[n], ns, serialize_message(m))
            lost += sum(p.status == LOST for p in res.parts)
            err = None
            if have_truth:
                for k, s in enumerate(sides):
                    q = nearest(truth_h[s], g.stamp)
                    kt = model.hands[k].joint_positions(q)
                    ke = model.hands[k].joint_positions(res.params[model.slices[
                        model.part_names[k]]][:N_DOF])
                    errs.append(float(np.mean(np.linalg.norm(kt - ke, axis=1))) * 1e3)
                err = errs[-1]
            if progress:
                st = ", ".join(f"{p.name} {p.status} {p.confidence:.2f}" for p in res.parts)
                e = "" if err is None else f", joint error {err:.1f} mm"
                print(f"group {i + 1}/{len(groups)} at {g.stamp:.3f} s: {st}{e} "
                      f"({secs[-1]:.2f} s)", flush=True)
    finally:
        writer.close()
    return TrackBagSummary(out, len(groups), runner.tracked, dict(runner.rejected),
                           float(np.mean(secs)), float(np.mean(errs)) if errs else None, lost)


def main(args: list[str] | None = None) -> int:
    """Entry point of the multiview_tracker console script."""
    return run_node(MultiviewTrackerNode, args)


if __name__ == "__main__":
    sys.exit(main())
