"""Real camera sources without hardware: RealSense (absent driver / fake SDK), OpenCV (missing
index, a video file), and the reconnecting supervisor (no ROS)."""

from __future__ import annotations

import sys
import threading
import time
import types

import cv2
import numpy as np
import pytest

from hand_capture.cameras.base import DriverNotInstalledError, Frame, FrameSource, Intrinsics
from hand_capture.cameras.opencv import OpenCVConfig, OpenCVSource
from hand_capture.cameras.realsense import RealSenseConfig, RealSenseSource
from hand_capture.cameras.supervisor import CameraSupervisor
from hand_capture.errors import ConfigError, DeviceError

# --- RealSense ----------------------------------------------------------------------------


def test_missing_pyrealsense2_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)  # import fails
    src = RealSenseSource(RealSenseConfig(serial="123"))
    with pytest.raises(DriverNotInstalledError, match="pip install pyrealsense2"):
        src.open()
    assert isinstance(DriverNotInstalledError("x"), DeviceError)
    assert not src.is_open


class _FakeRS:
    """Just enough of pyrealsense2 for RealSenseSource (devices can be plugged / unplugged)."""

    def __init__(self, serials=("f1230",), depth_scale=0.0001, w=64, h=48):
        self.serials = list(serials)
        self.depth_scale = depth_scale
        self.w, self.h = w, h
        self.delivering = True
        self.started_with = None
        self.start_error: Exception | None = None

    def module(self) -> types.ModuleType:
        fake = self
        m = types.ModuleType("pyrealsense2")
        m.camera_info = types.SimpleNamespace(serial_number="sn", name="name",
                                              firmware_version="fw")
        m.stream = types.SimpleNamespace(depth="depth", color="color")
        m.format = types.SimpleNamespace(z16="z16", rgb8="rgb8")
        m.distortion = types.SimpleNamespace(brown_conrady=0, inverse_brown_conrady=1,
                                             kannala_brandt4=2)

        class Device:
            def __init__(self, serial):
                self.info = {"sn": serial, "name": "Intel RealSense D435", "fw": "5.16"}

            def get_info(self, key):
                return self.info[key]

        class Context:
            def query_devices(self):
                return [Device(s) for s in fake.serials]

        class Config:
            def __init__(self):
                self.streams, self.device = [], None

            def enable_device(self, serial):
                self.device = serial

            def enable_stream(self, *args):
                self.streams.append(args)

        class VideoProfile:
            def __init__(self, fx):
                self.fx = fx

            def as_video_stream_profile(self):
                return self

            def get_intrinsics(self):
                return types.SimpleNamespace(width=fake.w, height=fake.h, fx=self.fx,
                                             fy=self.fx + 1, ppx=31.5, ppy=23.5, model=1,
                                             coeffs=[0.0] * 5)

        class Profile:
            def get_device(self):
                sensor = types.SimpleNamespace(get_depth_scale=lambda: fake.depth_scale)
                return types.SimpleNamespace(first_depth_sensor=lambda: sensor)

            def get_stream(self, stream):
                return VideoProfile(60.0 if stream == "color" else 50.0)

        class VFrame:
            def __init__(self, data, t_ms):
                self.data, self.t_ms = data, t_ms

            def __bool__(self):
                return True

            def get_data(self):
                return self.data

            def get_timestamp(self):
                return self.t_ms

        class Frames:
            def __init__(self, n):
                d = np.full((fake.h, fake.w), 4000 + n, np.uint16)  # 0.4 m at 0.1 mm units
                c = np.zeros((fake.h, fake.w, 3), np.uint8)
                c[..., 0] = 200  # red in RGB
                self.d, self.c = VFrame(d, 1000.0 + n), VFrame(c, 1000.0 + n)

            def get_depth_frame(self):
                return self.d

            def get_color_frame(self):
                return self.c

        class Pipeline:
            def __init__(self, ctx=None):
                self.n = 0

            def start(self, cfg):
                if fake.start_error is not None:
                    raise fake.start_error
                fake.started_with = cfg
                return Profile()

            def try_wait_for_frames(self, timeout_ms):
                if not fake.delivering:
                    time.sleep(min(timeout_ms, 20) / 1000.0)
                    return False, None
                self.n += 1
                return True, Frames(self.n)

            def stop(self):
                pass

        class Align:
            def __init__(self, to):
                self.to = to

            def process(self, frames):
                return frames

        m.context, m.config, m.pipeline, m.align = Context, Config, Pipeline, Align
        return m


def test_no_realsense_device_names_the_serial_looked_for(monkeypatch):
    fake = _FakeRS(serials=())
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.module())
    with pytest.raises(DeviceError, match="no RealSense device found.*'0042'"):
        RealSenseSource(RealSenseConfig(serial="0042")).open()
    fake.serials = ["f1230"]
    with pytest.raises(DeviceError, match=r"serial '0042'.*\['f1230'\]"):
        RealSenseSource(RealSenseConfig(serial="0042")).open()
    fake.start_error = RuntimeError("Couldn't resolve requests")
    with pytest.raises(DeviceError, match="cannot stream"):
        RealSenseSource(RealSenseConfig()).open()


def test_realsense_frames_are_aligned_millimetres_and_rgb(monkeypatch):
    fake = _FakeRS(depth_scale=0.0001)
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.module())
    src = RealSenseSource(RealSenseConfig(width=64, height=48, fps=30))
    with src:
        assert fake.started_with.device == "f1230"
        assert ("depth", 64, 48, "z16", 30) in fake.started_with.streams
        f = src.read(0.5)
        assert f.depth.dtype == np.uint16 and f.depth[0, 0] == 400  # 4001 * 0.1 mm, rounded
        assert f.color[0, 0].tolist() == [200, 0, 0]
        # aligned: depth uses the colour intrinsics and frame
        assert f.depth_intrinsics == f.color_intrinsics
        assert f.depth_intrinsics.fx == 60.0 and f.depth_intrinsics.cx == 31.5
        assert f.depth_intrinsics.frame_id == "camera_color_optical_frame"
        assert f.device_stamp_s == pytest.approx(1.001)
        assert src.read(0.5).sequence == 1
        d = src.describe()
        assert d["serial"] == "f1230" and d["depth_scale_m"] == "0.0001"
    assert not src.is_open
    # unaligned depth keeps its own intrinsics and frame
    with RealSenseSource(RealSenseConfig(align_depth=False)) as src:
        f = src.read(0.5)
        assert f.depth_intrinsics.fx == 50.0
        assert f.depth_intrinsics.frame_id == "camera_depth_optical_frame"
    with pytest.raises(ConfigError):
        RealSenseConfig(enable_depth=False, enable_color=False)


def test_unplugged_realsense_is_reported_and_the_supervisor_reconnects(monkeypatch):
    fake = _FakeRS()
    monkeypatch.setitem(sys.modules, "pyrealsense2", fake.module())
    src = RealSenseSource(RealSenseConfig(lost_after_s=0.1))
    logs = []
    sup = CameraSupervisor(src, retry_s=0.05, max_retry_s=0.1, read_timeout_s=0.02,
                           log=lambda lvl, msg: logs.append((lvl, msg)))
    assert isinstance(sup.step(), Frame)
    fake.delivering, fake.serials = False, []  # unplug
    deadline = time.monotonic() + 5.0
    while sup.stats.read_errors == 0 and time.monotonic() < deadline:
        assert sup.step() is None
    assert sup.stats.read_errors == 1 and not sup.stats.connected
    assert any("disconnected" in m for _, m in logs)
    # still unplugged: reopen attempts fail and are counted
    while sup.stats.open_failures == 0 and time.monotonic() < deadline:
        sup.step()
    assert sup.stats.open_failures >= 1
    fake.delivering, fake.serials = True, ["f1230"]  # plug back in
    frame = None
    while frame is None and time.monotonic() < deadline:
        frame = sup.step()
    assert frame is not None and sup.stats.reconnects == 1 and sup.stats.connected


# --- OpenCV -------------------------------------------------------------------------------


def test_opencv_missing_index_names_it():
    src = OpenCVSource(OpenCVConfig(device="57"))
    with pytest.raises(DeviceError, match="index 57"):
        src.open()
    assert not src.is_open
    with pytest.raises(DeviceError, match="/dev/video99"):
        OpenCVSource(OpenCVConfig(device="/dev/video99")).open()


def test_opencv_reads_a_video_as_rgb_and_reports_its_end(tmp_path):
    path = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    assert w.isOpened()
    for k in range(3):
        bgr = np.zeros((48, 64, 3), np.uint8)
        bgr[..., 2] = 220  # red in BGR
        bgr[..., 1] = 40 * k
        w.write(bgr)
    w.release()
    src = OpenCVSource(OpenCVConfig(device=str(path), hfov_deg=90.0,
                                    failures_to_disconnect=2))
    src.open()
    f = src.read()
    assert f.depth is None and f.color.shape == (48, 64, 3)
    r, g, b = f.color[24, 32].astype(int)
    assert r > 180 and b < 40  # converted to RGB
    assert f.color_intrinsics.fx == pytest.approx(32.0)  # 64 px over 90 deg
    assert f.color_intrinsics.frame_id == "camera_color_optical_frame"
    frames = [src.read(), src.read()]
    assert all(x is not None for x in frames)
    assert src.read() is None  # end of the stream: one failed read
    with pytest.raises(DeviceError, match="stopped delivering"):
        src.read()
    src.close()
    cal = OpenCVSource(OpenCVConfig(device=str(path), fx=100.0, cy=20.0))
    cal.open()
    i = cal.read().color_intrinsics
    assert (i.fx, i.fy, i.cx, i.cy) == (100.0, 100.0, 31.5, 20.0)
    cal.close()
    with pytest.raises(ConfigError, match="fourcc"):
        OpenCVConfig(fourcc="MJPEG")


def test_opencv_video_file_loops_and_plays_at_its_frame_rate(tmp_path):
    """A video file stands in for a webcam: with ``loop`` it starts again at its end (frame
    order kept), and frames come at the file's rate, not as fast as they decode."""
    path = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 20.0, (64, 48))
    for k in range(3):
        w.write(np.full((48, 64, 3), 60 * (k + 1), np.uint8))
    w.release()
    src = OpenCVSource(OpenCVConfig(device=str(path), loop=True, failures_to_disconnect=1))
    src.open()
    t0 = time.monotonic()
    levels = [int(src.read().color[24, 32, 0]) for _ in range(7)]
    elapsed = time.monotonic() - t0
    src.close()
    assert src.loops == 2
    assert [round(v / 60) for v in levels] == [1, 2, 3, 1, 2, 3, 1]
    assert elapsed >= 6 * 0.05 * 0.9   # 7 frames at 20 Hz span 6 periods
    fast = OpenCVSource(OpenCVConfig(device=str(path), realtime=False))
    fast.open()
    assert all(fast.read() is not None for _ in range(3)) and fast.read() is None
    fast.close()


# --- supervisor ---------------------------------------------------------------------------


class _Flaky(FrameSource):
    """Fails to open ``open_failures`` times, then delivers frames; ``lose()`` unplugs it."""

    driver = "flaky"

    def __init__(self, open_failures=0, driver_missing=False):
        self.open_failures = open_failures
        self.driver_missing = driver_missing
        self.opened = False
        self.lost = False
        self.n = 0

    @property
    def is_open(self):
        return self.opened

    def open(self):
        if self.driver_missing:
            raise DriverNotInstalledError("pip install something")
        if self.open_failures > 0:
            self.open_failures -= 1
            raise DeviceError("no flaky camera with serial 'X'")
        self.opened, self.lost = True, False

    def read(self, timeout_s=1.0):
        if self.lost:
            raise DeviceError("flaky camera unplugged")
        self.n += 1
        intr = Intrinsics(4, 3, 2.0, 2.0, 1.5, 1.0)
        return Frame(stamp_s=float(self.n), sequence=self.n,
                     depth=np.zeros((3, 4), np.uint16), depth_intrinsics=intr)

    def close(self):
        self.opened = False


def test_supervisor_backs_off_while_opening_fails_then_streams():
    now = [0.0]
    src = _Flaky(open_failures=3)
    logs = []
    sup = CameraSupervisor(src, retry_s=1.0, max_retry_s=3.0, clock=lambda: now[0],
                           log=lambda lvl, msg: logs.append((lvl, msg)))
    assert sup.step() is None and sup.stats.open_failures == 1
    assert "serial 'X'" in logs[0][1] and logs[0][0] == "error"
    assert sup.seconds_until_retry() == pytest.approx(1.0)
    assert sup.step() is None and sup.stats.open_failures == 1  # not due yet
    delays = []
    for _ in range(2):
        now[0] += sup.seconds_until_retry()
        assert sup.step() is None
        delays.append(sup.seconds_until_retry())
    assert delays == [2.0, 3.0]  # doubling, capped
    now[0] += 3.0
    assert isinstance(sup.step(), Frame) and sup.stats.connected
    assert sup.stats.reconnects == 0  # first connection is not a reconnect
    src.lost = True
    assert sup.step() is None and sup.stats.read_errors == 1 and not src.is_open
    now[0] += 1.0
    assert isinstance(sup.step(), Frame) and sup.stats.reconnects == 1
    assert sup.stats.frames == 2


def test_supervisor_missing_driver_is_fatal_and_thread_delivers_frames():
    with pytest.raises(DriverNotInstalledError):
        CameraSupervisor(_Flaky(driver_missing=True)).try_open()
    got, calls = [], [0]
    done = threading.Event()

    def on_frame(f):
        calls[0] += 1
        if calls[0] == 2:
            raise RuntimeError("consumer bug")  # counted, not fatal
        got.append(f.sequence)
        if len(got) >= 5:
            done.set()

    sup = CameraSupervisor(_Flaky(open_failures=1), retry_s=0.01, max_retry_s=0.02)
    sup.start(on_frame)
    assert done.wait(5.0)
    sup.stop()
    assert not sup.running and not sup.source.is_open
    assert sup.stats.callback_errors == 1 and got[:2] == [1, 3]
    with pytest.raises(ConfigError):
        CameraSupervisor(_Flaky(), retry_s=2.0, max_retry_s=1.0)
