"""CPU depth/label renderers for triangle meshes seen by a pinhole camera (no OpenGL).

Three interchangeable renderers produce the same :class:`RenderResult` (depth in metres, the
face and label seen at each pixel, the cosine of the incidence angle):

* :class:`ZBufferRenderer` -- vectorised numpy rasteriser (the default). The pixel centres
  of every triangle's bounding box are enumerated exactly (face by face, flat; boxes over
  ``_TILE`` pixels in tiles) and tested with edge functions at once, depth is interpolated
  perspective-correctly (1/z is affine in screen space) and the nearest candidate per pixel
  wins through one ``np.minimum.at`` on a packed (depth, face) key, in a buffer spanning the
  candidates' rows only.
* :class:`RaycastRenderer` -- Open3D's ``t.geometry.RaycastingScene`` (BVH rebuilt per frame,
  rays cast only inside the projected bounding box of the scene).
* :class:`NaiveRenderer` -- a per-triangle Python loop; the baseline of the benchmark.

All three use the OpenCV pixel convention (pixel (i, j) samples the ray through u = j,
v = i) and count a pixel centre on a shared edge as inside, so watertight meshes leave no
cracks. Meshes must be given in the camera optical frame (z forward, metres).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import ConfigError, InputError

__all__ = [
    "Mesh",
    "NaiveRenderer",
    "RaycastRenderer",
    "RenderResult",
    "Renderer",
    "ZBufferRenderer",
    "make_renderer",
]

_NONE = np.uint64(np.iinfo(np.uint64).max)
_FACE_BITS = np.uint64(24)  # packed key: depth [um] << 24 | face index (16.7 M faces max)
_DEPTH_Q = 1e6  # depth quantum of the key: 1 um
_TILE = 128  # faces with a larger pixel box are rasterised in tiles of this size
_TILES_PER_CHUNK = 16  # tiles tested at once (16 * 128^2 candidates)
_CANDIDATES = 1 << 18  # pixel centres of small faces' boxes tested at once (about)


@dataclass
class Mesh:
    """A triangle mesh in the camera optical frame.

    Attributes:
        vertices: (V, 3) positions [m].
        faces: (F, 3) vertex indices.
        label: label written into :attr:`RenderResult.label` where the mesh is seen
            (1 = hand by convention, 2.. = objects; 0 is the background).
        color: RGB in [0, 1] used by the colour shader.
        closed: the mesh is closed and wound counter-clockwise seen from outside, so faces
            turned away from the camera can be culled (renderers with ``cull_backfaces``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    label: int = 1
    color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    closed: bool = False

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.faces = np.asarray(self.faces)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise InputError(f"Mesh.vertices must be (V, 3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise InputError(f"Mesh.faces must be (F, 3), got {self.faces.shape}")
        if not np.issubdtype(self.faces.dtype, np.integer):
            raise InputError(f"Mesh.faces must be integers, got {self.faces.dtype}")
        if self.faces.size and (self.faces.min() < 0
                                or self.faces.max() >= len(self.vertices)):
            raise InputError("Mesh.faces index a vertex that does not exist")
        if not np.all(np.isfinite(self.vertices)):
            raise InputError("Mesh.vertices contain NaN or Inf")
        if not 0 <= int(self.label) <= 255:
            raise InputError(f"Mesh.label must be in [0, 255], got {self.label}")

    def transformed(self, R: np.ndarray, t: np.ndarray) -> Mesh:
        """A copy with vertices mapped by ``x -> R x + t``."""
        return Mesh(self.vertices @ np.asarray(R).T + np.asarray(t), self.faces, self.label,
                    self.color, self.closed)


@dataclass
class RenderResult:
    """What a renderer saw.

    Attributes:
        depth: (H, W) float32 z-depth [m] along the optical axis, 0 where nothing was hit.
        face: (H, W) int32 index of the visible face in the concatenated scene, -1 if none.
        label: (H, W) uint8 label of the visible mesh, 0 if none.
        cos_incidence: (H, W) float32 |cos| of the angle between the face normal and the
            viewing ray (1 = facing the camera, 0 = grazing), 0 where nothing was hit.
    """

    depth: np.ndarray
    face: np.ndarray
    label: np.ndarray
    cos_incidence: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(H, W) bool, True where a surface was hit."""
        return self.face >= 0


class _Scene:
    """Meshes concatenated into one vertex/face array with a label per face."""

    def __init__(self, meshes: Sequence[Mesh], near: float) -> None:
        self.near = near
        if not meshes:
            self.V = np.zeros((0, 3))
            self.F = np.zeros((0, 3), np.int64)
            self.face_label = np.zeros(0, np.uint8)
            self.face_closed = np.zeros(0, bool)
            return
        if len(meshes) == 1:
            m = meshes[0]
            self.V = m.vertices
            self.F = m.faces.astype(np.int64, copy=False)
            self.face_label = np.full(len(m.faces), int(m.label), np.uint8)
            self.face_closed = np.full(len(m.faces), bool(m.closed))
            return
        Vs, Fs, Ls, Cs = [], [], [], []
        off = 0
        for m in meshes:
            Vs.append(m.vertices)
            Fs.append(m.faces.astype(np.int64) + off)
            Ls.append(np.full(len(m.faces), int(m.label), np.uint8))
            Cs.append(np.full(len(m.faces), bool(m.closed)))
            off += len(m.vertices)
        self.V = np.concatenate(Vs)
        self.F = np.concatenate(Fs)
        self.face_label = np.concatenate(Ls)
        self.face_closed = np.concatenate(Cs)

    def face_normals(self, faces: np.ndarray) -> np.ndarray:
        """Unit normals (N, 3) of the given faces ((b - a) x (c - a) direction)."""
        F = self.F[faces]
        a = self.V[F[:, 0]]
        e1 = self.V[F[:, 1]] - a
        e2 = self.V[F[:, 2]] - a
        n = np.empty_like(e1)
        n[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
        n[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
        n[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        norm = np.sqrt(np.einsum("ij,ij->i", n, n))
        return n / np.maximum(norm, 1e-30)[:, None]


_RAYS: dict[tuple, np.ndarray] = {}


def unit_rays(intr: Intrinsics) -> np.ndarray:
    """(H*W, 3) unit viewing rays of every pixel (cached per intrinsics)."""
    key = (intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)
    rays = _RAYS.get(key)
    if rays is None:
        a, b = intr.ray_grid()
        d = np.stack([a.ravel(), b.ravel(), np.ones(a.size)], 1)
        rays = d / np.linalg.norm(d, axis=1, keepdims=True)
        rays.setflags(write=False)
        if len(_RAYS) > 16:
            _RAYS.clear()
        _RAYS[key] = rays
    return rays


def _finish(scene: _Scene, intr: Intrinsics, pix: np.ndarray, depth: np.ndarray,
            face: np.ndarray) -> RenderResult:
    """Assemble a RenderResult from the visible pixels (flat indices) and their faces."""
    H, W = intr.height, intr.width
    out_depth = np.zeros(H * W, np.float32)
    out_face = np.full(H * W, -1, np.int32)
    out_label = np.zeros(H * W, np.uint8)
    out_cos = np.zeros(H * W, np.float32)
    if pix.size:
        out_depth[pix] = depth
        out_face[pix] = face
        out_label[pix] = scene.face_label[face]
        n = scene.face_normals(face)
        out_cos[pix] = np.abs(np.einsum("ij,ij->i", n, unit_rays(intr)[pix]))
    return RenderResult(out_depth.reshape(H, W), out_face.reshape(H, W),
                        out_label.reshape(H, W), out_cos.reshape(H, W))


class Renderer:
    """Base class: ``render(meshes, intrinsics) -> RenderResult``."""

    name = "renderer"

    def __init__(self, near: float = 0.01) -> None:
        if not near > 0:
            raise ConfigError(f"renderer near plane must be > 0 m, got {near}")
        self.near = float(near)

    def render(self, meshes: Sequence[Mesh], intr: Intrinsics) -> RenderResult:
        scene = _Scene(meshes, self.near)
        if len(scene.F) == 0:
            return _finish(scene, intr, np.zeros(0, np.int64), np.zeros(0), np.zeros(0, int))
        pix, depth, face = self._visible(scene, intr)
        return _finish(scene, intr, pix, depth, face)

    def _visible(self, scene: _Scene, intr: Intrinsics
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        raise NotImplementedError


def _min3(a, b, c):
    return np.minimum(np.minimum(a, b), c)


def _max3(a, b, c):
    return np.maximum(np.maximum(a, b), c)


@dataclass
class _Faces:
    """Screen-space data of the faces that can cover a pixel centre (one row per face)."""

    idx: np.ndarray  # index into the scene's faces
    u: tuple[np.ndarray, np.ndarray, np.ndarray]  # pixel coordinates of the 3 corners
    v: tuple[np.ndarray, np.ndarray, np.ndarray]
    iz: tuple[np.ndarray, np.ndarray, np.ndarray]  # 1 / z of the 3 corners
    inv_area: np.ndarray  # 1 / (twice the signed screen area)
    umin: np.ndarray  # inclusive pixel bounding box, clipped to the image
    umax: np.ndarray
    vmin: np.ndarray
    vmax: np.ndarray


def _project_faces(scene: _Scene, intr: Intrinsics, near: float,
                   cull_backfaces: bool) -> _Faces:
    V, F = scene.V, scene.F
    z = V[:, 2]
    zs = np.where(z > near, z, np.inf)
    iz = 1.0 / zs
    u = intr.fx * V[:, 0] * iz + intr.cx
    v = intr.fy * V[:, 1] * iz + intr.cy
    f0, f1, f2 = F[:, 0], F[:, 1], F[:, 2]
    u0, u1, u2 = u[f0], u[f1], u[f2]
    v0, v1, v2 = v[f0], v[f1], v[f2]
    iz0, iz1, iz2 = iz[f0], iz[f1], iz[f2]
    # faces touching the near plane have iz == 0 at a corner and are dropped
    keep = (iz0 > 0) & (iz1 > 0) & (iz2 > 0)
    umin = np.maximum(np.ceil(_min3(u0, u1, u2)), 0)
    umax = np.minimum(np.floor(_max3(u0, u1, u2)), intr.width - 1)
    vmin = np.maximum(np.ceil(_min3(v0, v1, v2)), 0)
    vmax = np.minimum(np.floor(_max3(v0, v1, v2)), intr.height - 1)
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    keep &= (umin <= umax) & (vmin <= vmax) & (np.abs(area) > 1e-12)
    if cull_backfaces and scene.face_closed.any():
        # Closed meshes wound CCW from outside: a face whose normal points at the camera
        # (n . v0 < 0) has a negative signed screen area with u right and v down (z > 0);
        # the others are back faces, hidden behind the front of the same closed mesh.
        keep &= ~scene.face_closed | (area < 0)
    k = np.flatnonzero(keep)
    return _Faces(k, (u0[k], u1[k], u2[k]), (v0[k], v1[k], v2[k]), (iz0[k], iz1[k], iz2[k]),
                  1.0 / area[k], umin[k].astype(np.int64), umax[k].astype(np.int64),
                  vmin[k].astype(np.int64), vmax[k].astype(np.int64))


class ZBufferRenderer(Renderer):
    """Vectorised numpy z-buffer rasteriser (see the module docstring).

    Args:
        near: near clipping distance [m]; faces with a vertex closer are skipped.
        cull_backfaces: skip the back faces of meshes marked ``closed`` (outward CCW
            winding); about halves the work. Open meshes are always two-sided.
    """

    name = "zbuffer"

    def __init__(self, near: float = 0.01, cull_backfaces: bool = True) -> None:
        super().__init__(near)
        self.cull_backfaces = bool(cull_backfaces)
        self._grids: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _grid(self, s: int) -> tuple[np.ndarray, np.ndarray]:
        if s not in self._grids:
            oy, ox = np.divmod(np.arange(s * s), s)
            self._grids[s] = (ox[None, :], oy[None, :])
        return self._grids[s]

    @staticmethod
    def _test(fc: _Faces, fi: np.ndarray, px: np.ndarray, py: np.ndarray, W: int
              ) -> tuple[np.ndarray, np.ndarray] | None:
        """Pixel centres (px, py) against faces ``fi`` (indices into fc), element by element:
        the covered ones as flat pixel indices and packed (depth, face) keys."""
        (U0, U1, U2), (V0, V1, V2), (Z0, Z1, Z2) = fc.u, fc.v, fc.iz
        u0, u1, u2 = U0[fi], U1[fi], U2[fi]
        v0, v1, v2 = V0[fi], V1[fi], V2[fi]
        ia = fc.inv_area[fi]
        # barycentric weights from edge functions (signed areas / total area)
        w0 = ((u1 - px) * (v2 - py) - (u2 - px) * (v1 - py)) * ia
        w1 = ((u2 - px) * (v0 - py) - (u0 - px) * (v2 - py)) * ia
        w2 = 1.0 - w0 - w1
        eps = -1e-9  # pixel centres on a shared edge count for both faces: no cracks
        k = np.flatnonzero((w0 >= eps) & (w1 >= eps) & (w2 >= eps))
        if k.size == 0:
            return None
        f = fi[k]
        # perspective-correct depth: 1/z is affine in screen space
        invz = w0[k] * Z0[f] + w1[k] * Z1[f] + w2[k] * Z2[f]
        key = (np.rint(_DEPTH_Q / invz).astype(np.uint64) << _FACE_BITS) | \
            fc.idx[f].astype(np.uint64)
        return py[k] * W + px[k], key

    def _raster_boxes(self, fc: _Faces, sel: np.ndarray, W: int
                      ) -> tuple[np.ndarray, np.ndarray] | None:
        """Every pixel centre of the bounding box of each face ``sel`` (exactly the box,
        enumerated flat: face by face, row by row)."""
        wb = fc.umax[sel] - fc.umin[sel] + 1
        cnt = wb * (fc.vmax[sel] - fc.vmin[sel] + 1)
        rep = np.repeat(np.arange(sel.size), cnt)
        off = np.arange(rep.size) - (np.cumsum(cnt) - cnt)[rep]
        dy, dx = np.divmod(off, wb[rep])
        fi = sel[rep]
        return self._test(fc, fi, fc.umin[fi] + dx, fc.vmin[fi] + dy, W)

    def _raster_tiles(self, fc: _Faces, sel: np.ndarray, u_org: np.ndarray,
                      v_org: np.ndarray, W: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The ``_TILE`` x ``_TILE`` pixel centres from the origins (u_org, v_org) against the
        faces ``sel``, one tile per row (large faces)."""
        ox, oy = self._grid(_TILE)
        px = u_org[:, None] + ox
        py = v_org[:, None] + oy
        inside = (px <= fc.umax[sel, None]) & (py <= fc.vmax[sel, None])
        r, c = np.nonzero(inside)
        return self._test(fc, sel[r], px[r, c], py[r, c], W)

    def _visible(self, scene, intr):
        fc = _project_faces(scene, intr, self.near, self.cull_backfaces)
        if fc.idx.size == 0:
            return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
        W = intr.width
        wb = fc.umax - fc.umin + 1
        hb = fc.vmax - fc.vmin + 1
        parts = []
        # small faces: every pixel centre of their boxes, a bounded number at a time
        small = np.flatnonzero((wb <= _TILE) & (hb <= _TILE))
        if small.size:
            ends = np.cumsum(wb[small] * hb[small])
            cut = np.searchsorted(ends, np.arange(_CANDIDATES, ends[-1], _CANDIDATES),
                                  side="right")
            for sel in np.split(small, cut):
                if sel.size:
                    parts.append(self._raster_boxes(fc, sel, W))
        # large faces: cut their boxes into _TILE x _TILE tiles, a bounded number at a time
        big = np.flatnonzero((wb > _TILE) | (hb > _TILE))
        if big.size:
            tf, tu, tv = [], [], []
            for k in big:
                us = np.arange(fc.umin[k], fc.umax[k] + 1, _TILE)
                vs = np.arange(fc.vmin[k], fc.vmax[k] + 1, _TILE)
                uu, vv = np.meshgrid(us, vs)
                tf.append(np.full(uu.size, k))
                tu.append(uu.ravel())
                tv.append(vv.ravel())
            tf, tu, tv = np.concatenate(tf), np.concatenate(tu), np.concatenate(tv)
            for i in range(0, tf.size, _TILES_PER_CHUNK):
                j = slice(i, i + _TILES_PER_CHUNK)
                parts.append(self._raster_tiles(fc, tf[j], tu[j], tv[j], W))
        parts = [p for p in parts if p is not None]
        if not parts:
            return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
        pix = np.concatenate([p[0] for p in parts]) if len(parts) > 1 else parts[0][0]
        key = np.concatenate([p[1] for p in parts]) if len(parts) > 1 else parts[0][1]
        # nearest candidate per pixel (depth in the high bits of the key), in a buffer that
        # spans the candidates only (the rows of the hand, not the whole image)
        lo = int(pix.min())
        buf = np.full(int(pix.max()) - lo + 1, _NONE, np.uint64)
        np.minimum.at(buf, pix - lo, key)
        vis = np.flatnonzero(buf != _NONE)
        k = buf[vis]
        face = (k & np.uint64((1 << 24) - 1)).astype(np.int64)
        depth = (k >> _FACE_BITS).astype(np.float64) / _DEPTH_Q
        return vis + lo, depth, face


class NaiveRenderer(Renderer):
    """Per-triangle loop rasteriser: the slow, obviously-correct baseline."""

    name = "naive"

    def _visible(self, scene, intr):
        fc = _project_faces(scene, intr, self.near, False)
        H, W = intr.height, intr.width
        zbuf = np.full((H, W), np.inf)
        fbuf = np.full((H, W), -1, np.int64)
        for k in range(fc.idx.size):
            jj, ii = np.meshgrid(np.arange(fc.umin[k], fc.umax[k] + 1),
                                 np.arange(fc.vmin[k], fc.vmax[k] + 1))
            u0, u1, u2 = (c[k] for c in fc.u)
            v0, v1, v2 = (c[k] for c in fc.v)
            w0 = ((u1 - jj) * (v2 - ii) - (u2 - jj) * (v1 - ii)) * fc.inv_area[k]
            w1 = ((u2 - jj) * (v0 - ii) - (u0 - jj) * (v2 - ii)) * fc.inv_area[k]
            w2 = 1.0 - w0 - w1
            m = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
            if not m.any():
                continue
            invz = w0[m] * fc.iz[0][k] + w1[m] * fc.iz[1][k] + w2[m] * fc.iz[2][k]
            z = 1.0 / invz
            ii, jj = ii[m], jj[m]
            win = z < zbuf[ii, jj]
            zbuf[ii[win], jj[win]] = z[win]
            fbuf[ii[win], jj[win]] = fc.idx[k]
        vis = np.flatnonzero(fbuf.ravel() >= 0)
        return vis, zbuf.ravel()[vis], fbuf.ravel()[vis]


class RaycastRenderer(Renderer):
    """Open3D ``RaycastingScene`` ray caster (CPU, no GL); rays only inside the scene's box.

    Args:
        nthreads: threads for BVH build and ray casting (0 = all cores).
    """

    name = "raycast"

    def __init__(self, near: float = 0.01, nthreads: int = 1) -> None:
        super().__init__(near)
        try:
            import open3d as o3d
        except ImportError as e:  # pragma: no cover - open3d is a hard dependency
            raise ConfigError("the raycast renderer needs open3d (pip install open3d)") from e
        self._o3d = o3d
        self.nthreads = int(nthreads)

    def _visible(self, scene, intr):
        o3d = self._o3d
        V, F = scene.V, scene.F
        front = V[:, 2] > self.near
        if not front.any():
            return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
        uv = intr.project(V[front])
        j0 = max(int(np.floor(uv[:, 0].min())), 0)
        j1 = min(int(np.ceil(uv[:, 0].max())), intr.width - 1)
        i0 = max(int(np.floor(uv[:, 1].min())), 0)
        i1 = min(int(np.ceil(uv[:, 1].max())), intr.height - 1)
        if j0 > j1 or i0 > i1:
            return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
        keep = np.all(V[F, 2] > self.near, axis=1)
        fidx = np.flatnonzero(keep)
        rs = o3d.t.geometry.RaycastingScene(nthreads=self.nthreads)
        rs.add_triangles(o3d.core.Tensor(V.astype(np.float32)),
                         o3d.core.Tensor(F[fidx].astype(np.uint32)))
        jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
        d = np.stack([(jj - intr.cx) / intr.fx, (ii - intr.cy) / intr.fy,
                      np.ones(jj.shape)], -1).reshape(-1, 3)
        rays = np.concatenate([np.zeros_like(d), d], 1).astype(np.float32)
        ans = rs.cast_rays(o3d.core.Tensor(rays), nthreads=self.nthreads)
        t = ans["t_hit"].numpy()
        prim = ans["primitive_ids"].numpy().astype(np.int64)
        ok = np.isfinite(t)
        pix = (ii.ravel() * intr.width + jj.ravel())[ok]
        # t is measured along d whose z component is 1, so t is the z-depth
        return pix, t[ok].astype(np.float64), fidx[prim[ok]]


def make_renderer(name: str, **kw) -> Renderer:
    """Renderer by name: ``zbuffer`` (default), ``raycast`` or ``naive``."""
    table = {"zbuffer": ZBufferRenderer, "raycast": RaycastRenderer, "naive": NaiveRenderer}
    if name not in table:
        raise ConfigError(f"unknown renderer {name!r}; valid: {sorted(table)}")
    return table[name](**kw)
