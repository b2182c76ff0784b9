"""The common 21 hand keypoints: the order every tracker publishes and retargeting reads.

Order (the one most hand trackers share, e.g. MediaPipe's hand landmarks and the OpenPose /
FreiHAND hand keypoints): the wrist, then per finger -- thumb, index, middle, ring, little --
four points from the base joint to the tip:

* thumb: CMC (the trapeziometacarpal joint), MCP, IP, tip;
* the other fingers: MCP, PIP, DIP, tip.

Index ``0`` is the wrist, the tips are ``4, 8, 12, 16, 20`` (:data:`TIP_INDEX`), finger ``f``
(0 = thumb .. 4 = little) occupies ``1 + 4 f .. 4 + 4 f``. Points are 3-D positions [m] in one
frame (a camera optical frame for trackers, the world frame for the model); 2-D image
keypoints [px] use the same order.

The suite's :class:`~hand_capture.model.HandModel` already computes 21 keypoints
(``KEYPOINT_NAMES``: ``thumb_tm`` is the thumb CMC); :data:`MODEL_TO_21` maps them into this
order by name, so a change of the model's internal order cannot silently permute them.
"""

from __future__ import annotations

import functools

import numpy as np

from hand_capture.errors import InputError
from hand_capture.model.joints import FINGERS
from hand_capture.model.skeleton import KEYPOINT_NAMES

#: The joints of each finger from base to tip in the common order.
THUMB_POINTS: tuple[str, ...] = ("cmc", "mcp", "ip", "tip")
FINGER_POINTS: tuple[str, ...] = ("mcp", "pip", "dip", "tip")

#: The 21 names in the common order: ``wrist``, ``thumb_cmc`` .. ``little_tip``.
KEYPOINT21_NAMES: tuple[str, ...] = ("wrist",) + tuple(
    f"{f}_{p}" for f in FINGERS for p in (THUMB_POINTS if f == "thumb" else FINGER_POINTS))
N_KEYPOINTS21: int = len(KEYPOINT21_NAMES)
KEYPOINT21_INDEX: dict[str, int] = {n: i for i, n in enumerate(KEYPOINT21_NAMES)}
#: Indices of the fingertips (thumb, index, middle, ring, little).
TIP_INDEX: np.ndarray = np.array([4, 8, 12, 16, 20], dtype=np.int64)
#: Index of the wrist.
WRIST_INDEX: int = 0
#: (4,) indices of each finger's points, base to tip, by finger name.
FINGER_INDEX: dict[str, np.ndarray] = {
    f: np.arange(1 + 4 * k, 5 + 4 * k, dtype=np.int64) for k, f in enumerate(FINGERS)}

assert N_KEYPOINTS21 == 21

# The model's keypoint names that differ from the common ones (the rest are identical).
_MODEL_ALIAS: dict[str, str] = {"thumb_tm": "thumb_cmc"}


def _model_to_21() -> np.ndarray:
    """Index into the model's KEYPOINT_NAMES for each common keypoint, matched by name."""
    by_name = {_MODEL_ALIAS.get(n, n): i for i, n in enumerate(KEYPOINT_NAMES)}
    missing = [n for n in KEYPOINT21_NAMES if n not in by_name]
    if missing:  # pragma: no cover - a broken model vocabulary, caught at import
        raise InputError(f"the hand model has no keypoint for {missing}; it has "
                         f"{list(KEYPOINT_NAMES)}")
    idx = np.array([by_name[n] for n in KEYPOINT21_NAMES], dtype=np.int64)
    idx.setflags(write=False)
    return idx


#: (21,) row of the model's ``joint_positions`` for each common keypoint.
MODEL_TO_21: np.ndarray = _model_to_21()


@functools.lru_cache(maxsize=2)
def _default_model(side: str) -> object:
    from hand_capture.model.hand import HandModel  # the mesh is built only when needed

    return HandModel(side=side)


def keypoints21(model: object | None, pose: object, side: str = "right") -> np.ndarray:
    """The 21 common keypoints of a hand pose from the suite's hand model FK.

    Args:
        model: a :class:`~hand_capture.model.HandModel` (its shape and side are used), or None
            for the template hand (default shape) of ``side``.
        pose: (27,) or (B, 27) pose in JOINT_NAMES order [m, rad].
        side: ``"right"`` or ``"left"``, used only when ``model`` is None.

    Returns:
        (21, 3) or (B, 21, 3) keypoints in :data:`KEYPOINT21_NAMES` order [m], in the pose's
        parent frame (where the root translation lives).

    Raises:
        InputError: a malformed pose, an unknown side.
    """
    if model is None:
        if side not in ("right", "left"):
            raise InputError(f"side must be 'right' or 'left', got {side!r}")
        model = _default_model(side)
    kp = model.joint_positions(pose)
    return kp[..., MODEL_TO_21, :]


#: The keypoints fixed to the palm (wrist, thumb CMC, the four MCPs): they define the hand frame.
PALM_KEYPOINTS: tuple[str, ...] = ("wrist", "thumb_cmc", "index_mcp", "middle_mcp", "ring_mcp",
                                   "little_mcp")
_PALM_IDX = np.array([KEYPOINT21_INDEX[n] for n in PALM_KEYPOINTS], dtype=np.int64)


@functools.lru_cache(maxsize=4)
def _palm_template(side: str) -> np.ndarray:
    from hand_capture.model.joints import rest_pose

    pts = keypoints21(None, rest_pose(), side)[_PALM_IDX]
    pts.setflags(write=False)
    return pts


def hand_frame_from_keypoints21(points: object, side: str = "right",
                                template: np.ndarray | None = None
                                ) -> tuple[np.ndarray, np.ndarray]:
    """The hand (palm) frame of 21 keypoints: rotation (3, 3) and origin (3,) [m].

    The frame is the suite's hand frame (joints.py: ``+x`` distal, ``+y`` radial, ``+z``
    dorsal, origin at the wrist): the rotation is the least-squares rigid fit (Kabsch, Acta
    Cryst. A32, 1976, via the SVD of the cross-covariance) of the template hand's
    :data:`PALM_KEYPOINTS` (palm frame, rest pose) onto the observed ones; the origin is the
    wrist keypoint. For keypoints of the suite's model of the same shape it returns the
    model's root frame exactly; for other hands it is the best rigid match of the palm.

    Args:
        points: (21, 3) keypoints in the common order [m].
        side: ``"right"`` or ``"left"`` (the template's side).
        template: (6, 3) palm keypoints of another hand shape in its palm frame (default: the
            template hand of ``side``).

    Raises:
        InputError: a wrong shape, NaN among the palm keypoints, or degenerate palm points.
    """
    p = validate_keypoints21(points)[_PALM_IDX]
    if not np.isfinite(p).all():
        raise InputError("the palm keypoints (wrist, thumb CMC, MCPs) must be finite to "
                         "define the hand frame")
    t = _palm_template(side) if template is None else np.asarray(template, dtype=np.float64)
    pc, tc = p.mean(axis=0), t.mean(axis=0)
    cov = (t - tc).T @ (p - pc)  # sum of template (x) observed
    u, sv, vt = np.linalg.svd(cov)
    if sv[1] < 1e-10:
        raise InputError("the palm keypoints are degenerate (collinear): no hand frame")
    dfix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ dfix @ u.T  # observed = rot @ template + ...
    return rot, p[0].copy()


def validate_keypoints21(points: object, name: str = "keypoints") -> np.ndarray:
    """``points`` as a float64 (21, 3) array; NaN entries are allowed (unknown keypoints).

    Raises:
        InputError: not numeric, or a shape other than (21, 3) / 63 values.
    """
    try:
        a = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name} is not numeric: {e}") from e
    if a.size != 3 * N_KEYPOINTS21 or (a.ndim == 2 and a.shape != (N_KEYPOINTS21, 3)):
        raise InputError(f"{name} must be {N_KEYPOINTS21} points (21, 3) in the common order "
                         f"{KEYPOINT21_NAMES[:3]}...; got shape {a.shape}")
    return a.reshape(N_KEYPOINTS21, 3)


__all__ = [
    "FINGER_INDEX", "FINGER_POINTS", "KEYPOINT21_INDEX", "KEYPOINT21_NAMES", "MODEL_TO_21",
    "N_KEYPOINTS21", "PALM_KEYPOINTS", "THUMB_POINTS", "TIP_INDEX", "WRIST_INDEX",
    "hand_frame_from_keypoints21", "keypoints21", "validate_keypoints21",
]
