"""Composite motion control: PD servos + virtual object wrench realised by grasp torques
(seed 000 eq. 8-13, dissertation eq. III.19-III.23). Depends on the hand model and the
contact QP, never on the simulator (the kinematics interface: ``kinematics.py``)."""

from hand_control.control.composite import (
    CompositeController,
    ControlOutput,
    ObjectState,
    ObjectTarget,
    grasp_torques,
    object_virtual_wrench,
    pd_torques,
    quaternion_error,
)
from hand_control.control.gains import GAIN_ROWS, CompositeControlConfig, gain_row, joint_gains
from hand_control.control.kinematics import (
    ControlReference,
    HandKinematics,
    LiveContacts,
    ReferenceSample,
)
from hand_control.control.loop import Command, ControllerCore, ControllerNodeConfig

__all__ = [
    "GAIN_ROWS",
    "Command",
    "CompositeControlConfig",
    "CompositeController",
    "ControlOutput",
    "ControlReference",
    "ControllerCore",
    "ControllerNodeConfig",
    "HandKinematics",
    "LiveContacts",
    "ReferenceSample",
    "ObjectState",
    "ObjectTarget",
    "gain_row",
    "grasp_torques",
    "joint_gains",
    "object_virtual_wrench",
    "pd_torques",
    "quaternion_error",
]
