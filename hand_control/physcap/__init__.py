"""Physics-based manipulation capture (seed 000 sec. 6-7): sampling-based optimisation of the
composite controller's control from a kinematic capture, replay and retargeting.

The data types and the entry point are in :mod:`hand_control.physcap.capture`."""

from hand_control.physcap.capture import (
    Capture,
    CapturedObject,
    CaptureError,
    PhysCapConfig,
    PhysCapResult,
    load_capture_npz,
    optimise_capture,
    save_capture_npz,
)

__all__ = ["Capture", "CaptureError", "CapturedObject", "PhysCapConfig", "PhysCapResult",
           "load_capture_npz", "optimise_capture", "save_capture_npz"]
