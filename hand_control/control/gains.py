"""Gains of the composite controller: Table 1 of seed 000 = Table III.1 of dissertation 003.

The tables give one (Kp, Kd) pair per joint of the hand, numbered from the root to the tip of
each finger (``index1`` is the index MCP, ``index3`` the DIP; ``thumb1`` the trapeziometacarpal
joint), one pair for the wrist translation and one for its rotation; Table III.1 adds the gains
of the virtual object PD servo (eq. III.22). A joint's degrees of freedom share its joint's
gains (e.g. ``index_mcp_abd`` and ``index_mcp_flex`` both use ``index1``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.joints import FINGERS
from hand_capture.model.mjcf import GAIN_TABLE
from hand_control.errors import ConfigError

__all__ = ["GAIN_ROWS", "CompositeControlConfig", "gain_row", "joint_gains"]

#: Rows of Table 1 / Table III.1, in the order of ``joint_kp`` and ``joint_kd``; the values come
#: from the one copy of the table, ``hand_capture.model.mjcf.GAIN_TABLE``.
GAIN_ROWS: tuple[str, ...] = tuple(GAIN_TABLE)
_TABLE_KP = tuple(GAIN_TABLE[r][0] for r in GAIN_ROWS)
_TABLE_KD = tuple(GAIN_TABLE[r][1] for r in GAIN_ROWS)

# joint of the model -> its number in the tables (root to tip)
_THUMB_JOINT = {"tm": 1, "mcp": 2, "ip": 3}
_FINGER_JOINT = {"mcp": 1, "pip": 2, "dip": 3}
_TABLE_FINGER = {"little": "pinky"}


def gain_row(joint_name: str) -> str:
    """The row of Table 1 / III.1 that holds the gains of a joint of the hand model.

    Raises:
        ConfigError: for a name outside the model's vocabulary (``hand_capture.model.joints``).
    """
    if joint_name in ("root_tx", "root_ty", "root_tz"):
        return "root_translate"
    if joint_name in ("root_rx", "root_ry", "root_rz"):
        return "root_rotate"
    finger, _, rest = joint_name.partition("_")
    joint = rest.partition("_")[0]
    numbers = _THUMB_JOINT if finger == "thumb" else _FINGER_JOINT
    if finger in FINGERS and joint in numbers:
        return f"{_TABLE_FINGER.get(finger, finger)}{numbers[joint]}"
    raise ConfigError(f"joint {joint_name!r} has no row in the gain table (rows: {GAIN_ROWS})")


@dataclass(frozen=True)
class CompositeControlConfig:
    """Composite motion control (seed 000 eq. 8-13, dissertation eq. III.19-III.23)."""

    mode: str = param(
        "composite",
        "'composite' = PD + grasp torques from the contact-force QP (eq. 13 / III.19); "
        "'pd_only' = PD (+ gravity compensation) alone, the papers' baseline",
        choices=("composite", "pd_only"),
    )
    joint_kp: tuple[float, ...] = param(
        _TABLE_KP,
        "PD stiffness per row of Table 1 / Table III.1, rows in GAIN_ROWS order "
        "[N m/rad; N/m for root_translate]",
        lo=0.0,
    )
    joint_kd: tuple[float, ...] = param(
        _TABLE_KD,
        "PD damping per row of Table 1 / Table III.1, rows in GAIN_ROWS order "
        "[N m s/rad; N s/m for root_translate]",
        lo=0.0,
    )
    object_kp_translate: float = param(
        5.0, "virtual object force stiffness, eq. (III.22), Table III.1 [N/m]", lo=0.0
    )
    object_kd_translate: float = param(
        0.5, "virtual object force damping, eq. (III.22), Table III.1 [N s/m]", lo=0.0
    )
    object_kp_rotate: float = param(
        5.0, "virtual object torque stiffness, eq. (III.22), Table III.1 [N m/rad]", lo=0.0
    )
    object_kd_rotate: float = param(
        0.5, "virtual object torque damping, eq. (III.22), Table III.1 [N m s/rad]", lo=0.0
    )
    gravity: tuple[float, ...] = param(
        (0.0, 0.0, -9.81), "gravity acceleration in the world frame [m/s^2]"
    )
    gravity_compensation: bool = param(
        True, "add the gravity compensation torque tau_gravity of eq. (III.19)"
    )

    def __post_init__(self) -> None:
        validate(self)
        for name in ("joint_kp", "joint_kd"):
            if len(getattr(self, name)) != len(GAIN_ROWS):
                raise ConfigError(
                    f"CompositeControlConfig.{name} needs {len(GAIN_ROWS)} values "
                    f"(rows {GAIN_ROWS}), got {len(getattr(self, name))}"
                )
        if len(self.gravity) != 3:
            raise ConfigError(f"CompositeControlConfig.gravity needs 3 values, got {self.gravity}")


def joint_gains(
    config: CompositeControlConfig, joint_names: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Per-DoF ``(kp, kd)`` arrays for the joints in ``joint_names`` (in that order).

    Raises:
        ConfigError: for a joint name that has no row in the table.
    """
    rows = [GAIN_ROWS.index(gain_row(name)) for name in joint_names]
    return np.asarray(config.joint_kp)[rows], np.asarray(config.joint_kd)[rows]
