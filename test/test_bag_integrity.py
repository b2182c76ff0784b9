"""Bag integrity (issue #20 items 6, 7, 10): MCAP CRCs written and checked, damaged bags refused
with one line naming the damage, recovery that never deletes a folder and works on sqlite3, and
MCAP files from other writers (no QoS metadata, no repeated channels) read. No ROS graph."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from hand_capture.bag import BagReader, BagWriter, recover_bag
from hand_capture.bag.typestore import default_typestore
from hand_capture.errors import BagError

ROOT = Path(__file__).resolve().parents[1]


def _image(k: int, side: int = 24) -> bytes:
    """A CDR sensor_msgs/Image whose every pixel is k % 251 (damage is visible)."""
    store = default_typestore()
    T = store.types
    img = T["sensor_msgs/msg/Image"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=k, nanosec=0),
                                        frame_id="cam"),
        height=side, width=side, encoding="mono8", is_bigendian=0, step=side,
        data=__import__("numpy").full(side * side, k % 251, dtype="uint8"))
    return bytes(store.serialize_cdr(img, "sensor_msgs/msg/Image"))


def _image_bag(path: Path, n: int = 12, chunk_every: int = 4,
               compress: bool = False) -> dict[int, bytes]:
    """An MCAP bag of ``n`` images on /img (several chunks); returns stamp -> payload."""
    w = BagWriter(path, flush_period=3600.0, compress=compress)
    w.add_topic("/img", "sensor_msgs/msg/Image")
    sent = {}
    for k in range(n):
        sent[1000 + k] = _image(k)
        w.write("/img", 1000 + k, sent[1000 + k])
        if k % chunk_every == chunk_every - 1:
            w.flush()  # closes a chunk
    w.close()
    return sent


@pytest.mark.parametrize("compress", [False, True])
def test_mcap_crcs_are_written_and_accepted_by_independent_readers(tmp_path: Path,
                                                                    compress: bool) -> None:
    from mcap.records import Chunk, DataEnd, Footer
    from mcap.stream_reader import StreamReader, breakup_chunk
    from rosbags.rosbag2 import Reader

    sent = _image_bag(tmp_path / "b", compress=compress)
    f = tmp_path / "b" / "b.mcap"
    seen = {"chunks": 0}
    with f.open("rb") as fh:  # the raw records, chunks not broken up
        for rec in StreamReader(fh, validate_crcs=True, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                assert rec.uncompressed_crc != 0
                assert rec.compression == ("zstd" if compress else "")
                breakup_chunk(rec, validate_crc=True)
                seen["chunks"] += 1
            elif isinstance(rec, DataEnd):
                assert rec.data_section_crc != 0
            elif isinstance(rec, Footer):
                assert rec.summary_crc != 0
    assert seen["chunks"] == 3
    with f.open("rb") as fh:  # the reference reader checks every CRC and reads every message
        msgs = [m for m in StreamReader(fh, validate_crcs=True).records
                if type(m).__name__ == "Message"]
    assert {m.log_time: bytes(m.data) for m in msgs} == sent
    with Reader(tmp_path / "b") as raw:  # rosbags checks the chunk CRCs it reads
        assert {ts: bytes(d) for _, ts, d in raw.messages()} == sent


def _flip(f: Path, offset: int, data: bytes) -> None:
    d = bytearray(data)
    d[offset] ^= 0x5A
    f.write_bytes(bytes(d))


def _read_all(path: Path) -> dict[int, bytes]:
    r = BagReader(path)
    try:
        out = {}
        for m in r.messages():
            r.check(m)
            out[m.timestamp_ns] = m.data
        return out
    finally:
        r.close()


def test_bit_flips_never_return_a_damaged_image(tmp_path: Path) -> None:
    """Issue #20 item 6: single-byte flips at offsets across the whole file (header, chunks,
    message indexes, metadata, summary, footer): the reader refuses the bag (BagError) or
    returns exactly the images written; never a damaged one."""
    sent = _image_bag(tmp_path / "b")
    f = tmp_path / "b" / "b.mcap"
    data = f.read_bytes()
    offsets = sorted({int(i * (len(data) - 1) / 60) for i in range(61)}
                     | {len(data) - 1 - k for k in range(0, 37, 3)})
    refused = 0
    for off in offsets:
        _flip(f, off, data)
        try:
            got = _read_all(tmp_path / "b")
        except BagError:
            refused += 1
            continue
        assert got == sent, f"flip at byte {off} of {len(data)} returned damaged data"
    f.write_bytes(data)
    assert _read_all(tmp_path / "b") == sent
    assert refused == len(offsets)  # every byte is covered by a CRC or a structure check


def test_damaged_chunk_is_named_by_bag_info_in_one_line(tmp_path: Path) -> None:
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    _image_bag(tmp_path / "b")
    f = tmp_path / "b" / "b.mcap"
    data = f.read_bytes()
    with f.open("rb") as fh:
        n = 0
        for rec in StreamReader(fh, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                n += 1
                if n == 2:
                    break
    # a byte inside the second chunk's image data
    off = data.index(bytes([5]) * 64)
    _flip(f, off + 10, data)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for action in ("info", "check"):
        p = subprocess.run([sys.executable, "-m", "hand_control.cli", "bag", action,
                            str(tmp_path / "b")], capture_output=True, text=True, env=env,
                           timeout=120)
        assert p.returncode == 2
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1, p.stderr
        assert "data section CRC mismatch: chunk 1" in lines[0] and "b.mcap" in lines[0]


def test_bag_check_accepts_a_good_bag(tmp_path: Path) -> None:
    _image_bag(tmp_path / "b")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.run([sys.executable, "-m", "hand_control.cli", "bag", "check",
                        str(tmp_path / "b")], capture_output=True, text=True, env=env,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    assert "ok (12 messages" in p.stdout


# --- recovery ----------------------------------------------------------------------------

_KILLED_WRITER = """
import struct, sys, time
from hand_capture.bag.bagfile import BagWriter
w = BagWriter(sys.argv[1], storage=sys.argv[2], flush_period=3600)
w.add_topic("/x", "std_msgs/msg/String")
s = b"a" * 20000
m = b"\\x00\\x01\\x00\\x00" + struct.pack("<I", len(s) + 1) + s + b"\\x00"
for i in range(10):
    w.write("/x", i, m)
w.flush()
for i in range(10, 400):  # never flushed: spills into the journal / a partial chunk
    w.write("/x", i, m)
print("ready", flush=True)
time.sleep(60)
"""


def _killed_bag(path: Path, storage: str) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(path), storage],
                         stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert p.stdout.readline().strip() == "ready"
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=30)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_recover_killed_recorder_names_what_it_salvaged(tmp_path: Path, storage: str) -> None:
    """Issue #20 item 7: sqlite3 recovery failed with 'attempt to write a readonly
    database' (the killed writer's hot journal); the source files stay untouched."""
    _killed_bag(tmp_path / "k", storage)
    before = {p.name: p.read_bytes() for p in (tmp_path / "k").iterdir()}
    res = recover_bag(tmp_path / "k")
    assert res.messages >= 10 and res.per_topic == {"/x": res.messages}
    assert res.output == tmp_path / "k_recovered"
    text = res.describe()
    assert f"recovered {res.messages} messages on 1 topics" in text and "/x" in text
    assert [m.timestamp_ns for m in BagReader(res.output).messages()] == list(
        range(res.messages))
    assert {p.name: p.read_bytes() for p in (tmp_path / "k").iterdir()} == before


def test_recover_never_deletes_an_existing_output(tmp_path: Path) -> None:
    _killed_bag(tmp_path / "k", "mcap")
    keep = tmp_path / "mine"
    keep.mkdir()
    (keep / "thesis.txt").write_text("do not delete")
    with pytest.raises(BagError, match="exists"):
        recover_bag(tmp_path / "k", keep)
    assert (keep / "thesis.txt").read_text() == "do not delete"
    (tmp_path / "k_recovered").mkdir()
    (tmp_path / "k_recovered" / "notes.txt").write_text("mine")
    res = recover_bag(tmp_path / "k")  # default output taken: a new numbered folder
    assert res.output == tmp_path / "k_recovered_2"
    assert (tmp_path / "k_recovered" / "notes.txt").read_text() == "mine"


def test_recover_stops_at_a_damaged_chunk_and_says_so(tmp_path: Path) -> None:
    sent = _image_bag(tmp_path / "b")
    (tmp_path / "b" / "metadata.yaml").unlink()
    f = tmp_path / "b" / "b.mcap"
    data = f.read_bytes()
    _flip(f, data.index(bytes([5]) * 64) + 10, data)  # image 5: second chunk
    res = recover_bag(tmp_path / "b")
    assert res.messages == 4  # the first chunk only
    assert "CRC" in res.stopped or "crc" in res.stopped
    got = {m.timestamp_ns: m.data for m in BagReader(res.output).messages()}
    assert got == {k: v for k, v in sent.items() if k < 1004}


# --- MCAP from other writers ---------------------------------------------------------------

def _foreign_mcap(path: Path, **writer_kw: object) -> list[int]:
    """An MCAP file as the ``mcap`` tools write it: no QoS metadata on the channel."""
    from mcap.writer import Writer

    store = default_typestore()
    data = bytes(store.serialize_cdr(store.types["std_msgs/msg/String"](data="hi"),
                                     "std_msgs/msg/String"))
    stamps = [1_000_000 + (k * 7) % 5 * 1_000_000 for k in range(5)]
    with path.open("wb") as fh:
        w = Writer(fh, **writer_kw)
        w.start(profile="ros2", library="mcap-tools")
        sid = w.register_schema(name="std_msgs/msg/String", encoding="ros2msg",
                                data=b"string data")
        cid = w.register_channel(topic="/chatter", message_encoding="cdr", schema_id=sid)
        for ts in stamps:
            w.add_message(cid, log_time=ts, data=data, publish_time=ts)
        w.finish()
    return sorted(stamps)


@pytest.mark.parametrize("kw", [{}, {"repeat_channels": False},
                                {"repeat_channels": False, "use_statistics": False},
                                {"use_chunking": False, "enable_data_crcs": True}])
def test_mcap_from_other_writers_is_read(tmp_path: Path, kw: dict) -> None:
    """Issue #20 item 10: rosbags' reader saw 0 of 5 messages in such files ('truncated
    bag'); the mcap library reads them."""
    f = tmp_path / "ext.mcap"
    stamps = _foreign_mcap(f, **kw)
    r = BagReader(f)
    assert r.topics == {"/chatter": "std_msgs/msg/String"} and r.message_count == 5
    msgs = list(r.messages())
    assert [m.timestamp_ns for m in msgs] == stamps
    assert r.check(msgs[0]).data == "hi"
    assert r.qos("/chatter") == []


def test_recorded_qos_is_exposed(tmp_path: Path) -> None:
    from rosbags.interfaces import QosDurability

    from hand_capture.bag import make_qos

    w = BagWriter(tmp_path / "q")
    w.add_topic("/hand/shape", "hand_msgs/msg/HandShape", [make_qos(True, True, depth=1)])
    w.close()
    (q,) = BagReader(tmp_path / "q").qos("/hand/shape")
    assert q.durability == QosDurability.TRANSIENT_LOCAL and q.depth == 1


def test_hostile_sizes_in_a_foreign_file_are_refused(tmp_path: Path) -> None:
    f = tmp_path / "ext.mcap"
    _foreign_mcap(f)
    data = bytearray(f.read_bytes())
    struct.pack_into("<Q", data, len(data) - 37 + 9, 2**62)  # footer: summary offset
    f.write_bytes(bytes(data))
    with pytest.raises(BagError, match="footer"):
        BagReader(f)
