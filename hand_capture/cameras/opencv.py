"""UVC colour cameras (and video files/streams) through OpenCV's ``cv2.VideoCapture``.

``device`` is a camera index (``"0"`` = /dev/video0) or a path/URL (``"/dev/video2"``,
``"clip.avi"``, ``"rtsp://..."``). Frames are converted from OpenCV's BGR to RGB. A UVC
camera does not report its intrinsics: they come from ``fx, fy, cx, cy`` when given (e.g.
from a calibration) and otherwise from a nominal horizontal field of view.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hand_capture.cameras.base import Frame, FrameSource, Intrinsics
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, DeviceError
from hand_capture.paths import resolve_path

__all__ = ["OpenCVConfig", "OpenCVSource"]

_BACKENDS = ("any", "v4l2", "ffmpeg", "gstreamer")


@dataclass(frozen=True)
class OpenCVConfig:
    """Parameters of :class:`OpenCVSource`."""

    device: str = param("0", "camera index (e.g. '0') or a device path / video file / URL",
                        read_only=True)
    backend: str = param("any", "OpenCV capture backend", choices=_BACKENDS, read_only=True)
    width: int = param(640, "requested image width [px] (the device may choose another)",
                       lo=16, hi=8192, read_only=True)
    height: int = param(480, "requested image height [px]", lo=16, hi=8192, read_only=True)
    fps: float = param(30.0, "requested frame rate [Hz]", lo=0.5, hi=500.0, read_only=True)
    fourcc: str = param("", "pixel format to request, e.g. 'MJPG'; empty = device default",
                        read_only=True)
    hfov_deg: float = param(60.0, "horizontal field of view used when fx is 0 [deg]",
                            lo=1.0, hi=179.0)
    fx: float = param(0.0, "focal length [px]; 0 = from hfov_deg", lo=0.0)
    fy: float = param(0.0, "focal length [px]; 0 = same as fx", lo=0.0)
    cx: float = param(-1.0, "principal point [px]; negative = image centre")
    cy: float = param(-1.0, "principal point [px]; negative = image centre")
    frame_id: str = param("camera_color_optical_frame", "optical frame of the images")
    failures_to_disconnect: int = param(
        5, "consecutive failed reads that mean the device is gone", lo=1, hi=1000)
    loop: bool = param(False, "a video file starts again at its end (else its end is the "
                       "end of the stream)")
    realtime: bool = param(True, "a video file plays at its own frame rate (else as fast "
                           "as it decodes)")

    def __post_init__(self) -> None:
        validate(self)
        if self.fourcc and len(self.fourcc) != 4:
            raise ConfigError(f"OpenCVConfig.fourcc must be 4 characters, got {self.fourcc!r}")


def _target(device: str) -> int | str:
    d = device.strip()
    if d.isdigit():
        return int(d)
    if "://" in d or d.startswith("/dev/"):
        return d
    # a relative video path missing here names the shipped file (data/webcam/...)
    return str(resolve_path(d))


class OpenCVSource(FrameSource):
    """Colour frames from a UVC camera or a video through ``cv2.VideoCapture``."""

    driver = "opencv"

    def __init__(self, config: OpenCVConfig | None = None) -> None:
        self.config = config or OpenCVConfig()
        self._cap = None
        self._intr: Intrinsics | None = None
        self._seq = 0
        self._fails = 0
        self._is_file = False
        self._period = 0.0
        self._next_t: float | None = None
        #: times a looping video file started again
        self.loops = 0

    @property
    def is_open(self) -> bool:
        return self._cap is not None

    @property
    def nominal_fps(self) -> float:
        return float(self.config.fps)

    def _what(self) -> str:
        t = _target(self.config.device)
        return f"index {t}" if isinstance(t, int) else f"{t!r}"

    def open(self) -> None:
        if self.is_open:
            return
        import cv2

        c = self.config
        api = {"any": cv2.CAP_ANY, "v4l2": cv2.CAP_V4L2, "ffmpeg": cv2.CAP_FFMPEG,
               "gstreamer": cv2.CAP_GSTREAMER}[c.backend]
        target = _target(c.device)
        try:
            cap = cv2.VideoCapture(target, api)
        except cv2.error as e:
            raise DeviceError(f"OpenCV cannot open camera {self._what()}: {e}") from e
        if not cap.isOpened():
            cap.release()
            hint = " (is the camera plugged in? see `ls /dev/video*`)" \
                if isinstance(target, int) or str(target).startswith("/dev/") else ""
            raise DeviceError(f"no OpenCV camera at {self._what()} "
                              f"(backend {c.backend}){hint}")
        if isinstance(target, int) or str(target).startswith("/dev/"):
            if c.fourcc:
                cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*c.fourcc))
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, c.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, c.height)
            cap.set(cv2.CAP_PROP_FPS, c.fps)
        self._is_file = isinstance(target, str) and Path(target).is_file()
        file_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) if self._is_file else 0.0
        self._period = 1.0 / (file_fps if 0.5 <= file_fps <= 500.0 else c.fps)
        self._next_t = None
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) or c.width
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) or c.height
        self._cap = cap
        self._intr = self._make_intrinsics(w, h)
        self._seq = 0
        self._fails = 0

    def _make_intrinsics(self, w: int, h: int) -> Intrinsics:
        c = self.config
        if c.fx > 0:
            fx, fy = c.fx, (c.fy if c.fy > 0 else c.fx)
            return Intrinsics(w, h, fx, fy, c.cx if c.cx >= 0 else (w - 1) / 2.0,
                              c.cy if c.cy >= 0 else (h - 1) / 2.0, frame_id=c.frame_id)
        intr = Intrinsics.from_fov(w, h, c.hfov_deg, frame_id=c.frame_id)
        if c.cx >= 0 or c.cy >= 0:
            intr = Intrinsics(w, h, intr.fx, intr.fy, c.cx if c.cx >= 0 else intr.cx,
                              c.cy if c.cy >= 0 else intr.cy, frame_id=c.frame_id)
        return intr

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        """The next frame (blocks for up to one frame period inside OpenCV)."""
        if self._cap is None:
            raise DeviceError(f"OpenCV camera {self._what()} is not open")
        import cv2

        ok, bgr = self._cap.read()
        if (not ok or bgr is None) and self._is_file and self.config.loop:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, bgr = self._cap.read()
            self.loops += 1
        if not ok or bgr is None:
            self._fails += 1
            if self._fails >= self.config.failures_to_disconnect:
                raise DeviceError(f"OpenCV camera {self._what()} stopped delivering frames "
                                  f"({self._fails} failed reads; unplugged or end of stream)")
            return None
        self._fails = 0
        if self._is_file and self.config.realtime:
            self._pace(timeout_s)
        if bgr.ndim == 2:
            rgb = cv2.cvtColor(bgr, cv2.COLOR_GRAY2RGB)
        else:
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        h, w = rgb.shape[:2]
        if self._intr is None or (self._intr.width, self._intr.height) != (w, h):
            self._intr = self._make_intrinsics(w, h)
        frame = Frame(stamp_s=time.time(), sequence=self._seq, color=np.ascontiguousarray(rgb),
                      color_intrinsics=self._intr)
        self._seq += 1
        return frame

    def _pace(self, timeout_s: float) -> None:
        """Hold a video file's frame until its time (one period after the previous one)."""
        now = time.monotonic()
        if self._next_t is None:
            self._next_t = now
        wait = self._next_t - now
        if wait > 0:
            time.sleep(min(wait, max(timeout_s, 0.0)))
        # a late reader does not get a burst of catch-up frames
        self._next_t = max(self._next_t + self._period, time.monotonic() - self._period)

    def close(self) -> None:
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()

    def describe(self) -> dict[str, str]:
        c = self.config
        res = f"{self._intr.width}x{self._intr.height}" if self._intr else \
            f"{c.width}x{c.height} (requested)"
        return {"driver": self.driver, "device": c.device, "backend": c.backend,
                "resolution": res, "fps": f"{c.fps:g}"}
