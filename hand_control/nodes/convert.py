"""Conversions between hand_msgs / builtin messages and the cores' arrays (shared by the
sim and controller nodes; not a node)."""

from __future__ import annotations

import numpy as np
from hand_msgs.msg import Contact, ContactArray


def set_time(time_msg, t: float) -> None:
    """Fill a builtin_interfaces/Time from seconds."""
    ns = int(round(t * 1e9))
    time_msg.sec, time_msg.nanosec = ns // 1_000_000_000, ns % 1_000_000_000


def stamp(header, t: float) -> None:
    """Set a header's stamp from seconds."""
    set_time(header.stamp, t)


def contact_array(cf, t: float, frame_id: str) -> ContactArray:
    """A :class:`~hand_control.sim.contacts.ContactFrame` as ``hand_msgs/ContactArray``."""
    msg = ContactArray()
    stamp(msg.header, t)
    msg.header.frame_id = frame_id
    pts, nrm, frc = cf.points.tolist(), cf.normals.tolist(), cf.forces.tolist()
    out = []
    for k in range(len(cf)):
        c = Contact()
        c.body1, c.body2 = cf.body1[k], cf.body2[k]
        c.point.x, c.point.y, c.point.z = pts[k]
        c.normal.x, c.normal.y, c.normal.z = nrm[k]
        c.penetration = float(cf.penetration[k])
        c.force.x, c.force.y, c.force.z = frc[k]
        c.torsional_torque = float(cf.torsional[k])
        c.friction = float(cf.friction[k])
        out.append(c)
    msg.contacts = out
    return msg


def contacts_from_msg(msg: ContactArray) -> tuple[list[str], list[str], np.ndarray, np.ndarray,
                                                   np.ndarray, np.ndarray]:
    """``(body1, body2, points, normals, forces, friction)`` arrays of a ContactArray."""
    cs = msg.contacts
    b1 = [c.body1 for c in cs]
    b2 = [c.body2 for c in cs]
    pts = np.array([(c.point.x, c.point.y, c.point.z) for c in cs]).reshape(-1, 3)
    nrm = np.array([(c.normal.x, c.normal.y, c.normal.z) for c in cs]).reshape(-1, 3)
    frc = np.array([(c.force.x, c.force.y, c.force.z) for c in cs]).reshape(-1, 3)
    mu = np.array([c.friction for c in cs], dtype=float)
    return b1, b2, pts, nrm, frc, mu
