"""The combined scene model of the multi-view tracker: skinned hands and rigid objects.

Seed 002 (sec. 3) treats both hands and the manipulated object as ONE skinned model whose
configuration is a single vector, with joint limits as linear (box) bounds. Here the hands are
the suite's :class:`~hand_capture.model.HandModel` (LBS, eq. II.8, which is seed 002's eq. (1)
with the subject's shape applied) and every object is a rigid triangle mesh with 6 DoF.

Parameter layout (``SceneModel.n_params`` values; :attr:`SceneModel.slices` names each part's
``slice``, in this order):

* every hand, in the order given (at most one right and one left hand): its 27 DoF in
  :data:`~hand_capture.model.joints.JOINT_NAMES` order: wrist position [m, world], wrist
  orientation as intrinsic XYZ hinge angles [rad], then the finger joints [rad];
* every object: ``tx, ty, tz`` [m, world] of its frame's origin (the mesh centre) and
  ``rx, ry, rz`` [rad], the same intrinsic XYZ angles as a hand's root
  (``R = Rx(rx) Ry(ry) Rz(rz)``, :func:`~hand_capture.model.joints.root_rotation_matrix`).

``lo`` / ``hi`` are the box constraints: the hand's joint limits, a workspace of +-``reach_m``
around the world origin for every position, and free angles (+-inf) for the roots.

Geometry per pose (:meth:`SceneModel.pose` -> :class:`SceneState`): vertices per part [m,
world], faces per part, the bone of every hand vertex (0 for objects), the salient vertices
(the centre of each nail, seed 002 sec. 4.1) and the hands' 21 keypoints.

Projection (:meth:`SceneModel.project`, :meth:`SceneModel.project_jacobian`) uses the rig
camera's pinhole and distortion; the Jacobian of a projected vertex with respect to the
parameters is ``d uv / d x`` (2 x 3, analytic pinhole, distortion by central differences in
normalised coordinates) chained with the part's vertex Jacobian
(:meth:`SceneModel.linearize`, analytic: the hand's LBS Jacobian, the rigid motion's
``a_k x (p - t)`` for objects).

Rendering (:meth:`SceneModel.render`): the suite's numpy z-buffer rasteriser
(:class:`~hand_capture.cameras.render.ZBufferRenderer`) draws every part into a depth map and
a part-label image (0 = nothing, ``i + 1`` = part ``i``), optionally at a reduced ``scale``;
:meth:`SceneModel.visible` gives the vertices seen in that view. Cost: about 5 ms per
640x480 view for two hands and a ball on the 2-core machine, about 2 ms at ``scale = 0.5``
(measured with ``hand-suite bench multiview --quick``, which prints it as ``render_ms``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.render import Mesh, ZBufferRenderer
from hand_capture.errors import ConfigError, InputError
from hand_capture.model import HandModel
from hand_capture.model.joints import (
    JOINT_LIMITS,
    N_DOF,
    root_angles_from_matrix,
    root_rotation_matrix,
)
from hand_capture.model.skeleton import KEYPOINT_BONE
from hand_capture.multiview.rig import RigCamera, distort

__all__ = ["OBJECT_DOF", "SceneModel", "SceneObject", "SceneRender", "SceneState",
           "euler_axes", "object_mesh", "salient_vertices", "scaled_intrinsics"]

#: parameters of a rigid object: position (3) and XYZ angles (3)
OBJECT_DOF = 6
#: distal keypoint pairs (DIP / IP joint, tip) of thumb .. little finger
_NAIL_CHAINS = ((3, 4), (7, 8), (11, 12), (15, 16), (19, 20))


@dataclass(frozen=True)
class SceneObject:
    """A rigid object of the scene: a closed triangle mesh in its own frame.

    Attributes:
        name: the object's name (the studio's body name; ``object/pose`` frame).
        vertices: (V, 3) [m] in the object frame (origin at the centre).
        faces: (F, 3) int32, counter-clockwise seen from outside.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float)
        f = np.asarray(self.faces, dtype=np.int32)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.all(np.isfinite(v)):
            raise ConfigError(f"object {self.name!r}: vertices must be (V >= 4, 3) finite")
        if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v):
            raise ConfigError(f"object {self.name!r}: faces must be (F, 3) vertex indices")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)


def object_mesh(spec: object, edge_m: float = 0.006) -> SceneObject:
    """The mesh of a studio object (:class:`~hand_capture.model.mjcf.ObjectSpec` or its
    kind), subdivided so that no edge is longer than ``edge_m`` [m] (edge and flow
    correspondences need vertices along the object's outline)."""
    import trimesh

    from hand_capture.model.mjcf import ObjectSpec

    s = spec if isinstance(spec, ObjectSpec) else ObjectSpec(str(spec))
    if s.kind == "box":
        m = trimesh.creation.box(extents=[2.0 * x for x in s.size])
    elif s.kind == "ball":
        m = trimesh.creation.icosphere(subdivisions=3, radius=s.size[0])
    elif s.kind == "stick":
        m = trimesh.creation.cylinder(radius=s.size[0], height=2.0 * s.size[1], sections=24)
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    else:  # cup: its outer cylinder (the handle is not modelled)
        m = trimesh.creation.cylinder(radius=s.size[0], height=2.0 * s.size[1], sections=32)
    v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=edge_m)
    m = trimesh.Trimesh(v, f, process=True)
    m.fix_normals()
    return SceneObject(s.name, np.asarray(m.vertices), np.asarray(m.faces))


def salient_vertices(hand: HandModel) -> np.ndarray:
    """(5,) vertex index of each nail's centre (thumb .. little), seed 002 sec. 4.1: the
    vertex of the distal phalanx nearest to a point 60 % of the way from the distal joint
    to the tip, lifted 2 cm dorsally (+z of the rest hand, both sides)."""
    fk = hand.forward(np.zeros(N_DOF))
    kp, v = fk.joint_positions, fk.vertices
    out = np.empty(5, dtype=np.int64)
    for f, (a, b) in enumerate(_NAIL_CHAINS):
        target = kp[a] + 0.6 * (kp[b] - kp[a]) + np.array([0.0, 0.0, 0.02])
        cand = np.flatnonzero(hand.vertex_labels == KEYPOINT_BONE[b])
        out[f] = cand[np.argmin(np.linalg.norm(v[cand] - target, axis=1))]
    return out


def euler_axes(angles: np.ndarray) -> np.ndarray:
    """(3, 3) world axes (rows) of the intrinsic XYZ hinges ``Rx(rx) Ry(ry) Rz(rz)`` at
    ``angles`` (3,): x, then Rx's y column, then (Rx Ry)'s z column."""
    cx, sx = np.cos(angles[0]), np.sin(angles[0])
    cy, sy = np.cos(angles[1]), np.sin(angles[1])
    return np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [sy, -sx * cy, cx * cy]])


@dataclass(frozen=True)
class SceneState:
    """The posed scene (see the module docstring).

    Attributes:
        params: (n_params,) the configuration.
        vertices: per part (V_i, 3) [m, world].
        keypoints: per hand (21, 3) [m, world] (KEYPOINT_NAMES order).
        object_poses: per object (4, 4) world <- object.
    """

    params: np.ndarray
    vertices: tuple[np.ndarray, ...]
    keypoints: tuple[np.ndarray, ...]
    object_poses: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class SceneRender:
    """One camera's rendering of a :class:`SceneState`.

    Attributes:
        depth: (h, w) float32 z-depth [m], 0 where nothing is hit (h, w = scale * image).
        labels: (h, w) uint8: 0 nothing, ``i + 1`` part ``i``.
        scale: the image scale it was rendered at (pixel (u, v) of the full image is
            ``(u * scale, v * scale)`` here, up to the half-pixel convention).
    """

    depth: np.ndarray
    labels: np.ndarray
    scale: float


class SceneModel:
    """Hands plus rigid objects with one parameter vector; see the module docstring.

    Args:
        hands: one or two :class:`HandModel` (the subjects' shapes), at most one per side.
        objects: the rigid objects (:class:`SceneObject`, e.g. from :func:`object_mesh`).
        reach_m: half-size of the workspace box every position is bounded to [m].
        wrist_cut_m: hand vertices closer than this to the wrist plane (rest x) [m] are not
            used as edge vertices (see :attr:`edge_usable`).
        salient: per hand, the salient vertices (default: the nail centres,
            :func:`salient_vertices`; a detector trained on other points gives its own).
    """

    def __init__(self, hands: Sequence[HandModel], objects: Sequence[SceneObject] = (),
                 reach_m: float = 3.0, wrist_cut_m: float = 0.015,
                 salient: Sequence[np.ndarray] | None = None) -> None:
        hands = tuple(hands)
        if not 1 <= len(hands) <= 2 or not all(isinstance(h, HandModel) for h in hands):
            raise ConfigError("a scene holds one or two HandModel hands")
        sides = [h.side for h in hands]
        if len(set(sides)) != len(sides):
            raise ConfigError(f"one hand per side, got {sides}")
        if not reach_m > 0:
            raise ConfigError(f"reach_m must be > 0 m, got {reach_m}")
        self.hands = hands
        self.objects = tuple(objects)
        names = [*sides, *(o.name for o in self.objects)]
        if len(set(names)) != len(names):
            raise ConfigError(f"part names must be unique, got {names}")
        self.part_names: tuple[str, ...] = tuple(names)
        self.n_hands = len(hands)
        self.slices: dict[str, slice] = {}
        lo, hi = [], []
        start = 0
        for name in names[: self.n_hands]:
            self.slices[name] = slice(start, start + N_DOF)
            lim = JOINT_LIMITS.copy()
            lim[:3] = (-reach_m, reach_m)
            lo.append(lim[:, 0])
            hi.append(lim[:, 1])
            start += N_DOF
        for name in names[self.n_hands:]:
            self.slices[name] = slice(start, start + OBJECT_DOF)
            lo.append([-reach_m] * 3 + [-np.inf] * 3)
            hi.append([reach_m] * 3 + [np.inf] * 3)
            start += OBJECT_DOF
        self.n_params = start
        self.lo = np.concatenate(lo).astype(float)
        self.hi = np.concatenate(hi).astype(float)
        self.lo.setflags(write=False)
        self.hi.setflags(write=False)
        self.faces: tuple[np.ndarray, ...] = (*(h.faces for h in hands),
                                              *(o.faces for o in self.objects))
        self.salient: tuple[np.ndarray, ...] = tuple(
            salient_vertices(h) for h in hands) if salient is None else tuple(
            np.asarray(s, dtype=np.int64) for s in salient)
        if len(self.salient) != len(hands):
            raise ConfigError("give the salient vertices of every hand")
        self.vertex_bones: tuple[np.ndarray, ...] = (
            *(h.vertex_labels for h in hands),
            *(np.zeros(len(o.vertices), dtype=np.int64) for o in self.objects))
        self.n_vertices = tuple(len(b) for b in self.vertex_bones)
        #: per part, the vertices whose outline can be matched to image edges: not the
        #: hand's wrist cap, where the real forearm continues the silhouette
        self.edge_usable: tuple[np.ndarray, ...] = (
            *(h.rest_vertices[:, 0] > wrist_cut_m for h in hands),
            *(np.ones(len(o.vertices), bool) for o in self.objects))
        self._renderer = ZBufferRenderer(near=0.02)
        self._edges = tuple(_edge_faces(f) for f in self.faces)

    # ------------------------------------------------------------------------ parameters
    def part_index(self, name: str) -> int:
        """Index of a part (``'right'``, ``'left'`` or an object's name)."""
        try:
            return self.part_names.index(name)
        except ValueError:
            raise InputError(f"no part {name!r}; parts: {list(self.part_names)}") from None

    def part_params(self, params: np.ndarray, part: int) -> np.ndarray:
        """The slice of ``params`` of part ``part``."""
        return params[self.slices[self.part_names[part]]]

    def check(self, params: object) -> np.ndarray:
        """``params`` as a finite (n_params,) float array (InputError otherwise)."""
        p = np.asarray(params, dtype=float).reshape(-1)
        if p.shape != (self.n_params,) or not np.all(np.isfinite(p)):
            raise InputError(f"scene params must be {self.n_params} finite values, got "
                             f"{p.shape}")
        return p

    def clip(self, params: np.ndarray) -> np.ndarray:
        """``params`` clipped into the box ``[lo, hi]``."""
        return np.clip(params, self.lo, self.hi)

    def pack(self, hand_poses: Sequence[np.ndarray], object_poses: Sequence[np.ndarray] = ()
             ) -> np.ndarray:
        """Parameters from 27-DoF hand poses (hand order) and (4, 4) object poses."""
        if len(hand_poses) != self.n_hands or len(object_poses) != len(self.objects):
            raise InputError(f"need {self.n_hands} hand poses and {len(self.objects)} object "
                             f"poses, got {len(hand_poses)} and {len(object_poses)}")
        out = np.zeros(self.n_params)
        for i, q in enumerate(hand_poses):
            out[self.slices[self.part_names[i]]] = np.asarray(q, dtype=float).reshape(N_DOF)
        for i, T in enumerate(object_poses):
            T = np.asarray(T, dtype=float)
            sl = self.slices[self.objects[i].name]
            out[sl] = np.concatenate([T[:3, 3], root_angles_from_matrix(T[:3, :3])])
        return out

    @staticmethod
    def object_transform(p6: np.ndarray) -> np.ndarray:
        """(4, 4) world <- object of an object's 6 parameters."""
        T = np.eye(4)
        T[:3, :3] = root_rotation_matrix(p6[3:6])
        T[:3, 3] = p6[:3]
        return T

    # --------------------------------------------------------------------------- geometry
    def pose(self, params: object) -> SceneState:
        """Every part posed at ``params`` (InputError on a malformed vector)."""
        p = self.check(params)
        verts, kps, objs = [], [], []
        for i, h in enumerate(self.hands):
            fk = h.forward(self.part_params(p, i))
            verts.append(fk.vertices)
            kps.append(fk.joint_positions)
        for j, o in enumerate(self.objects):
            T = self.object_transform(self.part_params(p, self.n_hands + j))
            verts.append(o.vertices @ T[:3, :3].T + T[:3, 3])
            objs.append(T)
        return SceneState(p, tuple(verts), tuple(kps), tuple(objs))

    def linearize(self, params: np.ndarray, part: int, vertex_idx: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Vertices ``vertex_idx`` of part ``part`` (N, 3) [m] and their Jacobian
        (N, 3, n_part) with respect to that part's parameters (analytic)."""
        pp = self.part_params(params, part)
        idx = np.asarray(vertex_idx, dtype=np.int64)
        if part < self.n_hands:
            return self.hands[part].linearize(pp, idx)
        o = self.objects[part - self.n_hands]
        T = self.object_transform(pp)
        pts = o.vertices[idx] @ T[:3, :3].T + T[:3, 3]
        jac = np.empty((len(idx), 3, OBJECT_DOF))
        jac[:, :, :3] = np.eye(3)
        rel = pts - T[:3, 3]
        for k, a in enumerate(euler_axes(pp[3:6])):   # d p / d angle_k = a_k x (p - t)
            jac[:, :, 3 + k] = np.cross(a, rel)
        return pts, jac

    # ------------------------------------------------------------------------- projection
    @staticmethod
    def project(camera: RigCamera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) [px] of world points (N, 3) and a (N,) in-front mask (z > 2 cm)."""
        pc = (np.asarray(points, dtype=float).reshape(-1, 3) - camera.t_wc) @ camera.R_wc
        z = pc[:, 2]
        front = z > 0.02
        zs = np.where(front, z, 1.0)
        x, y = pc[:, 0] / zs, pc[:, 1] / zs
        k = camera.intrinsics
        if any(k.distortion):
            x, y = distort(x, y, k.distortion)
        return np.stack([k.fx * x + k.cx, k.fy * y + k.cy], axis=1), front

    @staticmethod
    def project_jacobian(camera: RigCamera, points: np.ndarray) -> np.ndarray:
        """d uv / d x (N, 2, 3) [px / m] of world points (N, 3): the pinhole derivative
        (analytic) times the distortion's (central differences, skipped when there is none),
        times the world -> camera rotation."""
        pc = camera.to_camera(np.asarray(points, dtype=float).reshape(-1, 3))
        z = np.where(pc[:, 2] > 1e-9, pc[:, 2], 1e-9)
        x, y = pc[:, 0] / z, pc[:, 1] / z
        dn = np.zeros((len(pc), 2, 3))       # d (x, y) / d pc
        dn[:, 0, 0] = 1.0 / z
        dn[:, 0, 2] = -x / z
        dn[:, 1, 1] = 1.0 / z
        dn[:, 1, 2] = -y / z
        k = camera.intrinsics
        dd = np.zeros((len(pc), 2, 2))
        if any(abs(c) > 0 for c in k.distortion):
            h = 1e-6
            for j, (ex, ey) in enumerate(((h, 0.0), (0.0, h))):
                xp, yp = distort(x + ex, y + ey, k.distortion)
                xm, ym = distort(x - ex, y - ey, k.distortion)
                dd[:, 0, j] = (xp - xm) / (2 * h)
                dd[:, 1, j] = (yp - ym) / (2 * h)
        else:
            dd[:, 0, 0] = dd[:, 1, 1] = 1.0
        f = np.array([k.fx, k.fy])[None, :, None]
        return (f * dd) @ dn @ camera.R_wc.T[None]

    # -------------------------------------------------------------------------- rendering
    def render(self, camera: RigCamera, state: SceneState, scale: float = 1.0,
               parts: Sequence[int] | None = None) -> SceneRender:
        """Depth and part labels of ``state`` seen by ``camera`` (lens distortion ignored),
        at ``scale`` times the camera's resolution, drawing ``parts`` (default: all); see the
        module docstring for its cost."""
        if not 0.05 <= scale <= 1.0:
            raise InputError(f"render scale must be in [0.05, 1], got {scale}")
        intr = scaled_intrinsics(camera.intrinsics, scale)
        draw = range(len(self.part_names)) if parts is None else parts
        meshes = [Mesh(camera.to_camera(state.vertices[i]), self.faces[i], label=i + 1,
                       closed=True) for i in draw]
        res = self._renderer.render(meshes, intr)
        return SceneRender(res.depth, res.label, scale)

    def contour(self, camera: RigCamera, state: SceneState, part: int) -> np.ndarray:
        """(V,) bool: the vertices of part ``part`` on its contour seen from ``camera``,
        i.e. on a mesh edge between a face turned to the camera and one turned away. They
        project exactly onto the part's outline (where it is not occluded); vertices merely
        near the rendered outline lie up to a pixel inside it."""
        v = state.vertices[part]
        f = self.faces[part]
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        front = np.einsum("ij,ij->i", n, v[f[:, 0]] - camera.t_wc) < 0
        ev, ef = self._edges[part]
        on = front[ef[:, 0]] != front[ef[:, 1]]
        out = np.zeros(len(v), bool)
        out[ev[on].ravel()] = True
        return out

    def salient_seen(self, camera: RigCamera, state: SceneState, render: SceneRender,
                     hand: int, tol_m: float = 0.015) -> np.ndarray:
        """(5,) bool: the salient vertices of ``hand`` whose fingertip ``camera`` sees: at the
        vertex's rendered pixel, the nearest rendered surface (of any part) at most ``tol_m``
        from the vertex, or no surface (the tip on the outline, over the background).
        ``tol_m`` is a fingertip's thickness: a fingertip detector fires on the tip whether
        its nail or its pad faces the camera, and on a tip pressed on an object; another
        finger or the object farther in front hides it. :meth:`visible` answers for the
        vertex itself (6 mm), which drops the tips seen from the pad side. Testing only this
        hand's surface there (not the nearest one) dropped tips the detector sees: on the
        (rendered) outline and pressed on an object."""
        _, z, row, col, ok = self._render_pixels(camera, state.vertices[hand][self.salient[hand]],
                                                 render)
        out = np.zeros(len(z), bool)
        idx = np.flatnonzero(ok)
        d = render.depth[row[idx], col[idx]]
        out[idx] = (d == 0) | (np.abs(d - z[idx]) <= tol_m)
        return out

    def visible(self, camera: RigCamera, state: SceneState, render: SceneRender,
                part: int, tol_m: float = 0.006) -> tuple[np.ndarray, np.ndarray]:
        """Visible vertices of part ``part`` in ``render``: (indices (n,), pixels (n, 2)).

        A vertex is visible when it projects inside the image in front of the camera and is
        not behind the rendered surface by more than ``tol_m`` (vertices on the outline,
        where the rendered pixel misses the part, count as visible)."""
        uv, z, row, col, ok = self._render_pixels(camera, state.vertices[part], render)
        idx = np.flatnonzero(ok)
        d = render.depth[row[idx], col[idx]]
        lab = render.labels[row[idx], col[idx]]
        seen = (d == 0) | ((lab == part + 1) & (z[idx] <= d + tol_m)) | (z[idx] <= d + 1e-4)
        idx = idx[seen]
        return idx, uv[idx]

    def _render_pixels(self, camera: RigCamera, v: np.ndarray, render: SceneRender
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Where points ``v`` (n, 3) [m, world] fall in ``render``: their image points (n, 2)
        [px, full resolution], camera depths (n,) [m], the row and column (n,) of the scaled
        pixel each is in, and whether that pixel is inside the render and the point in
        front of the camera (n,)."""
        uv, front = self.project(camera, v)
        z = camera.to_camera(v)[:, 2]
        h, w = render.depth.shape
        col = np.floor((uv[:, 0] + 0.5) * render.scale).astype(np.int64)
        row = np.floor((uv[:, 1] + 0.5) * render.scale).astype(np.int64)
        ok = front & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        return uv, z, row, col, ok


def _edge_faces(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior edges of a triangle mesh: (E, 2) vertex pairs and (E, 2) their two faces
    (edges with one face or more than two are left out)."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    fid = np.tile(np.arange(len(f)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, fid = key[order], fid[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    i = np.flatnonzero(same)
    # keep pairs that are exactly two faces (not part of a run of three or more)
    ok = np.ones(len(i), bool)
    if len(i) > 1:
        run = np.diff(i) == 1
        ok[1:] &= ~run
        ok[:-1] &= ~run
    i = i[ok]
    return key[i], np.stack([fid[i], fid[i + 1]], axis=1)


def scaled_intrinsics(intr: Intrinsics, scale: float) -> Intrinsics:
    """Pinhole of the same camera at ``scale`` times its resolution (no distortion)."""
    if scale == 1.0 and not any(intr.distortion):
        return intr
    w, h = max(1, round(intr.width * scale)), max(1, round(intr.height * scale))
    return Intrinsics(w, h, intr.fx * scale, intr.fy * scale, (intr.cx + 0.5) * scale - 0.5,
                      (intr.cy + 0.5) * scale - 0.5, intr.distortion_model,
                      (0.0,) * len(intr.distortion), intr.frame_id)
