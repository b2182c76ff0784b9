"""Camera sources: RealSense and UVC cameras, and the synthetic RGB-D camera (no ROS here).

Every source implements :class:`FrameSource` (``open`` / ``read`` -> :class:`Frame` / ``close``);
depth is ``uint16`` millimetres, colour ``uint8`` RGB, intrinsics :class:`Intrinsics`.

* :class:`RealSenseSource` -- Intel RealSense via the optional ``pyrealsense2``;
* :class:`OpenCVSource` -- UVC cameras and videos via ``cv2.VideoCapture``;
* :class:`SyntheticCamera` -- the hand model rendered by a CPU rasteriser with a depth-sensor
  noise model, driven by motion clips, with ground truth (dissertation ch. II.4.4);
* :class:`CameraSupervisor` -- reopens a lost camera with backoff;
* :func:`render_benchmark` -- renderer speed (``hand_capture.cameras.bench``).

Typical use::

    from hand_capture.cameras import SyntheticCamera, SyntheticCameraConfig
    cam = SyntheticCamera(SyntheticCameraConfig(clip="grasp", shape_seed=3))
    cam.open()
    frame = cam.render(1.5)        # frame.depth (mm), frame.color, frame.pose (27,), ...
"""

from hand_capture.cameras.base import (
    DEPTH_UNIT_M,
    DriverNotInstalledError,
    Frame,
    FrameSource,
    Intrinsics,
    depth_m_to_mm,
)
from hand_capture.cameras.motion import CLIPS, Keyframe, MotionClip, builtin_clip, load_motion
from hand_capture.cameras.noise import DepthNoiseConfig, DepthNoiseModel
from hand_capture.cameras.opencv import OpenCVConfig, OpenCVSource
from hand_capture.cameras.primitives import SceneObject
from hand_capture.cameras.realsense import RealSenseConfig, RealSenseSource
from hand_capture.cameras.render import (
    Mesh,
    NaiveRenderer,
    RaycastRenderer,
    RenderResult,
    ZBufferRenderer,
    make_renderer,
)
from hand_capture.cameras.supervisor import CameraSupervisor, SupervisorStats
from hand_capture.cameras.synthetic import (
    HAND_LABEL,
    SyntheticCamera,
    SyntheticCameraConfig,
    SyntheticFrame,
)


def render_benchmark(quick: bool = False, **kwargs):
    """See :func:`hand_capture.cameras.bench.render_benchmark` (imported on first use)."""
    from hand_capture.cameras.bench import render_benchmark as _rb

    return _rb(quick, **kwargs)


__all__ = [
    "CLIPS", "DEPTH_UNIT_M", "HAND_LABEL", "CameraSupervisor", "DepthNoiseConfig",
    "DepthNoiseModel", "DriverNotInstalledError", "Frame", "FrameSource", "Intrinsics",
    "Keyframe", "Mesh", "MotionClip", "NaiveRenderer", "OpenCVConfig", "OpenCVSource",
    "RaycastRenderer", "RealSenseConfig", "RealSenseSource", "RenderResult", "SceneObject",
    "SupervisorStats", "SyntheticCamera", "SyntheticCameraConfig", "SyntheticFrame",
    "ZBufferRenderer", "builtin_clip", "depth_m_to_mm", "load_motion", "make_renderer",
    "render_benchmark",
]
