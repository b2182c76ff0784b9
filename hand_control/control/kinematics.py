"""What the controller needs to know about the hand and the world: small interfaces.

The composite controller (:mod:`hand_control.control.loop`) depends on these Protocols only,
never on the simulator: ``hand_control.sim`` implements them from MuJoCo
(:class:`hand_control.sim.kinematics.MujocoKinematics`, :class:`hand_control.sim.world.SimWorld`),
and a hardware hand or another simulator can implement them from its own model.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["ControlReference", "HandKinematics", "LiveContacts", "ReferenceSample"]


@runtime_checkable
class HandKinematics(Protocol):
    """Kinematics of the hand: contact Jacobians from joint positions, and the hand's limits.

    Attributes:
        joint_names: the hand DoFs, the order of every joint array (the model's vocabulary).
        position_limits: (n_hand, 2) lower / upper limit of each DoF's position target
            [rad or m]; +-inf where there is none.
        effort_limits: (n_hand,) largest feed-forward effort the actuator of each DoF can
            apply [N m or N]; inf where there is none.
    """

    joint_names: tuple[str, ...]
    position_limits: np.ndarray
    effort_limits: np.ndarray

    def is_hand_body(self, name: str) -> bool:
        """Whether ``name`` is a body of the hand (a contact's hand side)."""
        ...

    def update(self, q: np.ndarray) -> None:
        """Set the joint positions (n_hand,) [rad or m] whose Jacobians follow."""
        ...

    def jacobians(self, bodies: Sequence[str], points: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3, n_hand) translational and rotational Jacobians of the hand bodies
        ``bodies[k]`` at the world points ``points[k]`` (K, 3) [m], for the Jacobian-transpose
        map of eq. (12) / (III.21)."""
        ...


@runtime_checkable
class LiveContacts(Protocol):
    """A simulated world in the controller's own process (the lockstep loop): its current
    hand-object contacts and the Jacobian-transpose map evaluated on its live state."""

    def object_contacts(self, body: int
                        ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, list[int]]:
        """``(K, points (K, 3), normals (K, 3) from the hand, friction (K,), hand body ids)``
        of the object ``body``'s contacts with the hand (``None`` arrays when K = 0)."""
        ...

    def hand_body_names(self, bodies: Sequence[int]) -> tuple[str, ...]:
        """The names of hand body ids."""
        ...

    def wrench_torques(self, bodies: Sequence[int], point: np.ndarray,
                       wrenches: np.ndarray) -> np.ndarray:
        """(n_hand,) joint torques that make hand body ``bodies[k]`` apply the wrench
        ``wrenches[k] = (f_k, t_k)`` at ``point`` (eq. 12 / III.21)."""
        ...

    def contact_torques(self, bodies: Sequence[int], points: np.ndarray, forces: np.ndarray,
                        torsion: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(n_hand,) ``sum_k Jp_k^T f_k + Jr_k^T (l_k n_k)`` at the contacts (eq. 12)."""
        ...


class ReferenceSample(Protocol):
    """The references of one instant: hand PD targets and the object's target pose."""

    q_target: np.ndarray        # (n_hand,) [rad or m]
    object_position: np.ndarray  # (3,) [m]
    object_quaternion: np.ndarray  # (4,) w, x, y, z
    grasp: bool                 # grasp torques on (manipulation phases)
    phase: str


class ControlReference(Protocol):
    """A reference motion: its sample at time ``t`` [s]."""

    def __call__(self, t: float) -> ReferenceSample: ...

    def is_finite(self) -> bool:
        """Every sample is finite (lets the controller skip re-checking them)."""
        ...
