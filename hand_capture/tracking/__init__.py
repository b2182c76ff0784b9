"""Depth hand tracking (dissertation ch. II.3.6-II.5): segmentation, Gauss-Newton ICP,
shape-indexed cascaded regression forests, hybrid tracking with recovery, calibration.

Pure numpy/scipy/OpenCV (no rclpy). Typical use::

    from hand_capture.tracking import HybridTracker, TrackerConfig, load_regressor
    from hand_capture.model import HandModel

    cfg = TrackerConfig()
    # the shipped regressors: data/tracker/regressor.npz and, with ``ensemble``, the
    # second one (regressor_tubes.npz)
    tracker = HybridTracker(HandModel(shape), cfg, load_regressor(cfg))
    result = tracker.process(depth_mm, intrinsics)   # TrackResult: pose, success, status...

Modules: ``config`` (every weight/threshold), ``preprocess`` (segmentation, forearm cut),
``armseg`` (per-pixel hand/arm classifier, issue 13), ``icp``
(model-based tracking, eq. II.21-II.27), ``forest`` (numpy random regression forest),
``regressor`` (shape-indexed features and hierarchical cascades, eq. II.12-II.18), ``train``
(:func:`train_tracker`), ``hybrid`` (steps 1-6 of II.5.1, eq. II.19-II.20), ``calibration``
(eq. II.11, per-subject storage).
"""

from hand_capture.tracking.calibration import (
    CALIBRATION_POSES,
    CalibrationResult,
    calibrate,
    load_shape,
    save_shape,
)
from hand_capture.tracking.config import TrackerConfig
from hand_capture.tracking.hybrid import (
    HybridTracker,
    TrackResult,
    default_model_path,
    load_regressor,
)
from hand_capture.tracking.icp import ModelTracker
from hand_capture.tracking.preprocess import HandObservation, cut_forearm, segment_hand
from hand_capture.tracking.regressor import HandRegressor, RegressorSet
from hand_capture.tracking.train import train_tracker

__all__ = ["CALIBRATION_POSES", "CalibrationResult", "HandObservation", "HandRegressor",
           "HybridTracker", "ModelTracker", "RegressorSet", "TrackResult", "TrackerConfig",
           "calibrate", "cut_forearm", "default_model_path", "load_regressor", "load_shape",
           "save_shape", "segment_hand", "train_tracker"]
