"""Common interface of every camera source: intrinsics, frames, open/read/close.

A source (RealSense, OpenCV/UVC, synthetic) is a plain Python object with no ROS dependency::

    with OpenCVSource(OpenCVConfig(device="0")) as cam:
        frame = cam.read(timeout_s=1.0)   # Frame, or None when no frame arrived in time

Conventions (shared with realsense-ros and ``sensor_msgs/CameraInfo``):

* depth images are ``uint16`` millimetres, 0 = no measurement (``16UC1``);
* colour images are ``uint8`` RGB, shape (H, W, 3) (``rgb8``);
* intrinsics use the OpenCV pinhole convention: the centre of the top-left pixel is (0, 0),
  a point (x, y, z) in the optical frame (z forward, x right, y down) projects to
  ``u = fx x / z + cx``, ``v = fy y / z + cy``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hand_capture.errors import ConfigError, DeviceError, InputError

__all__ = [
    "DEPTH_UNIT_M",
    "DriverNotInstalledError",
    "Frame",
    "FrameSource",
    "Intrinsics",
    "depth_m_to_mm",
]

#: One unit of a ``16UC1`` depth image [m] (realsense-ros and OpenNI use millimetres).
DEPTH_UNIT_M = 0.001


class DriverNotInstalledError(DeviceError):
    """The Python driver of a device (e.g. ``pyrealsense2``) is not installed.

    Retrying cannot help, unlike an unplugged device, so supervisors treat it as fatal.
    """


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of one image stream, the fields of ``sensor_msgs/CameraInfo``.

    Attributes:
        width, height: image size [px].
        fx, fy: focal lengths [px]; cx, cy: principal point [px] (OpenCV convention).
        distortion_model: ``"plumb_bob"`` (k1, k2, t1, t2, k3) as in ROS.
        distortion: distortion coefficients; zeros for an ideal or rectified image.
        frame_id: optical frame of the stream (z forward, x right, y down).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = "plumb_bob"
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    frame_id: str = "camera_depth_optical_frame"

    def __post_init__(self) -> None:
        if not (isinstance(self.width, (int, np.integer)) and self.width > 0
                and isinstance(self.height, (int, np.integer)) and self.height > 0):
            raise ConfigError(
                f"Intrinsics: width and height must be positive integers, "
                f"got {self.width}x{self.height}")
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if not math.isfinite(float(v)):
                raise ConfigError(f"Intrinsics.{name} must be finite, got {v}")
            object.__setattr__(self, name, float(v))
        if self.fx <= 0 or self.fy <= 0:
            raise ConfigError(f"Intrinsics: fx, fy must be > 0, got {self.fx}, {self.fy}")
        object.__setattr__(self, "distortion", tuple(float(d) for d in self.distortion))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, **kw: Any) -> Intrinsics:
        """Square-pixel intrinsics from a horizontal field of view, centred principal point."""
        if not 1.0 <= hfov_deg <= 179.0:
            raise ConfigError(f"hfov_deg = {hfov_deg} is out of range [1, 179]")
        f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, **kw)

    @property
    def K(self) -> np.ndarray:
        """3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def P(self) -> np.ndarray:
        """3x4 projection matrix (no stereo baseline), as in CameraInfo.p."""
        return np.hstack([self.K, np.zeros((3, 1))])

    def with_frame(self, frame_id: str) -> Intrinsics:
        """The same intrinsics in another optical frame."""
        return Intrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy,
                          self.distortion_model, self.distortion, frame_id)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of points (N, 3) in the optical frame (z > 0)."""
        p = np.asarray(points, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"project: points must have shape (N, 3), got {p.shape}")
        z = p[:, 2]
        return np.stack([self.fx * p[:, 0] / z + self.cx, self.fy * p[:, 1] / z + self.cy], 1)

    def ray_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel ray slopes ``(x/z, y/z)``, each of shape (H, W)."""
        u = (np.arange(self.width) - self.cx) / self.fx
        v = (np.arange(self.height) - self.cy) / self.fy
        return np.broadcast_to(u[None, :], (self.height, self.width)), \
            np.broadcast_to(v[:, None], (self.height, self.width))

    def backproject(self, depth_m: np.ndarray) -> np.ndarray:
        """Points (H, W, 3) [m] of a depth image in metres (0 stays at the origin)."""
        d = np.asarray(depth_m, dtype=float)
        if d.shape != (self.height, self.width):
            raise InputError(f"backproject: depth shape {d.shape} != "
                             f"({self.height}, {self.width})")
        a, b = self.ray_grid()
        return np.stack([a * d, b * d, d], axis=-1)


def depth_m_to_mm(depth_m: np.ndarray) -> np.ndarray:
    """Metres (float, 0/NaN/inf = none) to ``uint16`` millimetres (0 = none), rounded.

    Values beyond 65.535 m saturate to 0 (no measurement), as a sensor's range limit would.
    """
    d = np.asarray(depth_m, dtype=np.float32)
    mm = np.rint(d * np.float32(1.0 / DEPTH_UNIT_M))
    bad = ~np.isfinite(mm) | (mm <= 0) | (mm > 65535)
    mm[bad] = 0
    return mm.astype(np.uint16)


@dataclass
class Frame:
    """One capture of a source: aligned depth and/or colour with their intrinsics.

    Attributes:
        stamp_s: host time of the capture [s] (``time.time()`` for real sources; the
            synthetic source uses the time it was asked to render).
        sequence: frame counter of the source, starting at 0 after each open().
        depth: (H, W) ``uint16`` [mm], 0 = no measurement; None for colour-only sources.
        color: (H, W, 3) ``uint8`` RGB; None for depth-only sources.
        depth_intrinsics, color_intrinsics: intrinsics of each image (None if absent).
        device_stamp_s: the device's own timestamp [s] when it provides one.
        meta: free-form extras (e.g. the device serial, exposure).
    """

    stamp_s: float
    sequence: int
    depth: np.ndarray | None = None
    color: np.ndarray | None = None
    depth_intrinsics: Intrinsics | None = None
    color_intrinsics: Intrinsics | None = None
    device_stamp_s: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.depth is not None:
            if self.depth.dtype != np.uint16 or self.depth.ndim != 2:
                raise InputError(f"Frame.depth must be a 2-D uint16 array [mm], got "
                                 f"{self.depth.dtype} {self.depth.shape}")
            if self.depth_intrinsics is not None and self.depth.shape != (
                    self.depth_intrinsics.height, self.depth_intrinsics.width):
                raise InputError(f"Frame.depth shape {self.depth.shape} does not match its "
                                 f"intrinsics {self.depth_intrinsics.width}x"
                                 f"{self.depth_intrinsics.height}")
        if self.color is not None:
            if self.color.dtype != np.uint8 or self.color.ndim != 3 or self.color.shape[2] != 3:
                raise InputError(f"Frame.color must be (H, W, 3) uint8 RGB, got "
                                 f"{self.color.dtype} {self.color.shape}")
            if self.color_intrinsics is not None and self.color.shape[:2] != (
                    self.color_intrinsics.height, self.color_intrinsics.width):
                raise InputError(f"Frame.color shape {self.color.shape} does not match its "
                                 f"intrinsics {self.color_intrinsics.width}x"
                                 f"{self.color_intrinsics.height}")


class FrameSource(ABC):
    """A camera that can be opened, read frame by frame and closed.

    ``read`` returns None when no frame arrived within the timeout (or the source dropped
    it) and raises :class:`~hand_capture.errors.DeviceError` when the device is missing or
    was lost; a supervisor (:mod:`hand_capture.cameras.supervisor`) then closes and reopens
    it.
    """

    #: short name of the driver, e.g. ``"realsense"``.
    driver: str = "source"

    @abstractmethod
    def open(self) -> None:
        """Connect to the device and start streaming; DeviceError if it is not there."""

    @abstractmethod
    def read(self, timeout_s: float = 1.0) -> Frame | None:
        """The next frame, or None if none arrived within ``timeout_s``."""

    @abstractmethod
    def close(self) -> None:
        """Stop streaming and release the device; safe to call more than once."""

    @property
    @abstractmethod
    def is_open(self) -> bool:
        """Whether open() succeeded and close() has not been called since."""

    @property
    def nominal_fps(self) -> float:
        """The frame rate the source was configured for [Hz]."""
        return 30.0

    def describe(self) -> dict[str, str]:
        """Key/value facts for diagnostics (driver, serial, resolution, fps, ...)."""
        return {"driver": self.driver}

    def __enter__(self) -> FrameSource:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
