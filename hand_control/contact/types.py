"""Contacts between the hand and an object, as arrays, validated once.

Conventions (the same as ``hand_msgs/Contact``): every vector is in the world frame; the normal
points from the hand body into the object; a force or torsional torque is the one the hand
applies on the object.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_control.errors import InputError

__all__ = ["ContactSet", "as_finite_array"]


def as_finite_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` (``None`` = any length) with finite entries.

    Raises:
        InputError: naming ``name``, for a wrong shape, NaN/Inf or a non-numeric value.
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name} is not a numeric array: {e}") from e
    if arr.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(arr.shape, shape, strict=True)
    ):
        want = "x".join("N" if s is None else str(s) for s in shape) or "scalar"
        raise InputError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name} contains NaN or Inf")
    return arr



def unchecked(cls: type, **fields: object) -> object:
    """An instance of the frozen dataclass ``cls`` built without ``__init__`` and its checks:
    the ``trusted`` constructors of the control loop's hot path use it."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)  # a frozen dataclass without slots keeps its fields there
    return obj

@dataclass(frozen=True, eq=False)
class ContactSet:
    """K contacts between the hand and one object.

    Attributes:
        points: (K, 3) contact points [m].
        normals: (K, 3) contact normals, hand -> object; normalised on construction.
        mu: (K,) Coulomb friction coefficients (a scalar is broadcast), >= 0.
        forces: (K, 3) contact forces the simulator applied on the object [N], needed by the
            seed-000 method (eq. 10 scales them); ``None`` otherwise.
        jacp: (K, 3, nv) translational Jacobians of the hand point at each contact
            (d point / d q), needed to map forces to joint torques (eq. 12 / III.21).
        jacr: (K, 3, nv) rotational Jacobians of the hand body at each contact, needed to map
            torsional torques to joint torques.
    """

    points: np.ndarray
    normals: np.ndarray
    mu: np.ndarray
    forces: np.ndarray | None = None
    jacp: np.ndarray | None = None
    jacr: np.ndarray | None = None

    def __post_init__(self) -> None:
        points = as_finite_array("contact points", self.points, (None, 3))
        k = points.shape[0]
        normals = as_finite_array("contact normals", self.normals, (k, 3))
        norm = np.linalg.norm(normals, axis=1)
        if (norm < 1e-9).any():
            raise InputError("contact normals must be non-zero vectors")
        mu = np.full(k, self.mu) if np.ndim(self.mu) == 0 else self.mu
        mu = as_finite_array("friction coefficients mu", mu, (k,))
        if (mu < 0).any():
            raise InputError(f"friction coefficients must be >= 0, got {mu.tolist()}")
        set_ = object.__setattr__
        set_(self, "points", points)
        set_(self, "normals", normals / norm[:, None])
        set_(self, "mu", mu)
        if self.forces is not None:
            set_(self, "forces", as_finite_array("contact forces", self.forces, (k, 3)))
        nv = None
        for name in ("jacp", "jacr"):
            jac = getattr(self, name)
            if jac is None:
                continue
            jac = as_finite_array(f"contact Jacobians {name}", jac, (k, 3, nv))
            nv = jac.shape[2]
            set_(self, name, jac)

    @classmethod
    def trusted(
        cls, points: np.ndarray, normals: np.ndarray, mu: np.ndarray,
        forces: np.ndarray | None = None, jacp: np.ndarray | None = None,
        jacr: np.ndarray | None = None,
    ) -> ContactSet:
        """Without the checks, for arrays a simulator produced (the hot path of the control
        loop): the caller vouches for float64, finite, matching shapes, unit normals and
        ``mu`` (K,) >= 0. Nothing is copied."""
        return unchecked(cls, points=points, normals=normals, mu=mu, forces=forces,
                         jacp=jacp, jacr=jacr)

    def __len__(self) -> int:
        return self.points.shape[0]

    @property
    def nv(self) -> int | None:
        """Number of hand DoFs the Jacobians act on (``None`` without Jacobians)."""
        jac = self.jacp if self.jacp is not None else self.jacr
        return None if jac is None else jac.shape[2]
