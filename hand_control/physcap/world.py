"""The simulation a capture is optimised in: the hand, the table and the captured object.

Collision geometry is kept simple (seed 000 sec. 4.1 approximates each bone by a few
primitives; contacts dominate a step's cost): the hand's capsules, and for the object its
primitive (box, sphere, cylinder) or, for a mesh, the box of its extents along its principal
axes. The object frame of a capture is the body frame of that primitive (for a mesh: its centre
of mass and principal axes, :func:`mesh_principal_frame`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hand_capture.model.joints import JOINT_NAMES
from hand_capture.model.mjcf import ObjectSpec, build_scene
from hand_control.control import CompositeControlConfig, joint_gains
from hand_control.errors import HandSuiteError
from hand_control.physcap.capture import CapturedObject, CaptureError
from hand_control.sim.config import SimConfig
from hand_control.sim.world import SimWorld

__all__ = ["OBJECT_NAME", "build_capture_world", "mesh_principal_frame", "object_half_height"]

OBJECT_NAME = "object"


def mesh_principal_frame(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mesh's centre of mass (3,), principal axes (3, 3, columns, right-handed) and the
    half extents (3,) of its vertices along them [m] (uniform density, trimesh).

    Raises:
        CaptureError: the file cannot be read as a mesh.
    """
    try:
        import trimesh

        mesh = trimesh.load(str(path), force="mesh")
        com = np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, float)
        inertia = np.asarray(mesh.moment_inertia, float)
    except Exception as e:  # trimesh raises many kinds
        raise CaptureError(f"cannot read mesh {path}: {e}") from e
    _, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    local = (np.asarray(mesh.vertices, float) - com) @ axes
    half = np.maximum(np.abs(local).max(axis=0), 0.002)
    return com, axes, half


def object_spec(obj: CapturedObject) -> ObjectSpec:
    """The MJCF object of a captured object (named :data:`OBJECT_NAME`)."""
    if obj.kind == "mesh":
        _, _, half = mesh_principal_frame(obj.mesh)
        kind, size = "box", tuple(float(h) for h in half)
    else:
        kind = {"box": "box", "sphere": "ball", "cylinder": "stick"}[obj.kind]
        size = obj.size
    return ObjectSpec(kind, name=OBJECT_NAME, size=size, mass=obj.mass, friction=obj.friction,
                      pos=(0.3, 0.3, 0.2))


def object_half_height(obj: CapturedObject, quaternion: np.ndarray) -> float:
    """Half the vertical extent [m] of the object's collision shape at orientation
    ``quaternion`` (w, x, y, z): how high its centre sits when it rests on the table."""
    spec = object_spec(obj)
    w, x, y, z = np.asarray(quaternion, float) / np.linalg.norm(quaternion)
    rot_row_z = np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
    s = np.asarray(spec.size, float)
    if spec.kind == "ball":
        return float(s[0])
    if spec.kind == "stick":  # cylinder along the body x: radius r, half length h
        r, h = s
        c = abs(rot_row_z[0])
        return float(h * c + r * np.sqrt(max(0.0, 1.0 - c * c)))
    return float(np.abs(rot_row_z) @ s)


def build_capture_world(obj: CapturedObject, hand_q: np.ndarray, object_pose: np.ndarray,
                        timestep: float = 0.001, mode: str = "composite"
                        ) -> tuple[SimWorld, CompositeControlConfig]:
    """The world of a capture: its object, the hand and the object placed at ``hand_q``
    (27,) and ``object_pose`` (7,) at rest (the reset state), servos with Table 1's gains.

    Raises:
        CaptureError: the object or the scene cannot be built.
    """
    gains = CompositeControlConfig(mode=mode)
    kp, kd = joint_gains(gains, JOINT_NAMES)
    try:
        xml = build_scene([object_spec(obj)], hand_gravcomp=True, servo_kp=kp, servo_kd=kd)
        world = SimWorld(xml, SimConfig(timestep=timestep))
        world.set_initial_state(np.asarray(hand_q, float), {
            OBJECT_NAME: (object_pose[0:3], object_pose[3:7])})
    except HandSuiteError as e:
        raise CaptureError(f"cannot build the simulation of the capture: {e}") from e
    return world, gains
