"""Retargeting of a human hand (21 keypoints or a suite HandPose) onto any robot hand model.

* :mod:`.robot`: a robot hand from MJCF or URDF through MuJoCo (joints, points, FK, analytic
  Jacobians);
* :mod:`.config`: the YAML config of a robot hand (``config/retarget/*.yaml``) and the
  solver settings;
* :mod:`.solver`: the per-frame optimisation (position, vector and pinch modes).

Typical use::

    from hand_control.retarget import HandRetargeter

    rt = HandRetargeter("leap_hand")          # config/retarget/leap_hand.yaml
    res = rt.solve(keypoints21)               # (21, 3) [m] -> res.q (16,) [rad]
    dict(zip(rt.joint_names, res.q))
"""

from hand_control.retarget.config import (
    MODES,
    RetargetConfig,
    RetargetSettings,
    load_retarget_config,
    retarget_config_from_dict,
)
from hand_control.retarget.robot import BUILTIN_SUITE_HAND, RobotHand, load_mujoco_model
from hand_control.retarget.solver import HandRetargeter, RetargetResult, solve_box_qp

__all__ = [
    "BUILTIN_SUITE_HAND", "MODES", "HandRetargeter", "RetargetConfig", "RetargetResult",
    "RetargetSettings", "RobotHand", "load_mujoco_model", "load_retarget_config",
    "retarget_config_from_dict", "solve_box_qp",
]
