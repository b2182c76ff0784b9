"""Large RViz markers without building thousands of Point messages per frame.

A skinned hand as a TRIANGLE_LIST has 21,180 points; building them as ``geometry_msgs/Point``
objects in Python and serialising them takes about 110 ms, more than tracking the frame.
:class:`SerializedMarkers` serialises a template MarkerArray once, with recognisable values
where the stamps, colours and points go, records their byte offsets, and then writes each new
frame's values straight into a copy of those bytes (numpy for the points), which
``Publisher.publish`` sends as an already serialised message.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np
from rclpy.serialization import serialize_message
from visualization_msgs.msg import MarkerArray

from hand_capture.errors import InputError

__all__ = ["SerializedMarkers"]


def _find_once(buf: bytes, needle: bytes, what: str) -> int:
    at = buf.find(needle)
    if at < 0 or buf.find(needle, at + 1) >= 0:
        raise InputError(f"marker template: {what} not found exactly once")
    return at


class SerializedMarkers:
    """A MarkerArray whose stamps, colours and point coordinates change per message.

    Args:
        template: the markers (types, namespaces, scales, frame ids...) with the number of
            points each will carry; their stamps, colours and points are overwritten here.
    """

    def __init__(self, template: MarkerArray) -> None:
        self.counts = [len(m.points) for m in template.markers]
        for k, m in enumerate(template.markers):  # recognisable values
            m.header.stamp.sec, m.header.stamp.nanosec = 0x3A5C0000 + k, 0x4B6D0000 + k
            m.color.r, m.color.g, m.color.b, m.color.a = (1001.0 + k, 2001.0 + k, 3001.0 + k,
                                                          4001.0 + k)
            for j, p in enumerate(m.points):
                p.x, p.y, p.z = 1e9 + 1e7 * k + j, -(1e9 + 1e7 * k + j), 0.5 + j
        self._raw = serialize_message(template)
        self._stamps, self._colors, self._points = [], [], []
        for k, m in enumerate(template.markers):
            self._stamps.append(_find_once(self._raw, struct.pack(
                "<iI", m.header.stamp.sec, m.header.stamp.nanosec), f"stamp of marker {k}"))
            self._colors.append(_find_once(self._raw, struct.pack(
                "<4f", m.color.r, m.color.g, m.color.b, m.color.a), f"colour of marker {k}"))
            if m.points:
                p0 = m.points[0]
                self._points.append(_find_once(self._raw, struct.pack(
                    "<3d", p0.x, p0.y, p0.z), f"points of marker {k}"))
            else:
                self._points.append(-1)

    def serialize(self, stamp: object, colors: Sequence[Sequence[float]],
                  points: Sequence[np.ndarray]) -> bytes:
        """The serialised MarkerArray for one frame.

        Args:
            stamp: builtin_interfaces/Time for every marker.
            colors: per marker (r, g, b, a).
            points: per marker an (n_k, 3) array [m], n_k as in the template.

        Raises:
            InputError: wrong number of markers or points.
        """
        if len(colors) != len(self.counts) or len(points) != len(self.counts):
            raise InputError(f"expected {len(self.counts)} markers")
        buf = bytearray(self._raw)
        for k, n in enumerate(self.counts):
            struct.pack_into("<iI", buf, self._stamps[k], stamp.sec, stamp.nanosec)
            struct.pack_into("<4f", buf, self._colors[k], *colors[k])
            pts = np.asarray(points[k], dtype="<f8")
            if pts.shape != (n, 3):
                raise InputError(f"marker {k}: expected ({n}, 3) points, got {pts.shape}")
            if n:
                np.ndarray((n, 3), "<f8", buf, self._points[k])[:] = pts
        return bytes(buf)
