"""Training and test data for the multi-touch encoder, generated with the hand model.

The paper trains on 7,083 motion-capture frames of one subject "making moving, grasping,
pinching, and rotating motions with various combinations of fingers" on an iPad, and tests on
2,538 frames captured on another day (sec. 4). We have no capture, so the same kind of data is
synthesised with :class:`hand_capture.model.hand.HandModel`:

1. Each sequence picks 2-5 contacting fingers and one motion: *moving* (the contacts slide
   together), *rotating* (they turn about their centroid), *grasping* (they close towards or
   open away from the centroid) or *pinching* (the thumb and one or two fingers close on each
   other).
2. A natural posture is sampled (correlated curl of the fingers, spread, thumb opposition,
   wrist yaw and tilt) and the hand is laid on the surface: damped Gauss-Newton (Levenberg-
   Marquardt) on the 27 DoF moves the pads of the chosen fingertips onto the plane z = 0 at
   their sampled positions, keeps the other fingertips at least ``clearance`` above it and stays
   close to the natural posture (prior); joint limits are enforced by projection.
3. The contact targets follow the motion over the frames; each frame warm-starts the solver
   from the previous one while the natural posture drifts, so lifted fingers move as well.
   Frames whose contacts miss their targets, lifted fingers touch, or any collision capsule of
   the hand dips under the surface are dropped.

Everything runs on a batch of sequences at once (one batched FK per Jacobian column group).
Datasets are cached under ``data/touch/cache/`` keyed by their parameters and a fingerprint of
the hand model, so the benchmark and the trainer share them.

Frames: the IK works in the table frame T (z up; see :mod:`hand_capture.touch.encoding`);
surface coordinates are ``(x_T, -y_T)``.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.joints import FINGER_DOFS, FINGERS, JOINT_INDEX, JOINT_LIMITS, N_DOF
from hand_capture.touch.encoding import (
    N_FINGERS,
    ContactFrame,
    encode_input,
    relative_pose,
)

MOTIONS: tuple[str, ...] = ("moving", "rotating", "grasping", "pinching")

#: slot k of the finger joints: the k-th DoF of every finger (-1 where a finger has fewer)
_SLOTS = np.full((5, N_FINGERS), -1, dtype=np.intp)
for _fi, _d in enumerate(FINGER_DOFS):
    _SLOTS[: len(_d), _fi] = _d
_ARTIC = np.arange(6, N_DOF)
_LO, _HI = JOINT_LIMITS[:, 0].copy(), JOINT_LIMITS[:, 1].copy()


@dataclass(frozen=True)
class GenConfig:
    """What to generate (every field enters the cache key)."""

    sequences: int = 1100
    frames: int = 8
    seed: int = 0
    shape_seed: int = -1          # -1: the template hand; else sample_shape(shape_seed)
    clearance: float = 0.010      # lifted pads at least this high [m]
    contact_tol: float = 0.002    # frames whose pads miss their targets by more are dropped [m]
    penetration_tol: float = 0.003  # capsules may dip this much under the surface [m]
    first_iterations: int = 30
    iterations: int = 6
    yaw_deg: float = 35.0         # wrist yaw uniform in +-yaw_deg
    pitch_deg: tuple[float, float] = (-8.0, 5.0)  # wrist pitch: mean, sd (negative: fingers down)
    roll_sd_deg: float = 5.0      # wrist roll sd
    curl: tuple[float, float] = (0.1, 0.6)  # shared finger curl, uniform range (0..1)
    curl_sd: float = 0.08         # per-finger curl deviation from the shared level
    spread: tuple[float, float] = (-0.3, 1.0)  # shared finger spread, uniform range
    thumb_abd_deg: tuple[float, float] = (0.0, 40.0)   # thumb TM abduction, uniform [deg]
    thumb_flex_deg: tuple[float, float] = (-10.0, 35.0)  # thumb TM flexion, uniform [deg]

    def __post_init__(self) -> None:
        if self.sequences < 1 or self.frames < 1:
            raise InputError("sequences and frames must be >= 1")
        if not (0.0 <= self.yaw_deg <= 90.0 and 0.0 <= self.roll_sd_deg <= 45.0
                and len(self.pitch_deg) == 2 and 0.0 <= self.pitch_deg[1] <= 45.0):
            raise InputError("wrist ranges: yaw_deg in [0, 90], roll_sd_deg in [0, 45], "
                             "pitch_deg = (mean, sd) with sd in [0, 45]")
        for name in ("curl", "spread", "thumb_abd_deg", "thumb_flex_deg"):
            lo_hi = getattr(self, name)
            if len(lo_hi) != 2 or lo_hi[0] > lo_hi[1]:
                raise InputError(f"{name} must be a range (lo, hi) with lo <= hi, got {lo_hi}")


@dataclass
class TouchDataset:
    """Generated frames (N of them).

    Attributes:
        poses: (N, 27) absolute poses, table frame (root position [m], angles [rad]).
        pads: (N, 5, 2) fingertip pad positions on the surface, surface coordinates [m].
        contact: (N, 5) bool, which fingers touch.
        sequence: (N,) sequence index; frame: (N,) frame index in it; motion: (N,) index into
        MOTIONS.
    """

    poses: np.ndarray
    pads: np.ndarray
    contact: np.ndarray
    sequence: np.ndarray
    frame: np.ndarray
    motion: np.ndarray

    def __len__(self) -> int:
        return len(self.poses)

    def inputs(self, frame: ContactFrame | None = None, **kw: float
               ) -> tuple[np.ndarray, np.ndarray]:
        """Encoder inputs u (N, 15) and the relative poses (N, 27) (sec. 2 and 4), relative
        to the leftmost contact or, with ``frame``, in the contacts' frame."""
        if frame is not None:
            u, origin, phi = frame.encode(self.pads, self.contact, **kw)
            return u, ContactFrame.to_frame(self.poses, origin, phi)
        u, origin = encode_input(self.pads, self.contact, **kw)
        return u, relative_pose(self.poses, origin)

    @property
    def n_contacts(self) -> np.ndarray:
        return self.contact.sum(axis=1)

    def subset(self, mask: np.ndarray) -> TouchDataset:
        return TouchDataset(*(getattr(self, k)[mask] for k in _FIELDS))

    @staticmethod
    def concatenate(parts: list[TouchDataset]) -> TouchDataset:
        return TouchDataset(*(np.concatenate([getattr(p, k) for p in parts]) for k in _FIELDS))

    def save(self, path: str | Path) -> None:
        np.savez_compressed(path, **{k: getattr(self, k) for k in _FIELDS})

    @staticmethod
    def load(path: str | Path) -> TouchDataset:
        with np.load(path) as d:
            return TouchDataset(*(d[k] for k in _FIELDS))


_FIELDS = ("poses", "pads", "contact", "sequence", "frame", "motion")


# --- natural postures ------------------------------------------------------------------------

def sample_natural(rng: np.random.Generator, n: int, yaw_deg: float = GenConfig.yaw_deg,
                   pitch_deg: tuple[float, float] = GenConfig.pitch_deg,
                   roll_sd_deg: float = GenConfig.roll_sd_deg,
                   curl: tuple[float, float] = GenConfig.curl,
                   curl_sd: float = GenConfig.curl_sd,
                   spread: tuple[float, float] = GenConfig.spread,
                   thumb_abd_deg: tuple[float, float] = GenConfig.thumb_abd_deg,
                   thumb_flex_deg: tuple[float, float] = GenConfig.thumb_flex_deg
                   ) -> np.ndarray:
    """Natural relaxed postures (n, 27) of a right hand held palm-down over a table
    (defaults: :class:`GenConfig`'s).

    Finger curl is correlated across fingers (one shared level plus a per-finger deviation)
    with DIP flexion about 2/3 of PIP flexion; the spread is shared (a level uniform in
    ``spread``; MCP abduction 12 deg x level x +1 index .. -1.2 little); the thumb is abducted
    towards opposition (trapeziometacarpal abduction and flexion uniform in ``thumb_abd_deg``,
    ``thumb_flex_deg`` [deg]). The wrist is yawed uniformly within +-``yaw_deg``, pitched by
    N(``pitch_deg``) and rolled by N(0, ``roll_sd_deg``) [deg]; its position is left at the
    origin.
    """
    q = np.zeros((n, N_DOF))
    shared = rng.uniform(curl[0], curl[1], n)
    level = rng.uniform(spread[0], spread[1], n)  # shared spread
    spread_dir = {"index": 1.0, "middle": 0.1, "ring": -0.6, "little": -1.2}
    for f in FINGERS[1:]:
        c = np.clip(shared + rng.normal(0.0, curl_sd, n), 0.0, 0.9)
        j = {k: JOINT_INDEX[f"{f}_{k}"] for k in ("mcp_abd", "mcp_flex", "pip_flex", "dip_flex")}
        q[:, j["mcp_flex"]] = np.radians(-5.0 + 70.0 * c + rng.normal(0.0, 5.0, n))
        q[:, j["pip_flex"]] = np.radians(90.0 * c + rng.normal(0.0, 6.0, n))
        q[:, j["dip_flex"]] = q[:, j["pip_flex"]] * 2.0 / 3.0 + np.radians(rng.normal(0.0, 4.0, n))
        q[:, j["mcp_abd"]] = np.radians(12.0 * level * spread_dir[f] + rng.normal(0.0, 3.0, n))
    t = {k: JOINT_INDEX[f"thumb_{k}"] for k in ("tm_abd", "tm_flex", "mcp_abd", "mcp_flex",
                                                "ip_flex")}
    q[:, t["tm_abd"]] = np.radians(rng.uniform(thumb_abd_deg[0], thumb_abd_deg[1], n))
    q[:, t["tm_flex"]] = np.radians(rng.uniform(thumb_flex_deg[0], thumb_flex_deg[1], n))
    q[:, t["mcp_abd"]] = np.radians(rng.normal(0.0, 4.0, n))
    q[:, t["mcp_flex"]] = np.radians(rng.uniform(0.0, 35.0, n))
    q[:, t["ip_flex"]] = np.radians(rng.uniform(0.0, 40.0, n))
    # palm down, fingers away from the user (+y_T), thumb to the left: R = Rx Ry Rz(pi/2 + yaw)
    # (read right to left about the fixed table axes: yaw, then roll about the forearm (y_T),
    # then pitch about x_T, negative = fingers pointing down)
    q[:, 3] = np.radians(rng.normal(pitch_deg[0], pitch_deg[1], n))  # pitch
    q[:, 4] = np.radians(rng.normal(0.0, roll_sd_deg, n))   # roll
    q[:, 5] = np.pi / 2 + np.radians(rng.uniform(-yaw_deg, yaw_deg, n))
    return np.clip(q, _LO, _HI)


# --- contact IK ----------------------------------------------------------------------------

@dataclass
class _Weights:
    contact: float = 1.0 / 0.0005    # 1 / [m]
    clearance: float = 1.0 / 0.0005  # 1 / [m]
    tau: float = 0.0015              # softness of the clearance bound [m]
    prior: float = 1.0 / 0.35        # 1 / [rad] on the finger joints
    root_prior: float = 1.0 / 0.5    # 1 / [rad] on the root angles
    damping: float = 1e-3


class ContactIK:
    """Batched damped least squares putting chosen fingertip pads on the plane z = 0.

    Residuals per hand: pad - target for contacting fingers (3 each), the clearance deficit of
    lifted pads (one-sided), and the distance to the prior posture (finger joints and root
    angles). The Jacobian of the pads is taken by forward differences, grouping the k-th joint
    of every finger into one column evaluation (a finger's pad depends on its own joints only),
    so one Jacobian costs 8 batched FK calls.
    """

    def __init__(self, model: object, clearance: float, weights: _Weights | None = None
                 ) -> None:
        self.model = model
        self.clearance = clearance
        self.w = weights or _Weights()

    def pads(self, q: np.ndarray) -> np.ndarray:
        return self.model.fingertips(q, where="pad")

    def pad_jacobian(self, q: np.ndarray, p0: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        """(B, 5, 3, 27) d pad / d q."""
        b = len(q)
        jac = np.zeros((b, N_FINGERS, 3, N_DOF))
        jac[:, :, 0, 0] = jac[:, :, 1, 1] = jac[:, :, 2, 2] = 1.0
        for k in (3, 4, 5):
            qp = q.copy()
            qp[:, k] += eps
            jac[..., k] = (self.pads(qp) - p0) / eps
        for slot in _SLOTS:
            qp = q.copy()
            has = slot >= 0
            qp[:, slot[has]] += eps
            d = (self.pads(qp) - p0) / eps
            for fi in np.nonzero(has)[0]:
                jac[:, fi, :, slot[fi]] = d[:, fi]
        return jac

    def solve(self, q: np.ndarray, prior: np.ndarray, targets: np.ndarray,
              contact: np.ndarray, iterations: int) -> np.ndarray:
        """Refine poses q (B, 27) towards pads on ``targets`` (B, 5, 2) (x_T, y_T) where
        ``contact`` (B, 5); returns the new poses."""
        w = self.w
        q = q.copy()
        cmask = contact[:, :, None].astype(float)
        prior_w = np.zeros(N_DOF)
        prior_w[_ARTIC] = w.prior
        prior_w[3:6] = w.root_prior
        eye = np.eye(N_DOF)
        for _ in range(iterations):
            p = self.pads(q)
            jac = self.pad_jacobian(q, p)
            # contact residuals (B, 5, 3)
            err = np.concatenate([p[..., :2] - targets, p[..., 2:]], axis=-1) * cmask
            rc = w.contact * err
            jc = w.contact * jac * cmask[..., None]
            # clearance (B, 5): smooth one-sided penalty tau * softplus((c - z) / tau) on
            # lifted pads (a hard active set makes the prior and the bound take turns)
            x = (self.clearance - p[..., 2]) / w.tau
            lifted = ~contact
            rl = w.clearance * w.tau * np.logaddexp(0.0, x) * lifted
            sig = 0.5 * (1.0 + np.tanh(0.5 * x))
            jl = (-w.clearance * sig * lifted)[..., None] * jac[:, :, 2, :]
            # prior (B, 27)
            rp = prior_w * (q - prior)
            jtj = (np.einsum("bfim,bfin->bmn", jc, jc) + np.einsum("bfm,bfn->bmn", jl, jl)
                   + np.diag(prior_w ** 2))
            jtr = (np.einsum("bfim,bfi->bm", jc, rc) + np.einsum("bfm,bf->bm", jl, rl)
                   + prior_w * rp)
            a = jtj + w.damping * (np.einsum("bii->bi", jtj)[:, :, None] * eye + eye)
            step = np.linalg.solve(a, -jtr[..., None])[..., 0]
            q = np.clip(q + step, _LO, _HI)
        return q


# --- motions -------------------------------------------------------------------------------

def _choose_fingers(rng: np.random.Generator, motion: str) -> np.ndarray:
    """A contact mask (5,) for one sequence."""
    mask = np.zeros(N_FINGERS, bool)
    if motion == "pinching":
        mask[0] = True
        others = rng.choice(np.arange(1, 5), size=rng.choice([1, 2], p=[0.6, 0.4]),
                            replace=False, p=[0.5, 0.3, 0.12, 0.08])
        mask[others] = True
        return mask
    n = rng.choice([2, 3, 4, 5], p=[0.25, 0.3, 0.25, 0.2])
    with_thumb = motion in ("grasping", "rotating") and rng.random() < 0.85 or \
        motion == "moving" and rng.random() < 0.5
    pool = np.arange(1, 5)
    if with_thumb:
        mask[0] = True
        n -= 1
    p = np.array([0.35, 0.3, 0.2, 0.15]) if with_thumb else np.full(4, 0.25)
    if not with_thumb and n == 5:
        n = 4
    mask[rng.choice(pool, size=n, replace=False, p=p / p.sum())] = True
    return mask


def _trajectory(rng: np.random.Generator, motion: str, start: np.ndarray, mask: np.ndarray,
                frames: int) -> np.ndarray:
    """Contact targets (frames, 5, 2) in table coordinates for one sequence."""
    t = np.linspace(0.0, 1.0, frames)[:, None, None]
    c = start[mask].mean(axis=0)
    rel = start - c
    if motion == "moving":
        ang = rng.uniform(0, 2 * np.pi)
        d = rng.uniform(0.02, 0.07) * np.array([np.cos(ang), np.sin(ang)])
        out = start[None] + t * d
    elif motion == "rotating":
        th = rng.choice([-1, 1]) * np.radians(rng.uniform(15.0, 50.0)) * t[..., 0]
        cs, sn = np.cos(th), np.sin(th)
        out = c + np.stack([cs * rel[:, 0] - sn * rel[:, 1], sn * rel[:, 0] + cs * rel[:, 1]],
                           axis=-1)
    elif motion == "grasping":
        s = rng.uniform(0.55, 0.85)
        if rng.random() < 0.4:  # opening: start closed
            scale = s + (1.0 - s) * t
        else:
            scale = 1.0 + (s - 1.0) * t
        out = c + scale * rel
    else:  # pinching: the contacts close on their centroid
        frac = rng.uniform(0.3, 0.7)
        scale = 1.0 - frac * t
        out = c + scale * rel
    # a little independent wobble of each finger (smooth)
    phase = rng.uniform(0, 2 * np.pi, (1, N_FINGERS, 2))
    out = out + 0.002 * np.sin(2 * np.pi * t + phase)
    return out


def _penetration(model: object, q: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """Deepest capsule penetration under z = 0 (B,) [m], ignoring contacting distal bones."""
    seg = model.capsule_segments(q)  # (B, C, 2, 3)
    radii = np.array([c.radius for c in model.capsules])
    low = seg[..., 2].min(axis=-1) - radii  # (B, C)
    names = [c.name for c in model.capsules]
    for fi, f in enumerate(FINGERS):
        k = names.index(f"{f}_distal")
        low[:, k] = np.where(contact[:, fi], 0.0, low[:, k])
    return np.maximum(0.0, -low.min(axis=1))


def generate(model: object, cfg: GenConfig) -> TouchDataset:
    """Generate sequences with ``model`` (see the module docstring); valid frames only."""
    rng = np.random.default_rng(cfg.seed)
    b, nf = cfg.sequences, cfg.frames
    ik = ContactIK(model, cfg.clearance)
    motion = rng.integers(0, len(MOTIONS), b)
    mask = np.stack([_choose_fingers(rng, MOTIONS[m]) for m in motion])
    natural = {"yaw_deg": cfg.yaw_deg, "pitch_deg": cfg.pitch_deg, "roll_sd_deg": cfg.roll_sd_deg,
               "curl": cfg.curl, "curl_sd": cfg.curl_sd, "spread": cfg.spread,
               "thumb_abd_deg": cfg.thumb_abd_deg, "thumb_flex_deg": cfg.thumb_flex_deg}
    prior_a = sample_natural(rng, b, **natural)
    prior_b = sample_natural(rng, b, **natural)
    prior_b[:, 3:6] = prior_a[:, 3:6] + np.radians(rng.normal(0.0, 4.0, (b, 3)))
    # start: natural posture with the wrist lowered so the contacting pads reach the surface
    q = prior_a.copy()
    pads0 = ik.pads(q)
    q[:, 2] = 0.0 - np.where(mask, pads0[..., 2], np.inf).min(axis=1)
    pads0 = ik.pads(q)
    targets = np.stack([_trajectory(rng, MOTIONS[m], pads0[i, :, :2], mask[i], nf)
                        for i, m in enumerate(motion)], axis=1)  # (frames, B, 5, 2)
    out_q, out_p, ok = [], [], []
    for k in range(nf):
        s = k / max(nf - 1, 1)
        prior = prior_a + s * (prior_b - prior_a)  # its root position has no weight
        q = ik.solve(q, prior, targets[k], mask, cfg.first_iterations if k == 0
                     else cfg.iterations)
        p = ik.pads(q)
        err = np.linalg.norm(np.concatenate([p[..., :2] - targets[k], p[..., 2:]], -1), axis=-1)
        good = (np.where(mask, err, 0.0).max(axis=1) <= cfg.contact_tol)
        good &= np.where(mask, np.inf, p[..., 2]).min(axis=1) >= cfg.clearance - 0.002
        good &= _penetration(model, q, mask) <= cfg.penetration_tol
        out_q.append(q.copy())
        out_p.append(p.copy())
        ok.append(good)
    poses = np.stack(out_q, axis=1).reshape(-1, N_DOF)   # sequence-major
    pads_t = np.stack(out_p, axis=1).reshape(-1, N_FINGERS, 3)
    valid = np.stack(ok, axis=1).reshape(-1)
    pads_s = np.stack([pads_t[..., 0], -pads_t[..., 1]], axis=-1)  # table -> surface (x, y)
    contact = np.repeat(mask, nf, axis=0)
    seq = np.repeat(np.arange(b), nf)
    frame = np.tile(np.arange(nf), b)
    mot = np.repeat(motion, nf)
    ds = TouchDataset(poses, pads_s, contact, seq, frame, mot)
    return ds.subset(valid)


# --- cache -----------------------------------------------------------------------------------

def model_fingerprint(model: object) -> str:
    """A short hash of the model's kinematics (pads of a few fixed poses)."""
    rng = np.random.default_rng(12345)
    q = np.clip(rng.normal(0.0, 0.4, (4, N_DOF)), _LO, _HI)
    pads = np.round(model.fingertips(q, where="pad"), 7)
    return hashlib.sha1(pads.tobytes()).hexdigest()[:12]


#: GenConfig fields added after the cache key was fixed, with their defaults: a default value
#: stays out of the key, so the cached sets made before them keep their files.
_LATER_FIELDS = {f.name: f.default for f in fields(GenConfig)
                 if f.name in ("spread", "thumb_abd_deg", "thumb_flex_deg")}


def config_params(cfg: GenConfig) -> dict:
    """The fields of ``cfg`` as a dict, without the later fields that hold their defaults
    (what the cache key and a model file's ``parts`` record: unchanged for older configs)."""
    return {k: v for k, v in asdict(cfg).items()
            if k not in _LATER_FIELDS or v != _LATER_FIELDS[k]}


def cache_dir() -> Path:
    from hand_capture.paths import share_dir

    return share_dir() / "data" / "touch" / "cache"


def build_model(shape_seed: int) -> object:
    """The right hand with the template shape (shape_seed < 0) or ``sample_shape(seed)``."""
    from hand_capture.model.hand import HandModel
    from hand_capture.model.shape import sample_shape

    return HandModel(None if shape_seed < 0 else sample_shape(shape_seed), side="right")


def load_or_generate(cfg: GenConfig, model: object | None = None,
                     cache: Path | None | bool = True) -> TouchDataset:
    """The dataset of ``cfg`` from the cache, generated (and cached) when absent.

    Args:
        model: the hand model to use (default: :func:`build_model` of ``cfg.shape_seed``).
        cache: a folder, True for :func:`cache_dir`, False/None for no cache.
    """
    model = model if model is not None else build_model(cfg.shape_seed)
    if not cache:
        return generate(model, cfg)
    folder = cache_dir() if cache is True else Path(cache)
    key = hashlib.sha1(json.dumps({**config_params(cfg), "model": model_fingerprint(model),
                                   "version": 2}, sort_keys=True).encode()).hexdigest()[:16]
    path = folder / f"touch_{cfg.seed}_{cfg.shape_seed}_{key}.npz"
    if path.exists():
        try:
            return TouchDataset.load(path)
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
            path.unlink(missing_ok=True)  # a damaged cache file: generate again
    ds = generate(model, cfg)
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")  # two processes may fill one cache
    ds.save(tmp)
    tmp.replace(path)
    return ds
