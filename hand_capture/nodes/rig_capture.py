"""Multi-view captures: the studio rendered from every camera of a rig, straight into a bag.

For every instant the studio (:mod:`hand_capture.multiview.studio`) renders all cameras; each
camera's images get that camera's own stamp (the instant plus a constant clock offset and
jitter, as free-running cameras have), so a replay exercises the synchroniser. The ground
truth carries the instant's nominal stamp in the world frame. No DDS is involved: the same rig,
motion and seeds give the same bag.

Topics (``N`` = each camera of the rig):
    /camN/color/image_raw (rgb8), /camN/color/camera_info,
    /camN/depth/image_raw (16UC1, mm), /camN/depth/camera_info,
    /camN/labels/image_raw (mono8: 0 background, 1 hand, 2... objects),
    /hand/pose_truth (hand_msgs/HandPose, world), /hand/shape_truth (HandShape, with a held-out
    surface), /object/pose_truth (PoseStamped, world;
    one object) or /object/NAME/pose_truth (several)

    hand-suite capture --rig studio6 -o DIR [--seconds 1] [--fps 10] [--objects box]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from hand_msgs.msg import HandPose
from hand_msgs.msg import HandShape as HandShapeMsg
from rclpy.serialization import serialize_message

from hand_capture.bag import BagWriter, prepare_output
from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.model.joints import matrix_to_quat
from hand_capture.multiview.rig import load_rig
from hand_capture.multiview.studio import Studio, StudioNoise, jittered_stamps, studio_motion
from hand_capture.nodes.images import camera_info_msg, depth_image_msg, numpy_to_image
from hand_capture.posemsg import fill_pose_msg

__all__ = ["SAMPLE_RIG_CAPTURE", "RigCaptureSummary", "write_rig_capture"]

#: The shipped multi-view sample (``hand-suite capture --rig studio6 --seconds 1 --fps 10
#: --sensor-noise 0``)
SAMPLE_RIG_CAPTURE = Path(__file__).resolve().parents[2] / "data" / "sample_rig_capture"


@dataclass(frozen=True)
class RigCaptureSummary:
    """What :func:`write_rig_capture` wrote."""

    path: Path
    frames: int
    cameras: int
    messages: int
    size_bytes: int


def _stamp(t_ns: int) -> Time:
    return Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)


def _heldout_subject(studio: Studio, seed: int) -> object:
    """Put a held-out subject (skeleton + surface) in the studio; its HandShape."""
    from hand_capture.evaldata.scene import sample_subject
    from hand_capture.evaldata.surface import sample_surface

    rng = np.random.default_rng(seed)
    subject = sample_subject(rng)
    studio.set_surface(subject, sample_surface(rng, forearm=True))
    return subject.shape


def write_rig_capture(path: str | Path, rig: str = "studio6", *, seconds: float = 1.0,
                      fps: float = 10.0, objects: Sequence[object] = ("box",),
                      poses: np.ndarray | None = None, qpos: np.ndarray | None = None,
                      noise_seed: int = 0,
                      noise: StudioNoise | None = None, two_hands: bool = False,
                      surface_seed: int | None = None,
                      jitter_s: float = 0.002, t0_ns: int = 1_700_000_000_000_000_000,
                      overwrite: bool = False) -> RigCaptureSummary:
    """Render ``seconds`` of a performance from every camera of ``rig`` into an MCAP bag.

    Args:
        path: bag directory to create (refused if it exists, unless ``overwrite``).
        rig: rig name or file.
        seconds, fps: length [s] and rate [Hz] of the capture.
        objects: object kinds on the table (``box``, ``ball``, ``stick``, ``cup``) or
            ``ObjectSpec``.
        poses: (n, 27) world hand poses, one per frame; default
            :func:`~hand_capture.multiview.studio.studio_motion`.
        qpos: (n, nq) full scene states instead of ``poses`` (e.g. a simulated scenario of
            the same objects: physically consistent hand and object motion).
        surface_seed: show the right hand as a subject of the held-out surface family
            (:mod:`hand_capture.evaldata`: other finger and palm shapes, nails, a forearm, a
            sleeve half the time) drawn from this seed; its skeleton goes to
            /hand/shape_truth (HandShape), the pose truth is on that skeleton.
        two_hands: add a left hand 0.3 m to the left, performing the same motion half a
            cycle later; both hands' truth goes to /hand/pose_truth (``handedness`` tells).
        noise_seed: seed of the colour noise and of the stamps' jitter.
        noise: colour noise model (default :class:`StudioNoise` with ``noise_seed``);
            ``StudioNoise(sensor_sigma=0, ...)`` gives images that compress several times
            better.
        jitter_s: uniform stamp jitter per camera [s] (offsets up to 3 ms on top).
    """
    from hand_capture.multiview.studio import studio_scene

    out = prepare_output(path, overwrite)
    r = load_rig(rig)
    n = int(round(seconds * fps))
    if n < 1:
        raise InputError(f"seconds * fps must give at least one frame, got {seconds} * {fps}")
    if qpos is not None:
        if poses is not None or two_hands:
            raise InputError("qpos holds the whole scene: give no poses and no second hand")
        full = np.asarray(qpos, dtype=float)
        if full.ndim != 2 or full.shape[0] != n:
            raise InputError(f"qpos must have {n} rows ({seconds} s at {fps} Hz), got "
                             f"{full.shape}")
        q = full[:, :27]
    else:
        full = None
        q = studio_motion(n) if poses is None else np.asarray(poses, dtype=float)
    if q.shape != (n, 27):
        raise InputError(f"poses must have shape ({n}, 27), got {q.shape}")
    offsets = np.linspace(-0.003, 0.003, len(r))
    stamps = jittered_stamps(n, fps, len(r), jitter_s=jitter_s, offsets_s=offsets,
                             seed=noise_seed)
    writer = BagWriter(out, storage="mcap", compress=True)
    infos: dict[str, Intrinsics] = {c.name: c.intrinsics for c in r.cameras}
    for cam in r.names:
        for stream in ("color", "depth"):
            writer.add_topic(f"/{cam}/{stream}/image_raw", "sensor_msgs/msg/Image")
            writer.add_topic(f"/{cam}/{stream}/camera_info", "sensor_msgs/msg/CameraInfo")
        writer.add_topic(f"/{cam}/labels/image_raw", "sensor_msgs/msg/Image")
    writer.add_topic("/hand/pose_truth", "hand_msgs/msg/HandPose")
    try:
        noise = noise or StudioNoise(seed=noise_seed)
        left = None
        if two_hands:
            left = np.roll(studio_motion(n) if poses is None else q, n // 2, axis=0)
            left[:, 1] += 0.3
        with Studio(r, studio_scene(list(objects), two_hands=two_hands), noise) as st:
            if surface_seed is not None:
                shape = _heldout_subject(st, surface_seed)
                writer.add_topic("/hand/shape_truth", "hand_msgs/msg/HandShape")
                msg = HandShapeMsg(subject_id=shape.subject_id, global_scale=shape.global_scale,
                                   alpha=list(shape.alpha), beta=list(shape.beta))
                msg.header.stamp = _stamp(t0_ns)
                writer.write("/hand/shape_truth", t0_ns, serialize_message(msg))
            names = st.object_names
            obj_topics = {o: "/object/pose_truth" if len(names) == 1
                          else f"/object/{o}/pose_truth" for o in names}
            for topic in obj_topics.values():
                writer.add_topic(topic, "geometry_msgs/msg/PoseStamped")
            for k in range(n):
                if full is not None:
                    st.set_qpos(full[k])
                else:
                    st.set_state(q[k], left_pose=None if left is None else left[k])
                t_ns = t0_ns + int(round(k * 1e9 / fps))
                for i, cam in enumerate(r.names):
                    view = st.render(i)
                    c_ns = t0_ns + int(round(stamps[k, i] * 1e9))
                    stamp, intr = _stamp(c_ns), infos[cam]
                    depth_mm = np.round(view.depth_m * 1000.0).clip(0, 65535).astype(np.uint16)
                    msgs = {
                        f"/{cam}/color/image_raw": numpy_to_image(view.rgb, "rgb8", stamp,
                                                                  intr.frame_id),
                        f"/{cam}/color/camera_info": camera_info_msg(intr, stamp),
                        f"/{cam}/depth/image_raw": depth_image_msg(depth_mm, stamp,
                                                                   intr.frame_id),
                        f"/{cam}/depth/camera_info": camera_info_msg(intr, stamp),
                        f"/{cam}/labels/image_raw": numpy_to_image(view.labels, "mono8", stamp,
                                                                   intr.frame_id),
                    }
                    for topic, msg in msgs.items():
                        writer.write(topic, max(c_ns, t_ns), serialize_message(msg))
                hands = [("right", q[k])] + ([] if left is None else [("left", left[k])])
                for side, pose in hands:
                    truth = fill_pose_msg(HandPose(), pose, side=side, status="ground_truth",
                                          source="studio")
                    truth.header.stamp, truth.header.frame_id = _stamp(t_ns), r.world_frame
                    writer.write("/hand/pose_truth", t_ns, serialize_message(truth))
                for o, topic in obj_topics.items():
                    T = st.object_pose(o)
                    msg = PoseStamped()
                    msg.header.stamp, msg.header.frame_id = _stamp(t_ns), r.world_frame
                    p, rot = msg.pose.position, msg.pose.orientation
                    p.x, p.y, p.z = (float(v) for v in T[:3, 3])
                    rot.x, rot.y, rot.z, rot.w = (float(v) for v in matrix_to_quat(T[:3, :3]))
                    writer.write(topic, t_ns, serialize_message(msg))
    finally:
        writer.close()
    size = sum(f.stat().st_size for f in out.iterdir())
    return RigCaptureSummary(out, n, len(r), writer.count, size)
