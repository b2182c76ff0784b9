"""Cascaded hierarchical hand pose regression with 3D shape-indexed features (ch. II.4).

* **Features** (eq. II.15): a feature is a pair of 3D points, each a mesh vertex ``M`` of the
  current skinned model plus an offset ``delta`` expressed in a reference frame ``T_ref``
  (the palm frame for palm regression, the finger-root frame for finger regression),
  projected into the image: ``f = I(CamProj(M1 + T_ref d1)) - I(CamProj(M2 + T_ref d2))``.
  The pairs are drawn, as in the dissertation, by sampling 3D points around the rest-pose
  hand and attaching each to its nearest vertex, so the features follow the subject's shape.
  Pixels off the hand (or off the image) read a constant background depth.
* **Hierarchy** (eq. II.17, II.18): palm first (6 palm keypoints: wrist, thumb TM and the four
  MCPs), then each finger (its three distal keypoints). Each stage regresses keypoint
  *positions* in the reference frame (``q_s = q_(s-1) + T R_s(I, M_(s-1))``); the palm pose
  is recovered from the keypoints by a rigid (Kabsch) fit, the finger angles by a few
  Gauss-Newton inverse-kinematics steps with the model's keypoint Jacobian.
* **Initialisation** (II.4.2): the middle MCP at the centroid of the point cloud, the palm
  axes by PCA (largest variance = distal, least = palm normal), fingers straight.
* **Modes** (II.4.3): the last palm stage keeps every tree's leaf modes and clusters them;
  each cluster centre is a palm candidate, and finger regression runs for each.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from hand_capture.cameras.base import Intrinsics
from hand_capture.errors import InputError
from hand_capture.model import JOINT_LIMITS, N_DOF, HandModel
from hand_capture.model.joints import root_angles_from_matrix, root_rotation_matrix
from hand_capture.tracking.forest import ForestGroup, RegressionForest

__all__ = ["BACKGROUND_M", "BACKGROUND_REL_M", "DepthLookup", "FeatureSet", "HandRegressor",
           "RegressorSet",
           "ModelFrames", "PALM_KP", "FINGER_KP", "ik_fingers", "kabsch", "palm_init_pca"]

#: depth read off the hand or off the image [m]
BACKGROUND_M = 2.0
#: what a feature's point off the hand reads beyond the point's own depth, in a model
#: trained with a relative background (``info["background"] == "relative"``) [m]
BACKGROUND_REL_M = 1.0
#: palm keypoints (wrist, thumb TM, index..little MCP) in KEYPOINT_NAMES order
PALM_KP = np.array([0, 1, 5, 9, 13, 17])
#: per finger (thumb..little) the three keypoints regressed by finger regression
FINGER_KP = np.array([[2, 3, 4], [6, 7, 8], [10, 11, 12], [14, 15, 16], [18, 19, 20]])
#: per finger the keypoint at the finger root (origin of the finger frame)
FINGER_ROOT_KP = np.array([1, 5, 9, 13, 17])
#: per finger its first bone
FINGER_BONE = np.array([1, 4, 7, 10, 13])
_FINGER_ALL = np.arange(6, N_DOF)


# ------------------------------------------------------------------------------------------
# Geometry helpers
# ------------------------------------------------------------------------------------------
def kabsch(local: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising ``sum ||R local_i + t - world_i||^2``."""
    cl, cw = local.mean(axis=0), world.mean(axis=0)
    H = (local - cl).T @ (world - cw)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cw - R @ cl


@dataclass
class ModelFrames:
    """Shape-specific constants of one hand model for regression."""

    model: HandModel
    palm_local: np.ndarray = field(init=False)    # (6, 3) palm keypoints in the palm frame
    finger_rot: np.ndarray = field(init=False)    # (5, 3, 3) finger-root frames in the palm
    rest_vertices: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        fk = self.model.forward(np.zeros(N_DOF))
        self.palm_local = fk.joint_positions[PALM_KP]
        self.finger_rot = fk.joint_frames[FINGER_BONE, :3, :3]
        self.rest_vertices = fk.vertices
        self._cache: dict[int, tuple[object, object]] = {}

    def cached(self, owner: object, make: Callable[[], object]) -> object:
        """Per-model data derived from ``owner`` (e.g. a feature set's skinning rows), made
        once by ``make()``."""
        hit = self._cache.get(id(owner))
        if hit is None or hit[0] is not owner:
            hit = (owner, make())
            self._cache[id(owner)] = hit
        return hit[1]

    def palm_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return root_rotation_matrix(q[3:6]), q[0:3].copy()

    def set_palm(self, q: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        out = q.copy()
        out[0:3] = t
        out[3:6] = root_angles_from_matrix(R)
        return out


def _rows_and_rest(model: HandModel, ids: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Skinning rows of vertices ``ids`` and their rest-pose positions."""
    rows = model.skinning_rows(ids)
    return rows, rows @ model.bone_basis(np.zeros(N_DOF))[0]


def palm_init_pca(points: np.ndarray, frames: ModelFrames) -> np.ndarray:
    """Initial pose (II.4.2): middle MCP at the centroid, palm axes from PCA, fingers 0."""
    if len(points) < 3:
        raise InputError("palm initialisation needs at least 3 points")
    n = len(points)
    c = (np.ones(n) @ points) / n
    X = points - c
    w, v = np.linalg.eigh((X.T @ X) / (n - 1))       # covariance of the cloud
    x = v[:, 2]   # largest variance: distal
    z = v[:, 0]   # least variance: palm normal (dorsal)
    if x[1] > 0:  # fingers point up in the image (-y) by convention
        x = -x
    if z[2] < 0:  # back of the hand away from the camera (palm facing it)
        z = -z
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    t = c - R @ frames.palm_local[3]
    q = np.zeros(N_DOF)
    return frames.set_palm(q, R, t)


# ------------------------------------------------------------------------------------------
# Depth lookup and features
# ------------------------------------------------------------------------------------------
@dataclass
class DepthLookup:
    """Depth [m] of a (possibly cropped) hand image at projected 3D points."""

    depth: np.ndarray       # (h, w) float32 hand depth [m], 0 = off the hand
    u0: int                 # column of depth[:, 0] in the full image
    v0: int                 # row of depth[0, :]
    intr: Intrinsics
    #: off the hand: the point's own depth + BACKGROUND_REL_M (True) or BACKGROUND_M
    relative: bool = False

    def __call__(self, pts: np.ndarray) -> np.ndarray:
        z = np.maximum(pts[..., 2], 1e-3)
        u = np.rint(self.intr.fx * pts[..., 0] / z + self.intr.cx).astype(np.int64)
        v = np.rint(self.intr.fy * pts[..., 1] / z + self.intr.cy).astype(np.int64)
        # the image with background filled in and a one-pixel background border: a pixel off
        # the image reads the border (clipped index), a pixel off the hand the background
        # (relative: marked -1 here, read as the point's depth + BACKGROUND_REL_M below, so
        # that no feature depends on how far the hand is from the camera)
        img = getattr(self, "_padded", None)
        if img is None:
            h, w = self.depth.shape
            back = np.float32(-1.0 if self.relative else BACKGROUND_M)
            img = np.full((h + 2, w + 2), back, np.float32)
            img[1:-1, 1:-1] = np.where(self.depth > 0, self.depth, back)
            self._padded = img
        h, w = img.shape
        u += 1 - self.u0   # the padded image's column and row
        v += 1 - self.v0
        np.clip(u, 0, w - 1, out=u)
        np.clip(v, 0, h - 1, out=v)
        v *= w
        v += u
        d = img.ravel().take(v)
        if self.relative:
            d = np.where(d < 0, (pts[..., 2] + BACKGROUND_REL_M).astype(d.dtype), d)
        return d


@dataclass
class FeatureSet:
    """F shape-indexed pixel-pair features (eq. II.15) in one reference frame."""

    m1: np.ndarray   # (F,) vertex indices
    d1: np.ndarray   # (F, 3) offsets in the reference frame [m]
    m2: np.ndarray
    d2: np.ndarray

    @classmethod
    def sample(cls, rest_vertices: np.ndarray, region: np.ndarray, frame_rot: np.ndarray,
               n: int, radius: float, rng: np.random.Generator) -> FeatureSet:
        """Sample 3D points around the ``region`` vertices of the rest-pose model (hand frame),
        attach each to its nearest vertex, express the offset in the frame ``frame_rot``."""
        out = []
        for _ in range(2):
            base = rest_vertices[rng.choice(region, n)]
            dirs = rng.normal(size=(n, 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            P = base + dirs * (radius * rng.random(n) ** (1 / 3))[:, None]
            d2 = ((P[:, None, :] - rest_vertices[None, region, :]) ** 2).sum(axis=2)
            m = region[np.argmin(d2, axis=1)]
            out.append((m.astype(np.int32), ((P - rest_vertices[m]) @ frame_rot).astype(
                np.float32)))
        return cls(out[0][0], out[0][1], out[1][0], out[1][1])

    @property
    def vertex_ids(self) -> np.ndarray:
        return np.unique(np.r_[self.m1, self.m2])

    def evaluate(self, V: dict[int, np.ndarray] | np.ndarray, R: np.ndarray,
                 lookup: DepthLookup) -> np.ndarray:
        """Feature values (F,) given vertex positions (indexable by vertex id) and the world
        rotation ``R`` of the reference frame."""
        p1 = V[self.m1] + self.d1 @ R.T
        p2 = V[self.m2] + self.d2 @ R.T
        return lookup(p1) - lookup(p2)

    def local_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(vertex_ids, m1, m2)`` with m1 / m2 as positions in ``vertex_ids`` (cached)."""
        li = getattr(self, "_local", None)
        if li is None:
            ids, inv = np.unique(np.r_[self.m1, self.m2], return_inverse=True)
            li = (ids, inv[:len(self.m1)], inv[len(self.m1):])
            self._local = li
        return li

    def evaluate_batch(self, V: np.ndarray, R: np.ndarray, lookup: DepthLookup
                       ) -> np.ndarray:
        """Feature values (B, F) for vertex sets (B, V, 3) and frame rotations (B, 3, 3)."""
        Rt = np.swapaxes(R, 1, 2)
        p1 = V[:, self.m1] + np.matmul(self.d1[None].astype(np.float64), Rt)
        p2 = V[:, self.m2] + np.matmul(self.d2[None].astype(np.float64), Rt)
        return lookup(p1) - lookup(p2)

    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}m1": self.m1, f"{prefix}d1": self.d1, f"{prefix}m2": self.m2,
                f"{prefix}d2": self.d2}

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray], prefix: str) -> FeatureSet:
        return cls(np.asarray(a[prefix + "m1"]), np.asarray(a[prefix + "d1"]),
                   np.asarray(a[prefix + "m2"]), np.asarray(a[prefix + "d2"]))


# ------------------------------------------------------------------------------------------
# Inverse kinematics of the fingers
# ------------------------------------------------------------------------------------------
def ik_fingers(model: HandModel, q: np.ndarray, targets: np.ndarray, iterations: int = 2,
               damping: float = 1e-4) -> np.ndarray:
    """Finger angles (palm fixed) moving the 15 finger keypoints ``FINGER_KP`` towards
    ``targets`` (5, 3, 3): damped Gauss-Newton with the keypoint Jacobian, clamped to limits.
    Works on one pose (27,) or a batch (B, 27) with targets (B, 5, 3, 3)."""
    single = q.ndim == 1
    Q = np.atleast_2d(q).copy()
    T = targets.reshape(len(Q), 15, 3)
    rows = FINGER_KP.reshape(-1)
    lo, hi = JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1]
    for _ in range(iterations):
        kp, J = model.keypoints_and_jacobian(Q, rows, _FINGER_ALL)     # (B, 15, 3 (, 21))
        J = J.reshape(len(Q), 45, 21)
        r = (kp - T).reshape(len(Q), 45)
        Jt = np.swapaxes(J, 1, 2)
        A = Jt @ J + damping * np.eye(21)[None]
        g = (Jt @ r[..., None])[..., 0]
        dq = -np.linalg.solve(A, g[..., None])[..., 0]
        Q[:, 6:] = np.clip(Q[:, 6:] + dq, lo, hi)
    return Q[0] if single else Q


# ------------------------------------------------------------------------------------------
# The regressor
# ------------------------------------------------------------------------------------------
@dataclass
class HandRegressor:
    """Trained cascades: ``palm[s]`` and ``fingers[s][f]`` with their feature sets."""

    palm_features: list[FeatureSet]
    palm_forests: list[RegressionForest]
    finger_features: list[list[FeatureSet]]
    finger_forests: list[list[RegressionForest]]
    ik_iterations: int = 2
    info: dict[str, str] = field(default_factory=dict)

    @property
    def palm_stages(self) -> int:
        return len(self.palm_forests)

    def lookup(self, depth: np.ndarray, u0: int, v0: int, intr: Intrinsics) -> DepthLookup:
        """The :class:`DepthLookup` this model's features were trained with (a relative
        background when ``info["background"]`` says so; older files: the constant)."""
        return DepthLookup(depth, u0, v0, intr,
                           relative=self.info.get("background") == "relative")

    @property
    def finger_stages(self) -> int:
        return len(self.finger_forests)

    # ------------------------------------------------------------------------ one stage
    @staticmethod
    def palm_features_at(fs: FeatureSet, frames: ModelFrames, q: np.ndarray,
                         lookup: DepthLookup) -> np.ndarray:
        V = frames.model.vertices(q)
        R, _ = frames.palm_pose(q)
        return fs.evaluate(V, R, lookup)

    @staticmethod
    def palm_update(frames: ModelFrames, q: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """Apply a palm keypoint update (18,) in the current palm frame (eq. II.17)."""
        R, t = frames.palm_pose(q)
        cur = frames.palm_local @ R.T + t
        new = cur + delta.reshape(6, 3) @ R.T
        R2, t2 = kabsch(frames.palm_local, new)
        return frames.set_palm(q, R2, t2)

    @staticmethod
    def palm_target(frames: ModelFrames, q: np.ndarray, q_true: np.ndarray,
                    true_model: HandModel | None = None) -> np.ndarray:
        R, t = frames.palm_pose(q)
        cur = frames.palm_local @ R.T + t
        m = true_model or frames.model
        true = m.joint_positions(q_true)[PALM_KP]
        return ((true - cur) @ R).reshape(-1)

    @staticmethod
    def finger_frames(frames: ModelFrames, q: np.ndarray) -> np.ndarray:
        """(5, 3, 3) world rotations of the finger-root frames (fingers straight, T_f)."""
        R, _ = frames.palm_pose(q)
        return np.einsum("ij,fjk->fik", R, frames.finger_rot)

    # ------------------------------------------------------------------------- inference
    def _palm_features_fast(self, fs: FeatureSet, frames: ModelFrames, q: np.ndarray,
                            lookup: DepthLookup) -> np.ndarray:
        """:meth:`palm_features_at` skinning only the vertices the features use."""
        ids, m1, m2 = fs.local_index()
        rows, rest = frames.cached(fs, lambda: _rows_and_rest(frames.model, ids))
        R = root_rotation_matrix(q[3:6])
        if q[6:].any():
            V = rows @ frames.model.bone_basis(q)[0]
        else:  # straight fingers: the hand moves rigidly with the palm
            V = rest @ R.T + q[0:3]
        n = len(m1)
        p = np.concatenate([V[m1] + fs.d1 @ R.T, V[m2] + fs.d2 @ R.T])
        d = lookup(p)
        return d[:n] - d[n:]

    def _finger_stage(self, s: int, frames: ModelFrames) -> dict:
        """Constants of finger stage ``s`` for this model: all five feature sets' vertices
        (and the keypoints) skinned by one sparse product, the five forests as a group."""
        feats = self.finger_features[s]

        def make() -> dict:
            ids = np.unique(np.concatenate([fs.vertex_ids for fs in feats]))
            pos = np.searchsorted(ids, np.stack([np.r_[fs.m1, fs.m2] for fs in feats]))
            n = len(feats[0].m1)
            model = frames.model
            rows = sp.vstack([model.skinning_rows(ids), sp.csr_matrix(model.keypoint_rows())],
                             format="csr")
            rest = rows @ model.bone_basis(np.zeros(N_DOF))[0]
            # per finger the 2F feature points: F first points, then F second points
            return {"rows": rows, "rest": rest, "n_v": len(ids), "m": pos, "n": n,
                    "d": np.stack([np.r_[fs.d1, fs.d2] for fs in feats]).astype(np.float64),
                    "group": ForestGroup(self.finger_forests[s])}

        return frames.cached(feats[0], make)

    def palm_modes(self, frames: ModelFrames, lookup: DepthLookup, q0: np.ndarray,
                   n_modes: int) -> list[np.ndarray]:
        """Palm candidates: the cascade from ``q0``, the last stage split into modes."""
        q = q0.copy()
        for s, (fs, forest) in enumerate(zip(self.palm_features, self.palm_forests,
                                             strict=True)):
            x = self._palm_features_fast(fs, frames, q, lookup)
            if s < self.palm_stages - 1 or n_modes <= 1:
                q = self.palm_update(frames, q, forest.predict(x[None])[0])
            else:
                centres, _ = forest.predict_modes(x, n_modes)
                return [self.palm_update(frames, q, c) for c in centres]
        return [q]

    def regress_fingers(self, frames: ModelFrames, lookup: DepthLookup, q: np.ndarray,
                        ik_iterations: int | None = None) -> np.ndarray:
        """Finger cascade (eq. II.18) from straight fingers, palm of ``q`` kept.

        ``q`` is one pose (27,) or a batch (B, 27) (the palm candidates of one frame, all
        regressed together).
        """
        single = q.ndim == 1
        Q = np.atleast_2d(q).copy()
        Q[:, 6:] = 0.0
        for s in range(self.finger_stages):
            targets = self.finger_targets(s, frames, lookup, Q)
            Q = ik_fingers(frames.model, Q, targets, ik_iterations or self.ik_iterations)
        return Q[0] if single else Q

    def finger_targets(self, s: int, frames: ModelFrames, lookup: DepthLookup, Q: np.ndarray,
                       T: np.ndarray | None = None) -> np.ndarray:
        """Stage ``s`` of the finger cascade (eq. II.18) for poses ``Q`` (B, 27): the finger
        keypoints ``FINGER_KP`` moved by the stage's regressed offsets, (B, 5, 3, 3) [m].
        ``T``: ``frames.model.bone_basis(Q)[0]`` when the caller has it (B, 64, 3)."""
        st = self._finger_stage(s, frames)
        model = frames.model
        B = len(Q)
        R0 = root_rotation_matrix(Q[:, 3:6])                                 # palm bone
        if Q[:, 6:].any():
            T = model.bone_basis(Q)[0] if T is None else T                   # (B, 64, 3)
            P = st["rows"] @ np.swapaxes(T, 0, 1).reshape(T.shape[1], 3 * B)
            P = np.swapaxes(P.reshape(-1, B, 3), 0, 1)                      # (B, n, 3)
        else:  # straight fingers (first stage): the hand moves rigidly with the palm
            P = np.matmul(st["rest"][None], np.swapaxes(R0, 1, 2)) + Q[:, None, 0:3]
        V, kp = P[:, :st["n_v"]], P[:, st["n_v"]:]
        # finger-root frames T_f (B, 5, 3, 3): palm rotation times the rest frames
        Rf = np.einsum("bij,fjk->bfik", R0, frames.finger_rot)
        Rt = np.swapaxes(Rf, 2, 3)
        p = V[:, st["m"]] + np.matmul(st["d"][None], Rt)                     # (B, 5, 2F, 3)
        d = lookup(p)                                                       # (B, 5, 2F)
        n = st["n"]
        x = d[..., :n] - d[..., n:]                                         # eq. II.15
        delta = st["group"].predict(x).reshape(B, 5, 3, 3)
        return kp[:, FINGER_KP] + np.einsum("bfkj,bfij->bfki", delta, Rf)

    def predict(self, frames: ModelFrames, lookup: DepthLookup, points: np.ndarray,
                n_modes: int = 3) -> list[np.ndarray]:
        """Full hand candidates for one frame (palm modes, each with finger regression)."""
        q0 = palm_init_pca(points, frames)
        palms = np.array(self.palm_modes(frames, lookup, q0, n_modes))
        return list(self.regress_fingers(frames, lookup, palms))

    # ------------------------------------------------------------------------------- I/O
    def save(self, path: str | Path) -> None:
        arrays: dict[str, np.ndarray] = {
            "palm_stages": np.array(self.palm_stages),
            "finger_stages": np.array(self.finger_stages),
            "ik_iterations": np.array(self.ik_iterations),
            "info_keys": np.array(list(self.info.keys()), dtype=str),
            "info_values": np.array(list(self.info.values()), dtype=str),
        }
        for s in range(self.palm_stages):
            arrays.update(self.palm_features[s].to_arrays(f"pf{s}_"))
            arrays.update(self.palm_forests[s].to_arrays(f"pr{s}_"))
        for s in range(self.finger_stages):
            for f in range(5):
                arrays.update(self.finger_features[s][f].to_arrays(f"ff{s}_{f}_"))
                arrays.update(self.finger_forests[s][f].to_arrays(f"fr{s}_{f}_"))
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(p, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> HandRegressor:
        p = Path(path)
        try:
            a = dict(np.load(p, allow_pickle=False))
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read tracker model {p}: {e}") from e
        try:
            ps, fsn = int(a["palm_stages"]), int(a["finger_stages"])
            return cls(
                [FeatureSet.from_arrays(a, f"pf{s}_") for s in range(ps)],
                [RegressionForest.from_arrays(a, f"pr{s}_") for s in range(ps)],
                [[FeatureSet.from_arrays(a, f"ff{s}_{f}_") for f in range(5)]
                 for s in range(fsn)],
                [[RegressionForest.from_arrays(a, f"fr{s}_{f}_") for f in range(5)]
                 for s in range(fsn)],
                int(a["ik_iterations"]),
                dict(zip(a["info_keys"].tolist(), a["info_values"].tolist(), strict=True)))
        except KeyError as e:
            raise InputError(f"tracker model {p} lacks {e}") from e


class RegressorSet:
    """Several trained cascades whose candidates join one pool (a departure from II.4, which
    trains one): every member's palm modes (step 1), and every member's finger regression
    (step 2) on all of those palms. Members trained on other seeds or other training
    surfaces miss the true pose in different ways on a hand unlike the training's, so the
    pool more often holds a candidate in its basin (issue 13: the held-out misses are the
    search's). The same interface as :class:`HandRegressor` where the tracker uses it.

    Args:
        members: the cascades, at least one; the first one's ``info`` is the set's.
    """

    def __init__(self, members: Sequence[HandRegressor]) -> None:
        if not members:
            raise InputError("a RegressorSet needs at least one HandRegressor")
        self.members = tuple(members)
        self.info = self.members[0].info
        self.ik_iterations = self.members[0].ik_iterations

    def lookup(self, depth: np.ndarray, u0: int, v0: int, intr: Intrinsics
               ) -> tuple[DepthLookup, ...]:
        """Every member's :meth:`HandRegressor.lookup` (their backgrounds may differ)."""
        return tuple(m.lookup(depth, u0, v0, intr) for m in self.members)

    def palm_modes(self, frames: ModelFrames, lookup: tuple[DepthLookup, ...],
                   q0: np.ndarray, n_modes: int) -> list[np.ndarray]:
        """Every member's ``n_modes`` palm candidates, member by member."""
        out: list[np.ndarray] = []
        for m, lk in zip(self.members, lookup, strict=True):
            out += m.palm_modes(frames, lk, q0, n_modes)
        return out

    def regress_fingers(self, frames: ModelFrames, lookup: tuple[DepthLookup, ...],
                        q: np.ndarray, ik_iterations: int | None = None) -> np.ndarray:
        """Every member's finger cascade on every palm of ``q`` (B, 27): (M * B, 27).

        Stage by stage, one FK pass and one inverse kinematics solve for all members'
        poses (each member's own features and forests): the same poses as each member's
        :meth:`HandRegressor.regress_fingers` in turn (members with other stage counts or
        IK iterations are run so)."""
        Q = np.atleast_2d(q)
        its = {ik_iterations or m.ik_iterations for m in self.members}
        stages = {m.finger_stages for m in self.members}
        if len(its) > 1 or len(stages) > 1:
            return np.concatenate([m.regress_fingers(frames, lk, Q, ik_iterations)
                                   for m, lk in zip(self.members, lookup, strict=True)])
        B, n_its = len(Q), its.pop()
        Qs = np.tile(Q, (len(self.members), 1))
        Qs[:, 6:] = 0.0
        for s in range(stages.pop()):
            T = frames.model.bone_basis(Qs)[0] if Qs[:, 6:].any() else None
            targets = np.concatenate([
                m.finger_targets(s, frames, lk, Qs[i * B:(i + 1) * B],
                                 None if T is None else T[i * B:(i + 1) * B])
                for i, (m, lk) in enumerate(zip(self.members, lookup, strict=True))])
            Qs = ik_fingers(frames.model, Qs, targets, n_its)
        return Qs
