"""rosbag2 bags on disk, built on ``rosbags``: a durable writer, a validating reader, recovery.

* :class:`BagWriter` writes rosbag2 format 9 (MCAP or sqlite3) with full message definitions.
  It makes written data durable every ``flush_period`` seconds: MCAP closes the pending chunk
  and flushes it to the file, sqlite3 commits the transaction. A process killed with SIGKILL
  therefore loses at most the last ``flush_period`` seconds; the bag then has no
  ``metadata.yaml`` and :func:`recover_bag` rebuilds a complete bag from what was flushed.
  MCAP files carry real CRC32s (rosbags writes zeros): each chunk's uncompressed data, the
  data section (DataEnd record) and the summary section (footer), per the MCAP specification.
* :class:`BagReader` opens a bag, refuses a missing, truncated or corrupt one with
  :class:`~hand_capture.errors.BagError` naming the file, and yields raw CDR messages in time
  order. On open it verifies an MCAP file's summary and data-section CRCs (a damaged bag is
  refused before a message is read, naming the damaged part); chunk CRCs are checked as chunks
  are read. :meth:`BagReader.check` deserialises a message so garbage is never published.
"""

from __future__ import annotations

import shutil
import sqlite3
import struct
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as _QosTime
from rosbags.rosbag2 import (
    CompressionFormat,
    CompressionMode,
    Reader,
    StoragePlugin,
    Writer,
)
from rosbags.rosbag2.errors import ReaderError, WriterError
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.typesys.store import Typestore

from hand_capture.bag.mcapio import (
    CrcMcapWriter,
    McapSource,
    verify_mcap,
    written_by_rosbags,
)
from hand_capture.bag.typestore import default_typestore, ensure_type
from hand_capture.errors import BagError

STORAGES = ("mcap", "sqlite3")
_PLUGINS = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
#: MCAP Message record head: opcode 0x05, record length, channel id, sequence, log time,
#: publish time (rosbags writes the same bytes field by field through a BytesIO per message)
_MCAP_MESSAGE = struct.Struct("<BQHIQQ")
_MCAP_MESSAGE_LEN = _MCAP_MESSAGE.size - 9  # the record length excludes opcode and length
_MCAP_CHUNK_SIZE = 2**20  # rosbags' McapWriter closes a chunk beyond this many bytes


@dataclass(frozen=True)
class BagMessage:
    """One recorded message: topic, type (``pkg/msg/Name``), receive time [ns], CDR bytes."""

    topic: str
    msgtype: str
    timestamp_ns: int
    data: bytes


def make_qos(reliable: bool, transient_local: bool = False, depth: int = 10) -> Qos:
    """A rosbags QoS profile for a connection's ``offered_qos_profiles``."""
    zero = _QosTime(0, 0)
    return Qos(
        QosHistory.KEEP_LAST,
        depth,
        QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        zero,
        zero,
        QosLiveliness.AUTOMATIC,
        zero,
        False,
    )


def prepare_output(path: str | Path, overwrite: bool = False) -> Path:
    """Clear the way for a new bag at ``path`` before any work is done for it.

    Args:
        path: the bag directory a tool is about to write.
        overwrite: remove what is at ``path`` (a previous bag, or a file) instead of refusing.

    Returns:
        ``path`` as a :class:`~pathlib.Path`, free for :class:`BagWriter`.

    Raises:
        BagError: ``path`` exists and ``overwrite`` is False.
    """
    out = Path(path)
    if out.exists() or out.is_symlink():
        if not overwrite:
            raise BagError(f"{out} exists; choose another output or pass overwrite "
                           "(--overwrite on the command line)")
        if out.is_dir() and not out.is_symlink():
            shutil.rmtree(out)
        else:
            out.unlink()
    return out


class BagWriter:
    """Write a rosbag2 bag with periodic durable flushes.

    Args:
        path: bag directory to create (must not exist).
        storage: ``"mcap"`` or ``"sqlite3"``.
        flush_period: seconds between durable flushes (0 = after every message).
        typestore: message definitions; defaults to Kilted + hand_msgs.
        compress: zstd-compress MCAP chunks (storage-side compression; MCAP only).
    """

    def __init__(
        self,
        path: str | Path,
        storage: str = "mcap",
        flush_period: float = 1.0,
        typestore: Typestore | None = None,
        compress: bool = False,
    ) -> None:
        if storage not in STORAGES:
            raise BagError(f"unknown storage {storage!r}; valid: {list(STORAGES)}")
        if flush_period < 0:
            raise BagError(f"flush_period must be >= 0 s, got {flush_period}")
        self.path = Path(path)
        self.storage = storage
        self.flush_period = flush_period
        self._store = typestore or default_typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=_PLUGINS[storage])
        if compress:
            if storage != "mcap":
                raise BagError("compression is supported for MCAP storage only")
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        try:
            self._writer.open()
        except WriterError as e:
            raise BagError(f"cannot create bag {self.path}: {e}") from e
        if type(self._writer.storage) is McapWriter:
            CrcMcapWriter.adopt(self._writer.storage)
        self._conns: dict[str, object] = {}
        # MCAP: messages are appended to rosbags' pending chunk directly (same bytes and
        # bookkeeping as its McapWriter.write, without its per-message Python overhead)
        self._mcap = (self._writer.storage if isinstance(self._writer.storage, McapWriter)
                      else None)
        self._last_flush = time.monotonic()
        self.count = 0
        self.bytes = 0
        self._closed = False

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> message type of every connection added so far."""
        return {t: c.msgtype for t, c in self._conns.items()}

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> None:
        """Add a connection; ``msgtype`` like ``sensor_msgs/msg/Image``.

        Raises:
            BagError: the topic exists already or its definition cannot be found.
        """
        if topic in self._conns:
            raise BagError(f"topic {topic} already added to {self.path}")
        ensure_type(self._store, msgtype)
        try:
            self._conns[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self._store, offered_qos_profiles=list(qos)
            )
        except WriterError as e:
            raise BagError(f"cannot add {topic} ({msgtype}) to {self.path}: {e}") from e

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Append one CDR-serialised message received at ``timestamp_ns`` [ns]."""
        conn = self._conns.get(topic)
        if conn is None:
            raise BagError(f"topic {topic} was not added; known: {sorted(self._conns)}")
        if self._mcap is not None and not self._closed:
            self._write_mcap(conn, int(timestamp_ns), data)
        else:
            self._writer.write(conn, int(timestamp_ns), data)
        self.count += 1
        self.bytes += len(data)
        if time.monotonic() - self._last_flush >= self.flush_period:
            self.flush()

    def _write_mcap(self, conn, ts: int, data: bytes) -> None:
        """rosbags' ``Writer.write`` + ``McapWriter.write`` for one message, in fewer steps."""
        w, st = self._writer, self._mcap
        cid = conn.id
        w.counts[cid] += 1
        if ts < w.min_timestamp:
            w.min_timestamp = ts
        if ts > w.max_timestamp:
            w.max_timestamp = ts
        if ts < st.message_start_time:
            st.message_start_time = ts
        if ts > st.message_end_time:
            st.message_end_time = ts
        st.channel_stats[cid] += 1
        chunk = st.chunk
        if ts < chunk.message_start_time:
            chunk.message_start_time = ts
        if ts > chunk.message_end_time:
            chunk.message_end_time = ts
        bio = chunk.bio
        chunk.msgs[cid].append((ts, bio.tell()))
        bio.write(_MCAP_MESSAGE.pack(0x05, _MCAP_MESSAGE_LEN + len(data), cid, 0, ts, ts))
        bio.write(data)
        if bio.tell() > _MCAP_CHUNK_SIZE:
            st.close_chunk()

    def flush(self) -> None:
        """Make everything written so far durable against a killed process."""
        st = self._writer.storage
        if st is None or self._closed:
            return
        if self.storage == "mcap":
            if st.chunk.bio.tell():
                st.close_chunk()
            st.bio.flush()
        else:
            st.conn.commit()
        self._last_flush = time.monotonic()

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has run."""
        return self._closed

    def close(self) -> None:
        """Finish the bag (writes the index and metadata.yaml). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._writer.close()


#: Trailing bytes accepted after a fully decoded CDR message. Fast DDS aligns an empty
#: 8-byte sequence (e.g. JointCommand.efforts = []) and rounds the buffer up, leaving up to
#: this many bytes (uninitialised) that rosbags' strict size check would refuse.
CDR_TRAILING_SLACK = 16


def decode_cdr(store: Typestore, data: bytes, msgtype: str) -> object:
    """Deserialise a CDR message as published by rclpy / Fast DDS.

    Like ``Typestore.deserialize_cdr``, but accepts the alignment slack Fast DDS leaves after
    trailing empty sequences (:data:`CDR_TRAILING_SLACK`). A payload that does not decode, or
    leaves more than that undecoded, raises ``ValueError``.
    """
    if len(data) < 4 or bytes(data[:2]) not in (b"\x00\x00", b"\x00\x01"):
        raise ValueError("invalid or unsupported CDR encapsulation")
    msgdef = store.get_msgdef(msgtype)
    func = msgdef.deserialize_cdr_le if data[1] else msgdef.deserialize_cdr_be
    try:
        message, pos = func(memoryview(data)[4:], 0, msgdef.cls, store)
    except (struct.error, UnicodeDecodeError, ValueError, IndexError) as e:
        raise ValueError(f"cannot decode {msgtype}: {e}") from e
    if pos + 4 > len(data) or len(data) - (pos + 4) > CDR_TRAILING_SLACK:
        raise ValueError(f"CDR size mismatch for {msgtype}: decoded {pos + 4} of "
                         f"{len(data)} bytes")
    return message


class BagReader:
    """Read a rosbag2 bag (MCAP or sqlite3) written by us or by ``ros2 bag record``.

    Raises:
        BagError: on open, if the bag is missing, has no metadata, or its storage file is
            truncated or corrupt; the message names the file.
    """

    def __init__(self, path: str | Path, typestore: Typestore | None = None) -> None:
        self.path = Path(path)
        self._store = typestore or default_typestore()
        if not self.path.exists():
            raise BagError(f"bag not found: {self.path}")
        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():
            raise BagError(
                f"{self.path} has no metadata.yaml: the recorder did not finish; run "
                f"'hand-suite bag recover {self.path}' to rebuild it from what was flushed"
            )
        #: whether every storage file carried a data-section CRC that matched (MCAP)
        self.crc_verified = False
        files = sorted(self.path.glob("*.mcap")) if self.path.is_dir() else [self.path]
        checked = [verify_mcap(f) for f in files if f.suffix == ".mcap"]
        self.crc_verified = bool(checked) and all(checked)
        try:
            if (self.path.is_file() and self.path.suffix == ".mcap"
                    and not written_by_rosbags(self.path)):
                self._reader = McapSource(self.path)
            else:
                self._reader = Reader(self.path)
                self._reader.open()
        except (ReaderError, FileNotFoundError, OSError, ValueError, KeyError) as e:
            raise BagError(f"cannot open bag {self.path}: {e}") from e
        except Exception as e:  # rosbags/mcap raise many types on corrupt files
            raise BagError(f"corrupt bag {self.path}: {type(e).__name__}: {e}") from e
        for conn in self._reader.connections:
            if conn.msgtype in self._store.fielddefs:
                continue
            try:
                if conn.msgdef.data:
                    self._store.register(_types_from_conn(conn))
                else:
                    ensure_type(self._store, conn.msgtype)
            except Exception as e:
                raise BagError(
                    f"{self.path}: no definition for {conn.msgtype} on {conn.topic}: {e}"
                ) from e

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> message type."""
        return {c.topic: c.msgtype for c in self._reader.connections}

    def qos(self, topic: str) -> list[Qos]:
        """The QoS profiles recorded for ``topic`` (empty when the bag has none, e.g. MCAP
        files from the ``mcap`` tools)."""
        for c in self._reader.connections:
            if c.topic == topic:
                return list(getattr(c.ext, "offered_qos_profiles", []) or [])
        return []

    @property
    def message_count(self) -> int:
        """Number of messages the bag's metadata announces."""
        return int(self._reader.message_count)

    @property
    def start_ns(self) -> int:
        """Receive time of the first message [ns]."""
        return int(self._reader.start_time)

    @property
    def end_ns(self) -> int:
        """Receive time of the last message [ns] (exclusive end of rosbags' range)."""
        return int(self._reader.end_time)

    @property
    def duration_s(self) -> float:
        """Time between first and last message [s]."""
        return max(0, self.end_ns - self.start_ns) * 1e-9

    def messages(self, start_ns: int | None = None) -> Iterator[BagMessage]:
        """Messages in receive-time order from ``start_ns`` on.

        Raises:
            BagError: the storage ends early (fewer messages than the metadata says) or a
                record is unreadable.
        """
        expected = self.message_count if start_ns is None else None
        n = 0
        try:
            for conn, ts, data in self._reader.messages(start=start_ns):
                n += 1
                yield BagMessage(conn.topic, conn.msgtype, int(ts), bytes(data))
        except BagError:
            raise
        except Exception as e:
            raise BagError(
                f"corrupt bag {self.path}: unreadable after {n} messages: "
                f"{type(e).__name__}: {e}"
            ) from e
        if expected is not None and n != expected:
            raise BagError(
                f"truncated bag {self.path}: metadata announces {expected} messages, "
                f"storage holds {n}"
            )

    def check(self, msg: BagMessage) -> object:
        """Deserialise one message; a malformed payload raises BagError (never published)."""
        try:
            return decode_cdr(self._store, msg.data, msg.msgtype)
        except Exception as e:
            raise BagError(
                f"corrupt message in {self.path}: {msg.topic} ({msg.msgtype}) at "
                f"t={msg.timestamp_ns} ns: {type(e).__name__}: {e}"
            ) from e

    def close(self) -> None:
        """Close the storage file."""
        self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _types_from_conn(conn: object) -> dict:
    from rosbags.typesys import get_types_from_msg

    return get_types_from_msg(conn.msgdef.data, conn.msgtype)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class RecoveryResult:
    """What :func:`recover_bag` saved.

    Attributes:
        output: the new bag.
        messages: messages salvaged.
        topics: topic -> message type of every connection found.
        per_topic: topic -> messages salvaged on it.
        start_ns, end_ns: receive times of the first and last salvaged message [ns] (0 if none).
        stopped: where and why reading the damaged storage stopped.
    """

    output: Path
    messages: int
    topics: dict[str, str]
    per_topic: dict[str, int] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    stopped: str = ""

    def describe(self) -> str:
        """Human-readable summary: what was salvaged, per topic, and where reading stopped."""
        span = (self.end_ns - self.start_ns) * 1e-9 if self.messages else 0.0
        lines = [f"recovered {self.messages} messages on {len(self.topics)} topics "
                 f"({span:.3f} s) into {self.output}"]
        for topic, msgtype in sorted(self.topics.items()):
            lines.append(f"  {topic:40s} {msgtype:36s} {self.per_topic.get(topic, 0)}")
        if self.stopped:
            lines.append(f"reading stopped: {self.stopped}")
        return "\n".join(lines)


def _recover_mcap(file: Path) -> tuple[dict[str, str], list[BagMessage], str]:
    from mcap.exceptions import McapError
    from mcap.records import Channel, DataEnd, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    msgs: list[BagMessage] = []
    stopped = "end of file reached without a DataEnd record (recording was cut off)"
    with file.open("rb") as fh:
        try:
            for rec in StreamReader(fh, validate_crcs=True).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ""))
                elif isinstance(rec, Message) and rec.channel_id in channels:
                    topic, msgtype = channels[rec.channel_id]
                    msgs.append(BagMessage(topic, msgtype, rec.log_time, bytes(rec.data)))
                elif isinstance(rec, DataEnd):
                    stopped = ""
                    break
        except (McapError, EOFError, ValueError, OSError) as e:
            # the file ends where the killed process stopped writing, or a chunk is damaged
            # (CRC): everything from there on is dropped
            stopped = (f"at byte {fh.tell()} of {file.stat().st_size}: "
                       f"{type(e).__name__}: {e}; later data dropped")
        except Exception as e:  # other damage also ends it
            if not msgs:
                raise BagError(f"{file} is not a readable MCAP file: {e}") from e
            stopped = f"at byte {fh.tell()}: {type(e).__name__}: {e}; later data dropped"
    return dict(channels.values()), msgs, stopped


def _recover_sqlite(file: Path) -> tuple[dict[str, str], list[BagMessage], str]:
    # A killed writer leaves a hot rollback journal (or a WAL): sqlite must roll it back before
    # reading, which a read-only connection cannot do ("attempt to write a readonly
    # database"). Work on a copy so the original files stay untouched.
    with tempfile.TemporaryDirectory(prefix="hand_suite_recover_") as tmp:
        copy = Path(tmp) / file.name
        for suffix in ("", "-journal", "-wal", "-shm"):
            part = file.with_name(file.name + suffix)
            if part.exists():
                shutil.copy2(part, Path(tmp) / part.name)
        try:
            db = sqlite3.connect(copy)
            try:
                topics = {tid: (name, typ) for tid, name, typ in
                          db.execute("SELECT id, name, type FROM topics")}
                rows = db.execute(
                    "SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp")
                msgs = [BagMessage(topics[t][0], topics[t][1], int(ts), bytes(d))
                        for t, ts, d in rows if t in topics]
            finally:
                db.close()
        except sqlite3.DatabaseError as e:
            raise BagError(f"{file} is not a readable sqlite3 bag: {e}") from e
    note = ("uncommitted writes after the last flush were rolled back"
            if file.with_name(file.name + "-journal").exists()
            or file.with_name(file.name + "-wal").exists() else "")
    return dict(topics.values()), msgs, note


def _free_output(src: Path, output: str | Path | None) -> Path:
    """The output directory: ``output`` if it does not exist (never overwritten), else a
    numbered ``<src>_recovered[_N]`` that does not exist."""
    if output is not None:
        out = Path(output)
        if out.exists():
            raise BagError(f"output {out} exists; recover never overwrites or deletes a "
                           f"folder: choose another with -o, or move it away")
        if out.resolve() == src.resolve():
            raise BagError(f"output {out} is the damaged bag itself")
        return out
    out = src.with_name(src.name + "_recovered")
    n = 2
    while out.exists():
        out = src.with_name(f"{src.name}_recovered_{n}")
        n += 1
    return out


def recover_bag(path: str | Path, output: str | Path | None = None) -> RecoveryResult:
    """Rebuild a complete bag from an unfinished or damaged one (recorder killed before
    closing, or a damaged MCAP chunk).

    Reads every message that was flushed to the storage file (for MCAP: up to the first
    damaged or cut-off record; chunks are CRC-checked) and writes them, with their
    definitions, into a new bag ``output`` (default: ``<path>_recovered``, or
    ``<path>_recovered_N`` if that exists). An existing ``output`` is refused, never replaced.

    Raises:
        BagError: no storage file, nothing readable in it, or ``output`` exists.
    """
    src = Path(path)
    mcaps = sorted(src.glob("*.mcap"))
    dbs = sorted(src.glob("*.db3"))
    if not mcaps and not dbs:
        raise BagError(f"no .mcap or .db3 storage file in {src}")
    out = _free_output(src, output)
    if mcaps:
        storage, (topics, msgs, stopped) = "mcap", _recover_mcap(mcaps[0])
    else:
        storage, (topics, msgs, stopped) = "sqlite3", _recover_sqlite(dbs[0])
    writer = BagWriter(out, storage=storage)
    per_topic: dict[str, int] = {}
    try:
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)
        for m in sorted(msgs, key=lambda m: m.timestamp_ns):
            writer.write(m.topic, m.timestamp_ns, m.data)
            per_topic[m.topic] = per_topic.get(m.topic, 0) + 1
    finally:
        writer.close()
    stamps = [m.timestamp_ns for m in msgs]
    return RecoveryResult(out, len(msgs), topics, per_topic, min(stamps, default=0),
                          max(stamps, default=0), stopped)
