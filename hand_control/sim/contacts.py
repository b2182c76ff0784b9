"""Contacts of one simulation step as plain arrays, in the conventions of ``hand_msgs/Contact``.

For every contact MuJoCo reports a frame whose first row is the normal pointing from ``geom1``
into ``geom2``, a distance (negative = penetration) and, through ``mj_contactForce``, the force
and torsional torque in that frame that ``geom1`` applies on ``geom2``. We rotate them to the
world frame and, for hand-object contacts, order the pair so that body 1 is the hand bone:
the normal then points from the hand into the object and the force is the one the hand applies
on the object (``hand_control.contact.types.ContactSet``'s convention).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from hand_control.contact.types import ContactSet

__all__ = ["ContactFrame", "SimContact"]


@dataclass(frozen=True)
class SimContact:
    """One contact, world frame (the fields of ``hand_msgs/Contact``)."""

    body1: str
    body2: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    penetration: float
    force: tuple[float, float, float]
    torsional_torque: float
    friction: float


@dataclass(frozen=True, eq=False)
class ContactFrame:
    """K contacts of one step as arrays (world frame).

    Attributes:
        body1, body2: names of the two bodies (a geom name for the world body, e.g. "table").
        body1_id, body2_id: (K,) MuJoCo body ids.
        points: (K, 3) contact points (midpoint between the surfaces) [m].
        normals: (K, 3) unit normals from body 1 into body 2.
        penetration: (K,) penetration depth [m] (>= 0 when overlapping).
        forces: (K, 3) force applied by body 1 on body 2 [N].
        torsional: (K,) torque about the normal applied by body 1 on body 2 [N m].
        friction: (K,) sliding friction coefficient of the pair.
        jacp, jacr: (K, 3, n) translational / rotational Jacobians of body 1's material point
            at each contact over the hand DoFs (``None`` unless asked for).
        time: simulation time [s].
    """

    body1: tuple[str, ...]
    body2: tuple[str, ...]
    body1_id: np.ndarray
    body2_id: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    penetration: np.ndarray
    forces: np.ndarray
    torsional: np.ndarray
    friction: np.ndarray
    jacp: np.ndarray | None = None
    jacr: np.ndarray | None = None
    time: float = 0.0

    def __len__(self) -> int:
        return len(self.body1)

    @classmethod
    def trusted(cls, *values: object) -> ContactFrame:
        """The frame from its field values in order, without the frozen-dataclass ``__init__``
        (the simulator's hot path builds one per control step)."""
        self = object.__new__(cls)
        self.__dict__.update(zip(_FIELDS, values, strict=True))
        return self

    @classmethod
    def empty(cls, time: float = 0.0, n_dof: int | None = None) -> ContactFrame:
        z3 = np.zeros((0, 3))
        jac = None if n_dof is None else np.zeros((0, 3, n_dof))
        return cls((), (), np.zeros(0, int), np.zeros(0, int), z3, z3.copy(), np.zeros(0),
                   z3.copy(), np.zeros(0), np.zeros(0), jac, jac, time)

    def select(self, mask: np.ndarray) -> ContactFrame:
        """The contacts where ``mask`` (K,) is true."""
        idx = np.nonzero(np.asarray(mask, dtype=bool))[0]
        pick = lambda a: None if a is None else a[idx]
        return ContactFrame(
            tuple(self.body1[i] for i in idx), tuple(self.body2[i] for i in idx),
            self.body1_id[idx], self.body2_id[idx], self.points[idx], self.normals[idx],
            self.penetration[idx], self.forces[idx], self.torsional[idx], self.friction[idx],
            pick(self.jacp), pick(self.jacr), self.time)

    def items(self) -> list[SimContact]:
        """The contacts as plain dataclasses."""
        return [SimContact(self.body1[k], self.body2[k], tuple(self.points[k]),
                           tuple(self.normals[k]), float(self.penetration[k]),
                           tuple(self.forces[k]), float(self.torsional[k]),
                           float(self.friction[k])) for k in range(len(self))]

    def net_force_on(self, body_id: int) -> np.ndarray:
        """Sum of the contact forces acting on one body (sign-corrected for either side)."""
        on2 = self.forces[self.body2_id == body_id].sum(axis=0)
        on1 = self.forces[self.body1_id == body_id].sum(axis=0)
        return on2 - on1

    def to_contact_set(self, trusted: bool = False) -> ContactSet:
        """The contacts as the controller's :class:`ContactSet` (forces, Jacobians included).

        ``trusted``: skip the checks, for a frame that :meth:`SimWorld.contacts` produced in
        this process (finite float64 arrays, unit normals; the guard stops the simulation
        before a non-finite state is read).
        """
        if trusted:
            return ContactSet.trusted(self.points, self.normals, self.friction,
                                      forces=self.forces, jacp=self.jacp, jacr=self.jacr)
        return ContactSet(self.points, self.normals, self.friction, forces=self.forces,
                          jacp=self.jacp, jacr=self.jacr)


_FIELDS = tuple(f.name for f in fields(ContactFrame))
