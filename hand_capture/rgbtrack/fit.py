"""Fit the suite's hand model to 2-D hand keypoints (and, when there is one, a depth image).

Unknowns: the 27-DoF pose ``q`` (JOINT_NAMES order) of a hand whose shape (the subject's
calibrated :class:`~hand_capture.model.HandShape`) is known, so the apparent size of the hand
fixes its distance from a colour image alone. Levenberg-Marquardt on the stacked, weighted
residuals

* reprojection: ``(pi(p_k(q)) - u_k) / sigma_px`` for the 21 keypoints ``p_k`` of the model
  (``u = fx x / z + cx``, ``v = fy y / z + cy``), with a Huber weight so that one wrong
  landmark does not drag the hand: Ballan et al.'s (seed 002) projected-point term,
  eq. (2), with detected keypoints in the place of their salient points, minimised as there by
  Levenberg-Marquardt kept inside the joint-limit box;
* depth (optional, aligned depth image): ``(z_k(q) - (d(u_k) + offset)) / sigma_d`` for the
  keypoints whose measured depth lies within ``depth_gate`` of the model (an occluded joint or
  the background further away is ignored); ``offset`` is about a finger radius, since the
  sensor sees the skin in front of the joint centre;
* temporal prior: ``(q - q_prev) / sigma_t`` (warm start from the previous frame, the
  tracking prior of the dissertation's eq. II.21 in a 2-D setting);
* pose prior: ``(q_f - q_neutral_f) / sigma_prior`` on the finger joints (a weak pull that
  resolves the flex-towards / away-from-the-camera ambiguity of a single view).

Jacobians are the model's analytic keypoint Jacobians (eq. II.8 differentiated,
``HandModel.keypoints_and_jacobian``) chained with the pinhole's
``d(u, v)/d(x, y, z) = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]``. The root orientation is
updated by a small rotation in the camera frame (``R <- exp([dw]x) R``) rather than through
its Euler angles, so the fit has no gimbal lock; joint limits are enforced by projecting every
step onto them (a step is accepted only when the projected pose lowers the cost).

A cold start (no previous pose) solves the wrist pose from the six palm-rigid keypoints
(wrist, thumb CMC, four MCPs) with OpenCV's PnP (both planar solutions when there are two)
and keeps the one whose full fit has the lower cost.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.cameras.transforms import matrix_to_rotvec, rotvec_to_matrix
from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model import JOINT_LIMITS, N_DOF, HandModel
from hand_capture.model.joints import root_angles_from_matrix, root_rotation_matrix
from hand_capture.model.keypoints21 import MODEL_TO_21

__all__ = ["PALM_KEYPOINTS", "FitConfig", "FitResult", "KeypointFitter", "project_points",
           "projection_jacobian"]

#: keypoints fixed in the palm frame (wrist, thumb CMC, index..little MCP), common 21 order
#: (``hand_capture.model.keypoints21``; detector pixels and fitted keypoints use it)
PALM_KEYPOINTS = np.array([0, 1, 5, 9, 13, 17])
_LO = JOINT_LIMITS[:, 0]
_HI = JOINT_LIMITS[:, 1]
_FINGER = np.arange(6, N_DOF)


@dataclass(frozen=True)
class FitConfig:
    """Weights and thresholds of :class:`KeypointFitter`."""

    iterations: int = param(4, "LM iterations per frame when warm-started (4 and 10 give "
                            "the same median error on the bench's suite set; 4 costs 30 % "
                            "less)", lo=1, hi=200)
    init_iterations: int = param(25, "LM iterations from a cold start (per PnP candidate)",
                                 lo=1, hi=500)
    pixel_sigma: float = param(3.0, "expected keypoint detection noise [px]", lo=0.1, hi=100.0)
    huber_px: float = param(8.0, "reprojection error beyond which a keypoint's weight falls "
                            "off (Huber) [px]", lo=0.5, hi=1000.0)
    thumb_cmc_weight: float = param(
        0.3, "weight of the thumb CMC keypoint (detectors place it loosely)", lo=0.0, hi=1.0)
    depth_sigma: float = param(0.008, "depth residual scale [m]", lo=1e-4, hi=1.0)
    depth_gate: float = param(0.04, "ignore a keypoint's depth further than this from the "
                              "model [m] (occlusion, background)", lo=0.001, hi=1.0)
    depth_offset: float = param(0.008, "the skin seen by the depth camera lies this far in "
                                "front of a joint centre [m]", lo=0.0, hi=0.05)
    depth_patch: int = param(2, "half size of the patch whose median depth is sampled [px]",
                             lo=0, hi=10)
    temporal_sigma_rad: float = param(0.25, "frame-to-frame change of a joint angle the prior "
                                      "allows without cost [rad]", lo=1e-3, hi=10.0)
    temporal_sigma_m: float = param(0.03, "frame-to-frame wrist motion the prior allows "
                                    "without cost [m]", lo=1e-4, hi=10.0)
    prior_sigma_rad: float = param(0.8, "spread of the finger-pose prior about the neutral "
                                   "pose [rad]", lo=0.01, hi=100.0)
    damping: float = param(1e-3, "initial Levenberg-Marquardt damping (relative to the "
                           "normal matrix diagonal)", lo=0.0, hi=1e6)
    min_z: float = param(0.05, "nearest plausible wrist distance [m]", lo=0.001, hi=10.0)
    max_z: float = param(3.0, "farthest plausible wrist distance [m]", lo=0.01, hi=100.0)

    def __post_init__(self) -> None:
        validate(self)
        if self.max_z <= self.min_z:
            raise InputError(f"FitConfig.max_z ({self.max_z}) must be > min_z ({self.min_z})")


@dataclass(frozen=True)
class FitResult:
    """Outcome of one fit.

    Attributes:
        pose: (27,) fitted pose in the camera optical frame (within the joint limits).
        keypoints: (21, 3) model keypoints of ``pose`` [m] (camera frame), common 21 order.
        projected: (21, 2) their projections [px].
        rms_px: RMS reprojection error over the keypoints [px].
        hand_px: size of the hand in the image (wrist to middle MCP of the fit) [px].
        depth_used: number of keypoints with a depth residual.
        cost: final value of the weighted objective (unitless).
        iterations: LM iterations run; ok: finite and in front of the camera.
        time_s: wall time of the fit [s].
    """

    pose: np.ndarray
    keypoints: np.ndarray
    projected: np.ndarray
    rms_px: float
    hand_px: float
    depth_used: int
    cost: float
    iterations: int
    ok: bool
    time_s: float

    @property
    def rel_residual(self) -> float:
        """RMS reprojection error relative to the hand's size in the image (unitless)."""
        return self.rms_px / max(self.hand_px, 1e-9)


def project_points(intr: Intrinsics, pts: np.ndarray) -> np.ndarray:
    """Pinhole projection (N, 3) -> (N, 2) [px] (z clamped to 1 mm)."""
    z = np.maximum(pts[:, 2], 1e-3)
    return np.stack([intr.fx * pts[:, 0] / z + intr.cx, intr.fy * pts[:, 1] / z + intr.cy], 1)


def projection_jacobian(intr: Intrinsics, pts: np.ndarray) -> np.ndarray:
    """d(u, v)/d(x, y, z) of the pinhole, (N, 2, 3)."""
    z = np.maximum(pts[:, 2], 1e-3)
    j = np.zeros((len(pts), 2, 3))
    j[:, 0, 0] = intr.fx / z
    j[:, 0, 2] = -intr.fx * pts[:, 0] / z ** 2
    j[:, 1, 1] = intr.fy / z
    j[:, 1, 2] = -intr.fy * pts[:, 1] / z ** 2
    return j





def sample_depth(depth_m: np.ndarray, pixels: np.ndarray, half: int) -> np.ndarray:
    """Median valid depth [m] of a (2 half + 1)^2 patch at each pixel (N,), NaN where none."""
    h, w = depth_m.shape
    out = np.full(len(pixels), np.nan)
    for i, (u, v) in enumerate(np.rint(pixels).astype(np.int64)):
        if not (0 <= u < w and 0 <= v < h):
            continue
        patch = depth_m[max(v - half, 0):v + half + 1, max(u - half, 0):u + half + 1]
        vals = patch[(patch > 0) & np.isfinite(patch)]
        if vals.size:
            out[i] = float(np.median(vals))
    return out


class KeypointFitter:
    """Fits a :class:`HandModel` to 2-D keypoints (module docstring).

    Args:
        model: the hand (side and calibrated shape) to fit.
        config: weights and thresholds.
        neutral: (27,) finger pose the prior pulls towards (default: slightly curled).
    """

    def __init__(self, model: HandModel, config: FitConfig | None = None,
                 neutral: np.ndarray | None = None) -> None:
        self.model = model
        self.config = config or FitConfig()
        if neutral is None:
            neutral = np.zeros(N_DOF)
            neutral[_FINGER] = np.clip(0.3, _LO[_FINGER], _HI[_FINGER])
        self.neutral = np.asarray(neutral, dtype=float)
        self._kp_w = np.ones(21)
        self._kp_w[1] = self.config.thumb_cmc_weight
        c = self.config
        # constant Jacobian rows of the priors (first order in the root rotation)
        self._j_temporal = np.zeros((N_DOF, N_DOF))
        self._j_temporal[0:3, 0:3] = np.eye(3) / c.temporal_sigma_m
        self._j_temporal[3:, 3:] = np.eye(N_DOF - 3) / c.temporal_sigma_rad
        self._j_prior = np.zeros((len(_FINGER), N_DOF))
        self._j_prior[:, _FINGER] = np.eye(len(_FINGER)) / c.prior_sigma_rad
        self._r_prev_t = np.eye(3)
        self._prev_ref: np.ndarray | None = None

    def set_model(self, model: HandModel) -> None:
        """Use another hand (e.g. a newly calibrated shape)."""
        self.model = model

    # ------------------------------------------------------------------------- residuals
    def _residuals(self, q: np.ndarray, obs: np.ndarray, intr: Intrinsics,
                   depth_obs: np.ndarray | None, prev: np.ndarray | None,
                   jac: bool) -> tuple[np.ndarray, np.ndarray | None, dict]:
        """Stacked weighted residual vector and its Jacobian (columns: translation 3, world
        rotation increment 3, finger joints 21)."""
        c = self.config
        if jac:
            kp, jk = self.model.keypoints_and_jacobian(q)
            kp, jk = kp[MODEL_TO_21], jk[MODEL_TO_21]
        else:
            kp, jk = self.model.joint_positions(q)[MODEL_TO_21], None
        uv = project_points(intr, kp)
        e = uv - obs            # Pi(v_k(q)) - p, eq. (2) of seed 002; (21, 2) [px]
        err = np.sqrt(e[:, 0] ** 2 + e[:, 1] ** 2)
        hub = np.where(err <= c.huber_px, 1.0, np.sqrt(c.huber_px / np.maximum(err, 1e-12)))
        w = self._kp_w * hub / c.pixel_sigma                     # (21,)
        res = [(e * w[:, None]).ravel()]
        jrows = []
        if jac:
            # root rotation columns as camera-frame rotations about the wrist: e_i x (p - t)
            d = kp - q[0:3]
            z = np.zeros(len(d))
            jk[:, :, 3] = np.stack([z, -d[:, 2], d[:, 1]], axis=1)
            jk[:, :, 4] = np.stack([d[:, 2], z, -d[:, 0]], axis=1)
            jk[:, :, 5] = np.stack([-d[:, 1], d[:, 0], z], axis=1)
            jp = projection_jacobian(intr, kp)                   # (21, 2, 3)
            jrows.append((np.matmul(jp, jk) * w[:, None, None]).reshape(-1, N_DOF))
        n_depth = 0
        if depth_obs is not None:
            dz = kp[:, 2] - (depth_obs + c.depth_offset)
            use = np.isfinite(dz) & (np.abs(dz) < c.depth_gate)
            n_depth = int(use.sum())
            if n_depth:
                res.append(dz[use] / c.depth_sigma)
                if jac:
                    jrows.append(jk[use, 2, :] / c.depth_sigma)
        if prev is not None:
            dt = np.empty(N_DOF)     # smoothness term, cf. E_smoothness of eq. (II.21)
            dt[0:3] = (q[0:3] - prev[0:3]) / c.temporal_sigma_m
            if self._prev_ref is not prev:
                self._prev_ref, self._r_prev_t = prev, root_rotation_matrix(prev[3:6]).T
            r_rel = root_rotation_matrix(q[3:6]) @ self._r_prev_t
            dt[3:6] = matrix_to_rotvec(r_rel) / c.temporal_sigma_rad
            dt[6:] = (q[6:] - prev[6:]) / c.temporal_sigma_rad
            res.append(dt)
            if jac:
                jrows.append(self._j_temporal)
        res.append((q[_FINGER] - self.neutral[_FINGER]) / c.prior_sigma_rad)
        if jac:
            jrows.append(self._j_prior)
        r = np.concatenate(res)
        info = {"kp": kp, "uv": uv, "err": err, "n_depth": n_depth}
        return r, (np.concatenate(jrows) if jac else None), info

    @staticmethod
    def _apply(q: np.ndarray, step: np.ndarray) -> np.ndarray:
        out = q + step
        rot = rotvec_to_matrix(step[3:6]) @ root_rotation_matrix(q[3:6])
        out[3:6] = root_angles_from_matrix(rot)
        return np.clip(out, _LO, _HI)

    def _lm(self, q: np.ndarray, obs: np.ndarray, intr: Intrinsics,
            depth_obs: np.ndarray | None, prev: np.ndarray | None, iters: int
            ) -> tuple[np.ndarray, float, int]:
        lam = self.config.damping
        r, jm, _ = self._residuals(q, obs, intr, depth_obs, prev, True)
        cost = float(r @ r)
        it = 0
        while it < iters:
            it += 1
            a = jm.T @ jm
            g = jm.T @ r
            diag = np.diag(a).copy()
            improved = False
            for _ in range(6):
                h = a + np.diag(lam * np.maximum(diag, 1e-9)) + 1e-9 * np.eye(N_DOF)
                try:
                    step = -np.linalg.solve(h, g)
                except np.linalg.LinAlgError:
                    lam *= 10.0
                    continue
                qn = self._apply(q, step)    # projected onto the limits (seed 002: in Theta)
                if not (self.config.min_z <= qn[2] <= self.config.max_z):
                    lam *= 10.0
                    continue
                rn, jn, _ = self._residuals(qn, obs, intr, depth_obs, prev, True)
                cn = float(rn @ rn)
                if cn < cost:
                    q, r, jm, lam = qn, rn, jn, max(lam / 3.0, 1e-9)
                    improved = cost - cn > 1e-6 * cost
                    cost = cn
                    break
                lam *= 10.0
            if not improved:
                break
        return q, cost, it

    # ----------------------------------------------------------------------------- init
    def initial_poses(self, obs: np.ndarray, intr: Intrinsics,
                      depth_obs: np.ndarray | None = None) -> list[np.ndarray]:
        """Candidate wrist poses from PnP on the palm keypoints (finger joints neutral)."""
        q0 = self.neutral.copy()
        q0[0:6] = 0.0
        local = self.model.joint_positions(q0)[MODEL_TO_21][PALM_KEYPOINTS]
        img = obs[PALM_KEYPOINTS].astype(np.float64)
        k = intr.K
        cands: list[np.ndarray] = []
        sols: list[tuple[np.ndarray, np.ndarray]] = []
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                local, img, k, None, flags=cv2.SOLVEPNP_IPPE)
            sols += [(np.asarray(rv).ravel(), np.asarray(tv).ravel())
                     for rv, tv in zip(rvecs, tvecs, strict=False)]
        except cv2.error:
            pass
        if not sols:
            try:
                ok, rv, tv = cv2.solvePnP(local, img, k, None, flags=cv2.SOLVEPNP_SQPNP)
                if ok:
                    sols.append((rv.ravel(), tv.ravel()))
            except cv2.error:
                pass
        for rv, tv in sols:
            if not (np.isfinite(rv).all() and np.isfinite(tv).all()):
                continue
            rot, _ = cv2.Rodrigues(rv)
            q = q0.copy()
            q[0:3] = tv
            q[3:6] = root_angles_from_matrix(rot)
            if depth_obs is not None:
                palm = depth_obs[PALM_KEYPOINTS]
                palm = palm[np.isfinite(palm)]
                if palm.size >= 3:
                    # slide along the wrist's ray so the palm's depth matches the image
                    kp = self.model.joint_positions(q)[MODEL_TO_21][PALM_KEYPOINTS]
                    zt = float(np.median(palm)) + self.config.depth_offset
                    s = zt / max(float(np.mean(kp[:, 2])), 1e-6)
                    q[0:3] = q[0:3] * s
            if self.config.min_z <= q[2] <= self.config.max_z:
                cands.append(q)
        if not cands:
            # no PnP: a hand of the model's size at the distance its image size implies
            span = float(np.linalg.norm(obs[9] - obs[0]))
            size = float(np.linalg.norm(local[3] - local[0]))
            z = float(np.clip(intr.fx * size / max(span, 1.0), self.config.min_z,
                              self.config.max_z))
            q = q0.copy()
            q[0:3] = ((obs[0, 0] - intr.cx) * z / intr.fx, (obs[0, 1] - intr.cy) * z / intr.fy,
                      z)
            cands.append(q)
        return cands

    # ------------------------------------------------------------------------------ fit
    def fit(self, pixels: np.ndarray, intr: Intrinsics, *, prev: np.ndarray | None = None,
            depth_m: np.ndarray | None = None) -> FitResult:
        """Fit the model to (21, 2) keypoints [px] in an image with intrinsics ``intr``.

        Args:
            pixels: detected keypoints (KEYPOINT_NAMES order) [px].
            intr: pinhole of the image (and of the aligned depth image).
            prev: (27,) previous pose: warm start and temporal prior; None = cold start.
            depth_m: (H, W) aligned depth [m] (0 / NaN = none), or None.

        Raises:
            InputError: wrong shapes or non-finite keypoints.
        """
        t0 = time.perf_counter()
        obs = np.asarray(pixels, dtype=np.float64)
        if obs.shape != (21, 2) or not np.isfinite(obs).all():
            raise InputError(f"fit: keypoints must be 21 finite (u, v) pixels, got shape "
                             f"{obs.shape}")
        depth_obs = None
        if depth_m is not None:
            d = np.asarray(depth_m)
            if d.shape != (intr.height, intr.width):
                raise InputError(f"fit: depth image {d.shape[::-1]} does not match the "
                                 f"intrinsics {intr.width}x{intr.height}")
            depth_obs = sample_depth(d, obs, self.config.depth_patch)
        c = self.config
        if prev is not None:
            p = np.asarray(prev, dtype=float)
            if p.shape != (N_DOF,) or not np.isfinite(p).all():
                raise InputError(f"fit: prev must be a finite ({N_DOF},) pose")
            q, cost, it = self._lm(np.clip(p, _LO, _HI), obs, intr, depth_obs, p, c.iterations)
        else:
            best = None
            it = 0
            for q0 in self.initial_poses(obs, intr, depth_obs):
                qc, cc, ic = self._lm(q0, obs, intr, depth_obs, None, c.init_iterations)
                it += ic
                if best is None or cc < best[1]:
                    best = (qc, cc)
            q, cost = best
        _, _, info = self._residuals(q, obs, intr, depth_obs, prev, False)
        kp, uv, err = info["kp"], info["uv"], info["err"]
        ok = bool(np.isfinite(q).all() and np.isfinite(cost) and (kp[:, 2] > 0).all())
        return FitResult(pose=q, keypoints=kp, projected=uv,
                         rms_px=float(np.sqrt(np.mean(err ** 2))),
                         hand_px=float(np.linalg.norm(uv[9] - uv[0])),
                         depth_used=info["n_depth"], cost=cost, iterations=it, ok=ok,
                         time_s=time.perf_counter() - t0)
