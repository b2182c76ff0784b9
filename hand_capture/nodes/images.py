"""numpy <-> sensor_msgs/Image and CameraInfo, without cv_bridge (not available from PyPI).

``uint8[]`` message fields are filled with an ``array.array('B')`` filled from the image's
buffer (one memcpy; assigning a list or ``bytes`` would make rosidl check every element), and read
back with ``np.frombuffer`` (no copy). Supported encodings: ``16UC1`` (depth [mm]),
``32FC1`` (depth [m]), ``rgb8``, ``bgr8``, ``mono8``, ``mono16``.
"""

from __future__ import annotations

import array
import sys

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError

__all__ = ["camera_info_msg", "depth_image_msg", "image_to_array", "intrinsics_from_msg",
           "numpy_to_image", "rgb_image_msg"]

_ENCODINGS = {  # encoding -> (dtype, channels)
    "16UC1": (np.uint16, 1), "mono16": (np.uint16, 1), "32FC1": (np.float32, 1),
    "rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "mono8": (np.uint8, 1),
}


def numpy_to_image(arr: np.ndarray, encoding: str, stamp: Time | None = None,
                   frame_id: str = "") -> Image:
    """An Image message holding ``arr`` (H, W) or (H, W, C) with the given encoding."""
    if encoding not in _ENCODINGS:
        raise InputError(f"unsupported encoding {encoding!r}; valid: {sorted(_ENCODINGS)}")
    dtype, ch = _ENCODINGS[encoding]
    a = np.asarray(arr)
    if a.dtype != dtype or (a.ndim != 2 if ch == 1 else (a.ndim != 3 or a.shape[2] != ch)):
        raise InputError(f"{encoding} needs a {dtype.__name__} array of shape "
                         f"{'(H, W)' if ch == 1 else f'(H, W, {ch})'}, got {a.dtype} {a.shape}")
    a = np.ascontiguousarray(a)
    msg = Image()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(a.shape[0]), int(a.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 1 if (a.dtype.byteorder == ">" or
                             (a.dtype.byteorder == "=" and sys.byteorder == "big")) else 0
    msg.step = int(a.shape[1] * a.itemsize * ch)
    data = array.array("B")
    data.frombytes(a.reshape(-1).view(np.uint8))  # from the array's buffer: one copy
    msg.data = data
    return msg


def depth_image_msg(depth_mm: np.ndarray, stamp: Time | None = None,
                    frame_id: str = "") -> Image:
    """``16UC1`` Image of a uint16 depth image in millimetres (0 = no measurement)."""
    return numpy_to_image(depth_mm, "16UC1", stamp, frame_id)


def rgb_image_msg(rgb: np.ndarray, stamp: Time | None = None, frame_id: str = "") -> Image:
    """``rgb8`` Image of a (H, W, 3) uint8 RGB image."""
    return numpy_to_image(rgb, "rgb8", stamp, frame_id)


def image_to_array(msg: Image) -> np.ndarray:
    """The pixels of an Image as a read-only numpy view: (H, W) or (H, W, C).

    Raises:
        InputError: unsupported encoding, or a size that does not match width/height/step.
    """
    if msg.encoding not in _ENCODINGS:
        raise InputError(f"unsupported image encoding {msg.encoding!r}; valid: "
                         f"{sorted(_ENCODINGS)}")
    dtype, ch = _ENCODINGS[msg.encoding]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = msg.width * ch * dt.itemsize
    if msg.step < row or len(msg.data) < msg.step * msg.height:
        raise InputError(f"image {msg.width}x{msg.height} {msg.encoding}: step {msg.step} "
                         f"and {len(msg.data)} bytes do not hold the pixels")
    buf = np.frombuffer(msg.data, dtype=np.uint8, count=msg.step * msg.height)
    rows = buf.reshape(msg.height, msg.step)
    a = rows if msg.step == row else np.ascontiguousarray(rows[:, :row])
    a = a.view(dt).reshape((msg.height, msg.width) if ch == 1 else (msg.height, msg.width, ch))
    if not dt.isnative:
        a = a.astype(dt.newbyteorder("="))
    return a


def camera_info_msg(intr: Intrinsics, stamp: Time | None = None) -> CameraInfo:
    """CameraInfo of an ideal (or rectified) pinhole stream: K, R = I, P = [K | 0], D."""
    msg = CameraInfo()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = intr.frame_id
    msg.width, msg.height = intr.width, intr.height
    msg.distortion_model = intr.distortion_model
    msg.d = [float(x) for x in intr.distortion]
    msg.k = [float(x) for x in intr.K.ravel()]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [float(x) for x in intr.P.ravel()]
    return msg


def intrinsics_from_msg(msg: CameraInfo) -> Intrinsics:
    """Intrinsics from a CameraInfo (K and D; frame from the header)."""
    k = list(msg.k)
    return Intrinsics(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5],
                      msg.distortion_model or "plumb_bob", tuple(msg.d) or (0.0,) * 5,
                      msg.header.frame_id)
