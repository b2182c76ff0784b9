"""Property-based fuzzing of the suite's byte-level inputs (issue #20): OSC datagrams into the
TUIO listener and bit flips into a bag. Each property: the input is rejected (counted, or a
BagError) or yields correct data; never a crash, a hang or damaged data. Bounded example
counts, no deadline per example, a hang guard per example; the seed corpus (``@example``)
keeps the cases found by hand as regression tests."""

from __future__ import annotations

import math
import shutil
import struct
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hand_capture.bag import BagReader, BagWriter
from hand_capture.errors import BagError
from hand_capture.touch.tuio import TuioConfig, TuioParser, TuioReceiver, cursor_bundle

_SETTINGS = settings(max_examples=150, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.too_slow])
_HANG_S = 10.0  # one example's decode gets this long [s] (it takes microseconds)


def _bounded(fn: Callable[[], object]) -> object:
    """Run ``fn`` in a daemon thread; fail (instead of hanging the suite) if it does not end
    within ``_HANG_S``; re-raise what it raised."""
    box: dict[str, object] = {}

    def run() -> None:
        try:
            box["value"] = fn()
        except BaseException as e:  # handed to the caller
            box["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(_HANG_S)
    assert not t.is_alive(), "hung"
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box.get("value")


# --- OSC / TUIO ------------------------------------------------------------------------------

_CFG = TuioConfig(port=0, width=0.2, height=0.15)
_GOOD = cursor_bundle({3: (0.25, 0.5), 9: (0.75, 0.1)}, 5, "fuzz@local")


@st.composite
def _mutated(draw) -> bytes:
    """A valid TUIO bundle with random byte flips, a truncation or an inserted int32."""
    data = bytearray(_GOOD)
    for _ in range(draw(st.integers(0, 4))):
        k = draw(st.integers(0, len(data) - 1))
        data[k] ^= draw(st.integers(1, 255))
    if draw(st.booleans()):
        data = data[:draw(st.integers(0, len(data)))]
    if draw(st.booleans()):
        k = draw(st.integers(0, len(data)))
        data[k:k] = struct.pack(">i", draw(st.integers(-2**31, 2**31 - 1)))
    return bytes(data)


@st.composite
def _hostile_bundle(draw) -> bytes:
    """A bundle header followed by elements with arbitrary (often lying) int32 sizes."""
    out = b"#bundle\x00" + bytes(8)
    for _ in range(draw(st.integers(0, 4))):
        out += struct.pack(">i", draw(st.integers(-2**31, 2**31 - 1)))
        out += draw(st.binary(max_size=24))
    return out


_DATAGRAMS = st.one_of(st.binary(max_size=256), _mutated(), _hostile_bundle())

_RX: list[TuioReceiver] = []


def _receiver() -> TuioReceiver:
    if not _RX:
        _RX.append(TuioReceiver(_CFG))  # decode() is the listener's per-datagram entry point
    return _RX[0]


@pytest.fixture(scope="module", autouse=True)
def _close_receiver():
    yield
    for rx in _RX:
        rx.close()
    _RX.clear()


@_SETTINGS
@given(_DATAGRAMS)
@example(b"#bundle\x00" + bytes(8) + struct.pack(">i", -4))  # hung python-osc (issue #20)
@example(b"#bundle\x00" + bytes(8) + struct.pack(">i", 0))
@example(b"#bundle\x00" + bytes(8) + struct.pack(">i", 2**31 - 4))
@example(b"/tuio/2Dcur\x00,b\x00\x00" + struct.pack(">i", -8))
@example(_GOOD)
def test_tuio_datagrams_are_rejected_or_parsed_never_hang(dgram: bytes) -> None:
    rx = _receiver()
    before = rx.stats.bad_datagrams
    msgs = _bounded(lambda: rx.decode(dgram))
    assert isinstance(msgs, list)
    if not msgs:
        assert rx.stats.bad_datagrams in (before, before + 1)
    for address, args in msgs:
        assert isinstance(address, str) and isinstance(args, list)
    # whatever decoded goes through the parser: frames only with finite, in-bounds positions
    parser = TuioParser(_CFG, clock=lambda: 0.0)
    m = _CFG.coord_margin
    frames = parser.feed_many(msgs)
    for frame in frames:
        assert all(math.isfinite(float(v)) for v in frame.positions.ravel())
        assert (frame.positions[:, 0] >= -m * _CFG.width - 1e-12).all()
        assert (frame.positions[:, 0] <= (1 + m) * _CFG.width + 1e-12).all()
        assert (frame.positions[:, 1] >= -m * _CFG.height - 1e-12).all()
        assert (frame.positions[:, 1] <= (1 + m) * _CFG.height + 1e-12).all()
    if dgram == _GOOD:  # the intact bundle: one frame with both cursors
        assert len(frames) == 1 and len(frames[0]) == 2


# --- bags ----------------------------------------------------------------------------------

_BAG_DIR = Path(tempfile.mkdtemp(prefix="hand_suite_fuzz_bag_"))


def _bag() -> tuple[Path, bytes, dict[int, bytes]]:
    """A small 3-chunk MCAP bag of byte-pattern images (written once per session)."""
    good = _BAG_DIR / "good"
    if not good.exists():
        w = BagWriter(good, flush_period=3600.0)
        w.add_topic("/img", "sensor_msgs/msg/Image")
        from hand_capture.bag.typestore import default_typestore

        store = default_typestore()
        T = store.types
        import numpy as np

        for k in range(9):
            img = T["sensor_msgs/msg/Image"](
                header=T["std_msgs/msg/Header"](
                    stamp=T["builtin_interfaces/msg/Time"](sec=k, nanosec=0), frame_id="c"),
                height=8, width=8, encoding="mono8", is_bigendian=0, step=8,
                data=np.full(64, 17 * k + 1, dtype=np.uint8))
            w.write("/img", 1000 + k, bytes(store.serialize_cdr(img, "sensor_msgs/msg/Image")))
            if k % 3 == 2:
                w.flush()
        w.close()
    sent = {m.timestamp_ns: m.data for m in BagReader(good).messages()}
    return good, (good / "good.mcap").read_bytes(), sent


@pytest.fixture(scope="module", autouse=True)
def _remove_bags():
    yield
    shutil.rmtree(_BAG_DIR, ignore_errors=True)


@_SETTINGS
@given(st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 255)),
                min_size=1, max_size=3))
def test_bit_flipped_bag_is_refused_or_read_exactly(flips: list[tuple[float, int]]) -> None:
    good, data, sent = _bag()
    bad = _BAG_DIR / "bad"
    if bad.exists():
        shutil.rmtree(bad)
    shutil.copytree(good, bad)
    damaged = bytearray(data)
    for where, mask in flips:
        damaged[int(where * len(damaged))] ^= mask
    (bad / "good.mcap").write_bytes(bytes(damaged))

    def read() -> dict[int, bytes] | None:
        try:
            r = BagReader(bad)
            try:
                got = {}
                for m in r.messages():
                    r.check(m)
                    got[m.timestamp_ns] = m.data
                return got
            finally:
                r.close()
        except BagError:
            return None

    got = _bounded(read)
    assert got is None or got == sent, f"damaged data returned for flips {flips}"
