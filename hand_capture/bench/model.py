"""Benchmark of the hand model: FK + LBS, batched FK + LBS, Jacobians (``hand-suite bench model``).

Baselines measured in the same run:

* FK + LBS (the headline): :class:`VectorisedHand`, the textbook vectorised numpy
  implementation -- batched Rodrigues rotations composed bone by bone (vectorised over poses),
  then linear blend skinning by blending the 16 bones' 3x4 skinning matrices per vertex with
  one ``einsum`` and applying them;
* FK + LBS, extra row: :class:`NaiveHand`, one 4x4 homogeneous transform per joint composed in
  a Python loop, then skinning as a sum over all 16 bones of weight x transformed vertex;
* Jacobian: central finite differences of the model's own (fast) vertex function, 54 calls.

Figures (JSON keys): ``fk_lbs_ms`` (one pose, FK + LBS of all vertices + keypoints),
``fk_lbs_batch100_ms`` (100 poses in one call), ``jacobian_ms`` (analytic pose Jacobian of every
vertex), ``jacobian_300_ms`` (300 vertices, what a tracker iteration uses), the baselines and
the speed-up ratios (``fk_lbs_speedup``, ``fk_lbs_batch_speedup``: against the vectorised
baseline; ``*_vs_naive``: against the naive one).

A renderer can add its figures: if ``hand_capture.cameras.synthetic`` defines
``render_benchmark(model, quick) -> dict`` its result is merged into the figures (e.g.
``render_fps``); its headline baseline is Open3D's ``RaycastingScene``
(``render_speedup_vs_raycast``), the per-triangle renderer an extra row.
"""

from __future__ import annotations

import importlib
import time
from typing import Any

import numpy as np

from hand_capture.bench import json_line, print_table, time_calls
from hand_capture.model import JOINT_LIMITS, HandModel, sample_shape
from hand_capture.model.skeleton import BONE_ABD_DOF, BONE_FLEX_DOF, BONE_PARENT, N_BONES


def _random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    lo = np.r_[-0.2, -0.2, 0.3, -np.pi, -1.2, -np.pi, JOINT_LIMITS[6:, 0]]
    hi = np.r_[0.2, 0.2, 0.6, np.pi, 1.2, np.pi, JOINT_LIMITS[6:, 1]]
    return rng.uniform(lo, hi, size=(n, 27))


def _hinge(axis: np.ndarray, angle: float) -> np.ndarray:
    """4x4 rotation about a unit axis (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    return t


class NaiveHand:
    """Per-joint loop FK with 4x4 matrices and dense per-bone LBS (the baseline)."""

    def __init__(self, model: HandModel) -> None:
        sk = model._sk
        self.rest = []
        for b in range(N_BONES):
            t = np.eye(4)
            t[:3, :3] = sk.rest_rot[b]
            t[:3, 3] = model._offset[b]
            self.rest.append(t)
        self.abd_axis = np.array([0.0, 0.0, sk.abd_axis_sign])
        self.weights = model.skinning_weights
        gr, gt = model._gr, model._gt
        self.inv_rest = [np.vstack([np.c_[gr[b], gt[b]], [0, 0, 0, 1]]) for b in range(N_BONES)]
        self.vt = np.c_[model._vt, np.ones(model.n_vertices)]

    def frames(self, q: np.ndarray) -> list[np.ndarray]:
        out = []
        for b in range(N_BONES):
            if b == 0:
                t = np.eye(4)
                t[:3, 3] = q[:3]
                for k, ax in enumerate(np.eye(3)):
                    t = t @ _hinge(ax, q[3 + k])
            else:
                t = out[BONE_PARENT[b]] @ self.rest[b]
                if BONE_ABD_DOF[b] >= 0:
                    t = t @ _hinge(self.abd_axis, q[BONE_ABD_DOF[b]])
                t = t @ _hinge(np.array([0.0, 1.0, 0.0]), q[BONE_FLEX_DOF[b]])
            out.append(t)
        return out

    def vertices(self, q: np.ndarray) -> np.ndarray:
        fr = self.frames(q)
        v = np.zeros((len(self.vt), 3))
        for b in range(N_BONES):
            v += self.weights[:, b:b + 1] * (self.vt @ (fr[b] @ self.inv_rest[b]).T)[:, :3]
        return v


def _rotations(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations about the unit ``axis`` by the ``angle`` (n,) (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


class VectorisedHand:
    """FK vectorised over poses and LBS by blended skinning matrices (the strong baseline)."""

    def __init__(self, model: HandModel) -> None:
        sk = model._sk
        self.rest_rot = sk.rest_rot
        self.offset = model._offset
        self.abd_axis = np.array([0.0, 0.0, sk.abd_axis_sign])
        self.weights = model.skinning_weights  # (V, 16)
        self.gr, self.gt = model._gr, model._gt  # inverse rest transforms
        self.vt = model._vt  # (V, 3) rest vertices

    def frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bone rotations (n, 16, 3, 3) and origins (n, 16, 3) of the poses ``q`` (n, 27)."""
        n = q.shape[0]
        rot = np.empty((n, N_BONES, 3, 3))
        pos = np.empty((n, N_BONES, 3))
        ex, ey, ez = np.eye(3)
        rot[:, 0] = _rotations(ex, q[:, 3]) @ _rotations(ey, q[:, 4]) @ _rotations(ez, q[:, 5])
        pos[:, 0] = q[:, :3]
        for b in range(1, N_BONES):
            p = BONE_PARENT[b]
            r = rot[:, p] @ self.rest_rot[b]
            if BONE_ABD_DOF[b] >= 0:
                r = r @ _rotations(self.abd_axis, q[:, BONE_ABD_DOF[b]])
            rot[:, b] = r @ _rotations(ey, q[:, BONE_FLEX_DOF[b]])
            pos[:, b] = pos[:, p] + rot[:, p] @ self.offset[b]
        return rot, pos

    def vertices(self, q: np.ndarray) -> np.ndarray:
        """Skinned vertices (n, V, 3) of the poses ``q`` (n, 27)."""
        rot, pos = self.frames(q)
        skin = np.empty(rot.shape[:2] + (3, 4))  # frame x inverse rest, per bone
        skin[..., :3] = rot @ self.gr
        skin[..., 3] = (rot @ self.gt[..., None])[..., 0] + pos
        # (V, 16) @ (n, 16, 12): the per-vertex blended 3x4 matrices in one BLAS product
        blended = (self.weights @ skin.reshape(len(q), N_BONES, 12)).reshape(
            len(q), -1, 3, 4)
        return np.einsum("nvij,vj->nvi", blended[..., :3], self.vt, optimize=True) \
            + blended[..., 3]


def _optional_render_figures(model: HandModel, quick: bool) -> dict[str, Any]:
    try:
        synthetic = importlib.import_module("hand_capture.cameras.synthetic")
    except ImportError:
        return {}
    fn = getattr(synthetic, "render_benchmark", None)
    if fn is None:
        return {}
    return dict(fn(model, quick))


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """Measure and print; returns the figures (see the module docstring). ``smoke``: a few
    calls of each (the renderer's quick run)."""
    n = 5 if smoke else 30 if quick else 200
    quick = quick or smoke
    t0 = time.perf_counter()
    model = HandModel(sample_shape(0))
    build_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    poses = _random_poses(rng, 100)
    q = poses[0]
    idx300 = rng.choice(model.n_vertices, 300, replace=False)
    naive = NaiveHand(model)
    naive_err = float(np.abs(naive.vertices(q) - model.vertices(q)).max())
    vec = VectorisedHand(model)
    vec_err = float(np.abs(vec.vertices(poses) - model.vertices(poses)).max())
    q1 = q[None]

    def fd_jac() -> np.ndarray:
        cols = []
        for k in range(27):
            d = np.zeros(27)
            d[k] = 1e-6
            cols.append((model.vertices(q + d) - model.vertices(q - d)) / 2e-6)
        return np.stack(cols, axis=-1)

    jac_err = float(np.abs(fd_jac() - model.jacobian(q)).max())
    ms = 1e3
    t_fk = np.median(time_calls(lambda: model.forward(q), n)) * ms
    t_batch = np.median(time_calls(lambda: model.forward(poses), max(n // 10, 5))) * ms
    t_jac = np.median(time_calls(lambda: model.jacobian(q), n)) * ms
    t_jac300 = np.median(time_calls(lambda: model.jacobian(q, idx300), n)) * ms
    t_kpjac = np.median(time_calls(lambda: model.keypoint_jacobian(q), n)) * ms
    t_shape = np.median(time_calls(lambda: model.shape_jacobian(q, idx300), n)) * ms
    t_normals = np.median(time_calls(lambda: model.normals(model.vertices(q)), n)) * ms
    t_naive = np.median(time_calls(lambda: naive.vertices(q), max(n // 3, 5))) * ms
    t_naive_fk = np.median(time_calls(lambda: naive.frames(q), n)) * ms
    t_fk_only = np.median(time_calls(lambda: model.joint_positions(q), n)) * ms
    t_fd = np.median(time_calls(fd_jac, max(n // 10, 3), warmup=1)) * ms
    t_vec = np.median(time_calls(lambda: vec.vertices(q1), n)) * ms
    t_vec_batch = np.median(time_calls(lambda: vec.vertices(poses), max(n // 10, 5))) * ms
    t_vec_fk = np.median(time_calls(lambda: vec.frames(q1), n)) * ms

    nan = float("nan")
    rows = [
        ("FK + LBS, 1 pose", t_fk, "vectorised numpy", t_vec, t_vec / t_fk),
        ("FK + LBS, 100 poses (per call)", t_batch, "vectorised numpy", t_vec_batch,
         t_vec_batch / t_batch),
        ("FK only (bone frames / 21 keypoints)", t_fk_only, "vectorised numpy", t_vec_fk,
         t_vec_fk / t_fk_only),
        ("FK + LBS, 1 pose", t_fk, "naive 4x4 loop", t_naive, t_naive / t_fk),
        ("FK + LBS, 100 poses (per call)", t_batch, "naive 4x4 loop", 100 * t_naive,
         100 * t_naive / t_batch),
        ("FK only (21 keypoints)", t_fk_only, "naive 4x4 loop", t_naive_fk,
         t_naive_fk / t_fk_only),
        ("pose Jacobian, all vertices", t_jac, "finite differences", t_fd, t_fd / t_jac),
        ("pose Jacobian, 300 vertices", t_jac300, "", nan, nan),
        ("keypoint Jacobian (21)", t_kpjac, "", nan, nan),
        ("shape Jacobian, 300 vertices", t_shape, "", nan, nan),
        ("vertex normals", t_normals, "", nan, nan),
    ]
    print_table(f"hand model ({model.n_vertices} vertices, {len(model.faces)} faces), "
                f"median of {n} calls [ms]; headline baseline = vectorised numpy FK + "
                "blended-matrix LBS", ["operation", "ms", "baseline", "baseline ms",
                                       "speed-up"], rows)
    print(f"template build {build_s:.2f} s; max vertex difference to the model: vectorised "
          f"{vec_err:.2e} m, naive {naive_err:.2e} m; analytic vs finite-difference Jacobian "
          f"{jac_err:.2e}")
    figures: dict[str, Any] = {
        "bench": "model",
        "quick": quick,
        "n_vertices": model.n_vertices,
        "fk_lbs_ms": t_fk,
        "fk_lbs_batch100_ms": t_batch,
        "jacobian_ms": t_jac,
        "jacobian_300_ms": t_jac300,
        "keypoint_jacobian_ms": t_kpjac,
        "shape_jacobian_300_ms": t_shape,
        "normals_ms": t_normals,
        "baseline_fk_lbs_ms": t_vec,
        "baseline_fk_lbs_batch100_ms": t_vec_batch,
        "baseline_jacobian_fd_ms": t_fd,
        "fk_lbs_speedup": t_vec / t_fk,
        "fk_lbs_batch_speedup": t_vec_batch / t_batch,
        "vectorised_max_diff_m": vec_err,
        "naive_fk_lbs_ms": t_naive,
        "fk_lbs_speedup_vs_naive": t_naive / t_fk,
        "fk_lbs_batch_speedup_vs_naive": 100 * t_naive / t_batch,
        "jacobian_speedup": t_fd / t_jac,
        "naive_max_diff_m": naive_err,
        "jacobian_fd_max_diff": jac_err,
        "template_build_s": build_s,
    }
    figures.update(_optional_render_figures(model, quick))
    return figures


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    print(json_line(run(quick=args.quick)))


if __name__ == "__main__":
    main()
