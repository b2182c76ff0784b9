"""Motions for held-out evaluation, not built from the suite's keyframe clips.

Finger trajectories are either sums of sinusoids per joint (random frequencies, phases and
amplitudes around a random mid-pose) or a smoothed random walk of per-finger closure with
independent joint jitter; every finger angle is clipped into the model's joint limits.
The wrist follows a Lissajous or random-walk path in front of the camera, and the palm
orientation a random smooth rotation (tilt, yaw and roll around a palm-to-camera view).
Nothing here reads ``hand_capture.cameras.motion`` or the training pose library.
"""

from __future__ import annotations

import math

import numpy as np

from hand_capture.model import JOINT_LIMITS, N_DOF
from hand_capture.model.joints import root_angles_from_matrix

__all__ = ["FPS", "palm_view", "random_motion"]

FPS = 30.0
#: the palm faces the camera, fingers up: hand +x -> image up (-y), +z (dorsal) -> +z
_VIEW = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _rotvec(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    if th < 1e-12:
        return np.eye(3)
    a = v / th
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def palm_view(tilt: np.ndarray | None = None) -> np.ndarray:
    """Rotation hand -> camera: palm towards the camera, then the camera-frame rotation
    vector ``tilt`` (3,) [rad]."""
    R = _VIEW
    if tilt is not None:
        R = _rotvec(np.asarray(tilt, float)) @ R
    return R


def _smooth_walk(rng: np.random.Generator, n: int, dims: int, sd: float, corr: float
                 ) -> np.ndarray:
    """(n, dims) Ornstein-Uhlenbeck walk, step correlation ``corr`` per frame, stationary
    standard deviation ``sd``, then a 5-frame moving average."""
    x = np.zeros((n, dims))
    x[0] = rng.normal(0.0, sd, dims)
    k = math.sqrt(1 - corr ** 2)
    for i in range(1, n):
        x[i] = corr * x[i - 1] + k * rng.normal(0.0, sd, dims)
    ker = np.ones(5) / 5
    return np.stack([np.convolve(np.pad(x[:, j], 2, mode="edge"), ker, "valid")
                     for j in range(dims)], axis=1)


def random_motion(rng: np.random.Generator, n_frames: int, *, depth_m: tuple[float, float]
                  = (0.32, 0.55), kind: str | None = None, max_tilt_deg: float = 40.0
                  ) -> np.ndarray:
    """Poses (n_frames, 27) at :data:`FPS`: hand in front of the camera at ``depth_m``.

    Args:
        rng: seeds everything.
        n_frames: length.
        depth_m: range of the palm's distance to the camera [m].
        kind: ``"sine"`` or ``"walk"`` finger trajectories; None = drawn.
        max_tilt_deg: largest palm rotation away from the palm-to-camera view [deg].
    """
    t = np.arange(n_frames) / FPS
    kind = kind or ("sine" if rng.random() < 0.5 else "walk")
    lo, hi = JOINT_LIMITS[6:, 0].copy(), JOINT_LIMITS[6:, 1].copy()
    # keep abductions modest (a free random abduction looks like no hand)
    q = np.zeros((n_frames, N_DOF))
    nf = N_DOF - 6
    if kind == "sine":
        mid = lo + (hi - lo) * rng.uniform(0.15, 0.55, nf)
        amp = (hi - lo) * rng.uniform(0.05, 0.35, nf)
        f1 = rng.uniform(0.15, 0.6, nf)
        f2 = rng.uniform(0.6, 1.2, nf)
        ph = rng.uniform(0, 2 * math.pi, (2, nf))
        q[:, 6:] = mid + amp * (0.8 * np.sin(2 * math.pi * f1 * t[:, None] + ph[0])
                                + 0.2 * np.sin(2 * math.pi * f2 * t[:, None] + ph[1]))
    else:
        closure = 0.5 + 0.5 * np.tanh(_smooth_walk(rng, n_frames, 5, 1.2, 0.97))
        base = lo + (hi - lo) * 0.1
        q[:, 6:] = base + _smooth_walk(rng, n_frames, nf, 0.12, 0.95)
        names = _finger_columns()
        for f, cols in enumerate(names):
            for c in cols:
                if c in _FLEX:
                    q[:, c] += closure[:, f] * (hi[c - 6] - lo[c - 6]) * 0.7
    abd = np.array([c for c in range(6, N_DOF) if c not in _FLEX])
    q[:, abd] *= 0.6
    q[:, 6:] = np.clip(q[:, 6:], lo, hi)
    # wrist path and palm orientation
    z0 = rng.uniform(*depth_m)
    zamp = 0.4 * (depth_m[1] - depth_m[0]) * rng.random()
    if rng.random() < 0.5:  # Lissajous
        fx, fy, fz = rng.uniform(0.1, 0.5, 3)
        ph = rng.uniform(0, 2 * math.pi, 3)
        c = np.stack([0.06 * np.sin(2 * math.pi * fx * t + ph[0]),
                      0.04 * np.sin(2 * math.pi * fy * t + ph[1]),
                      z0 + zamp * np.sin(2 * math.pi * fz * t + ph[2])], axis=1)
    else:
        w = _smooth_walk(rng, n_frames, 3, 1.0, 0.985)
        c = np.stack([0.05 * np.tanh(w[:, 0]), 0.035 * np.tanh(w[:, 1]),
                      z0 + zamp * np.tanh(w[:, 2])], axis=1)
    tilt0 = rng.normal(0.0, 0.35, 3) * math.radians(max_tilt_deg)
    tilt_w = _smooth_walk(rng, n_frames, 3, 0.5, 0.98) * math.radians(max_tilt_deg)
    tilt = np.clip(tilt0 + tilt_w, -math.radians(max_tilt_deg), math.radians(max_tilt_deg))
    for i in range(n_frames):
        R = palm_view(tilt[i])
        q[i, 3:6] = root_angles_from_matrix(R)
        # place the palm centre (about 5 cm distal of the wrist) on the path
        q[i, 0:3] = c[i] - R @ np.array([0.05, 0.0, 0.0])
    return q


def _finger_columns() -> list[list[int]]:
    return [list(range(6, 11))] + [list(range(11 + 4 * k, 15 + 4 * k)) for k in range(4)]


#: flexion columns of the 27-vector (thumb TM/MCP/IP flex; MCP/PIP/DIP of the fingers)
_FLEX = frozenset([7, 9, 10] + [c for k in range(4) for c in (12 + 4 * k, 13 + 4 * k,
                                                                  14 + 4 * k)])
