"""Synthetic benchmark captures with ground truth: a simulation scenario's episode (the
composite controller grasping and lifting its object, ``hand_control.sim.lockstep``) recorded
at the capture rate, then corrupted like a real tracker.

Corruption models (the benchmark develops on one and evaluates on another too):

* ``"tracker"``: independent per-frame noise on the hand pose (root 3 mm / 0.02 rad, fingers
  0.03 rad) and the object pose (2 mm / 0.02 rad), plus a constant flexion error on one or
  two of the grasping fingers that moves the fingertip 10-20 mm (the wrong contacts of seed
  000 Fig. 10: a finger hovering off the object or sunk into it).
* ``"contacts"``: the same noise, but EVERY grasping finger is 10-20 mm off at the tip, each
  independently floating off the object (opened) or sunk into it (closed) with equal
  probability: no grasping finger of the reference has its true contact.
* ``"drift"``: temporally correlated errors (a low-passed random walk) of similar size, the
  finger error growing over the capture and partly in abduction, and 5 % outlier frames of
  the hand pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.model.joints import JOINT_INDEX
from hand_control.physcap.capture import Capture, CapturedObject
from hand_control.sim.lockstep import record_motion
from hand_control.sim.scenario import ScenarioSpec

__all__ = ["SyntheticCapture", "corrupt", "scenario_capture"]

_FLEX = {f: [JOINT_INDEX[n] for n in names] for f, names in {
    "thumb": ("thumb_tm_flex", "thumb_mcp_flex", "thumb_ip_flex"),
    "index": ("index_mcp_flex", "index_pip_flex", "index_dip_flex"),
    "middle": ("middle_mcp_flex", "middle_pip_flex", "middle_dip_flex"),
    "ring": ("ring_mcp_flex", "ring_pip_flex", "ring_dip_flex")}.items()}
_FINGER_LEN = 0.08  # [m] MCP to tip, to turn a tip displacement into a flexion offset


@dataclass(frozen=True, eq=False)
class SyntheticCapture:
    """A corrupted capture and its ground truth (same frames)."""

    capture: Capture
    truth: Capture
    scenario: str
    corruption: str
    finger_errors_mm: dict[str, float]


def _captured_object(spec: ScenarioSpec, size: tuple[float, ...]) -> CapturedObject:
    kind = {"box": "box", "ball": "sphere", "cylinder": "cylinder"}[spec.object_kind]
    return CapturedObject(kind, tuple(size), spec.object_mass, spec.object_friction)


def scenario_capture(spec: ScenarioSpec, fps: float = 20.0, t_start: float | None = None,
                     t_end: float | None = None) -> Capture:
    """The ground-truth capture of a scenario's episode, frames ``t_start`` .. ``t_end``
    (default: from the end of reaching, where the hand is at rest above the object, to the
    end of lifting + 0.2 s)."""
    objects, qpos = record_motion(spec, fps)
    from hand_control.sim.lockstep import object_spec

    _, size = object_spec(spec)
    t_start = spec.t_reach if t_start is None else t_start
    t_end = (spec.t_reach + spec.t_close + spec.t_settle + spec.t_lift + 0.2) \
        if t_end is None else t_end
    times = np.arange(qpos.shape[0]) / fps
    sel = (times >= t_start - 1e-9) & (times <= t_end + 1e-9)
    q = qpos[sel]
    pose = q[:, 27:34].copy()
    pose[:, 3:7] /= np.linalg.norm(pose[:, 3:7], axis=1, keepdims=True)
    return Capture(spec.name, times[sel] - times[sel][0], q[:, 0:27], pose,
                   _captured_object(spec, size))


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, ...], sigma: float,
                  alpha: float = 0.25) -> np.ndarray:
    """Low-passed noise of stationary standard deviation ``sigma`` along axis 0."""
    w = rng.normal(0.0, sigma * np.sqrt((2 - alpha) / alpha), shape)
    out = np.empty(shape)
    acc = np.zeros(shape[1:])
    for i in range(shape[0]):
        acc = (1 - alpha) * acc + alpha * w[i]
        out[i] = acc
    return out


def corrupt(truth: Capture, model: str = "tracker", seed: int = 0,
            fingers: tuple[str, ...] = ("thumb", "index", "middle")) -> SyntheticCapture:
    """``truth`` corrupted by ``model`` (``"tracker"``, ``"contacts"`` or ``"drift"``, see
    the module); ``fingers``: the grasping fingers whose contacts go wrong."""
    rng = np.random.default_rng(seed)
    t = truth.n_frames
    q = truth.hand_q.copy()
    pose = truth.object_pose.copy()
    if model in ("tracker", "contacts"):
        noise = lambda shape, s: rng.normal(0.0, s, shape)
    elif model == "drift":
        noise = lambda shape, s: _smooth_noise(rng, shape, s)
    else:
        raise ValueError(f"unknown corruption model {model!r}")
    q[:, 0:3] += noise((t, 3), 0.003)
    q[:, 3:6] += noise((t, 3), 0.02)
    q[:, 6:27] += noise((t, 21), 0.03)
    # the wrong contacts: one or two (``contacts``: all) grasping fingers off by 10-20 mm at
    # the tip; + = closed (sunk into the object), - = opened (floating off it)
    k = len(fingers) if model == "contacts" else int(rng.integers(1, 3))
    chosen = rng.choice(len(fingers), size=k, replace=False)
    errors: dict[str, float] = {}
    ramp = np.linspace(0.3, 1.0, t) if model == "drift" else np.ones(t)
    p_sink = 0.5 if model == "contacts" else 0.3
    for j in chosen:
        f = fingers[int(j)]
        mm = float(rng.uniform(10.0, 20.0)) * (1 if rng.random() < p_sink else -1)
        errors[f] = mm
        offset = mm * 1e-3 / _FINGER_LEN / len(_FLEX[f]) * 1.5  # spread over the chain
        q[:, _FLEX[f]] += (offset * ramp)[:, None]
        if model == "drift":
            abd = JOINT_INDEX[f"{f}_mcp_abd" if f != "thumb" else "thumb_tm_abd"]
            q[:, abd] += 0.1 * np.sign(mm) * ramp
    if model == "drift":  # outlier frames
        bad = rng.random(t) < 0.05
        bad[0] = False
        q[bad, 6:27] += rng.normal(0.0, 0.15, (int(bad.sum()), 21))
    pose[:, 0:3] += noise((t, 3), 0.002)
    rv = noise((t, 3), 0.02)
    a = np.linalg.norm(rv, axis=1, keepdims=True)
    dq = np.concatenate([np.cos(a / 2), np.sinc(a / (2 * np.pi)) * 0.5 * rv], axis=1)
    w1, x1, y1, z1 = dq.T
    w2, x2, y2, z2 = pose[:, 3:7].T
    pose[:, 3:7] = np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                             w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                             w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                             w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=1)
    pose[:, 3:7] /= np.linalg.norm(pose[:, 3:7], axis=1, keepdims=True)
    # the first frame is the initial state: the object at rest where it truly is
    pose[0] = truth.object_pose[0]
    cap = Capture(f"{truth.name}_{model}{seed}", truth.times, q, pose, truth.obj)
    return SyntheticCapture(cap, truth, truth.name, model, errors)
