"""MCAP integrity and compatibility for :mod:`hand_capture.bag.bagfile`.

* :class:`CrcMcapWriter`: rosbags' MCAP writer with the CRC32s of the MCAP specification filled
  in (rosbags writes 0): each chunk's uncompressed data, the data section (DataEnd record), the
  summary section (footer).
* :func:`verify_mcap`: checks the footer, summary CRC and data-section CRC of a file and names
  the damaged part.
* :class:`McapSource`: reads MCAP files from other writers (the ``mcap`` tools) with the
  ``mcap`` library where rosbags' reader mis-reads them.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from collections.abc import Iterator
from io import BytesIO
from pathlib import Path

from rosbags.rosbag2.storage_mcap import (
    McapWriter,
    PendingChunk,
    write_channel,
    write_record,
    write_schema,
    write_string,
    write_uint16,
    write_uint32,
    write_uint64,
)
from rosbags.rosbag2.storage_mcap import decompress as _mcap_decompress

from hand_capture.errors import BagError

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_MCAP_FOOTER = 1 + 8 + 20 + 8  # opcode, length, (summary start, summary offset start, crc), magic


class _CrcFile:
    """The MCAP output file with a running CRC32 of every byte written (data section CRC)."""

    def __init__(self, fh, crc: int) -> None:
        self._fh = fh
        self.crc = crc

    def write(self, data) -> int:
        self.crc = zlib.crc32(data, self.crc)
        return self._fh.write(data)

    def tell(self) -> int:
        return self._fh.tell()

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


class CrcMcapWriter(McapWriter):
    """rosbags' MCAP writer with the CRCs the MCAP specification defines filled in: chunk
    ``uncompressed_crc``, DataEnd ``data_section_crc`` and footer ``summary_crc``. Records and
    their order are rosbags' (``close_chunk`` and ``close`` follow its code)."""

    @classmethod
    def adopt(cls, st: McapWriter) -> CrcMcapWriter:
        """Turn a freshly opened rosbags writer (header written) into this class."""
        st.bio.flush()
        st.__class__ = cls
        st.bio = _CrcFile(st.bio, zlib.crc32(st.path.read_bytes()))
        return st  # type: ignore[return-value]

    def close_chunk(self) -> None:
        raw = self.chunk.bio.getvalue()
        rec = BytesIO()
        write_uint64(rec, self.chunk.message_start_time)
        write_uint64(rec, self.chunk.message_end_time)
        write_uint64(rec, len(raw))
        write_uint32(rec, zlib.crc32(raw))
        compressed = self.compressor(raw)
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        rec.write(compressed)
        chunk_start = self.bio.tell()
        write_record(self.bio, 0x06, rec)
        chunk_end = self.bio.tell()
        offsets: list[tuple[int, int]] = []
        for cid, msgs in self.chunk.msgs.items():
            offsets.append((cid, self.bio.tell()))
            rec = BytesIO()
            write_uint16(rec, cid)
            write_uint32(rec, len(msgs) * 16)
            for ts, offset in msgs:
                write_uint64(rec, ts)
                write_uint64(rec, offset)
            write_record(self.bio, 0x07, rec)
        rec = BytesIO()
        write_uint64(rec, self.chunk.message_start_time)
        write_uint64(rec, self.chunk.message_end_time)
        write_uint64(rec, chunk_start)
        write_uint64(rec, chunk_end - chunk_start)
        write_uint32(rec, len(offsets) * 10)
        for cid, offset in offsets:
            write_uint16(rec, cid)
            write_uint64(rec, offset)
        write_uint64(rec, self.bio.tell() - chunk_end)
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        write_uint64(rec, len(raw))
        self.chunks.append(rec)
        self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

    def close(self, version: int, metadata: str) -> None:
        _ = version
        if self.chunk.bio.tell():
            self.close_chunk()
        metadata_start = self.bio.tell()
        rec = BytesIO()
        write_string(rec, "rosbag2")
        sub = BytesIO()
        write_string(sub, "serialized_metadata")
        write_string(sub, metadata)
        write_uint32(rec, sub.tell())
        rec.write(sub.getbuffer())
        write_record(self.bio, 0x0C, rec)
        metadata_end = self.bio.tell()
        rec = BytesIO()
        write_uint32(rec, self.bio.crc)  # DataEnd: CRC of everything before it
        write_record(self.bio, 0x0F, rec)
        # the summary is built in memory so its CRC covers exactly what the footer says
        base = self.bio.tell()
        summ = BytesIO()
        schema_start = base
        for schema in self.schemas:
            write_schema(summ, schema)
        channel_start = base + summ.tell()
        for channel in self.channels:
            write_channel(summ, channel, self.schemas)
        chunk_start = base + summ.tell()
        for chunk in self.chunks:
            write_record(summ, 0x08, chunk)
        metadata_index_start = base + summ.tell()
        rec = BytesIO()
        write_uint64(rec, metadata_start)
        write_uint64(rec, metadata_end - metadata_start)
        write_string(rec, "rosbag2")
        write_record(summ, 0x0D, rec)
        statistics_offset_start = base + summ.tell()
        rec = BytesIO()
        write_uint64(rec, sum(self.channel_stats.values()))
        write_uint16(rec, len(self.schemas))
        write_uint32(rec, len(self.channels))
        write_uint32(rec, 0)  # attachments
        write_uint32(rec, 1)  # metadata
        write_uint32(rec, len(self.chunks))
        write_uint64(rec, self.message_start_time)
        write_uint64(rec, self.message_end_time)
        write_uint32(rec, len(self.channel_stats) * 10)
        for cid, count in sorted(self.channel_stats.items()):
            write_uint16(rec, cid)
            write_uint64(rec, count)
        write_record(summ, 0x0B, rec)
        summary_offset_start = base + summ.tell()
        for op_, start, end in ((0x03, schema_start, channel_start),
                                (0x04, channel_start, chunk_start),
                                (0x08, chunk_start, metadata_index_start),
                                (0x0D, metadata_index_start, statistics_offset_start),
                                (0x0B, statistics_offset_start, summary_offset_start)):
            if start != end or op_ in (0x0D, 0x0B):
                rec = BytesIO()
                rec.write(bytes((op_,)))
                write_uint64(rec, start)
                write_uint64(rec, end - start)
                write_record(summ, 0x0E, rec)
        summ.write(b"\x02")  # footer: opcode, length, summary start, summary offset start
        write_uint64(summ, 20)
        write_uint64(summ, schema_start)
        write_uint64(summ, summary_offset_start)
        write_uint32(summ, zlib.crc32(summ.getbuffer()))  # summary CRC (MCAP spec)
        summ.write(_MCAP_MAGIC)
        self.bio.write(summ.getbuffer())
        self.bio.close()


def _read_at(fh, offset: int, size: int) -> bytes:
    fh.seek(offset)
    data = fh.read(size)
    if len(data) != size:
        raise ValueError(f"file ends before byte {offset + size}")
    return data


def _crc_range(fh, start: int, end: int, block: int = 1 << 20) -> int:
    crc = 0
    fh.seek(start)
    while start < end:
        data = fh.read(min(block, end - start))
        if not data:
            break
        crc = zlib.crc32(data, crc)
        start += len(data)
    return crc


def _locate_mcap_damage(fh, data_end: int) -> str:
    """Walk the data section's records to name the damaged one (after a CRC mismatch)."""
    pos, n_chunk = 8, 0
    while pos < data_end:
        head = _read_at(fh, pos, 9)
        op_, length = head[0], struct.unpack_from("<Q", head, 1)[0]
        if pos + 9 + length > data_end:
            return f"record at byte {pos} (opcode {op_:#04x}) has a damaged length {length}"
        if op_ == 0x06:
            body = _read_at(fh, pos + 9, length)
            size, crc = struct.unpack_from("<QI", body, 16)
            (clen,) = struct.unpack_from("<I", body, 28)
            comp = body[32:32 + clen].decode("utf-8", "replace")
            (dsize,) = struct.unpack_from("<Q", body, 32 + clen)
            data = body[40 + clen:40 + clen + dsize]
            try:
                _mcap_decompress(data, comp, size, crc)  # checks size and CRC
            except Exception as e:
                return f"chunk {n_chunk} at byte {pos}: {e}"
            n_chunk += 1
        pos += 9 + length
    return "a record outside the chunks (header, message index or metadata)"


def verify_mcap(file: str | Path) -> bool:
    """Check an MCAP file's footer, summary CRC and data-section CRC (the whole file is read);
    returns whether a data-section CRC was there to check.

    A CRC of 0 means "not computed" (MCAP spec; other writers and bags from before the CRCs
    were written) and is skipped; chunk CRCs are checked when chunks are read.

    Raises:
        BagError: naming the file and the damaged part (footer, summary/index, a chunk, or
            another record of the data section).
    """
    file = Path(file)
    size = file.stat().st_size
    try:
        with file.open("rb") as fh:
            if size < 8 + _MCAP_FOOTER or _read_at(fh, 0, 8) != _MCAP_MAGIC:
                raise BagError(f"corrupt bag file {file}: damaged header (MCAP magic)")
            foot = _read_at(fh, size - _MCAP_FOOTER, _MCAP_FOOTER)
            if (foot[0] != 0x02 or struct.unpack_from("<Q", foot, 1)[0] != 20
                    or foot[-8:] != _MCAP_MAGIC):
                raise BagError(f"corrupt bag file {file}: damaged footer (or truncated file)")
            summary_start, _, summary_crc = struct.unpack_from("<QQI", foot, 9)
            if summary_start == 0:
                return False  # no summary section: the reader scans the data
            if not 8 + 13 <= summary_start <= size - _MCAP_FOOTER:
                raise BagError(f"corrupt bag file {file}: damaged footer (summary offset "
                               f"{summary_start} outside the file)")
            if summary_crc and _crc_range(fh, summary_start, size - 12) != summary_crc:
                raise BagError(f"corrupt bag file {file}: summary section (index, "
                               f"statistics) CRC mismatch")
            data_end = summary_start - 13
            rec = _read_at(fh, data_end, 13)
            if rec[0] != 0x0F or struct.unpack_from("<Q", rec, 1)[0] != 4:
                raise BagError(f"corrupt bag file {file}: damaged footer or DataEnd record "
                               f"(no DataEnd before the summary at byte {summary_start})")
            (data_crc,) = struct.unpack_from("<I", rec, 9)
            if data_crc and _crc_range(fh, 0, data_end) != data_crc:
                where = _locate_mcap_damage(fh, data_end)
                raise BagError(f"corrupt bag file {file}: data section CRC mismatch: {where}")
            return bool(data_crc)
    except (OSError, ValueError, struct.error) as e:
        raise BagError(f"corrupt bag file {file}: {e}") from e


class McapSource:
    """An MCAP file read with the ``mcap`` library (the format's reference reader), for files
    that rosbags' reader mis-reads: channels only in the data section (no repeated channels in
    the summary), no statistics, no message indexes (as the ``mcap`` tools may write them).
    Offers the part of rosbags' ``Reader`` that :class:`BagReader` uses."""

    def __init__(self, file: Path) -> None:
        from mcap.reader import make_reader
        from rosbags.interfaces import (
            Connection,
            ConnectionExtRosbag2,
            MessageDefinition,
            MessageDefinitionFormat,
        )
        from rosbags.rosbag2.metadata import parse_qos

        self._fh = file.open("rb")
        self._make = make_reader
        self._stream = False  # read by scanning the records (the summary does not index them)
        reader = make_reader(self._fh, validate_crcs=True)
        schemas: dict[int, object] = {}
        channels: dict[int, object] = {}
        summary = reader.get_summary()
        if summary is not None and summary.channels:
            schemas, channels = dict(summary.schemas), dict(summary.channels)
        counts: dict[int, int] = {}
        stats = summary.statistics if summary is not None else None
        start, end, total = 2**63 - 1, 0, 0
        if stats is not None and channels:
            counts = dict(stats.channel_message_counts)
            start, end, total = stats.message_start_time, stats.message_end_time, \
                stats.message_count
        else:  # no usable summary: one scan of the records for channels, counts and times
            self._stream = True
            for schema, channel, message in self._scan():
                if schema is not None:
                    schemas[schema.id] = schema
                channels[channel.id] = channel
                counts[channel.id] = counts.get(channel.id, 0) + 1
                start, end = min(start, message.log_time), max(end, message.log_time)
                total += 1
        fmt = {"ros2msg": MessageDefinitionFormat.MSG, "ros2idl": MessageDefinitionFormat.IDL}
        self.connections = []
        for cid, ch in sorted(channels.items()):
            schema = schemas.get(ch.schema_id)
            msgdef = (MessageDefinition(fmt.get(schema.encoding, MessageDefinitionFormat.NONE),
                                        schema.data.decode("utf-8", "replace"))
                      if schema is not None else
                      MessageDefinition(MessageDefinitionFormat.NONE, ""))
            qos = parse_qos(ch.metadata.get("offered_qos_profiles", ""))
            self.connections.append(Connection(
                cid, ch.topic, schema.name if schema is not None else "", msgdef, "",
                counts.get(cid, 0), ConnectionExtRosbag2(ch.message_encoding, qos), self))
        self._by_id = {c.id: c for c in self.connections}
        self.message_count = total
        self.start_time = start if total else 2**63 - 1
        self.end_time = end + 1 if total else 0

    def _scan(self) -> Iterator[tuple[object, object, object]]:
        """(schema, channel, message) of every message, in file order (CRCs checked)."""
        from mcap.records import Channel, Message, Schema
        from mcap.stream_reader import StreamReader

        self._fh.seek(0)
        schemas: dict[int, object] = {}
        channels: dict[int, object] = {}
        for rec in StreamReader(self._fh, validate_crcs=True).records:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    raise ValueError(f"message on unknown channel {rec.channel_id}")
                yield schemas.get(ch.schema_id), ch, rec

    def messages(self, start: int | None = None) -> Iterator[tuple[object, int, bytes]]:
        if self._stream:  # unindexed: one scan, ordered in memory
            found = [(m.log_time, n, ch.id, m.data) for n, (_, ch, m) in enumerate(self._scan())
                     if start is None or m.log_time >= start]
            for ts, _, cid, data in sorted(found):
                yield self._by_id[cid], ts, data
            return
        self._fh.seek(0)
        reader = self._make(self._fh, validate_crcs=True)
        for _, channel, message in reader.iter_messages(start_time=start, log_time_order=True):
            yield self._by_id[channel.id], message.log_time, message.data

    def close(self) -> None:
        self._fh.close()


def written_by_rosbags(file: Path) -> bool:
    """Whether an MCAP file's header names rosbags as its writer (ours, or rosbags')."""
    try:
        with file.open("rb") as fh:
            head = fh.read(256)
        (n,) = struct.unpack_from("<I", head, 17)  # magic 8, opcode 1, length 8: profile
        (m,) = struct.unpack_from("<I", head, 21 + n)
        return head[25 + n:25 + n + m].startswith(b"rosbags")
    except (OSError, struct.error):
        return True  # let rosbags' reader name the problem
