"""The controller's kinematics interface implemented from MuJoCo (the sim side's adapter).

:class:`MujocoKinematics` is a kinematic copy of the simulated hand (the same MJCF, never
stepped): it turns the contacts received from the simulation (hand bone name, point) into
the contact Jacobians of eq. (12) with ``mj_jac``, and reads the hand's limits from the
model (joint ranges, actuator control and force ranges). It implements
:class:`hand_control.control.kinematics.HandKinematics`.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from hand_control.errors import InputError
from hand_control.sim.world import SimWorld

__all__ = ["MujocoKinematics", "hand_limits"]


def hand_limits(world: SimWorld) -> tuple[np.ndarray, np.ndarray]:
    """``(position_limits (n_hand, 2), effort_limits (n_hand,))`` of a world's hand: a DoF's
    joint range where it is limited, else its servo's control range (else +-inf); the force
    range of its actuator [N m or N] (else inf)."""
    m = world.model
    n = world.n_hand
    pos = np.tile([-np.inf, np.inf], (n, 1))
    eff = np.full(n, np.inf)
    jids = m.dof_jntid[world.dof_adr]
    for k, j in enumerate(jids):
        if m.jnt_limited[j]:
            pos[k] = m.jnt_range[j]
    for a in range(m.nu):
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            continue
        hit = np.nonzero(jids == m.actuator_trnid[a, 0])[0]
        if hit.size == 0:
            continue
        k = int(hit[0])
        if not m.jnt_limited[jids[k]] and m.actuator_ctrllimited[a]:
            pos[k] = m.actuator_ctrlrange[a]
        if m.actuator_forcelimited[a]:
            eff[k] = float(np.abs(m.actuator_forcerange[a]).min())
    return pos, eff


class MujocoKinematics:
    """Kinematics of the simulated hand (the sim's own MJCF) for Jacobians from joint states.

    Args:
        world: the simulated world whose model is copied (its state is never touched).
    """

    def __init__(self, world: SimWorld) -> None:
        self.model = world.model
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = world.data.qpos
        self.joint_names = world.joint_names
        self.qpos_adr = world.qpos_adr
        self.dof_adr = world.dof_adr
        self._body = dict(zip(world.hand_body_names(world.hand_body_ids),
                              world.hand_body_ids.tolist(), strict=True))
        self.position_limits, self.effort_limits = hand_limits(world)
        self._jacp = np.zeros((3, self.model.nv))
        self._jacr = np.zeros((3, self.model.nv))

    def is_hand_body(self, name: str) -> bool:
        return name in self._body

    def body_id(self, name: str) -> int:
        try:
            return self._body[name]
        except KeyError:
            raise InputError(f"{name!r} is not a hand body ({sorted(self._body)})") from None

    def update(self, q: np.ndarray) -> None:
        self.data.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def jacobians(self, bodies: Sequence[str], points: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3, n_hand) translational and rotational Jacobians at ``points`` on ``bodies``
        (call :meth:`update` first)."""
        k = len(bodies)
        jp = np.empty((k, 3, len(self.qpos_adr)))
        jr = np.empty_like(jp)
        for i, (b, p) in enumerate(zip(bodies, points, strict=True)):
            mujoco.mj_jac(self.model, self.data, self._jacp, self._jacr, p, self.body_id(b))
            jp[i] = self._jacp[:, self.dof_adr]
            jr[i] = self._jacr[:, self.dof_adr]
        return jp, jr
