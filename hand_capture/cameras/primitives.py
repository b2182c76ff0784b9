"""Triangle meshes of simple scene objects (box, sphere, cylinder, plane) and a scene spec.

Every mesh is closed (except the plane), centred at its origin and wound counter-clockwise
seen from outside, so outward normals are ``(b - a) x (c - a)``. A :class:`SceneObject`
places one of them with a pose; scene files (YAML) list objects as mappings, e.g.::

    objects:
      - {shape: sphere, size: [0.035], position: [0.0, 0.02, 0.45], color: [0.2, 0.4, 0.9]}
      - {shape: box, size: [0.3, 0.02, 0.3], position: [0, 0.12, 0.5]}
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hand_capture.cameras.transforms import rotvec_to_matrix
from hand_capture.errors import ConfigError

__all__ = ["SHAPES", "SceneObject", "box", "cylinder", "make_primitive", "plane",
           "scene_objects_from_mapping", "sphere"]


def box(size: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box with edge lengths ``size`` = (sx, sy, sz) [m]: 8 vertices, 12 faces."""
    sx, sy, sz = (0.5 * float(s) for s in size)
    V = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    # vertex index = 4*ix + 2*iy + iz
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    F = []
    for a, b, c, d in quads:
        F += [(a, b, c), (a, c, d)]
    return V, np.array(F, np.int64)


def sphere(radius: float, n_lat: int = 16, n_lon: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere of ``radius`` [m] with poles on the z axis."""
    r = float(radius)
    V = [(0.0, 0.0, r)]
    for i in range(1, n_lat):
        th = math.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * math.pi * j / n_lon
            V.append((r * math.sin(th) * math.cos(ph), r * math.sin(th) * math.sin(ph),
                      r * math.cos(th)))
    V.append((0.0, 0.0, -r))
    south = len(V) - 1
    F = []
    ring = lambda i, j: 1 + (i - 1) * n_lon + (j % n_lon)
    for j in range(n_lon):
        F.append((0, ring(1, j), ring(1, j + 1)))
        F.append((south, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)))
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            F += [(a, c, d), (a, d, b)]
    return np.array(V), np.array(F, np.int64)


def cylinder(radius: float, height: float, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder of ``radius`` and ``height`` [m] along the z axis."""
    r, h = float(radius), 0.5 * float(height)
    ang = 2 * np.pi * np.arange(n) / n
    ring = np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
    V = np.vstack([np.c_[ring, np.full(n, -h)], np.c_[ring, np.full(n, h)],
                   [[0, 0, -h], [0, 0, h]]])
    cb, ct = 2 * n, 2 * n + 1
    F = []
    for j in range(n):
        k = (j + 1) % n
        F += [(j, k, n + k), (j, n + k, n + j), (cb, k, j), (ct, n + j, n + k)]
    return V, np.array(F, np.int64)


def plane(size: Sequence[float], n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Rectangle of ``size`` = (sx, sy) [m] in the xy plane, front face towards -z.

    Split into ``n`` x ``n`` cells so that a large plane crossing the near plane loses only
    the cells that cross it (renderers skip such faces rather than clipping them).
    """
    n = max(int(n), 1)
    sx, sy = (float(s) for s in size[:2])
    xs = np.linspace(-0.5 * sx, 0.5 * sx, n + 1)
    ys = np.linspace(-0.5 * sy, 0.5 * sy, n + 1)
    X, Y = np.meshgrid(xs, ys)
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])
    return V, F.astype(np.int64)


#: shape name -> (builder, number of size values)
SHAPES = {"box": (box, 3), "sphere": (sphere, 1), "cylinder": (cylinder, 2),
          "plane": (plane, 2)}


def make_primitive(shape: str, size: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of a primitive by name; ConfigError for a bad name or size."""
    if shape not in SHAPES:
        raise ConfigError(f"unknown object shape {shape!r}; valid: {sorted(SHAPES)}")
    fn, n = SHAPES[shape]
    size = [float(s) for s in size]
    if len(size) != n or not all(math.isfinite(s) and s > 0 for s in size):
        raise ConfigError(f"{shape} needs {n} positive size value(s) [m], got {size}")
    return fn(*size) if shape in ("sphere", "cylinder") else fn(size)


@dataclass
class SceneObject:
    """A mesh placed in the world frame: ``x_world = R(rotvec) x + position``.

    Attributes:
        name: label for logs and ground truth.
        vertices, faces: the mesh in its own frame.
        position: [m]; rotvec: rotation vector [rad].
        color: RGB in [0, 1].
        closed: the mesh is closed and wound CCW from outside (back faces may be culled).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotvec: np.ndarray = field(default_factory=lambda: np.zeros(3))
    color: tuple[float, float, float] = (0.35, 0.55, 0.85)
    closed: bool = False

    def __post_init__(self) -> None:
        self.position = np.asarray(self.position, float).reshape(3)
        self.rotvec = np.asarray(self.rotvec, float).reshape(3)
        if not (np.all(np.isfinite(self.position)) and np.all(np.isfinite(self.rotvec))):
            raise ConfigError(f"object {self.name!r}: position/rotvec must be finite")

    @classmethod
    def primitive(cls, shape: str, size: Sequence[float], name: str | None = None,
                  **kw: Any) -> SceneObject:
        V, F = make_primitive(shape, size)
        return cls(name or shape, V, F, closed=shape != "plane", **kw)

    def world_vertices(self, position: np.ndarray | None = None) -> np.ndarray:
        """Vertices in the world frame (optionally at another position)."""
        p = self.position if position is None else np.asarray(position, float)
        return self.vertices @ rotvec_to_matrix(self.rotvec).T + p


def scene_objects_from_mapping(data: Mapping[str, Any] | Sequence[Any] | None
                               ) -> list[SceneObject]:
    """Objects from a parsed scene file (``{objects: [...]}`` or a bare list)."""
    if data is None:
        return []
    items = data.get("objects", []) if isinstance(data, Mapping) else data
    out = []
    for i, item in enumerate(items or []):
        if not isinstance(item, Mapping):
            raise ConfigError(f"scene object #{i} must be a mapping, got {item!r}")
        unknown = set(item) - {"shape", "size", "position", "rotvec", "color", "name"}
        if unknown:
            raise ConfigError(f"scene object #{i}: unknown key(s) {sorted(unknown)}")
        if "shape" not in item or "size" not in item:
            raise ConfigError(f"scene object #{i} needs 'shape' and 'size'")
        size = item["size"] if isinstance(item["size"], Sequence) else [item["size"]]
        kw: dict[str, Any] = {}
        for key in ("position", "rotvec"):
            if key in item:
                kw[key] = np.asarray(item[key], float)
        if "color" in item:
            kw["color"] = tuple(float(c) for c in item["color"])
        out.append(SceneObject.primitive(str(item["shape"]), size,
                                         name=item.get("name", f"{item['shape']}{i}"), **kw))
    return out
