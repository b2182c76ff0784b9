"""The colour-camera hand tracker: detect 2-D keypoints, fit the hand model, decide the status.

Per frame (:meth:`RgbTracker.process`):

1. :class:`~hand_capture.rgbtrack.detector.HandDetector` finds the hand's 21 keypoints
   (MediaPipe, tracking between frames);
2. :class:`~hand_capture.rgbtrack.fit.KeypointFitter` fits the subject's hand model to them,
   warm-started from the previous good pose (with its temporal prior) unless the last good
   frame is older than ``reset_after_s``; the aligned depth image is used when given;
3. the status: ``lost`` when there is no hand (``reason = "no_hand"``) or the fit does not
   explain the keypoints (RMS reprojection error above ``max_rel_residual`` of the hand's
   image size, ``reason = "fit_residual"``); ``recovering`` for the first good frame after a
   loss (a cold start); ``tracking`` otherwise. A lost frame carries no pose: the caller may
   show the last good one, but only with the LOST status.

Confidence: ``score_term * exp(-0.5 (rel / conf_rel_sigma)^2)`` with ``rel`` the relative
residual and ``score_term`` the detector's score mapped from [0.5, 1] to [0.5, 1] (its
handedness score; 0.5 is a coin toss about the side, not about the hand's presence).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from hand_capture.cameras.base import Intrinsics
from hand_capture.config import param, validate
from hand_capture.errors import InputError
from hand_capture.model import HandModel, HandShape
from hand_capture.rgbtrack.detector import Detection, DetectorConfig, HandDetector
from hand_capture.rgbtrack.fit import FitConfig, FitResult, KeypointFitter

__all__ = ["RgbTrackResult", "RgbTracker", "RgbTrackerConfig"]


@dataclass(frozen=True)
class RgbTrackerConfig:
    """Decision thresholds of :class:`RgbTracker` (detector and fit have their own)."""

    side: str = param("right", "hand to track", choices=("right", "left"), read_only=True)
    max_rel_residual: float = param(
        0.25, "RMS reprojection error, relative to the hand's image size (wrist to middle "
        "MCP), above which a fit is not trusted (LOST)", lo=0.001, hi=10.0)
    conf_rel_sigma: float = param(0.1, "relative residual at which the confidence falls to "
                                  "exp(-1/2) of the detector's", lo=1e-4, hi=10.0)
    reset_after_s: float = param(0.5, "a previous pose older than this is not used as warm "
                                 "start [s]", lo=0.0, hi=60.0)
    use_depth: bool = param(True, "use the aligned depth image when there is one")

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class RgbTrackResult:
    """Outcome of one frame.

    Attributes:
        status: ``"tracking"``, ``"recovering"`` or ``"lost"``.
        reason: why it is lost (``"no_hand"``, ``"fit_residual"``, ``"fit_failed"``), else "".
        pose: (27,) fitted pose (camera frame), None when lost.
        keypoints: (21, 3) model keypoints of the pose [m], None when lost.
        detection: the detector's output (None when no hand).
        fit: the fit (None when no hand).
        confidence: 0..1 (0 when lost).
        timing: stage -> wall time [s] (``detect``, ``fit``).
    """

    status: str
    reason: str = ""
    pose: np.ndarray | None = None
    keypoints: np.ndarray | None = None
    detection: Detection | None = None
    fit: FitResult | None = None
    confidence: float = 0.0
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def good(self) -> bool:
        return self.status in ("tracking", "recovering")


class RgbTracker:
    """Colour-image hand tracker (module docstring).

    Args:
        config: status thresholds and side.
        detector: a detector (default: :class:`HandDetector` built from ``detector_config``).
        fit_config: the fit's weights.
        shape: the subject's calibrated hand shape (default: the template hand).
        detector_config: used when ``detector`` is None.
    """

    def __init__(self, config: RgbTrackerConfig | None = None, *,
                 detector: object | None = None, fit_config: FitConfig | None = None,
                 shape: HandShape | None = None,
                 detector_config: DetectorConfig | None = None) -> None:
        self.config = config or RgbTrackerConfig()
        self.detector = detector if detector is not None else HandDetector(detector_config)
        self.model = HandModel(shape, side=self.config.side)
        self.fitter = KeypointFitter(self.model, fit_config)
        self.counts: Counter[str] = Counter()
        self._prev: np.ndarray | None = None
        self._prev_t = -math.inf
        self._was_good = False

    def set_shape(self, shape: HandShape) -> None:
        """Track with another subject's shape (the next frame starts cold)."""
        self.model = self.model.with_shape(shape)
        self.fitter.set_model(self.model)
        self._prev = None

    def reset(self) -> None:
        """Forget the previous pose and the detector's tracked hand."""
        self._prev = None
        self._was_good = False
        reset = getattr(self.detector, "reset", None)
        if reset is not None:
            reset()

    @property
    def last_good_pose(self) -> np.ndarray | None:
        """The pose of the last good frame (None before the first)."""
        return None if self._prev is None else self._prev.copy()

    def process(self, rgb: np.ndarray, intr: Intrinsics, *, stamp_s: float | None = None,
                depth_m: np.ndarray | None = None) -> RgbTrackResult:
        """Track one (H, W, 3) uint8 RGB image with intrinsics ``intr``.

        Args:
            stamp_s: the image time [s] (default: now) for the warm-start age.
            depth_m: (H, W) aligned depth [m] (0 = none), or None.

        Raises:
            InputError: an image that does not match ``intr`` or is not RGB uint8.
        """
        img = np.asarray(rgb)
        if img.ndim != 3 or img.shape[:2] != (intr.height, intr.width):
            raise InputError(f"image {img.shape} does not match the intrinsics "
                             f"{intr.width}x{intr.height}")
        t = time.monotonic() if stamp_s is None else float(stamp_s)
        self.counts["frames"] += 1
        t0 = time.perf_counter()
        det = self.detector.detect(img)
        timing = {"detect": time.perf_counter() - t0}
        if det is None:
            return self._lost("no_hand", None, None, timing)
        if det.handedness != self.config.side:
            self.counts["handedness_mismatch"] += 1
        prev = self._prev if (self._prev is not None
                              and 0.0 <= t - self._prev_t <= self.config.reset_after_s) \
            else None
        depth = depth_m if self.config.use_depth else None
        t1 = time.perf_counter()
        fit = self.fitter.fit(det.pixels, intr, prev=prev, depth_m=depth)
        timing["fit"] = time.perf_counter() - t1
        if not fit.ok:
            return self._lost("fit_failed", det, fit, timing)
        rel = fit.rel_residual
        if rel > self.config.max_rel_residual:
            if prev is not None:
                # a warm start may have been caught in a wrong minimum: one cold retry
                t2 = time.perf_counter()
                fit = self.fitter.fit(det.pixels, intr, prev=None, depth_m=depth)
                timing["fit"] += time.perf_counter() - t2
                rel = fit.rel_residual
                self.counts["cold_retries"] += 1
            if not fit.ok or rel > self.config.max_rel_residual:
                return self._lost("fit_residual", det, fit, timing)
        status = "tracking" if (self._was_good and prev is not None) else "recovering"
        self._prev, self._prev_t, self._was_good = fit.pose.copy(), t, True
        score_term = float(np.clip(det.score, 0.5, 1.0))
        conf = score_term * math.exp(-0.5 * (rel / self.config.conf_rel_sigma) ** 2)
        self.counts[status] += 1
        return RgbTrackResult(status=status, pose=fit.pose, keypoints=fit.keypoints,
                              detection=det, fit=fit, confidence=float(conf), timing=timing)

    def _lost(self, reason: str, det: Detection | None, fit: FitResult | None,
              timing: dict[str, float]) -> RgbTrackResult:
        self._was_good = False
        self.counts["lost"] += 1
        self.counts[f"lost_{reason}"] += 1
        return RgbTrackResult(status="lost", reason=reason, detection=det, fit=fit,
                              timing=timing)
