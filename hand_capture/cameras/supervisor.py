"""Keeps a camera source streaming: opens it, reads it, and reopens it after it was lost.

An unplugged camera must not stop the node graph. :class:`CameraSupervisor` wraps any
:class:`~hand_capture.cameras.base.FrameSource`; a ``DeviceError`` while opening or reading
is logged and counted, the source is closed and opening is retried with exponential backoff
(``retry_s`` doubling up to ``max_retry_s``) until the device is back. Only a missing
driver (:class:`~hand_capture.cameras.base.DriverNotInstalledError`) is fatal: retrying
cannot install it.

``step()`` does one unit of work and never sleeps, so tests drive it deterministically;
``start()`` runs it in a background thread that hands every frame to a callback.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from hand_capture.cameras.base import DriverNotInstalledError, Frame, FrameSource
from hand_capture.errors import ConfigError, DeviceError

__all__ = ["CameraSupervisor", "SupervisorStats"]

LogFn = Callable[[str, str], None]  # (level: "info" | "warn" | "error", message)


@dataclass
class SupervisorStats:
    """Counters for diagnostics."""

    connected: bool = False
    frames: int = 0
    timeouts: int = 0
    read_errors: int = 0
    open_failures: int = 0
    reconnects: int = 0
    callback_errors: int = 0
    last_error: str = ""
    last_frame_time: float | None = None


class CameraSupervisor:
    """Open / read / reconnect loop around one source (see the module docstring).

    Args:
        source: the camera; it is opened and closed by the supervisor.
        retry_s: first delay before reopening after a failure [s].
        max_retry_s: longest delay between attempts [s].
        read_timeout_s: timeout of one ``source.read`` [s].
        log: ``log(level, message)``; defaults to silence.
        clock: monotonic time source [s] (injectable for tests).
    """

    def __init__(self, source: FrameSource, *, retry_s: float = 0.5, max_retry_s: float = 5.0,
                 read_timeout_s: float = 1.0, log: LogFn | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not (0 < retry_s <= max_retry_s):
            raise ConfigError(f"need 0 < retry_s ({retry_s}) <= max_retry_s ({max_retry_s})")
        if not read_timeout_s > 0:
            raise ConfigError(f"read_timeout_s must be > 0, got {read_timeout_s}")
        self.source = source
        self.retry_s = float(retry_s)
        self.max_retry_s = float(max_retry_s)
        self.read_timeout_s = float(read_timeout_s)
        self._log_fn = log or (lambda level, msg: None)
        self._clock = clock
        self.stats = SupervisorStats()
        self._backoff = self.retry_s
        self._next_attempt = 0.0
        self._ever_connected = False
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()

    def _log(self, level: str, message: str) -> None:
        try:
            self._log_fn(level, message)
        except Exception:  # logging must never stop the camera
            pass

    # -- one unit of work ----------------------------------------------------------------
    def seconds_until_retry(self) -> float:
        """How long until the next open attempt (0 when connected or due)."""
        if self.source.is_open:
            return 0.0
        return max(0.0, self._next_attempt - self._clock())

    def try_open(self) -> bool:
        """One open attempt now; True on success. DriverNotInstalledError propagates."""
        with self._lock:
            return self._try_open_locked()

    def _try_open_locked(self) -> bool:
        try:
            self.source.open()
        except DriverNotInstalledError:
            raise
        except Exception as e:  # DeviceError, or a driver's own exception
            if not isinstance(e, DeviceError):
                e = DeviceError(f"{self.source.driver} camera failed to open: {e!r}")
            self.stats.open_failures += 1
            self.stats.last_error = str(e)
            self._log("warn" if self._ever_connected else "error",
                      f"{e}; retrying in {self._backoff:.1f} s")
            self._next_attempt = self._clock() + self._backoff
            self._backoff = min(2 * self._backoff, self.max_retry_s)
            return False
        if self._ever_connected:
            self.stats.reconnects += 1
            self._log("info", f"{self.source.driver} camera reconnected")
        else:
            self._log("info", f"{self.source.driver} camera opened: {self.source.describe()}")
        self._ever_connected = True
        self.stats.connected = True
        self._backoff = self.retry_s
        return True

    def step(self) -> Frame | None:
        """Open if due, else read one frame; None when there is nothing (yet)."""
        with self._lock:
            if not self.source.is_open:
                self.stats.connected = False
                if self._clock() < self._next_attempt or not self._try_open_locked():
                    return None
            try:
                frame = self.source.read(self.read_timeout_s)
            except Exception as e:  # DeviceError, or a driver's own exception
                if not isinstance(e, DeviceError):
                    e = DeviceError(f"{self.source.driver} camera read failed: {e!r}")
                self.stats.read_errors += 1
                self.stats.connected = False
                self.stats.last_error = str(e)
                self._log("warn", f"camera lost: {e}; reconnecting in {self._backoff:.1f} s")
                try:
                    self.source.close()
                except Exception as ce:  # a half-dead device may fail to close
                    self._log("warn", f"closing the lost camera failed: {ce!r}")
                self._next_attempt = self._clock() + self._backoff
                return None
            if frame is None:
                self.stats.timeouts += 1
                return None
            self.stats.frames += 1
            self.stats.last_frame_time = self._clock()
            return frame

    # -- background thread ---------------------------------------------------------------
    def start(self, on_frame: Callable[[Frame], None]) -> None:
        """Run :meth:`step` in a daemon thread, calling ``on_frame`` for every frame."""
        if self._thread is not None:
            return
        self._stop.clear()

        def loop() -> None:
            while not self._stop.is_set():
                wait = self.seconds_until_retry()
                if wait > 0:
                    self._stop.wait(min(wait, 0.2))
                    continue
                try:
                    frame = self.step()
                except DriverNotInstalledError as e:
                    self.stats.last_error = str(e)
                    self._log("error", str(e))
                    return
                except Exception as e:  # never let the capture thread die
                    self.stats.last_error = repr(e)
                    self._log("error", f"camera loop error: {e!r}")
                    self._stop.wait(self.retry_s)
                    continue
                if frame is None:
                    continue
                try:
                    on_frame(frame)
                except Exception as e:  # a failing consumer must not stop the camera
                    self.stats.callback_errors += 1
                    self._log("error", f"frame callback failed: {e!r}")

        self._thread = threading.Thread(target=loop, name="camera-supervisor", daemon=True)
        self._thread.start()

    def stop(self, join_timeout_s: float = 3.0) -> None:
        """Stop the thread (if any) and close the source."""
        self._stop.set()
        t, self._thread = self._thread, None
        if t is not None:
            t.join(join_timeout_s)
        with self._lock:
            self.source.close()
            self.stats.connected = False

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()
