"""TUIO 1.1 and evdev multi-touch protocol B parsing (no device, no ROS)."""

from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np
import pytest

from hand_capture.errors import DeviceError, InputError
from hand_capture.touch import evdev_mt as mt
from hand_capture.touch.frame import TouchFrame
from hand_capture.touch.tuio import (
    CURSOR_ADDRESS,
    TuioConfig,
    TuioParser,
    TuioReceiver,
    cursor_bundle,
    decode_osc,
)

W, H = 0.2, 0.15


def _cfg(**kw) -> TuioConfig:
    return TuioConfig(width=W, height=H, port=0, **kw)


def _msgs(*cmds):
    return [(CURSOR_ADDRESS, list(c)) for c in cmds]


def _by_id(frame: TouchFrame) -> dict[int, tuple[float, float, bool]]:
    return {int(i): (float(p[0]), float(p[1]), bool(c))
            for i, p, c in zip(frame.session_ids, frame.positions, frame.in_contact,
                               strict=True)}


# --- TUIO ---------------------------------------------------------------------------------

def test_tuio_set_alive_fseq_to_metres():
    p = TuioParser(_cfg(), clock=lambda: 1.5)
    frames = p.feed_many(_msgs(("source", "ipad@10.0.0.2"), ("alive", 3, 7),
                               ("set", 3, 0.5, 0.25, 0.0, 0.0, 0.0),
                               ("set", 7, 0.1, 0.9, 0.1, 0.0, 0.0), ("fseq", 1)))
    assert len(frames) == 1
    f = frames[0]
    assert f.stamp == 1.5 and f.width == W and f.height == H
    got = _by_id(f)
    assert got[3] == pytest.approx((0.5 * W, 0.25 * H, True))
    assert got[7] == pytest.approx((0.1 * W, 0.9 * H, True))
    assert "ipad@10.0.0.2" in p.stats.sources


def test_tuio_unchanged_cursor_keeps_position_and_lift_reported_once():
    p = TuioParser(_cfg())
    p.feed_many(_msgs(("alive", 1, 2), ("set", 1, 0.2, 0.2, 0, 0, 0),
                      ("set", 2, 0.4, 0.4, 0, 0, 0), ("fseq", 10)))
    # only cursor 2 moves: cursor 1 keeps its position
    (f,) = p.feed_many(_msgs(("alive", 1, 2), ("set", 2, 0.5, 0.5, 0, 0, 0), ("fseq", 11)))
    assert _by_id(f)[1][:2] == pytest.approx((0.2 * W, 0.2 * H))
    assert _by_id(f)[2][:2] == pytest.approx((0.5 * W, 0.5 * H))
    # cursor 1 lifts: reported with in_contact False at its last position, then gone
    (f,) = p.feed_many(_msgs(("alive", 2), ("fseq", 12)))
    assert _by_id(f)[1] == pytest.approx((0.2 * W, 0.2 * H, False))
    assert _by_id(f)[2][2] is True
    (f,) = p.feed_many(_msgs(("alive", 2), ("fseq", 13)))
    assert set(_by_id(f)) == {2}


def test_tuio_late_frame_dropped_and_keepalive_applied():
    p = TuioParser(_cfg())
    p.feed_many(_msgs(("alive", 1), ("set", 1, 0.2, 0.2, 0, 0, 0), ("fseq", 500)))
    # a reordered older bundle is dropped entirely
    assert p.feed_many(_msgs(("alive",), ("fseq", 499))) == []
    assert p.stats.late_frames == 1
    # fseq -1 (redundant keep-alive) is always applied
    (f,) = p.feed_many(_msgs(("alive", 1), ("fseq", -1)))
    assert set(_by_id(f)) == {1}
    # a much older fseq means the sender restarted: accepted
    (f,) = p.feed_many(_msgs(("alive", 4), ("set", 4, 0.3, 0.3, 0, 0, 0), ("fseq", 1)))
    assert _by_id(f)[4][2] and not _by_id(f)[1][2]


def test_tuio_bad_data_counted_not_raised():
    p = TuioParser(_cfg())
    frames = p.feed_many(_msgs(("alive", 1, 2), ("set", 1, float("nan"), 0.5, 0, 0, 0),
                               ("set", 2, 3.0, 0.5, 0, 0, 0), ("set", "x", 0.1, 0.1),
                               ("bogus",), ("fseq", 5)))
    assert p.stats.bad_coordinates == 2 and p.stats.bad_messages == 2
    # alive cursors without a valid position are not reported
    assert len(frames) == 1 and len(frames[0]) == 0
    assert p.feed("/tuio/2Dobj", ["alive"]) is None and p.stats.other_profiles == 1


def test_tuio_receiver_decodes_bundles_and_plain_messages():
    with TuioReceiver(_cfg()) as rx:
        host, port = rx.address
        assert host == "127.0.0.1" and port > 0
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            tx.sendto(cursor_bundle({5: (0.5, 0.5), 6: (0.25, 0.75)}, 1, "test@local"),
                      (host, port))
            tx.sendto(b"not osc", (host, port))
            deadline, frames = time.monotonic() + 2.0, []
            while time.monotonic() < deadline and not frames:
                frames += rx.poll(timeout=0.05)
        finally:
            tx.close()
        assert len(frames) == 1
        assert _by_id(frames[0])[6] == pytest.approx((0.25 * W, 0.75 * H, True))
        rx.poll(timeout=0.05)
        assert rx.stats.bad_datagrams == 1


#: Datagrams that hung (negative element size) or could crash an OSC decoder, each with the
#: reason it is malformed.
_HOSTILE_DATAGRAMS = {
    "negative element size": b"#bundle\x00" + bytes(8) + struct.pack(">i", -4),
    "zero element size": b"#bundle\x00" + bytes(8) + struct.pack(">i", 0),
    "huge element size": b"#bundle\x00" + bytes(8) + struct.pack(">i", 2**31 - 4),
    "element past the end": b"#bundle\x00" + bytes(8) + struct.pack(">i", 16) + b"/a\x00\x00",
    "truncated bundle header": b"#bundle\x00\x00\x00",
    "huge blob": b"/tuio/2Dcur\x00,b\x00\x00" + struct.pack(">i", 2**31 - 1),
    "negative blob": b"/tuio/2Dcur\x00,b\x00\x00" + struct.pack(">i", -8),
    "truncated int": b"/tuio/2Dcur\x00,i\x00\x00\x00\x01",
    "unterminated string": b"/tuio/2Dcur\x00,s\x00\x00abcd",
    "deep nesting": b"".join(b"#bundle\x00" + bytes(8) + struct.pack(">i", 16 * (40 - k))
                             for k in range(40)),
}


@pytest.mark.parametrize("name", sorted(_HOSTILE_DATAGRAMS))
def test_decode_osc_rejects_malformed(name):
    from hand_capture.touch.tuio import OscDecodeError

    with pytest.raises(OscDecodeError):
        decode_osc(_HOSTILE_DATAGRAMS[name])


def test_decode_osc_matches_python_osc_on_a_cursor_bundle():
    from pythonosc.osc_packet import OscPacket

    dgram = cursor_bundle({5: (0.5, 0.5), 6: (0.25, 0.75)}, 7, "test@local")
    ref = [(m.message.address, list(m.message.params)) for m in OscPacket(dgram).messages]
    assert decode_osc(dgram) == ref


def test_tuio_hostile_datagram_is_counted_and_listener_keeps_working():
    """Issue #20 item 3: a 20-byte bundle with a negative element size hung the listener."""
    with TuioReceiver(_cfg()) as rx:
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        frames: list = []

        def listen() -> None:
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not frames:
                frames.extend(rx.poll(timeout=0.05))

        try:
            for dgram in _HOSTILE_DATAGRAMS.values():
                tx.sendto(dgram, rx.address)
            tx.sendto(cursor_bundle({5: (0.5, 0.5)}, 1), rx.address)
            t = threading.Thread(target=listen, daemon=True)
            t.start()
            t.join(timeout=30.0)
        finally:
            tx.close()
        assert not t.is_alive(), "TUIO listener hung on a malformed datagram"
        assert rx.stats.bad_datagrams == len(_HOSTILE_DATAGRAMS)
        assert "from ('127.0.0.1'" in rx.stats.last_bad_datagram  # who sent it, and why
        assert len(frames) == 1 and _by_id(frames[0])[5][2]


def test_tuio_port_in_use_is_device_error():
    with TuioReceiver(_cfg()) as rx, pytest.raises(DeviceError, match="udp://"):
        TuioReceiver(TuioConfig(port=rx.address[1]))


# --- evdev MT protocol B ----------------------------------------------------------------

XR, YR = mt.AxisRange(0, 1000, 5), mt.AxisRange(0, 500, 5)  # 200 mm x 100 mm at 5 u/mm


def _ev(code, value):
    return (mt.EV_ABS, code, value)


SYN = (mt.EV_SYN, mt.SYN_REPORT, 0)


def test_axis_span_from_resolution():
    assert XR.span_m() == pytest.approx(0.2) and YR.span_m() == pytest.approx(0.1)
    assert mt.AxisRange(0, 10).span_m() == 0.0


def test_mt_b_two_fingers_move_lift():
    p = mt.MTParser(XR, YR, XR.span_m(), YR.span_m(), num_slots=4, clock=lambda: 0.0)
    frames = p.feed_many([
        _ev(mt.ABS_MT_SLOT, 0), _ev(mt.ABS_MT_TRACKING_ID, 45),
        _ev(mt.ABS_MT_POSITION_X, 100), _ev(mt.ABS_MT_POSITION_Y, 250),
        _ev(mt.ABS_MT_SLOT, 1), _ev(mt.ABS_MT_TRACKING_ID, 46),
        _ev(mt.ABS_MT_POSITION_X, 500), _ev(mt.ABS_MT_POSITION_Y, 50), SYN,
        # slot 1 still selected: only its X changes
        _ev(mt.ABS_MT_POSITION_X, 600), SYN,
        # slot 0 lifts
        _ev(mt.ABS_MT_SLOT, 0), _ev(mt.ABS_MT_TRACKING_ID, -1), SYN,
        SYN,
    ])
    assert len(frames) == 4
    f0, f1, f2, f3 = (_by_id(f) for f in frames)
    assert f0[45] == pytest.approx((0.02, 0.05, True))
    assert f0[46] == pytest.approx((0.10, 0.01, True))
    assert f1[45] == pytest.approx((0.02, 0.05, True))
    assert f1[46] == pytest.approx((0.12, 0.01, True))
    assert f2[45] == pytest.approx((0.02, 0.05, False)) and f2[46][2]
    assert set(f3) == {46}


def test_mt_b_slot_reuse_and_syn_dropped():
    p = mt.MTParser(XR, YR, 0.2, 0.1, num_slots=2)
    p.feed_many([_ev(mt.ABS_MT_SLOT, 0), _ev(mt.ABS_MT_TRACKING_ID, 1),
                 _ev(mt.ABS_MT_POSITION_X, 10), _ev(mt.ABS_MT_POSITION_Y, 10), SYN])
    # the slot gets a new tracking id without -1 in between: old contact lifts, new one starts
    (f,) = p.feed_many([_ev(mt.ABS_MT_TRACKING_ID, 2), _ev(mt.ABS_MT_POSITION_X, 900), SYN])
    got = _by_id(f)
    assert got[1][2] is False and got[2][2] is True
    assert got[2][0] == pytest.approx(0.18)
    # overflow: events until the next SYN_REPORT are dropped, every contact is lifted
    frames = p.feed_many([(mt.EV_SYN, mt.SYN_DROPPED, 0), _ev(mt.ABS_MT_POSITION_X, 1), SYN])
    assert _by_id(frames[0]) == {2: pytest.approx((0.18, 0.002, False))}
    assert p.stats.dropped_syncs == 1
    # out-of-range slot: counted, its events ignored
    (f,) = p.feed_many([_ev(mt.ABS_MT_SLOT, 9), _ev(mt.ABS_MT_TRACKING_ID, 3), SYN])
    assert len(f) == 0 and p.stats.bad_slots == 1


def test_mt_parser_needs_size():
    with pytest.raises(DeviceError, match="width/height"):
        mt.MTParser(mt.AxisRange(0, 100), mt.AxisRange(0, 100), 0.0, 0.0)


def test_evdev_missing_device_is_device_error():
    with pytest.raises(DeviceError, match="cannot open"):
        mt.EvdevTouchReader(mt.EvdevConfig(device="/dev/input/does-not-exist"))


# --- TouchFrame validation ---------------------------------------------------------------

def test_touch_frame_rejects_malformed():
    with pytest.raises(InputError):
        TouchFrame([1, 1], np.zeros((2, 2)), [True, True], W, H)
    with pytest.raises(InputError):
        TouchFrame([1], np.zeros((2, 2)), [True], W, H)
    with pytest.raises(InputError):
        TouchFrame([1], np.zeros((1, 2)), [True], 0.0, H)
    assert len(TouchFrame.empty(W, H)) == 0
