"""The controller's one configuration: every gain and QP setting of the papers.

:class:`CompositeControlConfig` holds, each as one field (one ROS parameter of the controller
node, one key of ``config/controller.yaml``):

* the PD gains of seed 000 Table 1 = dissertation Table III.1, one ``(Kp, Kd)`` per table row
  (``joint_kp``, ``joint_kd`` in ``GAIN_ROWS`` order; a joint's DoFs share its row, e.g.
  ``index_mcp_abd`` and ``index_mcp_flex`` both use ``index1``). They are the gains of the
  position servos the simulation steps (written into the MJCF by
  ``hand_capture.model.mjcf.build_scene``) and of ``tau_pd`` (eq. 8 / III.20);
* the virtual object servo of Table III.1 (eq. 9 / III.22);
* the contact-force QP: ``method`` (eq. III.23 or seed 000 eq. 10-11), ``alpha1..alpha4``,
  ``lambda1``, ``lambda2``, the friction pyramid and the solver settings. These fields are
  those of :class:`hand_control.contact.qp.ContactQPConfig`, inherited (declared once, in
  the QP's module, with their descriptions and ranges): a ``CompositeControlConfig`` is the
  QP's config too. Three defaults differ from the QP's (which are the dissertation's) for
  closed-loop control: ``alpha3 = alpha4 = 1e-3`` (the dissertation's 0.1 leaves a third of a
  1 kg load at mu = 0.3 unmet: the object is never lifted) and ``torsion_bound`` on (the
  torsional torques within the contacts' torsional friction, which the simulator enforces).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_capture.config import param, validate
from hand_capture.model.mjcf import GAIN_ROWS, GAIN_TABLE, dof_gains, gain_row
from hand_control.contact.qp import ContactQPConfig
from hand_control.errors import ConfigError

__all__ = ["GAIN_ROWS", "CompositeControlConfig", "gain_row", "joint_gains"]

_TABLE_KP = tuple(GAIN_TABLE[r][0] for r in GAIN_ROWS)
_TABLE_KD = tuple(GAIN_TABLE[r][1] for r in GAIN_ROWS)


def _closed_loop_default(name: str, value: Any) -> Any:
    """An inherited ``ContactQPConfig`` field with another default (its description and
    range stay the QP's: one declaration)."""
    return dataclasses.field(default=value,
                             metadata=ContactQPConfig.__dataclass_fields__[name].metadata)


@dataclass(frozen=True)
class CompositeControlConfig(ContactQPConfig):
    """Composite motion control (seed 000 eq. 8-13, dissertation eq. III.19-III.23): gains,
    object servo and the contact-force QP's settings (inherited from ``ContactQPConfig``;
    closed-loop defaults for ``alpha3``, ``alpha4``, ``torsion_bound``: module docstring)."""

    alpha3: float = _closed_loop_default("alpha3", 1e-3)
    alpha4: float = _closed_loop_default("alpha4", 1e-3)
    torsion_bound: bool = _closed_loop_default("torsion_bound", True)

    mode: str = param(
        "composite",
        "'composite' = PD + grasp torques from the contact-force QP (eq. 13 / III.19); "
        "'pd_only' = PD (+ gravity compensation) alone, the papers' baseline",
        choices=("composite", "pd_only"),
    )
    joint_kp: tuple[float, ...] = param(
        _TABLE_KP,
        "PD stiffness per row of Table 1 / Table III.1, rows in GAIN_ROWS order (root_translate, "
        "root_rotate, thumb1..3, index1..3, middle1..3, ring1..3, pinky1..3; 1 = the joint "
        "nearest the palm) [N m/rad; N/m for root_translate]",
        lo=1e-6, hi=1e5,
    )
    joint_kd: tuple[float, ...] = param(
        _TABLE_KD,
        "PD damping per row of Table 1 / Table III.1, rows in GAIN_ROWS order "
        "[N m s/rad; N s/m for root_translate]",
        lo=0.0, hi=1e4,
    )
    object_kp_translate: float = param(
        5.0, "virtual object force stiffness, eq. (III.22), Table III.1 [N/m]", lo=0.0, hi=1e5
    )
    object_kd_translate: float = param(
        0.5, "virtual object force damping, eq. (III.22), Table III.1 [N s/m]", lo=0.0, hi=1e4
    )
    object_kp_rotate: float = param(
        5.0, "virtual object torque stiffness, eq. (III.22), Table III.1 [N m/rad] (capped "
        "for light objects at 0.25 I / dt^2, see ControllerCore)", lo=0.0, hi=1e5
    )
    object_kd_rotate: float = param(
        0.5, "virtual object torque damping, eq. (III.22), Table III.1 [N m s/rad] (capped "
        "at 0.5 I / dt)", lo=0.0, hi=1e4
    )
    gravity: tuple[float, ...] = param(
        (0.0, 0.0, -9.81), "gravity acceleration in the world frame [m/s^2]", lo=-100.0,
        hi=100.0
    )
    gravity_compensation: bool = param(
        True, "add the gravity compensation torque tau_gravity of eq. (III.19) (the "
        "simulation cancels gravity on the hand itself when its hand_gravcomp is set; the "
        "controller then adds none)"
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

    def qp_config(self) -> ContactQPConfig:
        """The QP's settings alone (the inherited fields)."""
        return ContactQPConfig(**{f.name: getattr(self, f.name)
                                  for f in dataclasses.fields(ContactQPConfig)})


def joint_gains(
    config: CompositeControlConfig, joint_names: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Per-DoF ``(kp, kd)`` arrays for the joints in ``joint_names`` (in that order).

    Raises:
        ConfigError: for a joint name that has no row in the table.
    """
    return dof_gains(config.joint_kp, config.joint_kd, joint_names)
