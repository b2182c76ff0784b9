"""The parametric hand model ``H(alpha, beta, q; W, U)`` of the dissertation (eq. II.9).

Forward kinematics of the 16-bone skeleton, linear blend skinning of the template mesh
(eq. II.8) with the subject's bone scales and vertex offsets applied in the bones' local frames
(eq. II.3, II.5, II.7), analytic Jacobians of vertices / keypoints with respect to the pose and
the shape parameters (for Gauss-Newton tracking, eq. II.21-II.27, and calibration, eq. II.11),
fingertips, and the collision capsules.

Everything is vectorised over a batch of poses: a pose (27,) gives unbatched outputs, a
(B, 27) array gives outputs with a leading B axis.

Implementation notes. For bone ``j`` with world transform ``T_j(q) = [R_j | t_j]``, template rest
transform ``T^_j = [R^_j | t^_j]`` and local scale ``D_j = s_g diag(S_j)`` (eq. II.3), a template
vertex with offset, ``v~_i = v^_i + Q_i`` (eq. II.5, offsets applied in the rest pose before
scaling), is skinned as

    v_i(q) = sum_j w_ij (R_j D_j R^_j^T (v~_i - t^_j) + t_j) = (sum_j w_ij A_j) [v~_i; 1]

so one pose costs 16 small affine products plus a (V x 16) @ (16 x 12) blend. The Jacobian
column of a hinge ``k`` (world axis ``a_k`` through ``o_k``) is
``a_k x (sum_j w_ij m_jk P_ij - (sum_j w_ij m_jk) o_k)``, with ``P_ij`` the vertex carried rigidly
by bone ``j`` and ``m_jk`` = 1 when hinge k moves bone j.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from hand_capture.errors import InputError
from hand_capture.model import mesh as _mesh
from hand_capture.model.joints import N_DOF, root_rotation_matrix, validate_pose
from hand_capture.model.shape import (
    N_ALPHA,
    N_BETA,
    N_SCALES,
    SCALE_AXIS,
    SCALE_BASIS,
    SCALE_BONE,
    HandShape,
)
from hand_capture.model.skeleton import (
    BONE_ABD_DOF,
    BONE_DOF_MASK,
    BONE_FLEX_DOF,
    BONE_NAMES,
    BONE_PARENT,
    DESCENDANTS,
    FINGERTIP_KEYPOINTS,
    KEYPOINT_BONE,
    KEYPOINT_NAMES,
    LEVELS,
    N_BONES,
    N_KEYPOINTS,
    Skeleton,
    template_skeleton,
)

_FINGER_BONES = np.arange(1, N_BONES)
_ABD15 = BONE_ABD_DOF[1:]
_FLEX15 = BONE_FLEX_DOF[1:]
_HAS_ABD15 = _ABD15 >= 0
_ABD15_SAFE = np.where(_HAS_ABD15, _ABD15, 0)
_ABD_GATE15 = _HAS_ABD15.astype(np.float64)
#: (21, 1, 27) 1 where a DoF moves a keypoint's bone
_KP_DOF_MASK = BONE_DOF_MASK[KEYPOINT_BONE][:, None, :].astype(np.float64)


@dataclass(frozen=True)
class FKResult:
    """Output of :meth:`HandModel.forward` (leading batch axis when the pose was batched).

    Attributes:
        joint_positions: (..., 21, 3) keypoints in KEYPOINT_NAMES order [m].
        joint_frames: (..., 16, 4, 4) world transforms of the bones (BONE_NAMES order); the
            origin of each is its proximal joint centre.
        vertices: (..., V, 3) skinned mesh vertices [m].
        normals: (..., V, 3) outward unit vertex normals, or None unless requested.
    """

    joint_positions: np.ndarray
    joint_frames: np.ndarray
    vertices: np.ndarray
    normals: np.ndarray | None = None

    @property
    def fingertips(self) -> np.ndarray:
        """(..., 5, 3) fingertip keypoints (thumb, index, middle, ring, little)."""
        return self.joint_positions[..., FINGERTIP_KEYPOINTS, :]


@dataclass(frozen=True)
class Capsule:
    """A collision capsule fixed in a bone frame (shape applied)."""

    name: str
    bone: int
    p0: np.ndarray  # (3,) endpoint in the bone frame [m]
    p1: np.ndarray  # (3,)
    radius: float   # [m]


def _cross_into(out: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """``out[..., i, :] = (a x b)_i`` with the vector components on axis -2 (broadcasting)."""
    out[..., 0, :] = a[..., 1, :] * b[..., 2, :] - a[..., 2, :] * b[..., 1, :]
    out[..., 1, :] = a[..., 2, :] * b[..., 0, :] - a[..., 0, :] * b[..., 2, :]
    out[..., 2, :] = a[..., 0, :] * b[..., 1, :] - a[..., 1, :] * b[..., 0, :]


def segment_closest(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segments [p0, p1] and [q0, q1] (arrays (..., 3)): their parameters
    ``s`` on the first and ``t`` on the second (0 at p0 / q0, 1 at p1 / q1) and the distance
    between them, each of shape (...)."""
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    denom = a * e - b * b
    eps = 1e-14
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.maximum(denom, eps), 0.0, 1.0), 0.0)
    t = (b * s + f) / np.maximum(e, eps)
    t_c = np.clip(t, 0.0, 1.0)
    s = np.where(t < 0.0, np.clip(-c / np.maximum(a, eps), 0.0, 1.0),
                 np.where(t > 1.0, np.clip((b - c) / np.maximum(a, eps), 0.0, 1.0), s))
    cp = p0 + s[..., None] * d1
    cq = q0 + t_c[..., None] * d2
    return s, t_c, np.linalg.norm(cp - cq, axis=-1)


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray
                     ) -> np.ndarray:
    """Distance between segments [p0, p1] and [q0, q1] (arrays (..., 3)), shape (...)."""
    return segment_closest(p0, p1, q0, q1)[2]


class HandModel:
    """Skinned, shaped hand of one side.

    Args:
        shape: the subject's :class:`HandShape` (default: the template adult hand).
        side: ``'right'`` or ``'left'`` (the left hand is the mirror image of the right).
        mesh_step: grid step of the generated template surface [m] (about 3.5k vertices at the
            default; smaller is finer).

    The object is immutable; :meth:`with_shape` returns a model for another subject that shares
    the template (cheap: a few milliseconds).
    """

    bone_names: tuple[str, ...] = BONE_NAMES
    keypoint_names: tuple[str, ...] = KEYPOINT_NAMES

    def __init__(self, shape: HandShape | None = None, side: str = "right",
                 mesh_step: float = _mesh.DEFAULT_GRID_STEP) -> None:
        if shape is None:
            shape = HandShape()
        if not isinstance(shape, HandShape):
            raise InputError(f"shape must be a HandShape, got {type(shape).__name__}")
        self.side = side
        self.shape = shape
        self.mesh_step = float(mesh_step)
        self._sk = template_skeleton(side)
        self._tm = _mesh.template_mesh(side, self.mesh_step)
        self._incidence = _mesh.face_incidence(self.n_vertices, self._tm.faces)
        self._setup_shape()

    # ----------------------------------------------------------------------------- properties
    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int32 triangles, counter-clockwise seen from outside."""
        return self._tm.faces

    @property
    def n_vertices(self) -> int:
        return int(self._tm.vertices.shape[0])

    @property
    def skinning_weights(self) -> np.ndarray:
        """(V, 16) dense LBS weights ``W`` of eq. II.8 (rows sum to 1)."""
        return self._tm.weights

    @property
    def vertex_labels(self) -> np.ndarray:
        """(V,) the bone each vertex mainly belongs to (argmax of its weights)."""
        return self._dom_bone

    @property
    def rest_vertices(self) -> np.ndarray:
        """(V, 3) the shaped mesh in the zero pose."""
        return self._rest_vertices

    @property
    def bone_lengths(self) -> np.ndarray:
        """(16,) joint-to-joint lengths of the shaped skeleton (distal bones: to the tip) [m]."""
        return self._length

    @property
    def capsules(self) -> tuple[Capsule, ...]:
        """Collision capsules (one per finger segment, several for the palm), shaped."""
        return self._capsules

    @property
    def skeleton(self) -> Skeleton:
        """The template skeleton of this side (unscaled rest rotations, offsets, primitives)."""
        return self._sk

    @property
    def bone_offsets(self) -> np.ndarray:
        """(16, 3) origin of each bone in its parent's frame, shape applied (palm: zeros)."""
        return self._offset

    @property
    def bone_tips(self) -> np.ndarray:
        """(16, 3) distal end point of each bone in its own frame, shape applied."""
        return self._tip_local

    def with_shape(self, shape: HandShape) -> HandModel:
        """The same side and template with another subject shape."""
        new = object.__new__(HandModel)
        new.__dict__.update(self.__dict__)
        if not isinstance(shape, HandShape):
            raise InputError(f"shape must be a HandShape, got {type(shape).__name__}")
        new.shape = shape
        new._setup_shape()
        return new

    # ---------------------------------------------------------------------------- shape setup
    def _setup_shape(self) -> None:
        sk, tm, shape = self._sk, self._tm, self.shape
        sg = shape.global_scale
        scales = shape.bone_scales()
        diag = np.ones((N_BONES, 3))
        diag[SCALE_BONE, SCALE_AXIS] = scales
        diag *= sg
        self._diag = diag
        # skeleton of the subject: offsets scaled in the parent frame (eq. II.2)
        off = np.zeros((N_BONES, 3))
        off[1:] = diag[BONE_PARENT[1:]] * sk.offset[1:]
        self._offset = off
        self._tip_local = diag * sk.tip_local
        self._length = sk.length * diag[:, 0]
        self._rrest15 = sk.rest_rot[1:].copy()
        self._offset15 = off[1:].reshape(5, 3, 3)
        self._abd_sign = sk.abd_axis_sign
        self._rrest_z15 = self._rrest15[:, :, 2] * self._abd_sign  # abduction axis in parent
        # template rest frames (unscaled)
        rhat, that = sk.rest_world
        self._rhat, self._that = rhat, that
        # vertex offsets (eq. II.5, II.6): Q_i = sum_k beta_k phi_k(i) n_i, in the rest pose
        beta = np.asarray(shape.beta)
        q_off = (tm.beta_fields @ beta)[:, None] * tm.normals
        vt = tm.vertices + q_off
        self._vt = vt
        # per-bone affine G_j = D_j T^_j^-1 (3 x 4)
        gr = diag[:, :, None] * np.transpose(rhat, (0, 2, 1))
        gt = -np.einsum("jab,jb->ja", gr, that)
        self._gr, self._gt = gr, gt
        # per-slot data for the Jacobians
        bidx, bw = tm.bone_idx, tm.bone_w
        self._bidx, self._bw = bidx, bw
        u = np.einsum("vkba,vkb->vka", rhat[bidx], vt[:, None, :] - that[bidx])  # R^T(v - t)
        self._p_local = diag[bidx] * u  # scaled local coordinates per slot (V, K, 3)
        nv = len(vt)
        x = np.zeros((nv, N_BONES, 4))
        rows = np.arange(nv)
        for k in range(bidx.shape[1]):
            x[rows, bidx[:, k], :3] += bw[:, k, None] * self._p_local[:, k]
            x[rows, bidx[:, k], 3] += bw[:, k]
        self._xdense = x.reshape(nv, 4 * N_BONES)  # skinning matrix X (V, 64)
        self._xmat = sp.csr_matrix(self._xdense)
        self._kscale = self._scale_table(u, bidx, bw)  # (V, 17)
        self._dom_bone = np.argmax(tm.weights, axis=1)
        # keypoints as points on bones (template local, unscaled)
        kp_u = np.zeros((N_KEYPOINTS, 3))
        kp_u[FINGERTIP_KEYPOINTS] = sk.tip_local[KEYPOINT_BONE[FINGERTIP_KEYPOINTS]]
        self._kp_local = diag[KEYPOINT_BONE] * kp_u
        self._kp_kscale = self._scale_table(kp_u[:, None, :], KEYPOINT_BONE[:, None],
                                            np.ones((N_KEYPOINTS, 1)))
        kx = np.zeros((N_KEYPOINTS, N_BONES, 4))
        kx[np.arange(N_KEYPOINTS), KEYPOINT_BONE, :3] = self._kp_local
        kx[np.arange(N_KEYPOINTS), KEYPOINT_BONE, 3] = 1.0
        self._kp_x = kx.reshape(N_KEYPOINTS, 4 * N_BONES)
        # fingertip pads: palmar side of the distal segment, about one radius from the tip
        distal = LEVELS[2]
        r_tip = np.array([p.r1 for p in sk.primitives if p.bone in set(distal.tolist())])
        pad_u = sk.tip_local[distal].copy()
        pad_u[:, 0] -= 1.2 * r_tip
        pad_u[:, 2] -= 0.9 * r_tip
        self._pad_local = diag[distal] * pad_u
        # rest-pose vertices of this subject
        self._rest_vertices = self.vertices(np.zeros(N_DOF))
        self._capsules = self._build_capsules()

    def _scale_table(self, u: np.ndarray, bidx: np.ndarray, bw: np.ndarray) -> np.ndarray:
        """K[i, e] = sum_s w_is kappa_ise: d(point)/d(S_e) = s_g R_{b_e}[:, a_e] K[i, e]."""
        sk = self._sk
        # anc[j, e]: template offset component carried by bone j when S_e's bone is a proper
        # ancestor of j (the offset of the child of S_e's bone on the path to j)
        anc = np.zeros((N_BONES, N_SCALES))
        for j in range(N_BONES):
            c = j
            while BONE_PARENT[c] >= 0:
                p = BONE_PARENT[c]
                for e in np.nonzero(SCALE_BONE == p)[0]:
                    anc[j, e] = sk.offset[c][SCALE_AXIS[e]]
                c = p
        own = (bidx[:, :, None] == SCALE_BONE[None, None, :]) * u[:, :, SCALE_AXIS]
        return np.einsum("vk,vke->ve", bw, own + anc[bidx])

    def _build_capsules(self) -> tuple[Capsule, ...]:
        sk, tm = self._sk, self._tm
        off_mag = tm.beta_fields @ np.asarray(self.shape.beta)
        wsum = tm.weights.sum(axis=0)
        bone_off = (tm.weights * off_mag[:, None]).sum(axis=0) / np.maximum(wsum, 1e-9)
        caps = []
        count: dict[int, int] = {}
        for p in sk.primitives:
            if not p.collide:
                continue
            k = count.get(p.bone, 0)
            count[p.bone] = k + 1
            name = BONE_NAMES[p.bone] if p.bone != 0 else f"palm_{k}"
            d = self._diag[p.bone]
            r = self.shape.global_scale * (0.5 * (p.r0 + p.r1) + bone_off[p.bone])
            caps.append(Capsule(name, p.bone, d * np.array(p.p0), d * np.array(p.p1), float(r)))
        return tuple(caps)

    # ------------------------------------------------------------------------------------ FK
    def _fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (B, 16, 3, 3) and origins (B, 16, 3) of the bones."""
        b = q.shape[0]
        r0 = root_rotation_matrix(q[:, 3:6])
        t0 = q[:, 0:3]
        a = q[:, _ABD15_SAFE]
        a *= _ABD_GATE15 * self._abd_sign
        f = q[:, _FLEX15]
        ca, sa, cf, sf = np.cos(a), np.sin(a), np.cos(f), np.sin(f)
        j = np.empty((b, 15, 3, 3))  # Rz(a) @ Ry(f)
        j[..., 0, 0] = ca * cf
        j[..., 0, 1] = -sa
        j[..., 0, 2] = ca * sf
        j[..., 1, 0] = sa * cf
        j[..., 1, 1] = ca
        j[..., 1, 2] = sa * sf
        j[..., 2, 0] = -sf
        j[..., 2, 1] = 0.0
        j[..., 2, 2] = cf
        # bones 1..15 are ordered finger-major (1 + 3 f + level): view as (B, 5, 3, ...)
        local = np.matmul(self._rrest15, j).reshape(b, 5, 3, 3, 3)
        off = self._offset15
        rot = np.empty((b, N_BONES, 3, 3))
        pos = np.empty((b, N_BONES, 3))
        rot[:, 0] = r0
        pos[:, 0] = t0
        rf = rot[:, 1:].reshape(b, 5, 3, 3, 3)
        pf = pos[:, 1:].reshape(b, 5, 3, 3)
        rp = r0[:, None]
        tp = t0[:, None]
        for lvl in range(3):
            pf[:, :, lvl] = tp + np.matmul(rp, off[:, lvl, :, None])[..., 0]
            rp = np.matmul(rp, local[:, :, lvl])
            rf[:, :, lvl] = rp
            tp = pf[:, :, lvl]
        return rot, pos

    def _keypoints(self, rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
        rb = rot[:, KEYPOINT_BONE]
        return pos[:, KEYPOINT_BONE] + np.matmul(rb, self._kp_local[None, :, :, None])[..., 0]

    def _skin_all(self, rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """All skinned vertices (B, V, 3) (eq. II.8 with II.7).

        ``v_i = sum_j R_j (w_ij p_ij) + w_ij t_j`` with the per-shape sparse matrix
        ``X = [w_ij p_ij, w_ij]_j`` (V x 64): one sparse product with the stacked bone
        transforms per call, whatever the batch size.
        """
        b = rot.shape[0]
        tr = np.empty((N_BONES, 4, b, 3))
        tr[:, :3] = np.transpose(rot, (1, 3, 0, 2))  # R_j^T
        tr[:, 3] = np.swapaxes(pos, 0, 1)
        out = self._xmat @ tr.reshape(4 * N_BONES, 3 * b)  # (V, 3B)
        return np.swapaxes(out.reshape(-1, b, 3), 0, 1)

    @staticmethod
    def _batch(pose: object) -> tuple[np.ndarray, bool]:
        q = validate_pose(pose)
        return (q[None], True) if q.ndim == 1 else (q, False)

    def forward(self, pose: object, normals: bool = False) -> FKResult:
        """Keypoints, bone frames and skinned vertices for a pose (27,) or poses (B, 27).

        Raises:
            InputError: a malformed pose (see joints.validate_pose).
        """
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        verts = self._skin_all(rot, pos)
        frames = np.zeros(rot.shape[:2] + (4, 4))
        frames[..., :3, :3] = rot
        frames[..., :3, 3] = pos
        frames[..., 3, 3] = 1.0
        kp = self._keypoints(rot, pos)
        nrm = self.normals(verts) if normals else None
        if single:
            return FKResult(kp[0], frames[0], verts[0], None if nrm is None else nrm[0])
        return FKResult(kp, frames, verts, nrm)

    def vertices(self, pose: object, vertex_idx: object = None) -> np.ndarray:
        """Skinned vertices (V, 3) / (B, V, 3), optionally only ``vertex_idx``."""
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        if vertex_idx is None:
            v = self._skin_all(rot, pos)
        else:
            idx = self._check_idx(vertex_idx)
            v = self._points(rot, pos, idx)
        return v[0] if single else v

    def joint_positions(self, pose: object) -> np.ndarray:
        """The 21 keypoints (21, 3) / (B, 21, 3) in KEYPOINT_NAMES order."""
        q, single = self._batch(pose)
        kp = self._keypoints(*self._fk(q))
        return kp[0] if single else kp

    def keypoints_of_fk(self, fk: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """The 21 keypoints (B, 21, 3) [m] of the bone rotations (B, 16, 3, 3) and origins
        (B, 16, 3) that :meth:`bone_basis` returns for a batch (no second FK pass)."""
        return self._keypoints(*fk)

    def fingertips(self, pose: object, where: str = "tip") -> np.ndarray:
        """Fingertip points (5, 3) / (B, 5, 3), thumb to little finger.

        ``where='tip'``: the distal end of each finger; ``'pad'``: the centre of the palmar pad
        (about one tip radius proximal and palmar of the tip), where a finger touches a surface.
        """
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        if where == "tip":
            out = self._keypoints(rot, pos)[:, FINGERTIP_KEYPOINTS]
        elif where == "pad":
            d = LEVELS[2]
            out = pos[:, d] + np.matmul(rot[:, d], self._pad_local[None, :, :, None])[..., 0]
        else:
            raise InputError(f"where must be 'tip' or 'pad', got {where!r}")
        return out[0] if single else out

    def normals(self, vertices: np.ndarray) -> np.ndarray:
        """Outward unit vertex normals of skinned vertices (V, 3) or (B, V, 3)."""
        return _mesh.vertex_normals(np.asarray(vertices), self.faces, self._incidence)

    def _check_idx(self, vertex_idx: object) -> np.ndarray:
        idx = np.asarray(vertex_idx)
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise InputError("vertex_idx must be a 1-D integer array")
        if idx.size and (idx.min() < -self.n_vertices or idx.max() >= self.n_vertices):
            raise InputError(f"vertex_idx out of range [0, {self.n_vertices})")
        return idx

    def _points(self, rot: np.ndarray, pos: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Skinned vertices for a subset (B, N, 3): rows of the skinning matrix."""
        b = rot.shape[0]
        tr = np.empty((N_BONES, 4, b, 3))
        tr[:, :3] = np.transpose(rot, (1, 3, 0, 2))
        tr[:, 3] = np.swapaxes(pos, 0, 1)
        out = self._xdense[idx] @ tr.reshape(4 * N_BONES, 3 * b)
        return np.swapaxes(out.reshape(-1, b, 3), 0, 1)

    # ----------------------------------------------------------------------------- Jacobians
    def _dof_axes(self, q: np.ndarray, rot: np.ndarray, pos: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """World axis (B, 27, 3) and anchor (B, 27, 3) of every DoF (slides: direction)."""
        b = q.shape[0]
        axes = np.zeros((b, N_DOF, 3))
        anchors = np.zeros((b, N_DOF, 3))
        axes[:, 0:3] = np.eye(3)
        # columns of Rx(rx) (y) and Rx(rx) Ry(ry) (z), as root_rotation_matrix writes them
        cx, sx = np.cos(q[:, 3]), np.sin(q[:, 3])
        cy, sy = np.cos(q[:, 4]), np.sin(q[:, 4])
        axes[:, 3] = (1.0, 0.0, 0.0)
        axes[:, 4, 1] = cx
        axes[:, 4, 2] = sx
        axes[:, 5, 0] = sy
        axes[:, 5, 1] = -sx * cy
        axes[:, 5, 2] = cx * cy
        anchors[:, 3:6] = pos[:, None, 0]
        par = BONE_PARENT[_FINGER_BONES]
        abd_axis = np.matmul(rot[:, par], self._rrest_z15[None, :, :, None])[..., 0]
        axes[:, _ABD15[_HAS_ABD15]] = abd_axis[:, _HAS_ABD15]
        anchors[:, _ABD15[_HAS_ABD15]] = pos[:, _FINGER_BONES[_HAS_ABD15]]
        axes[:, _FLEX15] = rot[:, _FINGER_BONES][..., 1]
        anchors[:, _FLEX15] = pos[:, _FINGER_BONES]
        return axes, anchors

    def _jac_matrix(self, q: np.ndarray, rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """Per-pose matrix H (B, 64, 81) with ``d point / d pose = X_row @ H``.

        A point is ``sum_j w_j (R_j p_j + t_j)``, i.e. the row ``X = [w_j p_j, w_j]_j`` of the
        skinning matrix. The column of hinge k (world axis a_k through o_k) is
        ``sum_j m_jk w_j a_k x (R_j p_j + t_j - o_k)`` (m_jk = 1 when hinge k moves bone j),
        which is linear in X: ``H[(j, c<3), (i, k)] = m_jk ([a_k]x R_j)[i, c]`` and
        ``H[(j, 3), (i, k)] = m_jk (a_k x (t_j - o_k))[i]``; a root slide k has
        ``H[(j, 3), (i, k)] = delta_ik``. One (N x 64) @ (64 x 81) product then gives all
        Jacobians, whatever the number of points.
        """
        b = q.shape[0]
        axes, anchors = self._dof_axes(q, rot, pos)
        h = np.empty((b, N_BONES, 4, 3, N_DOF))
        ax = np.swapaxes(axes, 1, 2)[:, None, None, :, :]      # (B, 1, 1, 3, 27)
        # rows c < 3: a_k x (column c of R_j); row 3: a_k x (t_j - o_k); all four at once
        v = np.empty((b, N_BONES, 4, 3, N_DOF))
        v[:, :, :3] = np.swapaxes(rot, 2, 3)[..., None]          # (B, 16, 3 (c), 3, 1)
        v[:, :, 3] = pos[:, :, :, None] - np.swapaxes(anchors, 1, 2)[:, None]
        _cross_into(h, ax, v)
        h *= BONE_DOF_MASK[None, :, None, None, :]
        h[..., 0:3] = 0.0
        h[:, :, 3, :, 0:3] = np.eye(3)
        return h.reshape(b, 4 * N_BONES, 3 * N_DOF)

    def jacobian(self, pose: object, vertex_idx: object = None) -> np.ndarray:
        """d(vertex)/d(pose): (N, 3, 27) or (B, N, 3, 27) for ``vertex_idx`` (default: all).

        Analytic (eq. II.8 differentiated); use a subset of vertices (e.g. the ICP
        correspondences) to keep it fast.
        """
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        h = self._jac_matrix(q, rot, pos)
        jac = self._apply_rows(h, None if vertex_idx is None else self._check_idx(vertex_idx))
        return jac[0] if single else jac

    def _apply_rows(self, h: np.ndarray, idx: np.ndarray | None) -> np.ndarray:
        """``X[idx] @ h`` for h (B, 64, 81) -> (B, N, 3, 27).

        Uses the sparse skinning matrix (about 7 non-zeros per row): faster than a dense BLAS
        product here, and single-threaded, so it does not slow down when BLAS threads would
        compete with the other nodes for a small machine.
        """
        b = h.shape[0]
        xs = self._xmat if idx is None else self._xmat[idx]
        out = xs @ np.moveaxis(h, 0, 1).reshape(4 * N_BONES, b * 3 * N_DOF)
        return np.moveaxis(out.reshape(-1, b, 3, N_DOF), 1, 0)

    def linearize(self, pose: object, vertex_idx: object = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Vertices and their pose Jacobian from one FK pass (a Gauss-Newton step's needs).

        Returns ``(points (N, 3), jacobian (N, 3, 27))`` (with a leading batch axis for a batch
        of poses), identical to ``vertices(pose, idx)`` and ``jacobian(pose, idx)``.
        """
        q, single = self._batch(pose)
        idx = None if vertex_idx is None else self._check_idx(vertex_idx)
        rot, pos = self._fk(q)
        b = q.shape[0]
        h = self._jac_matrix(q, rot, pos)                      # (B, 64, 81)
        tr = np.empty((b, N_BONES, 4, 3))
        tr[:, :, :3] = np.swapaxes(rot, 2, 3)
        tr[:, :, 3] = pos
        both = np.concatenate([tr.reshape(b, 4 * N_BONES, 3), h], axis=2)  # (B, 64, 84)
        xs = self._xmat if idx is None else self._xmat[idx]
        out = xs @ np.moveaxis(both, 0, 1).reshape(4 * N_BONES, -1)
        out = np.moveaxis(out.reshape(-1, b, 3 + 3 * N_DOF), 1, 0)
        pts = out[..., :3]
        jac = out[..., 3:].reshape(b, -1, 3, N_DOF)
        return (pts[0], jac[0]) if single else (pts, jac)

    def skinning_rows(self, vertex_idx: object = None) -> sp.csr_matrix:
        """Rows (N, 64) of the sparse skinning matrix ``X = [w_ij p_ij, w_ij]_j`` (columns bone
        major, 4 per bone), for :meth:`bone_basis` (default: all vertices)."""
        return self._xmat if vertex_idx is None else self._xmat[self._check_idx(vertex_idx)]

    def keypoint_rows(self) -> np.ndarray:
        """Rows (21, 64) with ``keypoints = keypoint_rows() @ T`` for ``T`` of
        :meth:`bone_basis` (like :meth:`skinning_rows` for the keypoints)."""
        return self._kp_x.copy()

    def bone_basis(self, pose: object, jacobian: bool = False
                   ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """One FK pass in the form a Gauss-Newton loop over vertex subsets wants.

        Returns ``(T, H, rot, pos)``: ``T`` (64, 3) the stacked bone transforms, so that the
        skinned vertices are ``skinning_rows(idx) @ T`` (eq. II.8); ``H`` (64, 81) (only with
        ``jacobian=True``, else None) so that their pose Jacobian is
        ``(skinning_rows(idx) @ H).reshape(N, 3, 27)``; the bone rotations (16, 3, 3) and
        origins (16, 3). A batch of poses gives a leading batch axis. Same values as
        :meth:`vertices` / :meth:`jacobian`.
        """
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        b = q.shape[0]
        tr = np.empty((b, N_BONES, 4, 3))
        tr[:, :, :3] = np.swapaxes(rot, 2, 3)
        tr[:, :, 3] = pos
        T = tr.reshape(b, 4 * N_BONES, 3)
        H = self._jac_matrix(q, rot, pos) if jacobian else None
        if single:
            return T[0], None if H is None else H[0], rot[0], pos[0]
        return T, H, rot, pos

    def keypoints_and_jacobian(self, pose: object, keypoints: object = None,
                               dofs: object = None,
                               fk: tuple[np.ndarray, np.ndarray] | None = None
                               ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`joint_positions` and :meth:`keypoint_jacobian` from one FK pass, optionally
        only for some ``keypoints`` (rows) and ``dofs`` (columns).

        The Jacobian column of hinge k at keypoint p is ``a_k x (p - o_k)`` when the hinge
        moves p's bone (what :meth:`keypoint_jacobian` gives through the skinning rows).
        ``fk``: the bone rotations and origins of these poses, as :meth:`bone_basis` returns
        them for the same batch (that FK pass is then not repeated)."""
        q, single = self._batch(pose)
        if fk is None:
            rot, pos = self._fk(q)
        else:
            rot, pos = (fk[0][None], fk[1][None]) if single else fk
        kp = self._keypoints(rot, pos)
        axes, anchors = self._dof_axes(q, rot, pos)
        kr = np.arange(N_KEYPOINTS) if keypoints is None else np.asarray(keypoints)
        dc = np.arange(N_DOF) if dofs is None else np.asarray(dofs)
        kp = kp[:, kr]
        d = kp[:, :, None, :] - anchors[:, None, dc, :]           # (B, K, D, 3)
        jac = np.empty((q.shape[0], len(kr), 3, len(dc)))
        _cross_into(jac, np.swapaxes(axes[:, dc], 1, 2)[:, None], np.swapaxes(d, 2, 3))
        jac *= _KP_DOF_MASK[kr][:, :, dc]
        slide = np.flatnonzero(dc < 3)
        if len(slide):
            jac[..., slide] = np.eye(3)[:, dc[slide]]
        return (kp[0], jac[0]) if single else (kp, jac)

    def keypoint_jacobian(self, pose: object) -> np.ndarray:
        """d(keypoint)/d(pose): (21, 3, 27) or (B, 21, 3, 27)."""
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        jac = np.matmul(self._kp_x, self._jac_matrix(q, rot, pos)).reshape(
            q.shape[0], N_KEYPOINTS, 3, N_DOF)
        return jac[0] if single else jac

    def shape_jacobian(self, pose: object, vertex_idx: object = None,
                       keypoints: bool = False) -> np.ndarray:
        """d(point)/d(shape params) with columns ``HandShape.params = [s_g, alpha, beta]``.

        Shape (N, 3, 1 + N_ALPHA + N_BETA) or with a leading batch axis. ``keypoints=True``
        differentiates the 21 keypoints instead of vertices (their beta columns are zero).
        The bone scales are treated as ``S0 + C_S alpha`` without the 0.3 floor.
        """
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        sg = self.shape.global_scale
        # (B, 17, 3): column a_e of R_{b_e}
        rcols = np.einsum("bejk,ek->bej", rot[:, SCALE_BONE], np.eye(3)[SCALE_AXIS])
        ncol = 1 + N_ALPHA + N_BETA
        if keypoints:
            pts = self._keypoints(rot, pos)
            kscale = self._kp_kscale
            jac = np.zeros(pts.shape + (ncol,))
        else:
            idx = (np.arange(self.n_vertices) if vertex_idx is None
                   else self._check_idx(vertex_idx))
            blended = self._blend_subset(rot, pos, idx)
            vt = self._vt[idx]
            lin = blended[..., :9].reshape(blended.shape[:2] + (3, 3))
            pts = np.matmul(lin, vt[None, :, :, None])[..., 0] + blended[..., 9:]
            kscale = self._kscale[idx]
            jac = np.zeros(pts.shape + (ncol,))
            # beta: dv/dQ_i = sum_j w_ij R_j D_j R^_j^T (the blended linear part), eq. II.5
            dq = self._tm.beta_fields[idx][:, None, :] * self._tm.normals[idx][:, :, None]
            jac[..., 1 + N_ALPHA:] = np.matmul(lin, dq[None])
        jac[..., 0] = (pts - pos[:, None, 0]) / sg  # everything scales about the wrist
        d_scale = sg * kscale[None, :, None, :] * np.swapaxes(rcols, 1, 2)[:, None]  # (B,N,3,17)
        jac[..., 1:1 + N_ALPHA] = d_scale @ SCALE_BASIS
        return jac[0] if single else jac

    def _blend_subset(self, rot: np.ndarray, pos: np.ndarray, idx: np.ndarray) -> np.ndarray:
        b = rot.shape[0]
        ar = np.matmul(rot, self._gr[None])
        at = np.matmul(rot, self._gt[None, :, :, None])[..., 0] + pos
        a = np.concatenate([ar.reshape(b, N_BONES, 9), at], axis=2)
        return np.matmul(self._tm.weights[idx], a)

    # ----------------------------------------------------------------------------- collision
    def palm_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre and full extents of the box around the palm capsules (palm frame)."""
        pts, rad = [], []
        for c in self._capsules:
            if c.bone == 0:
                pts += [c.p0, c.p1]
                rad += [c.radius, c.radius]
        pts = np.array(pts)
        r = np.array(rad)[:, None]
        lo = (pts - r).min(axis=0)
        hi = (pts + r).max(axis=0)
        return 0.5 * (lo + hi), hi - lo

    def palm_inertia(self, mass: float) -> np.ndarray:
        """Diagonal inertia [kg m^2] of a uniform box of ``mass`` around the palm."""
        e = self.palm_box()[1]
        return mass / 12.0 * np.array([e[1] ** 2 + e[2] ** 2, e[0] ** 2 + e[2] ** 2,
                                       e[0] ** 2 + e[1] ** 2])

    def capsule_segments(self, pose: object) -> np.ndarray:
        """World endpoints of :attr:`capsules`: (C, 2, 3) or (B, C, 2, 3)."""
        q, single = self._batch(pose)
        rot, pos = self._fk(q)
        bones = np.array([c.bone for c in self._capsules])
        loc = np.stack([np.stack([c.p0, c.p1]) for c in self._capsules])  # (C, 2, 3)
        seg = (np.einsum("bcij,ckj->bcki", rot[:, bones], loc) + pos[:, bones, None, :])
        return seg[0] if single else seg

    @property
    def capsule_pairs(self) -> np.ndarray:
        """(P, 2) capsule index pairs checked for self-penetration: different bones, not
        parent/child, and not already overlapping in the zero pose."""
        if not hasattr(self, "_pairs_cache") or self._pairs_cache[0] is not self.shape:
            caps = self._capsules
            pairs = []
            for i in range(len(caps)):
                for j in range(i + 1, len(caps)):
                    bi, bj = caps[i].bone, caps[j].bone
                    if bi == bj or BONE_PARENT[bi] == bj or BONE_PARENT[bj] == bi:
                        continue
                    pairs.append((i, j))
            pairs = np.array(pairs, dtype=np.int64)
            seg = self.capsule_segments(np.zeros(N_DOF))
            radii = np.array([c.radius for c in caps])
            d = segment_distance(seg[pairs[:, 0], 0], seg[pairs[:, 0], 1],
                                 seg[pairs[:, 1], 0], seg[pairs[:, 1], 1])
            keep = d > radii[pairs[:, 0]] + radii[pairs[:, 1]] + 1e-4
            self._pairs_cache = (self.shape, pairs[keep])
        return self._pairs_cache[1]

    def self_penetration(self, pose: object) -> np.ndarray:
        """Penetration depth [m] of every :attr:`capsule_pairs` pair (> 0: overlapping),
        shape (P,) or (B, P)."""
        q, single = self._batch(pose)
        seg = self.capsule_segments(q)
        pairs = self.capsule_pairs
        radii = np.array([c.radius for c in self._capsules])
        d = segment_distance(seg[:, pairs[:, 0], 0], seg[:, pairs[:, 0], 1],
                             seg[:, pairs[:, 1], 0], seg[:, pairs[:, 1], 1])
        depth = radii[pairs[:, 0]] + radii[pairs[:, 1]] - d
        return depth[0] if single else depth


def bone_descendants(bone: int) -> np.ndarray:
    """Indices of ``bone`` and all bones below it."""
    return np.nonzero(DESCENDANTS[bone])[0]
