"""rosbag2 record / replay on top of ``rosbags`` (no ROS install needed)."""

from hand_capture.bag.bagfile import (
    STORAGES,
    BagMessage,
    BagReader,
    BagWriter,
    RecoveryResult,
    make_qos,
    prepare_output,
    recover_bag,
)
from hand_capture.bag.typestore import default_typestore, ensure_type

__all__ = [
    "STORAGES",
    "BagMessage",
    "BagReader",
    "BagWriter",
    "RecoveryResult",
    "default_typestore",
    "ensure_type",
    "make_qos",
    "prepare_output",
    "recover_bag",
]
