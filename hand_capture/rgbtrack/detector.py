"""2-D hand keypoints in colour images: a wrapper around MediaPipe's hand landmarker.

MediaPipe (0.10.14, pinned; its wheel carries the palm-detection and hand-landmark TFLite
models, so it runs offline once installed) finds a palm, then regresses 21 landmarks in the
suite's keypoint order (wrist, then thumb CMC/MCP/IP/tip, then MCP/PIP/DIP/tip of each
finger: the same order as ``hand_capture.model.KEYPOINT_NAMES``). Between frames it tracks
the hand from the previous landmarks and only runs the palm detector again when the hand is
lost (``static_image_mode = False``), which is what makes it fast.

API choice (measured on the 2-core machine, 640x480 renders): the legacy
``mediapipe.solutions.hands`` graph with the lite landmark model takes about 5.5 ms per frame
while tracking and 11 ms when it has to detect; the Tasks API (``HandLandmarker``) needs a
``.task`` bundle the wheel does not ship (one zipped from the wheel's full models ran at
12-21 ms and found fewer rendered hands), so the legacy graph is used.

MediaPipe's handedness assumes a mirrored (selfie) image; :class:`DetectorConfig.mirrored`
says whether the input is, and the label is flipped for an ordinary camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hand_capture.cameras.base import DriverNotInstalledError
from hand_capture.config import param, validate
from hand_capture.errors import InputError

__all__ = ["Detection", "DetectorConfig", "HandDetector", "N_KEYPOINTS_2D"]

N_KEYPOINTS_2D = 21
_INSTALL_HINT = ("MediaPipe is not installed: `pip install --no-deps mediapipe==0.10.14` "
                 "(see requirements-nodeps.txt); the colour tracker needs it")


@dataclass(frozen=True)
class DetectorConfig:
    """Parameters of :class:`HandDetector`."""

    model_complexity: int = param(0, "landmark model: 0 = lite (fast), 1 = full", lo=0, hi=1,
                                  read_only=True)
    min_detection_confidence: float = param(
        0.5, "palm-detection score needed to start tracking a hand (0..1)", lo=0.0, hi=1.0,
        read_only=True)
    min_tracking_confidence: float = param(
        0.5, "landmark presence score needed to keep tracking without re-detection (0..1)",
        lo=0.0, hi=1.0, read_only=True)
    static_image_mode: bool = param(
        False, "detect the palm in every frame (no tracking between frames; slower)",
        read_only=True)
    mirrored: bool = param(False, "the image is mirrored (selfie view); MediaPipe's "
                           "handedness label assumes it is")

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class Detection:
    """One detected hand.

    Attributes:
        pixels: (21, 2) keypoints in image pixels (u right, v down), KEYPOINT_NAMES order.
        rel_depth: (21,) MediaPipe's relative depth of each keypoint (wrist = 0, same scale
            as u; smaller = nearer the camera); a weak cue, kept for diagnostics.
        world: (21, 3) MediaPipe's metric keypoints about the hand centre [m] (its own
            hand-size prior), or None.
        handedness: ``"right"`` or ``"left"`` (already corrected for a non-mirrored image).
        score: MediaPipe's handedness classification score of this hand (0.5..1; the
            legacy graph exposes no presence score, a returned hand passed its presence test).
    """

    pixels: np.ndarray
    rel_depth: np.ndarray
    world: np.ndarray | None
    handedness: str
    score: float


class HandDetector:
    """MediaPipe hand landmarker on RGB images (module docstring).

    Raises :class:`~hand_capture.cameras.base.DriverNotInstalledError` on construction when
    MediaPipe is missing. Not thread-safe: one detector per thread.
    """

    def __init__(self, config: DetectorConfig | None = None) -> None:
        self.config = config or DetectorConfig()
        try:
            from mediapipe.python.solutions import hands as mp_hands
        except ImportError as e:
            raise DriverNotInstalledError(f"{_INSTALL_HINT} ({e})") from e
        self._mp_hands = mp_hands
        self._hands = None
        self._open()

    def _open(self) -> None:
        c = self.config
        self._hands = self._mp_hands.Hands(
            static_image_mode=c.static_image_mode, max_num_hands=1,
            model_complexity=c.model_complexity,
            min_detection_confidence=c.min_detection_confidence,
            min_tracking_confidence=c.min_tracking_confidence)

    def reset(self) -> None:
        """Forget the tracked hand (the next frame runs the palm detector)."""
        self.close()
        self._open()

    def close(self) -> None:
        h, self._hands = self._hands, None
        if h is not None:
            h.close()

    def __enter__(self) -> HandDetector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def detect(self, rgb: np.ndarray) -> Detection | None:
        """The hand in an (H, W, 3) uint8 RGB image, or None when there is none.

        Raises:
            InputError: not an (H, W, 3) uint8 image, or an empty one.
        """
        img = np.asarray(rgb)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise InputError(f"detect: need an (H, W, 3) uint8 RGB image, got {img.dtype} "
                             f"{img.shape}")
        h, w = img.shape[:2]
        if h < 16 or w < 16:
            raise InputError(f"detect: image {w}x{h} is too small (at least 16x16 px)")
        if self._hands is None:
            self._open()
        res = self._hands.process(np.ascontiguousarray(img))
        if not res.multi_hand_landmarks:
            return None
        lms = res.multi_hand_landmarks[0].landmark
        arr = np.array([(p.x, p.y, p.z) for p in lms], dtype=np.float64)
        if arr.shape != (N_KEYPOINTS_2D, 3) or not np.isfinite(arr).all():
            return None
        # normalised [0, 1] image coordinates -> pixels (MediaPipe: x * width, y * height)
        pixels = np.stack([arr[:, 0] * w, arr[:, 1] * h], axis=1)
        world = None
        if res.multi_hand_world_landmarks:
            wl = res.multi_hand_world_landmarks[0].landmark
            world = np.array([(p.x, p.y, p.z) for p in wl], dtype=np.float64)
            if world.shape != (N_KEYPOINTS_2D, 3) or not np.isfinite(world).all():
                world = None
        label, score = "right", 0.5
        if res.multi_handedness:
            cls = res.multi_handedness[0].classification[0]
            label, score = cls.label.lower(), float(cls.score)
        if not self.config.mirrored:
            label = "left" if label == "right" else "right"
        return Detection(pixels=pixels, rel_depth=arr[:, 2] * w, world=world,
                         handedness=label, score=score)
