"""The joint vocabulary of the suite: one declared order, used by every node.

27 degrees of freedom as in the dissertation (ch. II.3.1): 6 for the root (position and
orientation of the wrist), 5 for the thumb (TM 2, MCP 2, IP 1) and 4 for each other finger
(MCP 2, PIP 1, DIP 1). Messages carry joints by name; this order is only the order of arrays
inside the core.
"""

from __future__ import annotations

FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")

ROOT_JOINTS: tuple[str, ...] = (
    "root_tx", "root_ty", "root_tz",  # wrist position [m]
    "root_rx", "root_ry", "root_rz",  # wrist orientation, rotation vector components [rad]
)

THUMB_JOINTS: tuple[str, ...] = (
    "thumb_tm_abd", "thumb_tm_flex", "thumb_mcp_abd", "thumb_mcp_flex", "thumb_ip_flex",
)


def _finger_joints(finger: str) -> tuple[str, ...]:
    return (f"{finger}_mcp_abd", f"{finger}_mcp_flex", f"{finger}_pip_flex",
            f"{finger}_dip_flex")


FINGER_JOINTS: tuple[str, ...] = THUMB_JOINTS + tuple(
    j for f in FINGERS[1:] for j in _finger_joints(f)
)

#: Every degree of freedom, root first (27).
JOINT_NAMES: tuple[str, ...] = ROOT_JOINTS + FINGER_JOINTS

#: The articulated (hinge) joints that messages carry in joint_names (21).
ARTICULATED_JOINTS: tuple[str, ...] = FINGER_JOINTS

assert len(JOINT_NAMES) == 27 and len(set(JOINT_NAMES)) == 27
