"""Touch frames -> hand poses: finger labelling + polynomial encoding (Chung et al., fig. 1).

:class:`TouchEncoder` is the core of the ``touch_encoder`` node. For each :class:`TouchFrame`
it takes the touches in contact, keeps or searches their finger labels
(:class:`~hand_capture.touch.labelling.FingerLabeller`), and evaluates the encoder (eq. 1 for
the quadratic encoding) on the labelled input. Frames with no contact keep the last pose and
report the status ``"lost"``. Bad frames (non-finite positions, more than five contacts,
contacts outside the surface or farther apart than a hand spans) raise
:class:`~hand_capture.errors.InputError` and leave the state unchanged; the node counts them.
Encoded finger joints are clipped into the limits of :mod:`hand_capture.model.joints`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.threads import blas_threads
from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model.joints import (
    clamp_to_limits,
    root_angles_from_matrix,
    root_rotation_matrix,
)
from hand_capture.touch.encoding import (
    DEGREES,
    N_FINGERS,
    TABLE_TO_SURFACE,
)
from hand_capture.touch.frame import TouchFrame
from hand_capture.touch.labelling import FingerLabeller, LabellerConfig
from hand_capture.touch.touch_model import TouchModel


@dataclass(frozen=True)
class TouchEncoderConfig:
    """Parameters of the touch encoder (node ``touch_encoder``)."""

    model_file: str = param("", "trained model (.npz); '' = data/touch/touch_model.npz",
                            read_only=True)
    encoding: str = param("quadratic", "encoding used for poses and labelling (sec. 2)",
                          choices=tuple(DEGREES), read_only=True)
    position_weight: float = param(
        10.0, "labelling: weight of the wrist position in the pose distance [rad/m]",
        lo=0.0, hi=1e4)
    labelling: str = param(
        "layout", "finger labelling: 'nearest' training neighbour (the paper) or 'layout' "
        "(plus the model's layout prior)", choices=("nearest", "layout"))
    relabel: str = param("all", "labelling when a contact appears: 'all' contacts or only "
                         "the 'new' ones", choices=("all", "new"))
    surface_margin: float = param(
        0.005, "contacts farther than this outside the surface are rejected [m]", lo=0.0,
        hi=0.1)
    max_span: float = param(
        0.26, "contacts farther apart than this cannot be one hand: rejected [m]", lo=0.05,
        hi=1.0)
    confidence_scale: float = param(
        0.5, "nearest-neighbour pose distance at which the confidence is 1/e [rad]",
        lo=1e-6, hi=100.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class EncodedPose:
    """One reconstruction."""

    pose: np.ndarray          # (27,) surface frame, root position [m], angles [rad]
    status: str               # "tracking" or "lost" (no contact: last pose kept)
    labels: dict[int, int]    # session id -> finger index (0 thumb .. 4 little)
    relabelled: bool          # a labelling search ran for this frame
    confidence: float         # exp(-d / confidence_scale), d the nearest-neighbour distance
    stamp: float
    frame_id: str


class TouchEncoder:
    """Stateful frame -> pose encoder; see the module docstring."""

    def __init__(self, config: TouchEncoderConfig | None = None,
                 model: TouchModel | None = None) -> None:
        self.config = cfg = config or TouchEncoderConfig()
        self.model = model or TouchModel.load(cfg.model_file or None)
        self.encoder = self.model.encoder(cfg.encoding)
        self.labeller = FingerLabeller(
            self.encoder, self.model.reference_poses,
            LabellerConfig(position_weight=cfg.position_weight, relabel=cfg.relabel,
                           criterion=cfg.labelling),
            layout=self.model.layout)
        self.last_pose: np.ndarray | None = None

    def reset(self) -> None:
        self.labeller.reset()
        self.last_pose = None

    def process(self, frame: TouchFrame) -> EncodedPose | None:
        """Reconstruct the pose of one frame (None before the first contact ever).

        The small matrix products run on one BLAS thread (see :mod:`hand_capture.cameras.threads`).

        Raises:
            InputError: non-finite positions or more than five contacts.
        """
        with blas_threads(1):
            return self._process(frame)

    def _process(self, frame: TouchFrame) -> EncodedPose | None:
        ids, pos = frame.contacts()
        if len(ids) > N_FINGERS:
            raise InputError(f"{len(ids)} contacts in one frame; one hand makes at most "
                             f"{N_FINGERS}")
        if not np.isfinite(pos).all():
            raise InputError("touch frame has non-finite contact positions")
        off = frame.off_surface(self.config.surface_margin) & frame.in_contact
        if off.any():
            x, y = frame.positions[np.argmax(off)]
            raise InputError(f"contact at ({x:.3f}, {y:.3f}) m is outside the {frame.width:.3f}"
                             f" x {frame.height:.3f} m surface (margin "
                             f"{self.config.surface_margin} m)")
        if len(pos) > 1:
            span = float(np.linalg.norm(pos[:, None] - pos[None], axis=-1).max())
            if span > self.config.max_span:
                raise InputError(f"contacts {span:.3f} m apart; one hand spans at most "
                                 f"{self.config.max_span} m")
        if len(ids) == 0:
            self.labeller.reset()
            if self.last_pose is None:
                return None
            return EncodedPose(self.last_pose.copy(), "lost", {}, False, 0.0, frame.stamp,
                               frame.frame_id)
        labels, searched = self.labeller.update(ids, pos)
        fingertips = np.full((N_FINGERS, 2), np.nan)
        fingertips[labels] = pos
        contact = np.zeros(N_FINGERS, bool)
        contact[labels] = True
        enc = self.encoder
        u, origin, phi = enc.encode(fingertips, contact)
        rel = enc.predict(u[None])[0]  # eq. (1), in the contacts' frame
        distance = float(self.labeller.nearest_distance(rel)[0])
        # joints inside their limits (hand_capture.model.joints); the root is free
        pose = clamp_to_limits(enc.absolute(rel, origin, phi))
        self.last_pose = pose
        return EncodedPose(pose, "tracking", dict(self.labeller.labels), searched,
                           float(np.exp(-distance / self.config.confidence_scale)),
                           frame.stamp, frame.frame_id)


def surface_pose(pose: np.ndarray) -> np.ndarray:
    """A table-frame pose (27,) expressed in the surface frame (z into the surface).

    Finger angles are unchanged; the root position and orientation are rotated by
    :data:`~hand_capture.touch.encoding.TABLE_TO_SURFACE` (see :mod:`hand_capture.touch.encoding`).
    """
    q = np.array(pose, dtype=np.float64, copy=True)
    q[:3] = TABLE_TO_SURFACE @ q[:3]
    q[3:6] = root_angles_from_matrix(TABLE_TO_SURFACE @ root_rotation_matrix(q[3:6]))
    return q
