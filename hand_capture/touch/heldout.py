"""Held-out evaluation family for the touch encoder: data the training never sees.

The training set (:mod:`hand_capture.touch.datagen`) samples a correlated-curl posture and
puts the chosen pads on the table by damped least squares over all 27 DoF with a posture
prior, moving the contacts along four scripted motions. This module makes test frames by
another route, so that the encoder is measured on poses it was not built from (issue #13):

* **postures**: blends of two grasp keyframes (:data:`GRASP_SHAPES`: flat, claw, tripod,
  pinch, spread, cup, hook, point) plus per-joint noise, not the training's curl model;
* **wrist**: yaw +-45 deg, tilt -5..35 deg (fingers pointing down), roll +-20 deg, composed
  about the table's vertical and the forearm (another parameterisation than the training's);
* **hands**: subjects of uniform scale 0.92-1.08 with their own bone proportions;
* **contacts**: 2-5 fingers from another distribution; each contacting pad reaches the
  surface by a 1-D search of that finger's curl alone (a grid with a sign-change bracket and
  bisection), not by the training IK; lifted pads must clear the surface, no capsule may dip
  under it, every joint stays inside its limits;
* **placement**: anywhere on an iPad-sized surface (iPad 2 screen, 197 x 148 mm) with every
  contact on it;
* **panel**: reported positions carry a per-touch offset (contact-area centroid vs the pad,
  sd 1 mm), jitter (sd 0.4 mm) and quantisation to the panel's 132 ppi pixels.

Frames are independent (no sequences). Nothing in :mod:`hand_capture.touch.train` or
:mod:`hand_capture.touch.datagen` may import this module, and its seeds (:data:`SEED_BASE`
and up) are not the training's; ``test/test_touch_heldout.py`` checks both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.joints import (
    FINGERS,
    JOINT_INDEX,
    JOINT_LIMITS,
    N_DOF,
    root_angles_from_matrix,
)
from hand_capture.touch.datagen import TouchDataset

#: iPad 2 screen (9.7 in, 1024 x 768 px at 132 ppi) [m]
IPAD_SIZE = (0.1971, 0.1478)
PANEL_PITCH = 0.0254 / 132.0
#: Held-out seeds start here (training uses small seeds: 0 for the shipped model).
SEED_BASE = 900_000

_D = np.radians


def _finger(mcp: float, pip: float, dip: float, abd: float = 0.0) -> tuple[float, ...]:
    return (abd, mcp, pip, dip)


#: Grasp keyframes [deg]: thumb (tm_abd, tm_flex, mcp_abd, mcp_flex, ip_flex), then
#: (mcp_abd, mcp_flex, pip_flex, dip_flex) of index, middle, ring, little.
GRASP_SHAPES: dict[str, tuple[tuple[float, ...], ...]] = {
    "flat": ((5, -10, 0, 5, 5), _finger(5, 10, 5, 8), _finger(5, 10, 5, 0),
             _finger(5, 10, 5, -6), _finger(5, 10, 5, -12)),
    "claw": ((30, 10, 0, 20, 30), _finger(15, 75, 50, 4), _finger(15, 80, 55, 0),
             _finger(15, 80, 55, -4), _finger(15, 75, 50, -8)),
    "tripod": ((40, 30, 0, 25, 25), _finger(35, 45, 25, 0), _finger(35, 50, 30, -4),
               _finger(50, 80, 55, -6), _finger(55, 85, 60, -10)),
    "pinch": ((45, 35, 0, 30, 20), _finger(45, 50, 30, 2), _finger(30, 40, 25, -2),
              _finger(35, 50, 35, -6), _finger(40, 55, 40, -10)),
    "spread": ((10, -15, 0, 5, 10), _finger(10, 20, 12, 16), _finger(10, 20, 12, 3),
               _finger(10, 20, 12, -10), _finger(10, 20, 12, -20)),
    "cup": ((35, 20, 0, 20, 20), _finger(30, 35, 20, 6), _finger(30, 40, 25, 0),
            _finger(30, 40, 25, -6), _finger(30, 35, 20, -12)),
    "hook": ((15, 0, 0, 10, 10), _finger(0, 70, 40, 0), _finger(0, 75, 45, 0),
             _finger(0, 75, 45, -2), _finger(0, 70, 40, -4)),
    "point": ((30, 25, 0, 30, 35), _finger(0, 15, 8, 2), _finger(40, 60, 40, -2),
              _finger(45, 65, 45, -6), _finger(45, 65, 45, -10)),
}

_THUMB_NAMES = ("tm_abd", "tm_flex", "mcp_abd", "mcp_flex", "ip_flex")
_FINGER_NAMES = ("mcp_abd", "mcp_flex", "pip_flex", "dip_flex")
#: per finger: DoF indices and the curl direction [rad per unit] the contact search moves along
_CURL: list[tuple[np.ndarray, np.ndarray]] = [
    (np.array([JOINT_INDEX[f"thumb_{n}"] for n in ("tm_abd", "tm_flex", "ip_flex")]),
     _D(np.array([25.0, 15.0, 30.0])))]
for _f in FINGERS[1:]:
    _CURL.append((np.array([JOINT_INDEX[f"{_f}_{n}"] for n in ("mcp_flex", "pip_flex",
                                                               "dip_flex")]),
                  _D(np.array([40.0, 45.0, 30.0]))))
_CURL_GRID = np.linspace(-1.2, 1.6, 29)
#: share of the frames with 2, 3, 4, 5 contacts
COUNT_SHARE = (0.3, 0.3, 0.22, 0.18)


def keyframe_pose(name: str) -> np.ndarray:
    """The finger joints of grasp keyframe ``name`` as a pose (27,) (root zero) [rad]."""
    q = np.zeros(N_DOF)
    shape = GRASP_SHAPES[name]
    for n, v in zip(_THUMB_NAMES, shape[0], strict=True):
        q[JOINT_INDEX[f"thumb_{n}"]] = np.radians(v)
    for f, vals in zip(FINGERS[1:], shape[1:], strict=True):
        for n, v in zip(_FINGER_NAMES, vals, strict=True):
            q[JOINT_INDEX[f"{f}_{n}"]] = np.radians(v)
    return q


@dataclass(frozen=True)
class HeldoutConfig:
    """What the held-out family draws (every range inclusive)."""

    frames: int = 1200
    seed: int = SEED_BASE
    subjects: int = 6
    scale: tuple[float, float] = (0.92, 1.08)
    yaw_deg: tuple[float, float] = (-45.0, 45.0)
    tilt_deg: tuple[float, float] = (-5.0, 35.0)
    roll_deg: tuple[float, float] = (-20.0, 20.0)
    surface: tuple[float, float] = IPAD_SIZE
    edge_margin: float = 0.004       # contacts at least this far inside the surface [m]
    clearance: float = 0.008         # lifted pads at least this high [m]
    penetration_tol: float = 0.003   # capsules may dip this much under the surface [m]
    joint_noise_deg: float = 7.0
    touch_offset_sd: float = 0.001   # per-touch contact-centroid offset [m]
    touch_jitter_sd: float = 0.0004  # per-frame jitter [m]

    def __post_init__(self) -> None:
        if self.frames < 1 or self.subjects < 1:
            raise InputError("frames and subjects must be >= 1")
        if self.seed < SEED_BASE:
            raise InputError(f"held-out seeds start at {SEED_BASE} (training uses the "
                             f"small ones), got {self.seed}")


def subject_shapes(cfg: HeldoutConfig) -> list[object]:
    """The held-out subjects' :class:`~hand_capture.model.shape.HandShape` (one per
    ``cfg.subjects``; scales evenly over ``cfg.scale``, bone proportions random)."""
    from hand_capture.model.shape import N_ALPHA, HandShape

    rng = np.random.default_rng([cfg.seed, 1])
    scales = np.linspace(cfg.scale[0], cfg.scale[1], cfg.subjects)
    rng.shuffle(scales)
    return [HandShape(float(s), tuple(np.clip(rng.normal(0.0, 0.8, N_ALPHA), -2.0, 2.0)),
                      subject_id=f"heldout{k}") for k, s in enumerate(scales)]


def _contact_sets(rng: np.random.Generator, n: int, count: int) -> np.ndarray:
    """(n, 5) masks of ``count`` contacts: the thumb in 70 % (always with 5), the others
    uniform."""
    mask = np.zeros((n, 5), bool)
    for i in range(n):
        thumb = count == 5 or rng.random() < 0.7
        mask[i, 0] = thumb
        mask[i, 1 + rng.choice(4, size=count - int(thumb), replace=False)] = True
    return mask


def _orientation(rng: np.random.Generator, n: int, cfg: HeldoutConfig) -> np.ndarray:
    """Root angles (n, 3): R = Rz(yaw) Rx(-tilt) Ry(roll) Rz(pi/2) about table axes."""
    def rz(a: np.ndarray) -> np.ndarray:
        c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                         np.stack([z, z, o], -1)], -2)

    def rx(a: np.ndarray) -> np.ndarray:
        c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                         np.stack([z, s, c], -1)], -2)

    def ry(a: np.ndarray) -> np.ndarray:
        c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                         np.stack([-s, z, c], -1)], -2)

    yaw = _D(rng.uniform(*cfg.yaw_deg, n))
    tilt = _D(rng.uniform(*cfg.tilt_deg, n))
    roll = _D(rng.uniform(*cfg.roll_deg, n))
    rot = rz(yaw) @ rx(-tilt) @ ry(roll) @ rz(np.full(n, np.pi / 2))
    return root_angles_from_matrix(rot)


def _reach(model: object, q: np.ndarray, finger: int, target: np.ndarray,
           above: bool) -> tuple[np.ndarray, np.ndarray]:
    """Curl of one finger (along :data:`_CURL`) bringing its pad height to ``target`` (B,)
    (``above``: to at least ``target``), the crossing nearest the current posture.

    Returns:
        new poses (B, 27) and whether a solution inside the joint limits exists (B,).
    """
    dofs, direction = _CURL[finger]
    b = len(q)
    heights = np.empty((len(_CURL_GRID), b))
    for g, c in enumerate(_CURL_GRID):
        qq = q.copy()
        qq[:, dofs] += c * direction
        heights[g] = model.fingertips(qq, where="pad")[:, finger, 2]
    lo_lim, hi_lim = JOINT_LIMITS[dofs, 0], JOINT_LIMITS[dofs, 1]
    base = q[:, dofs]
    inside = np.stack([((base + c * direction >= lo_lim) & (base + c * direction <= hi_lim))
                       .all(axis=1) for c in _CURL_GRID])  # (G, B)
    f = heights - target
    best_c = np.full(b, np.nan)
    if above:
        okg = (f >= 0.0) & inside
        dist = np.where(okg, np.abs(_CURL_GRID)[:, None], np.inf)
        k = np.argmin(dist, axis=0)
        has = np.isfinite(dist[k, np.arange(b)])
        best_c[has] = _CURL_GRID[k[has]]  # the grid holds 0: a pad already clear stays
    else:
        cross = (np.sign(f[:-1]) != np.sign(f[1:])) & inside[:-1] & inside[1:]  # (G-1, B)
        mid = 0.5 * (_CURL_GRID[:-1] + _CURL_GRID[1:])
        dist = np.where(cross, np.abs(mid)[:, None], np.inf)
        k = np.argmin(dist, axis=0)
        has = np.isfinite(dist[k, np.arange(b)])
        lo = _CURL_GRID[k].copy()
        hi = _CURL_GRID[k + 1].copy()
        f_lo = f[k, np.arange(b)]
        for _ in range(20):  # bisection inside the bracket
            c = 0.5 * (lo + hi)
            qq = q.copy()
            qq[:, dofs] += c[:, None] * direction
            fc = model.fingertips(qq, where="pad")[:, finger, 2] - target
            same = np.sign(fc) == np.sign(f_lo)
            lo = np.where(same, c, lo)
            f_lo = np.where(same, fc, f_lo)
            hi = np.where(same, hi, c)
        best_c[has] = 0.5 * (lo + hi)[has]
    out = q.copy()
    cc = np.nan_to_num(best_c)
    out[:, dofs] += cc[:, None] * direction
    return out, has


def _penetration(model: object, q: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """Deepest dip (B,) [m] of any capsule under z = 0 except contacting distal bones."""
    seg = model.capsule_segments(q)
    radii = np.array([c.radius for c in model.capsules])
    low = seg[..., 2].min(axis=-1) - radii
    names = [c.name for c in model.capsules]
    for fi, f in enumerate(FINGERS):
        low[:, names.index(f"{f}_distal")] = np.where(contact[:, fi], 0.0,
                                                      low[:, names.index(f"{f}_distal")])
    return np.maximum(0.0, -low.min(axis=1))


def _subject_frames(model: object, rng: np.random.Generator, n: int, count: int,
                    cfg: HeldoutConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to n valid (poses, true pads (n, 5, 2) surface coordinates, contact) of one hand."""
    names = list(GRASP_SHAPES)
    keys = np.stack([keyframe_pose(k) for k in names])
    a, b = rng.integers(len(names), size=n), rng.integers(len(names), size=n)
    w = rng.uniform(0.0, 1.0, (n, 1))
    q = (1.0 - w) * keys[a] + w * keys[b]
    q[:, 6:] += _D(rng.normal(0.0, cfg.joint_noise_deg, (n, N_DOF - 6)))
    q = np.clip(q, JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])
    q[:, 3:6] = _orientation(rng, n, cfg)
    contact = _contact_sets(rng, n, count)
    pads = model.fingertips(q, where="pad")
    # the reference finger: the contacting pad nearest the median height keeps its curl
    z = np.where(contact, pads[..., 2], np.nan)
    ref = np.nanargmin(np.abs(z - np.nanmedian(z, axis=1, keepdims=True)), axis=1)
    q[:, 2] = -pads[np.arange(n), ref, 2]
    ok = np.ones(n, bool)
    for f in range(5):
        move = contact[:, f] & (ref != f)
        if move.any():
            qn, has = _reach(model, q[move], f, np.zeros(move.sum()), above=False)
            q[move] = qn
            ok[np.flatnonzero(move)[~has]] = False
        lift = ~contact[:, f]
        if lift.any():
            qn, has = _reach(model, q[lift], f, np.full(lift.sum(), cfg.clearance),
                             above=True)
            q[lift] = qn
            ok[np.flatnonzero(lift)[~has]] = False
    pads = model.fingertips(q, where="pad")
    ok &= np.where(contact, np.abs(pads[..., 2]), 0.0).max(axis=1) < 5e-4
    ok &= np.where(contact, np.inf, pads[..., 2]).min(axis=1) >= cfg.clearance - 1e-4
    ok &= _penetration(model, q, contact) <= cfg.penetration_tol
    ok &= ((q[:, 6:] >= JOINT_LIMITS[6:, 0] - 1e-9) & (q[:, 6:] <= JOINT_LIMITS[6:, 1] + 1e-9)
           ).all(axis=1)
    # placement: uniform over the positions that keep every contact on the surface
    w_s, h_s = cfg.surface
    sxy = np.stack([pads[..., 0], -pads[..., 1]], axis=-1)  # table -> surface (x, y)
    m = cfg.edge_margin
    lo = np.where(contact[..., None], sxy, np.inf).min(axis=1)   # (n, 2) contact box
    hi = np.where(contact[..., None], sxy, -np.inf).max(axis=1)
    room = np.array([w_s, h_s]) - 2.0 * m - (hi - lo)
    ok &= (room > 0.0).all(axis=1)
    shift = m - lo + rng.uniform(0.0, 1.0, (n, 2)) * np.maximum(room, 0.0)
    sxy = sxy + shift[:, None, :]
    q[:, 0] += shift[:, 0]
    q[:, 1] -= shift[:, 1]
    on = (sxy[..., 0] >= m) & (sxy[..., 0] <= w_s - m) & (sxy[..., 1] >= m) & \
        (sxy[..., 1] <= h_s - m)
    ok &= np.where(contact, on, True).all(axis=1)
    return q[ok], sxy[ok], contact[ok]


def generate_heldout(cfg: HeldoutConfig | None = None) -> tuple[TouchDataset, np.ndarray]:
    """The held-out frames.

    Returns:
        (dataset, reported): the dataset's ``pads`` are the true pad positions (surface
        coordinates [m]); ``reported`` (N, 5, 2) is what the panel reports (offset, jitter,
        quantisation), the encoder's input. ``sequence`` numbers the frames, ``frame`` is 0,
        ``motion`` the subject index (into :func:`subject_shapes`).
    """
    from hand_capture.model.hand import HandModel

    cfg = cfg or HeldoutConfig()
    rng = np.random.default_rng(cfg.seed)
    shapes = subject_shapes(cfg)
    share = np.asarray(COUNT_SHARE) * cfg.frames / cfg.subjects
    poses, pads, contact, subject = [], [], [], []
    for k, shape in enumerate(shapes):
        model = HandModel(shape, side="right")
        for count, quota in zip(range(2, 6), np.ceil(share).astype(int), strict=True):
            got, tries = 0, 0
            while got < quota and tries < 30:  # draw until this subject has its share
                q, p, c = _subject_frames(model, rng, 16 * (quota - got) + 32, count, cfg)
                take = min(len(q), quota - got)
                poses.append(q[:take])
                pads.append(p[:take])
                contact.append(c[:take])
                subject.append(np.full(take, k))
                got += take
                tries += 1
    order = rng.permutation(sum(len(p) for p in poses))[:cfg.frames]
    order.sort()
    poses_a = np.concatenate(poses)[order]
    pads_a = np.concatenate(pads)[order]
    contact_a = np.concatenate(contact)[order]
    subject_a = np.concatenate(subject)[order]
    n = len(poses_a)
    ds = TouchDataset(poses_a, pads_a, contact_a, np.arange(n), np.zeros(n, np.int64),
                      subject_a)
    reported = pads_a + rng.normal(0.0, cfg.touch_offset_sd, pads_a.shape) \
        + rng.normal(0.0, cfg.touch_jitter_sd, pads_a.shape)
    reported = np.round(reported / PANEL_PITCH) * PANEL_PITCH
    return ds, reported
