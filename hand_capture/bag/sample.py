"""A small bag the project makes itself: a hand opening and closing, with contacts.

Used by the README's main job (the replay graph) and by the tests. Messages are built with the
rosbags type store (no rclpy), so the bag can be written anywhere.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hand_capture.bag.bagfile import BagWriter
from hand_capture.bag.typestore import default_typestore
from hand_capture.model.joints import ARTICULATED_JOINTS

SAMPLE_TOPICS = {
    "/hand/pose": "hand_msgs/msg/HandPose",
    "/hand/joint_states": "sensor_msgs/msg/JointState",
    "/sim/contacts": "hand_msgs/msg/ContactArray",
}


def _flexion(t: float, period: float = 2.0) -> np.ndarray:
    """Joint angles [rad] of a fist that opens and closes with ``period`` [s]; shape (21,)."""
    s = 0.5 - 0.5 * np.cos(2 * np.pi * t / period)  # 0 open .. 1 closed
    q = np.zeros(len(ARTICULATED_JOINTS))
    for i, name in enumerate(ARTICULATED_JOINTS):
        if name.endswith("_flex"):
            q[i] = s * (1.2 if "thumb" not in name else 0.6)
    return q


def write_sample_bag(path: str | Path, duration: float = 3.0, rate: float = 30.0,
                     storage: str = "mcap", t0_ns: int = 1_700_000_000_000_000_000) -> int:
    """Write the sample bag; returns the number of messages.

    Args:
        path: bag directory to create (must not exist).
        duration: length of the recording [s].
        rate: message rate per topic [Hz].
        storage: ``"mcap"`` or ``"sqlite3"``.
        t0_ns: receive time of the first message [ns].
    """
    store = default_typestore()
    T = store.types
    w = BagWriter(path, storage=storage, flush_period=1.0)
    for topic, msgtype in SAMPLE_TOPICS.items():
        w.add_topic(topic, msgtype)
    names = list(ARTICULATED_JOINTS)
    n = int(round(duration * rate))
    try:
        for k in range(n):
            t_ns = t0_ns + int(k * 1e9 / rate)
            stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
            header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="camera_depth_optical_frame")
            q = _flexion(k / rate)
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.45),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
            hp = T["hand_msgs/msg/HandPose"](
                header=header, handedness=0, joint_names=names, positions=q, wrist_pose=pose,
                confidence=1.0, status=4, source="sample")
            js = T["sensor_msgs/msg/JointState"](
                header=header, name=names, position=q, velocity=np.zeros(len(names)),
                effort=np.zeros(0))
            vec = T["geometry_msgs/msg/Vector3"]
            contacts = [
                T["hand_msgs/msg/Contact"](
                    body1=f"{f}_distal", body2="ball",
                    point=T["geometry_msgs/msg/Point"](x=0.02 * i, y=0.0, z=0.45),
                    normal=vec(x=0.0, y=0.0, z=1.0), penetration=0.0005,
                    force=vec(x=0.0, y=0.0, z=float(q[4]) * 2.0), torsional_torque=0.0,
                    friction=0.8)
                for i, f in enumerate(("thumb", "index"))
            ]
            ca = T["hand_msgs/msg/ContactArray"](
                header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="world"),
                contacts=contacts)
            for topic, msg in (("/hand/pose", hp), ("/hand/joint_states", js),
                               ("/sim/contacts", ca)):
                w.write(topic, t_ns, bytes(store.serialize_cdr(msg, SAMPLE_TOPICS[topic])))
    finally:
        w.close()
    return n * len(SAMPLE_TOPICS)
