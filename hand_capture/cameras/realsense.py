"""Intel RealSense depth + colour through ``pyrealsense2`` (an optional extra).

``pyrealsense2`` is imported only when a RealSense source is opened; without it ``open()``
raises :class:`~hand_capture.cameras.base.DriverNotInstalledError` saying that
``pip install pyrealsense2`` is needed. The source streams z16 depth and rgb8 colour, aligns
depth to the colour image (``rs.align``) by default so both share the colour intrinsics, and
converts depth to millimetres whatever the device's depth unit.

Frame ids follow realsense-ros: ``<camera_name>_depth_optical_frame`` and
``<camera_name>_color_optical_frame``; aligned depth is in the colour optical frame.
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from hand_capture.cameras.base import (
    DEPTH_UNIT_M,
    DriverNotInstalledError,
    Frame,
    FrameSource,
    Intrinsics,
)
from hand_capture.config import param, validate
from hand_capture.errors import ConfigError, DeviceError

__all__ = ["RealSenseConfig", "RealSenseSource", "list_realsense_devices"]

INSTALL_HINT = ("the RealSense driver is not installed: pip install pyrealsense2 "
                "(an optional dependency of hand_suite)")


@dataclass(frozen=True)
class RealSenseConfig:
    """Parameters of :class:`RealSenseSource`."""

    serial: str = param("", "serial number of the device; empty = the first one found",
                        read_only=True)
    width: int = param(640, "image width [px]", lo=16, hi=4096, read_only=True)
    height: int = param(480, "image height [px]", lo=16, hi=4096, read_only=True)
    fps: int = param(30, "frame rate requested from the device [Hz]", lo=1, hi=300,
                     read_only=True)
    enable_depth: bool = param(True, "stream depth (z16)", read_only=True)
    enable_color: bool = param(True, "stream colour (rgb8)", read_only=True)
    align_depth: bool = param(True, "align depth to the colour image (same intrinsics)",
                              read_only=True)
    camera_name: str = param("camera", "prefix of the optical frame ids", read_only=True)
    lost_after_s: float = param(
        3.0, "no frame for this long while the device is gone = disconnected [s]", lo=0.1,
        hi=60.0)
    inter_cam_sync_mode: int = param(
        0, "hardware sync of a multi-camera rig (D400 sync cable): 0 free-running, "
        "1 master (drives the others' trigger), 2 slave (follows the master)",
        choices=(0, 1, 2), read_only=True)

    def __post_init__(self) -> None:
        validate(self)
        if not (self.enable_depth or self.enable_color):
            raise ConfigError("RealSenseConfig: enable at least one of depth and colour")


def _import_rs() -> Any:
    try:
        return importlib.import_module("pyrealsense2")
    except ImportError as e:
        raise DriverNotInstalledError(INSTALL_HINT) from e


def list_realsense_devices() -> list[dict[str, str]]:
    """Connected RealSense devices as ``{"serial", "name", "firmware"}`` dicts.

    Raises:
        DriverNotInstalledError: pyrealsense2 is missing.
    """
    rs = _import_rs()
    out = []
    for dev in rs.context().query_devices():
        info = {}
        for key, field in (("serial", "serial_number"), ("name", "name"),
                           ("firmware", "firmware_version")):
            try:
                info[key] = str(dev.get_info(getattr(rs.camera_info, field)))
            except Exception:  # some devices lack some fields
                info[key] = ""
        out.append(info)
    return out


def apply_sync_mode(rs: Any, device: Any, mode: int, serial: str) -> None:
    """Set the depth sensor's ``inter_cam_sync_mode`` (0 leaves the device as it is).

    Raises:
        DeviceError: the device has no such option (e.g. an L500 or an old firmware).
    """
    if mode == 0:
        return
    sensor = device.first_depth_sensor()
    if not sensor.supports(rs.option.inter_cam_sync_mode):
        raise DeviceError(f"RealSense {serial} does not support inter_cam_sync_mode "
                          f"(hardware sync needs a D400-series camera and its sync cable)")
    sensor.set_option(rs.option.inter_cam_sync_mode, float(mode))


def _intrinsics(rs: Any, profile: Any, frame_id: str) -> Intrinsics:
    """Intrinsics of a pyrealsense2 video stream profile."""
    i = profile.as_video_stream_profile().get_intrinsics()
    kb4 = getattr(rs.distortion, "kannala_brandt4", None)
    model = "equidistant" if kb4 is not None and i.model == kb4 else "plumb_bob"
    coeffs = tuple(float(c) for c in i.coeffs)
    if model == "plumb_bob":
        coeffs = (coeffs + (0.0,) * 5)[:5]
    return Intrinsics(int(i.width), int(i.height), float(i.fx), float(i.fy), float(i.ppx),
                      float(i.ppy), model, coeffs, frame_id)


class RealSenseSource(FrameSource):
    """Aligned depth (``uint16`` mm) and colour (RGB) from one RealSense device."""

    driver = "realsense"

    def __init__(self, config: RealSenseConfig | None = None) -> None:
        self.config = config or RealSenseConfig()
        self._rs: Any = None
        self._pipe: Any = None
        self._align: Any = None
        self._depth_scale = DEPTH_UNIT_M
        self._serial = self.config.serial
        self._name = ""
        self._firmware = ""
        self._depth_intr: Intrinsics | None = None
        self._color_intr: Intrinsics | None = None
        self._seq = 0
        self._last_frame_t = 0.0

    # -- FrameSource -------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._pipe is not None

    @property
    def nominal_fps(self) -> float:
        return float(self.config.fps)

    @property
    def depth_scale_m(self) -> float:
        """The device's depth unit [m] (converted to 1 mm in every frame)."""
        return self._depth_scale

    def open(self) -> None:
        if self.is_open:
            return
        c = self.config
        rs = _import_rs()
        self._rs = rs
        devices = list_realsense_devices()
        serials = [d["serial"] for d in devices]
        what = f"serial {c.serial!r}" if c.serial else "any serial"
        if not devices:
            raise DeviceError(f"no RealSense device found (looked for {what}); check the USB "
                              f"cable (USB 3) and udev rules")
        if c.serial and c.serial not in serials:
            raise DeviceError(f"no RealSense device with serial {c.serial!r}; "
                              f"connected: {serials}")
        dev = devices[serials.index(c.serial)] if c.serial else devices[0]
        self._serial, self._name, self._firmware = dev["serial"], dev["name"], dev["firmware"]
        cfg = rs.config()
        cfg.enable_device(self._serial)
        if c.enable_depth:
            cfg.enable_stream(rs.stream.depth, c.width, c.height, rs.format.z16, c.fps)
        if c.enable_color:
            cfg.enable_stream(rs.stream.color, c.width, c.height, rs.format.rgb8, c.fps)
        pipe = rs.pipeline(rs.context())
        try:
            profile = pipe.start(cfg)
        except RuntimeError as e:
            raise DeviceError(
                f"RealSense {self._serial} ({self._name}) cannot stream {c.width}x{c.height} "
                f"@ {c.fps} Hz: {e}") from e
        try:
            apply_sync_mode(rs, profile.get_device(), c.inter_cam_sync_mode, self._serial)
            if c.enable_depth:
                sensor = profile.get_device().first_depth_sensor()
                self._depth_scale = float(sensor.get_depth_scale())
            color_frame = f"{c.camera_name}_color_optical_frame"
            depth_frame = f"{c.camera_name}_depth_optical_frame"
            self._color_intr = _intrinsics(rs, profile.get_stream(rs.stream.color),
                                           color_frame) if c.enable_color else None
            if c.enable_depth:
                if c.enable_color and c.align_depth:
                    self._depth_intr = self._color_intr
                    self._align = rs.align(rs.stream.color)
                else:
                    self._depth_intr = _intrinsics(rs, profile.get_stream(rs.stream.depth),
                                                   depth_frame)
        except RuntimeError as e:
            pipe.stop()
            raise DeviceError(f"RealSense {self._serial}: cannot read stream settings: {e}"
                              ) from e
        except DeviceError:
            pipe.stop()
            raise
        self._pipe = pipe
        self._seq = 0
        self._last_frame_t = time.monotonic()

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if not self.is_open:
            raise DeviceError("RealSense source is not open")
        try:
            ok, frames = self._pipe.try_wait_for_frames(int(max(timeout_s, 0.001) * 1000))
        except RuntimeError as e:
            raise DeviceError(f"RealSense {self._serial} failed: {e}") from e
        if not ok:
            self._check_still_there()
            return None
        self._last_frame_t = time.monotonic()
        host_t = time.time()
        if self._align is not None:
            frames = self._align.process(frames)
        depth = color = None
        dev_t = None
        if self.config.enable_depth:
            df = frames.get_depth_frame()
            if df:
                raw = np.asanyarray(df.get_data())
                depth = self._to_mm(raw)
                dev_t = float(df.get_timestamp()) * 1e-3
        if self.config.enable_color:
            cf = frames.get_color_frame()
            if cf:
                color = np.array(np.asanyarray(cf.get_data()), dtype=np.uint8, copy=True)
                dev_t = dev_t if dev_t is not None else float(cf.get_timestamp()) * 1e-3
        if depth is None and color is None:
            return None
        frame = Frame(stamp_s=host_t, sequence=self._seq, depth=depth, color=color,
                      depth_intrinsics=self._depth_intr if depth is not None else None,
                      color_intrinsics=self._color_intr if color is not None else None,
                      device_stamp_s=dev_t, meta={"serial": self._serial})
        self._seq += 1
        return frame

    def close(self) -> None:
        pipe, self._pipe, self._align = self._pipe, None, None
        if pipe is not None:
            try:
                pipe.stop()
            except RuntimeError:  # already stopped / device gone
                pass

    def describe(self) -> dict[str, str]:
        c = self.config
        return {"driver": self.driver, "serial": self._serial or "(first found)",
                "name": self._name, "firmware": self._firmware,
                "resolution": f"{c.width}x{c.height}", "fps": str(c.fps),
                "depth_scale_m": f"{self._depth_scale:g}",
                "aligned": str(c.align_depth and c.enable_color and c.enable_depth)}

    # -- helpers -------------------------------------------------------------------------------
    def _to_mm(self, raw: np.ndarray) -> np.ndarray:
        """Device depth units to uint16 millimetres (a copy; the SDK reuses its buffer)."""
        if abs(self._depth_scale - DEPTH_UNIT_M) < 1e-9:
            return np.array(raw, dtype=np.uint16, copy=True)
        mm = raw.astype(np.float32) * np.float32(self._depth_scale / DEPTH_UNIT_M)
        return np.clip(np.rint(mm), 0, 65535).astype(np.uint16)

    def _check_still_there(self) -> None:
        """After a timeout: if the device has left the bus, say so (DeviceError)."""
        if time.monotonic() - self._last_frame_t < self.config.lost_after_s:
            return
        try:
            serials = [d["serial"] for d in list_realsense_devices()]
        except Exception:  # the query itself failing means the same thing
            serials = []
        silent = time.monotonic() - self._last_frame_t
        if self._serial not in serials:
            raise DeviceError(f"RealSense {self._serial} disconnected (no frame for "
                              f"{silent:.1f} s)")
        if silent > 3 * self.config.lost_after_s:
            raise DeviceError(f"RealSense {self._serial} stalled: no frame for {silent:.1f} s "
                              f"although it is connected")
