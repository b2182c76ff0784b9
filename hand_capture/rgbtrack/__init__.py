"""Hand tracking from an ordinary colour camera (pure core, no ROS).

* :mod:`~hand_capture.rgbtrack.detector`: 21 2-D hand keypoints from MediaPipe's hand
  landmarker (offline, models in the wheel), handedness and score;
* :mod:`~hand_capture.rgbtrack.fit`: the suite's hand model fitted to them by
  Levenberg-Marquardt on the reprojection error (analytic Jacobians, joint limits, the
  subject's calibrated shape for scale, optional aligned depth, temporal prior);
* :mod:`~hand_capture.rgbtrack.tracker`: both per frame, with status (TRACKING / RECOVERING /
  LOST) and confidence;
* :mod:`~hand_capture.rgbtrack.evaluate`: speed and accuracy on rendered colour images.

Typical use::

    from hand_capture.rgbtrack import RgbTracker
    tracker = RgbTracker()
    res = tracker.process(rgb, intrinsics)        # res.status, res.pose (27,), res.keypoints
"""

from hand_capture.rgbtrack.detector import Detection, DetectorConfig, HandDetector
from hand_capture.rgbtrack.fit import FitConfig, FitResult, KeypointFitter
from hand_capture.rgbtrack.tracker import RgbTracker, RgbTrackerConfig, RgbTrackResult

__all__ = ["Detection", "DetectorConfig", "FitConfig", "FitResult", "HandDetector",
           "KeypointFitter", "RgbTrackResult", "RgbTracker", "RgbTrackerConfig"]
