"""Objects to grasp: meshes (OBJ / STL / PLY via trimesh) or MuJoCo primitives, with mass,
friction, inertia and a precomputed signed distance field (dissertation III.4.1.4).

An object is the union of convex parts (what MuJoCo collides with) in its body frame, the
frame of III.3: origin at the centre of mass, z up as it rests on the table. A mesh file that
is not convex keeps its own surface for the distance field, and MuJoCo collides with its
convex hull (``hull_only`` says so).

The signed distance field (positive outside, negative inside, [m]) is a grid: the Euclidean
distance transform of the voxelised occupancy (scipy), then, in a band outside the surface,
the exact distance to the nearest triangle (trimesh); lookups interpolate trilinearly, so the
collision and contact terms of the synthesis are array lookups for any number of points.

Object specs (``parse_object``): a mesh path, or ``KIND[:a,b,...]`` with sizes in metres:
``box:hx,hy,hz``, ``sphere:r``, ``cylinder:r,hh``, ``capsule:r,hh``, ``ellipsoid:a,b,c``,
``mug:r,hh``, ``bottle:r,hh``, ``plate:r,hh``, ``torus:R,r``, ``convex:seed``,
``composite:seed`` (an L of two boxes and a ball, sized by the seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage

from hand_capture.model.mjcf import GeomPart, ObjectSpec
from hand_control.errors import InputError

__all__ = ["GraspObject", "SignedDistanceField", "make_object", "object_from_mesh",
           "parse_object", "PRIMITIVE_KINDS"]

#: kinds ``parse_object`` builds (sizes in metres); defaults of ordinary household items
PRIMITIVE_KINDS: dict[str, tuple[float, ...]] = {
    "box": (0.03, 0.03, 0.03), "sphere": (0.035,), "cylinder": (0.03, 0.06),
    "capsule": (0.025, 0.04), "ellipsoid": (0.04, 0.03, 0.025),
    "mug": (0.032, 0.045), "bottle": (0.032, 0.09), "plate": (0.045, 0.012),
    "torus": (0.045, 0.014), "convex": (0.0,), "composite": (0.0,),
}
_MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb")


class SignedDistanceField:
    """Signed distance grid [m] (> 0 outside) with trilinear lookups.

    Args:
        origin: (3,) position of voxel (0, 0, 0) [m].
        step: voxel size [m].
        values: (nx, ny, nz) signed distances at the voxel centres [m].
    """

    def __init__(self, origin: np.ndarray, step: float, values: np.ndarray) -> None:
        self.origin = np.asarray(origin, dtype=np.float64)
        self.step = float(step)
        self.values = np.ascontiguousarray(values, dtype=np.float64)
        self.shape = np.array(self.values.shape)
        g = np.stack(np.gradient(self.values, self.step), axis=-1)
        self._grad = np.ascontiguousarray(g.reshape(-1, 3))
        self._flat = self.values.reshape(-1)
        self.lo = self.origin
        self.hi = self.origin + (self.shape - 1) * self.step
        nx, ny, nz = self.values.shape
        self._strides = np.array([ny * nz, nz, 1])
        corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        self._offsets = corners @ self._strides

    def _cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corner flat indices (N, 8), trilinear weights (N, 8) and the distance of each
        point outside the grid box (N,)."""
        p = points.reshape(-1, 3)
        c = np.minimum(np.maximum(p, self.lo), self.hi)
        outside = np.sqrt(((p - c) ** 2).sum(axis=1))
        u = (c - self.origin) * (1.0 / self.step)
        i0 = np.minimum(u.astype(np.int64), self.shape - 2)  # u >= 0: truncation = floor
        f = u - i0
        g = 1.0 - f
        fx, fy, fz = f[:, 0:1], f[:, 1:2], f[:, 2:3]
        gx, gy, gz = g[:, 0:1], g[:, 1:2], g[:, 2:3]
        wxy = np.hstack([gx * gy, gx * fy, fx * gy, fx * fy])  # corners (i, j) = 00 01 10 11
        w = np.empty((len(p), 8))
        w[:, 0::2] = wxy * gz
        w[:, 1::2] = wxy * fz
        idx = (i0 @ self._strides)[:, None] + self._offsets
        return idx, w, outside

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (...) of points (..., 3) [m]; beyond the grid, the distance to the
        grid box is added (a lower bound there)."""
        pts = np.asarray(points, dtype=np.float64)
        idx, w, outside = self._cells(pts)
        d = np.einsum("nk,nk->n", self._flat[idx], w) + outside
        return d.reshape(pts.shape[:-1])

    def nearest(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (...) at the nearest voxel centre (one lookup; within half a voxel
        diagonal of the interpolated value): for yes/no penetration tests of many points."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        u = np.rint((pts - self.origin) * (1.0 / self.step)).astype(np.int64)
        inside = (u >= 0).all(axis=1) & (u < self.shape).all(axis=1)
        d = np.full(len(pts), np.inf)  # beyond the grid: outside the object
        d[inside] = self._flat[u[inside] @ self._strides]
        return d.reshape(np.shape(points)[:-1])

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """Unit outward normal direction (..., 3): the normalised interpolated gradient."""
        pts = np.asarray(points, dtype=np.float64)
        idx, w, _ = self._cells(pts)
        g = np.einsum("nk,nkj->nj", w, self._grad[idx])
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        return g.reshape(pts.shape)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearest surface points O (..., 3), outward normals there (..., 3) and the signed
        distances (...) of ``points``: ``O = p - d n`` (one projection step, then the
        normal is read again at O)."""
        d = self(points)
        n = self.gradient(points)
        o = points - d[..., None] * n
        return o, self.gradient(o), d


@dataclass(frozen=True, eq=False)
class GraspObject:
    """An object to grasp (body frame: origin at the centre of mass, z up).

    Attributes:
        name: object name (the MJCF body).
        mesh: its surface, body frame [m].
        parts: the convex collision parts (MuJoCo geoms), body frame.
        mass: [kg]; friction: sliding coefficient; inertia: (3, 3) about the centre of mass
            [kg m^2].
        sdf: the signed distance field of ``mesh``.
        half_extents: (3,) half size of the bounding box about the origin (max |coord|) [m].
        bottom: height of the lowest point below the centre of mass [m] (> 0).
        hull_only: MuJoCo collides with the convex hull of a non-convex mesh file.
        ik_proxy: ``(kind, size, centre)`` of the primitive the fingertip-IK substitute plans
            on (``sim.grasp.plan_grasp``: box / ball / upright stick; centre in the body
            frame [m]), or ``None``.
        spec: the spec it was made from.
    """

    name: str
    mesh: trimesh.Trimesh
    parts: tuple[GeomPart, ...]
    mass: float
    friction: float
    inertia: np.ndarray
    sdf: SignedDistanceField
    half_extents: np.ndarray
    bottom: float
    hull_only: bool = False
    ik_proxy: tuple[str, tuple[float, ...]] | None = None
    spec: str = ""

    def object_spec(self, xy: tuple[float, float] = (0.12, 0.0), yaw: float = 0.0,
                    name: str | None = None) -> ObjectSpec:
        """The MJCF object resting on the table (top at z = 0) at ``xy``, turned by ``yaw``
        about z [rad]."""
        he = self.half_extents
        return ObjectSpec("composite", name=name or self.name,
                          size=(float(he[0]), float(he[1]), float(he[2])), mass=self.mass,
                          friction=self.friction,
                          pos=(float(xy[0]), float(xy[1]), self.bottom + 1e-4),
                          euler=(0.0, 0.0, float(yaw)), parts=self.parts,
                          rgba=(0.3, 0.6, 0.4, 1.0))


# ------------------------------------------------------------------------------------- checks
def check_mesh(mesh: object, what: str = "mesh") -> trimesh.Trimesh:
    """A closed, consistently wound triangle mesh with finite vertices, or a clear error.

    Raises:
        InputError: not a mesh, empty, NaN / infinite vertices, open or non-manifold
            (not watertight), inconsistent winding, or no volume.
    """
    if isinstance(mesh, trimesh.Scene):
        geoms = list(mesh.geometry.values())
        mesh = trimesh.util.concatenate(geoms) if geoms else trimesh.Trimesh()
    if not isinstance(mesh, trimesh.Trimesh):
        raise InputError(f"{what}: not a triangle mesh ({type(mesh).__name__})")
    v = np.asarray(mesh.vertices)
    if len(v) == 0 or len(mesh.faces) == 0:
        raise InputError(f"{what}: empty mesh (no vertices or faces)")
    if not np.isfinite(v).all():
        raise InputError(f"{what}: {int((~np.isfinite(v)).any(axis=1).sum())} vertices are "
                         "NaN or infinite")
    mesh = trimesh.Trimesh(v, np.asarray(mesh.faces), process=True)  # merge duplicates
    if not mesh.is_watertight:
        raise InputError(f"{what}: not a closed manifold surface (open edges or edges shared "
                         "by more than two faces); repair it (e.g. trimesh.repair, or "
                         "Blender's 3D-print toolbox) first")
    if not mesh.is_winding_consistent:
        raise InputError(f"{what}: inconsistent face winding (non-manifold orientation)")
    if mesh.volume <= 0:
        mesh.invert()
    if not mesh.volume > 1e-9:
        raise InputError(f"{what}: encloses no volume ({mesh.volume:.3g} m^3)")
    return mesh


# ------------------------------------------------------------------------------------ parts
def _rot_quat(rot: np.ndarray) -> tuple[float, float, float, float]:
    q = trimesh.transformations.quaternion_from_matrix(np.block(
        [[rot, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
    return tuple(float(x) for x in q)  # w, x, y, z


class _Part:
    """A convex part: its trimesh (for the field, the mass) and MuJoCo geom (type, size) at
    a transform."""

    def __init__(self, mesh: trimesh.Trimesh, gtype: str, size: tuple[float, ...] = (),
                 transform: np.ndarray | None = None) -> None:
        t = np.eye(4) if transform is None else transform
        self.mesh = mesh.copy()
        self.mesh.apply_transform(t)
        self.gtype, self.size, self.transform = gtype, size, t

    def geom(self, shift: np.ndarray) -> GeomPart:
        vol = float(abs(self.mesh.volume))
        if self.gtype == "mesh":
            hull = self.mesh.convex_hull
            v = np.asarray(hull.vertices) - shift
            return GeomPart("mesh", vertices=tuple(v.ravel().tolist()),
                            faces=tuple(int(i) for i in np.asarray(hull.faces).ravel()),
                            volume=vol)
        pos = self.transform[:3, 3] - shift
        return GeomPart(self.gtype, size=self.size, pos=tuple(float(x) for x in pos),
                        quat=_rot_quat(self.transform[:3, :3]), volume=vol)


def _tr(x: float = 0.0, y: float = 0.0, z: float = 0.0, rot: np.ndarray | None = None
        ) -> np.ndarray:
    t = np.eye(4)
    if rot is not None:
        t[:3, :3] = rot
    t[:3, 3] = (x, y, z)
    return t


def _rot_x(a: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(a, (1, 0, 0))[:3, :3]


def _rot_z(a: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(a, (0, 0, 1))[:3, :3]


def _cyl(r: float, hh: float, t: np.ndarray | None = None, sections: int = 40) -> _Part:
    return _Part(trimesh.creation.cylinder(radius=r, height=2 * hh, sections=sections),
                 "cylinder", (r, hh), t)


def _capsule_between(p0: np.ndarray, p1: np.ndarray, r: float) -> _Part:
    d = np.asarray(p1, float) - np.asarray(p0, float)
    length = float(np.linalg.norm(d))
    rot = trimesh.geometry.align_vectors((0, 0, 1), d / length)[:3, :3]
    mid = 0.5 * (np.asarray(p0, float) + np.asarray(p1, float))
    m = trimesh.creation.capsule(height=length, radius=r, count=[12, 12])
    return _Part(m, "capsule", (r, length / 2), _tr(*mid, rot=rot))


def _ring(r_out: float, wall: float, hh: float, z: float, n: int = 16) -> list[_Part]:
    """A cylindrical wall of ``n`` boxes (the convex pieces of a tube)."""
    rm = r_out - wall / 2
    half_w = rm * math.tan(math.pi / n) + 2e-4
    parts = []
    for i in range(n):
        a = 2 * math.pi * i / n
        m = trimesh.creation.box(extents=(wall, 2 * half_w, 2 * hh))
        parts.append(_Part(m, "box", (wall / 2, half_w, hh),
                           _tr(rm * math.cos(a), rm * math.sin(a), z, rot=_rot_z(a))))
    return parts


def _parts_for(kind: str, size: tuple[float, ...]) -> tuple[list[_Part], tuple | None]:
    """The convex parts of a named kind (body frame before centring) and its IK proxy."""
    if kind == "box":
        hx, hy, hz = size
        return [_Part(trimesh.creation.box(extents=(2 * hx, 2 * hy, 2 * hz)), "box",
                      (hx, hy, hz))], ("box", (hx, hy, hz), (0.0, 0.0, 0.0))
    if kind == "sphere":
        r = size[0]
        return [_Part(trimesh.creation.icosphere(subdivisions=3, radius=r), "sphere",
                      (r,))], ("ball", (r,), (0.0, 0.0, 0.0))
    if kind == "cylinder":
        return [_cyl(*size)], ("stick", tuple(size), (0.0, 0.0, 0.0))
    if kind == "capsule":
        r, hh = size
        return [_Part(trimesh.creation.capsule(height=2 * hh, radius=r, count=[24, 24]),
                      "capsule", (r, hh))], ("stick", (r, hh + r), (0.0, 0.0, 0.0))
    if kind == "ellipsoid":
        m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        m.apply_scale(size)
        return [_Part(m, "ellipsoid", tuple(size))], ("box", tuple(size), (0.0, 0.0, 0.0))
    if kind == "mug":  # bottom, a tube of wall boxes, a C-shaped handle of capsules on +y
        r, hh = size
        wall = 0.005
        parts = [_cyl(r, wall / 2, _tr(z=-hh + wall / 2))]
        parts += _ring(r, wall, hh - wall / 2, wall / 2)
        y0, y1, z0, hr = r - 0.002, r + 0.55 * hh, 0.5 * hh, 0.006
        for a, b in (((0, y0, z0), (0, y1, z0)), ((0, y1, z0), (0, y1, -z0)),
                     ((0, y1, -z0), (0, y0, -z0))):
            parts.append(_capsule_between(np.array(a), np.array(b), hr))
        return parts, ("stick", (r, hh), (0.0, 0.0, 0.0))
    if kind == "bottle":  # body, a shoulder (a truncated cone), neck
        r, hh = size
        body_hh = 0.62 * hh
        neck_r, neck_hh = 0.4 * r, 0.2 * hh
        z0, z1 = -hh + 2 * body_hh, hh - 2 * neck_hh
        a = np.linspace(0, 2 * np.pi, 40, endpoint=False)
        ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
        pts = np.vstack([ring * r + (0, 0, z0), ring * neck_r + (0, 0, z1 + 1e-3)])
        shoulder = _Part(trimesh.Trimesh(vertices=pts).convex_hull, "mesh")
        return [_cyl(r, body_hh, _tr(z=-hh + body_hh)), shoulder,
                _cyl(neck_r, neck_hh, _tr(z=hh - neck_hh))], ("stick", (r, body_hh),
                                                             (0.0, 0.0, -hh + body_hh))
    if kind == "plate":
        r, hh = size
        return [_cyl(r, hh, sections=48)], ("box", (r * 0.7, r * 0.7, hh), (0.0, 0.0, 0.0))
    if kind == "torus":  # a ring lying flat: capsules around the circle
        rr, r = size
        n = 12
        pts = [np.array([rr * math.cos(2 * math.pi * i / n), rr * math.sin(2 * math.pi * i / n),
                         0.0]) for i in range(n + 1)]
        return [_capsule_between(pts[i], pts[i + 1], r) for i in range(n)], None
    if kind == "convex":  # random convex hull of points on an ellipsoid, sized by the seed
        rng = np.random.default_rng(int(size[0]))
        axes = rng.uniform(0.022, 0.04, 3)
        axes[2] = rng.uniform(0.025, 0.045)
        d = rng.normal(size=(40, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts = d * axes * rng.uniform(0.8, 1.0, (40, 1))
        pts[:, 2] = np.maximum(pts[:, 2], -0.6 * axes[2])  # a flat base: it rests, not rolls
        hull = trimesh.Trimesh(vertices=pts).convex_hull
        return [_Part(hull, "mesh")], None
    if kind == "composite":  # an L of two boxes with a ball on the long one
        rng = np.random.default_rng(int(size[0]))
        a = rng.uniform(0.045, 0.06)
        w = rng.uniform(0.02, 0.026)
        parts = [_Part(trimesh.creation.box(extents=(2 * a, 2 * w, 2 * w)), "box", (a, w, w)),
                 _Part(trimesh.creation.box(extents=(2 * w, 2 * w, 2 * w)), "box", (w, w, w),
                       _tr(a - w, 0.0, 2 * w)),
                 _Part(trimesh.creation.icosphere(subdivisions=2, radius=w * 1.1), "sphere",
                       (w * 1.1,), _tr(-a + w, 0.0, 0.6 * w))]
        return parts, None
    raise InputError(f"unknown object kind {kind!r}; valid: {sorted(PRIMITIVE_KINDS)} or a mesh "
                     f"file {_MESH_SUFFIXES}")


# ------------------------------------------------------------------------------------ field
def _scene(meshes: list[trimesh.Trimesh]) -> object:
    """An Open3D raycasting scene of the meshes (exact distances and ray-parity occupancy)."""
    import open3d as o3d

    sc = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        sc.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, dtype=np.float32)),
                         o3d.core.Tensor(np.asarray(m.faces, dtype=np.uint32)))
    return sc


def _occupancy(points: np.ndarray, parts: list[trimesh.Trimesh]) -> np.ndarray:
    """Inside the union: inside any closed part (ray parity per part)."""
    import open3d as o3d

    pts = o3d.core.Tensor(np.asarray(points, dtype=np.float32))
    inside = np.zeros(len(points), dtype=bool)
    for m in parts:
        inside |= _scene([m]).compute_occupancy(pts).numpy() > 0.5
    return inside


def _build_sdf(surface: trimesh.Trimesh, parts: list[trimesh.Trimesh], step: float,
               margin: float, max_voxels: int) -> SignedDistanceField:
    """The grid: distance transformation of the occupancy (III.4.1.4, [62]), exact
    distances to the surface (Open3D) in a band outside it."""
    import open3d as o3d

    lo = surface.bounds[0] - margin
    hi = surface.bounds[1] + margin
    step = max(step, float(np.prod(hi - lo) / max_voxels) ** (1 / 3))
    n = np.ceil((hi - lo) / step).astype(int) + 1
    axes = [lo[i] + step * np.arange(n[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = _occupancy(grid, parts).reshape(n)
    d_out = ndimage.distance_transform_edt(~inside) * step - 0.5 * step
    d_in = ndimage.distance_transform_edt(inside) * step - 0.5 * step
    sdf = np.where(inside, -d_in, d_out)
    band = np.abs(sdf) < 3.0 * step
    if band.any():
        pts = o3d.core.Tensor(grid[band.reshape(-1)].astype(np.float32))
        exact = _scene(parts).compute_distance(pts).numpy().astype(np.float64)
        approx = sdf[band]
        # inside, the nearest face may be a face between two overlapping parts (then much
        # nearer than the transform says): keep the transform's depth there
        sdf[band] = np.where(approx > 0, exact,
                             np.where(exact > -approx - step, -exact, approx))
    return SignedDistanceField(lo, step, sdf)


# ------------------------------------------------------------------------------- construction
def _mass_properties(parts: list[trimesh.Trimesh], own_mesh: trimesh.Trimesh | None,
                     mass: float, rng_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass (3,) and inertia about it (3, 3) of the union, uniform density."""
    if own_mesh is not None or len(parts) == 1:
        m = (own_mesh if own_mesh is not None else parts[0]).copy()
        m.density = mass / m.volume
        return np.asarray(m.center_mass), np.asarray(m.moment_inertia)
    # overlapping convex parts: Monte Carlo over the union (the parts' half-spaces)
    lo = np.min([p.bounds[0] for p in parts], axis=0)
    hi = np.max([p.bounds[1] for p in parts], axis=0)
    pts = np.random.default_rng(rng_seed).uniform(lo, hi, (200_000, 3))
    pts = pts[_occupancy(pts, parts)]
    com = pts.mean(axis=0)
    r = pts - com
    inertia = mass * (np.eye(3) * (r ** 2).sum(axis=1).mean() - (r.T @ r) / len(r))
    return com, inertia


def _finish(name: str, parts: list[_Part], own_mesh: trimesh.Trimesh | None, mass: float | None,
            density: float, friction: float, sdf_step: float, ik_proxy: tuple | None,
            spec: str, hull_only: bool = False) -> GraspObject:
    meshes = [p.mesh for p in parts]
    for i, m in enumerate(meshes):
        check_mesh(m, f"{name} part {i}")
    surface = own_mesh if own_mesh is not None else trimesh.util.concatenate(meshes)
    if mass is None:
        vol = own_mesh.volume if own_mesh is not None else sum(m.volume for m in meshes)
        mass = density * float(vol)
    if not (math.isfinite(mass) and 0 < mass <= 50):
        raise InputError(f"object mass must be in (0, 50] kg, got {mass}")
    if not (math.isfinite(friction) and 0 < friction <= 5):
        raise InputError(f"object friction must be in (0, 5], got {friction}")
    com, inertia = _mass_properties(meshes, own_mesh, mass)
    geoms = tuple(p.geom(com) for p in parts)  # before the meshes move to the body frame
    if ik_proxy is not None:  # its centre in the body frame
        ik_proxy = (ik_proxy[0], ik_proxy[1],
                    tuple(float(v) for v in np.asarray(ik_proxy[2]) - com))
    shift = _tr(*(-com))
    for m in meshes:
        m.apply_transform(shift)
    surface = surface.copy()
    surface.apply_transform(shift)
    sdf = _build_sdf(surface, [surface] if own_mesh is not None else meshes, sdf_step, 0.035,
                     400_000)
    ext = np.abs(surface.bounds).max(axis=0)
    return GraspObject(name, surface, geoms, float(mass), float(friction), inertia, sdf, ext,
                       float(-surface.bounds[0, 2]), hull_only, ik_proxy, spec)


def make_object(kind: str, size: tuple[float, ...] = (), mass: float | None = None,
                friction: float = 0.6, name: str | None = None, density: float = 600.0,
                sdf_step: float = 0.002) -> GraspObject:
    """A named kind (see the module docstring) of the given size [m] (default sizes in
    ``PRIMITIVE_KINDS``); ``mass`` [kg] (default: ``density`` [kg/m^3] x volume).

    Raises:
        InputError: unknown kind, wrong number of sizes, non-positive or NaN sizes.
    """
    if kind not in PRIMITIVE_KINDS:
        raise InputError(f"unknown object kind {kind!r}; valid: {sorted(PRIMITIVE_KINDS)}")
    size = tuple(float(s) for s in (size or PRIMITIVE_KINDS[kind]))
    if len(size) != len(PRIMITIVE_KINDS[kind]):
        raise InputError(f"{kind} takes {len(PRIMITIVE_KINDS[kind])} sizes, got {size}")
    seeded = kind in ("convex", "composite")
    if not all(math.isfinite(s) and (s > 0 or seeded) for s in size):
        raise InputError(f"{kind} sizes must be positive and finite [m], got {size}")
    parts, proxy = _parts_for(kind, size)
    spec = f"{kind}:{','.join(f'{s:g}' for s in size)}"
    return _finish(name or kind, parts, None, mass, density, friction, sdf_step, proxy, spec)


def object_from_mesh(path: str | Path, mass: float | None = None, friction: float = 0.6,
                     name: str | None = None, scale: float = 1.0, density: float = 600.0,
                     sdf_step: float = 0.002) -> GraspObject:
    """An object from a mesh file (units: metres x ``scale``; z up as it rests).

    Raises:
        InputError: missing / unreadable file, or a bad mesh (see :func:`check_mesh`).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"mesh file {p} does not exist")
    try:
        mesh = trimesh.load(p, force="mesh", process=False)
    except Exception as e:  # trimesh raises many kinds
        raise InputError(f"mesh file {p}: cannot read it ({e})") from e
    mesh = check_mesh(mesh, str(p))
    if scale != 1.0:
        mesh.apply_scale(scale)
    convex = bool(mesh.is_convex)
    part = _Part(mesh.convex_hull if not convex else mesh, "mesh")
    own = None if convex else mesh
    return _finish(name or p.stem, [part], own, mass, density, friction, sdf_step, None,
                   str(p), hull_only=not convex)


def parse_object(spec: str, mass: float | None = None, friction: float = 0.6,
                 name: str | None = None) -> GraspObject:
    """An object from a spec string: a mesh path or ``KIND[:a,b,...]`` (module docstring).

    Raises:
        InputError: a bad spec, size or mesh.
    """
    text = spec.strip()
    if Path(text).suffix.lower() in _MESH_SUFFIXES or Path(text).is_file():
        return object_from_mesh(text, mass, friction, name)
    kind, _, args = text.partition(":")
    try:
        size = tuple(float(a) for a in args.split(",")) if args else ()
    except ValueError as e:
        raise InputError(f"object spec {spec!r}: sizes must be numbers, e.g. box:0.03,0.03,0.03"
                         ) from e
    return make_object(kind, size, mass, friction, name)
