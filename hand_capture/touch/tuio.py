"""TUIO 1.1 cursor listener: ``/tuio/2Dcur`` messages over OSC/UDP -> :class:`TouchFrame`.

TUIO 1.1 (tuio.org) sends, per surface frame, one OSC bundle on the ``/tuio/2Dcur`` address:

* ``source  app@host``          (optional) the sending application,
* ``alive   s_id ...``          session ids of every cursor currently down,
* ``set     s_id x y X Y m``    position (normalised to [0, 1], origin top-left), velocity and
  acceleration of one cursor (only cursors that changed need a ``set``),
* ``fseq    f_id``              frame sequence number; it closes the frame.

:class:`TuioParser` is the pure state machine (feed it ``(address, args)`` pairs);
:class:`TuioReceiver` owns a non-blocking UDP socket, decodes datagrams (messages or nested
bundles) with :func:`decode_osc`, a bounds-checked OSC 1.0 walker (every size is checked against
the bytes left, nesting and message counts are capped, so a hostile datagram costs time linear
in its length and is rejected, never loops), and feeds the parser. Positions are scaled to
metres with the surface size. A cursor that leaves the ``alive`` list is reported once with
``in_contact = False`` at its last position. Bad data (non-finite or out-of-range
coordinates, wrong argument types, undecodable datagrams) is dropped and counted, never raised
into the caller's loop.
"""

from __future__ import annotations

import math
import socket
import struct
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hand_capture.config import param, validate
from hand_capture.errors import DeviceError
from hand_capture.touch.frame import TouchFrame

CURSOR_ADDRESS = "/tuio/2Dcur"

#: Frames whose fseq is this much older than the newest one are taken as a restarted sender,
#: as the TUIO reference client does.
_FSEQ_RESTART_GAP = 100
#: Caps of :func:`decode_osc`: bundle nesting depth and messages per datagram.
MAX_BUNDLE_DEPTH = 8
MAX_OSC_MESSAGES = 1024
_BUNDLE_TAG = b"#bundle\x00"


class OscDecodeError(ValueError):
    """A datagram that is not well-formed OSC 1.0 (the message names the defect)."""


def _osc_string(data: bytes, pos: int, end: int) -> tuple[str, int]:
    """A NUL-terminated, 4-byte padded OSC string at ``pos``; returns (text, next pos)."""
    nul = data.find(b"\x00", pos, end)
    if nul < 0:
        raise OscDecodeError(f"unterminated string at byte {pos}")
    nxt = (nul + 4) & ~3
    if nxt > end:
        raise OscDecodeError(f"string padding at byte {pos} runs past the element end")
    try:
        return data[pos:nul].decode("utf-8"), nxt
    except UnicodeDecodeError as e:
        raise OscDecodeError(f"string at byte {pos} is not UTF-8") from e


_FIXED = {"i": (4, ">i"), "f": (4, ">f"), "h": (8, ">q"), "d": (8, ">d"), "t": (8, ">Q"),
          "c": (4, ">I"), "r": (4, ">I"), "m": (4, ">I")}
_NO_DATA = {"T": True, "F": False, "N": None, "I": math.inf}


def _osc_message(data: bytes, pos: int, end: int) -> tuple[str, list[Any]]:
    """One OSC message occupying ``data[pos:end]``."""
    address, pos = _osc_string(data, pos, end)
    if not address.startswith("/"):
        raise OscDecodeError(f"address {address[:32]!r} does not start with '/'")
    if pos >= end:  # OSC 1.0 allows a message without a type tag string: no arguments
        return address, []
    tags, pos = _osc_string(data, pos, end)
    if not tags.startswith(","):
        raise OscDecodeError(f"type tags {tags[:32]!r} do not start with ','")
    args: list[Any] = []
    for tag in tags[1:]:
        if tag in _FIXED:
            size, fmt = _FIXED[tag]
            if pos + size > end:
                raise OscDecodeError(f"argument '{tag}' at byte {pos} runs past the end")
            args.append(struct.unpack_from(fmt, data, pos)[0])
            pos += size
        elif tag in ("s", "S"):
            text, pos = _osc_string(data, pos, end)
            args.append(text)
        elif tag == "b":
            if pos + 4 > end:
                raise OscDecodeError(f"blob size at byte {pos} runs past the end")
            (n,) = struct.unpack_from(">i", data, pos)
            if n < 0 or pos + 4 + n > end:
                raise OscDecodeError(f"blob of {n} bytes at byte {pos} does not fit")
            args.append(bytes(data[pos + 4:pos + 4 + n]))
            pos = (pos + 4 + n + 3) & ~3
        elif tag in _NO_DATA:
            args.append(_NO_DATA[tag])
        else:
            raise OscDecodeError(f"unsupported type tag {tag!r}")
    if pos > end:
        raise OscDecodeError("arguments run past the element end")
    return address, args


def decode_osc(data: bytes, max_messages: int = MAX_OSC_MESSAGES,
               max_depth: int = MAX_BUNDLE_DEPTH) -> list[tuple[str, list[Any]]]:
    """The OSC messages of one datagram (a message or nested bundles), in bundle order.

    Every element size is checked to be positive, a multiple of 4 and inside its bundle, so the
    walk always advances and ends after at most ``len(data) / 4`` steps.

    Raises:
        OscDecodeError: the datagram is not well-formed OSC 1.0, nests bundles deeper than
            ``max_depth`` or holds more than ``max_messages`` messages.
    """
    data = bytes(data)
    out: list[tuple[str, list[Any]]] = []

    def element(pos: int, end: int, depth: int) -> None:
        if end - pos < 4 or (end - pos) % 4:
            raise OscDecodeError(f"element of {end - pos} bytes at byte {pos} is not a "
                                 f"positive multiple of 4")
        if data.startswith(_BUNDLE_TAG, pos):
            if depth >= max_depth:
                raise OscDecodeError(f"bundles nested deeper than {max_depth}")
            pos += len(_BUNDLE_TAG) + 8  # tag, time tag
            if pos > end:
                raise OscDecodeError("bundle header runs past the end")
            while pos < end:
                if pos + 4 > end:
                    raise OscDecodeError(f"element size at byte {pos} runs past the end")
                (n,) = struct.unpack_from(">i", data, pos)
                if n <= 0 or n % 4 or pos + 4 + n > end:
                    raise OscDecodeError(f"bundle element size {n} at byte {pos} is invalid "
                                         f"({end - pos - 4} bytes left)")
                element(pos + 4, pos + 4 + n, depth + 1)
                pos += 4 + n
        else:
            if len(out) >= max_messages:
                raise OscDecodeError(f"more than {max_messages} messages in one datagram")
            out.append(_osc_message(data, pos, end))

    element(0, len(data), 0)
    return out


@dataclass(frozen=True)
class TuioConfig:
    """Where to listen and how big the surface is."""

    host: str = param("127.0.0.1", "address to bind the UDP socket to", read_only=True)
    port: int = param(3333, "UDP port of the TUIO stream (3333 is TUIO's default; 0 = any "
                      "free port)", lo=0, hi=65535, read_only=True)
    width: float = param(0.197, "surface width [m] (normalised x = 1)", lo=1e-3, hi=10.0)
    height: float = param(0.148, "surface height [m] (normalised y = 1)", lo=1e-3, hi=10.0)
    frame_id: str = param("touch_surface", "frame name of the surface")
    coord_margin: float = param(0.05, "normalised coordinates outside [-m, 1+m] are rejected",
                                lo=0.0, hi=1.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class TuioStats:
    """Counters of what the parser accepted and dropped."""

    frames: int = 0
    late_frames: int = 0
    bad_messages: int = 0
    bad_coordinates: int = 0
    bad_datagrams: int = 0
    last_bad_datagram: str = ""  # sender and defect of the last malformed datagram
    other_profiles: int = 0
    sources: set[str] = field(default_factory=set)


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


class TuioParser:
    """State machine of the TUIO 1.1 ``/tuio/2Dcur`` profile.

    Args:
        config: surface size and coordinate bounds.
        clock: returns the stamp given to each frame [s].
    """

    def __init__(self, config: TuioConfig | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        self.config = config or TuioConfig()
        self.clock = clock
        self.stats = TuioStats()
        self._positions: dict[int, tuple[float, float]] = {}  # committed, normalised
        self._pending_alive: list[int] | None = None
        self._pending_set: dict[int, tuple[float, float]] = {}
        self._fseq = -1

    def reset(self) -> None:
        """Forget every cursor (e.g. after the sender restarted)."""
        self._positions.clear()
        self._pending_alive = None
        self._pending_set.clear()
        self._fseq = -1

    def feed(self, address: str, args: Sequence[Any]) -> TouchFrame | None:
        """Take one OSC message; returns a frame when an ``fseq`` closes one."""
        if address != CURSOR_ADDRESS:
            self.stats.other_profiles += 1
            return None
        if not args or not isinstance(args[0], str):
            self.stats.bad_messages += 1
            return None
        cmd, rest = args[0], args[1:]
        if cmd == "alive":
            if not all(_is_int(a) for a in rest):
                self.stats.bad_messages += 1
                return None
            self._pending_alive = [int(a) for a in rest]
        elif cmd == "set":
            if len(rest) < 3 or not _is_int(rest[0]) or not all(_is_num(a) for a in rest[1:]):
                self.stats.bad_messages += 1
                return None
            x, y = float(rest[1]), float(rest[2])
            m = self.config.coord_margin
            if not (math.isfinite(x) and math.isfinite(y)
                    and -m <= x <= 1 + m and -m <= y <= 1 + m):
                self.stats.bad_coordinates += 1
                return None
            self._pending_set[int(rest[0])] = (x, y)
        elif cmd == "fseq":
            if len(rest) != 1 or not _is_int(rest[0]):
                self.stats.bad_messages += 1
                return None
            return self._close_frame(int(rest[0]))
        elif cmd == "source":
            if rest and isinstance(rest[0], str):
                self.stats.sources.add(rest[0])
        else:
            self.stats.bad_messages += 1
        return None

    def feed_many(self, messages: Iterable[tuple[str, Sequence[Any]]]) -> list[TouchFrame]:
        """Feed several messages; returns the frames they closed, in order."""
        frames = []
        for address, args in messages:
            f = self.feed(address, args)
            if f is not None:
                frames.append(f)
        return frames

    def _close_frame(self, fseq: int) -> TouchFrame | None:
        # TUIO 1.1: fseq > 0 numbers frames; an older one is a late (reordered) UDP packet and is
        # dropped, unless it is far older (sender restarted). fseq <= 0 (-1) marks a redundant
        # keep-alive bundle, which is always applied.
        if fseq > 0:
            if fseq < self._fseq and self._fseq - fseq <= _FSEQ_RESTART_GAP:
                self.stats.late_frames += 1
                self._pending_alive = None
                self._pending_set.clear()
                return None
            self._fseq = fseq
        alive = self._pending_alive
        if alive is None:  # a frame without alive message keeps the current cursors
            alive = list(self._positions)
        alive_set = set(alive)
        lifted = [(s, p) for s, p in self._positions.items() if s not in alive_set]
        new_positions: dict[int, tuple[float, float]] = {}
        for s in alive:
            if s in self._pending_set:
                new_positions[s] = self._pending_set[s]
            elif s in self._positions:
                new_positions[s] = self._positions[s]
            # an alive cursor with no position yet is reported once its set arrives
        self._positions = new_positions
        self._pending_alive = None
        self._pending_set.clear()
        self.stats.frames += 1
        return self._frame(new_positions, lifted)

    def _frame(self, down: dict[int, tuple[float, float]],
               lifted: list[tuple[int, tuple[float, float]]]) -> TouchFrame:
        cfg = self.config
        ids = list(down) + [s for s, _ in lifted]
        norm = list(down.values()) + [p for _, p in lifted]
        pos = np.asarray(norm, dtype=np.float64).reshape(-1, 2) * (cfg.width, cfg.height)
        flags = np.r_[np.ones(len(down), bool), np.zeros(len(lifted), bool)]
        return TouchFrame(np.asarray(ids, np.int64), pos, flags, cfg.width, cfg.height,
                          self.clock(), cfg.frame_id)


class TuioReceiver:
    """Non-blocking UDP listener for a TUIO stream; call :meth:`poll` from a timer.

    Raises:
        DeviceError: the socket cannot be bound (port in use, bad address).
    """

    #: Datagrams read per :meth:`poll` at most, so a flood cannot hold the caller's loop.
    MAX_DATAGRAMS_PER_POLL = 1000

    def __init__(self, config: TuioConfig | None = None,
                 clock: Callable[[], float] = time.time, max_datagram: int = 65536) -> None:
        self.config = config or TuioConfig()
        self.parser = TuioParser(self.config, clock)
        self._max = max_datagram
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((self.config.host, self.config.port))
        except OSError as e:
            self._sock.close()
            raise DeviceError(f"cannot listen for TUIO on udp://{self.config.host}:"
                              f"{self.config.port}: {e}") from e
        self._sock.setblocking(False)

    @property
    def address(self) -> tuple[str, int]:
        """The bound (host, port); the port is the real one when 0 was asked for."""
        return self._sock.getsockname()

    @property
    def stats(self) -> TuioStats:
        return self.parser.stats

    def decode(self, datagram: bytes, sender: object = None) -> list[tuple[str, list[Any]]]:
        """OSC messages of one datagram (a message or nested bundles), in bundle order; a
        malformed datagram is counted in ``stats.bad_datagrams`` (``stats.last_bad_datagram``
        names the sender and the defect) and gives none."""
        try:
            return decode_osc(datagram)
        except OscDecodeError as e:
            self.parser.stats.bad_datagrams += 1
            self.parser.stats.last_bad_datagram = (
                f"{len(datagram)} bytes{f' from {sender}' if sender else ''}: {e}")
            return []

    def poll(self, timeout: float = 0.0) -> list[TouchFrame]:
        """Read every datagram waiting (or up to ``timeout`` s for the first one)."""
        frames: list[TouchFrame] = []
        if timeout > 0:
            import select

            select.select([self._sock], [], [], timeout)
        for _ in range(self.MAX_DATAGRAMS_PER_POLL):
            try:
                data, sender = self._sock.recvfrom(self._max)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as e:
                raise DeviceError(f"TUIO socket failed: {e}") from e
            frames.extend(self.parser.feed_many(self.decode(data, sender)))
        return frames

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> TuioReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def cursor_bundle(session_positions: dict[int, tuple[float, float]], fseq: int,
                  source: str | None = None) -> bytes:
    """Build one TUIO 1.1 ``/tuio/2Dcur`` bundle (source?, alive, set..., fseq) as bytes.

    Used by tests and the demo sender; positions are normalised to [0, 1].
    """
    from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
    from pythonosc.osc_message_builder import OscMessageBuilder

    def msg(*args: Any) -> Any:
        b = OscMessageBuilder(address=CURSOR_ADDRESS)
        for a in args:
            b.add_arg(a, "f" if isinstance(a, float) else None)
        return b.build()

    bundle = OscBundleBuilder(IMMEDIATELY)
    if source is not None:
        bundle.add_content(msg("source", source))
    bundle.add_content(msg("alive", *[int(s) for s in session_positions]))
    for s, (x, y) in session_positions.items():
        bundle.add_content(msg("set", int(s), float(x), float(y), 0.0, 0.0, 0.0))
    bundle.add_content(msg("fseq", int(fseq)))
    return bundle.build().dgram
