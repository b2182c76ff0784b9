"""A process exit that needs no Python: ``_exit(code)`` from a POSIX timer's own thread.

rclpy's destroy calls hold the GIL while they wait inside Fast DDS, so when Fast DDS
deadlocks there (README "Networking and safety") no Python thread, timer or signal handler
of the process runs again. :class:`ExitTimer` arms a ``timer_create`` timer with
``SIGEV_THREAD`` whose notification function is libc's ``_exit`` and whose value is the exit
code: when it expires, a thread started by the C library calls ``_exit(code)``, GIL or not.
``cancel()`` disarms it. Linux with glibc (``timer_create`` in libc since 2.34, librt
before); elsewhere :meth:`ExitTimer.start` returns None and the caller goes without.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

__all__ = ["ExitTimer"]

_CLOCK_MONOTONIC = 1
_SIGEV_THREAD = 2


class _SigevThread(ctypes.Structure):
    _fields_ = [("function", ctypes.c_void_p), ("attribute", ctypes.c_void_p)]


class _SigevUnion(ctypes.Union):
    _fields_ = [("pad", ctypes.c_int * 12), ("thread", _SigevThread)]


class _Sigevent(ctypes.Structure):
    """glibc's ``struct sigevent`` (64 bytes on 64-bit Linux)."""

    _fields_ = [("value", ctypes.c_void_p),  # union sigval: sival_int in the low bytes
                ("signo", ctypes.c_int), ("notify", ctypes.c_int), ("un", _SigevUnion)]


class _Timespec(ctypes.Structure):
    _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("interval", _Timespec), ("value", _Timespec)]


@functools.cache
def _timer_lib() -> ctypes.CDLL | None:
    """The library with ``timer_create`` (libc, else librt); None where there is none."""
    for name in (None, "rt"):
        try:
            lib = ctypes.CDLL(name if name is None else ctypes.util.find_library(name))
            create, settime, delete = lib.timer_create, lib.timer_settime, lib.timer_delete
        except (OSError, AttributeError):
            continue
        create.argtypes = [ctypes.c_int, ctypes.POINTER(_Sigevent),
                           ctypes.POINTER(ctypes.c_void_p)]
        settime.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.POINTER(_Itimerspec),
                            ctypes.c_void_p]
        delete.argtypes = [ctypes.c_void_p]
        return lib
    return None


class ExitTimer:
    """``_exit(code)`` after ``seconds`` unless cancelled (module doc)."""

    def __init__(self, lib: ctypes.CDLL, timer_id: ctypes.c_void_p) -> None:
        self._lib = lib
        self._id: ctypes.c_void_p | None = timer_id

    @classmethod
    def start(cls, seconds: float, code: int) -> ExitTimer | None:
        """Arm the timer: ``seconds`` [s] > 0, exit ``code`` 0-255. None where the platform
        has no such timer (or arming failed)."""
        if not seconds > 0 or not 0 <= code <= 255:
            raise ValueError(f"ExitTimer.start needs seconds > 0 and code in 0..255, "
                             f"got {seconds}, {code}")
        lib = _timer_lib()
        if lib is None:
            return None
        exit_fn = ctypes.cast(lib._exit, ctypes.c_void_p).value
        ev = _Sigevent()
        ev.value = code
        ev.notify = _SIGEV_THREAD
        ev.un.thread.function = exit_fn
        timer_id = ctypes.c_void_p()
        if lib.timer_create(_CLOCK_MONOTONIC, ctypes.byref(ev), ctypes.byref(timer_id)) != 0:
            return None
        whole = int(seconds)
        spec = _Itimerspec(value=_Timespec(whole, int((seconds - whole) * 1e9)))
        if lib.timer_settime(timer_id, 0, ctypes.byref(spec), None) != 0:
            lib.timer_delete(timer_id)
            return None
        return cls(lib, timer_id)

    def cancel(self) -> None:
        """Disarm and delete the timer (idempotent)."""
        if self._id is not None:
            self._lib.timer_delete(self._id)
            self._id = None
